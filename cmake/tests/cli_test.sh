#!/usr/bin/env bash
# ctest cli_conventions: the command line's conventions, as a user meets them.
#  - the version has one source: --version prints CMake's project version, and
#    report.json says the same;
#  - `run --help` lists every target kind, mbtls:// included;
#  - a value an option cannot take is one line, "mbconform <command>: error: ...",
#    and exit 2, as every other usage error;
#  - check-capture, serve and restore take -q;
#  - default report directories are new: two runs started in the same second
#    write to two directories, check-capture's under reports/check-capture/
#    (the README's reports/<command>/<UTC date-time>/);
#  - a clean run's terminal output ends on its verdict in words, not on the
#    table; the report's title names the model, not a vendor the manual does
#    not print (hsc60's: "(not printed in the manual) HSC60 ..." once).
# usage: cli_test.sh MBCONFORM PROJECT_VERSION SOURCE_DIR WORK_DIR
set -euo pipefail
mbc=$1 version=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work" && cd "$work"
fail() { echo "cli_test: FAIL: $*" >&2; exit 1; }

# The version.
[ "$("$mbc" --version)" = "mbconform $version" ] || fail "--version says '$("$mbc" --version)', CMake says $version"

# A bad option value: one line named by its command, exit 2.
for args in "run --device hsc60 --target ref: --map-time xyz" "fuzz --device hsc60 --target ref: --seed abc" \
            "serve --device nope --tcp 127.0.0.1:0" "spec check --no-such-option-value=1 x"; do
  rc=0; "$mbc" $args >bad.txt 2>&1 || rc=$?
  cmd="mbconform ${args%% *}"; [ "${args%% *}" = spec ] && cmd="mbconform spec check"
  [ "$rc" = 2 ] && [ "$(wc -l <bad.txt)" = 1 ] && grep -q "^$cmd: error: " bad.txt ||
    { cat bad.txt >&2; fail "'$args': exit $rc, not one '$cmd: error:' line"; }
done

# Target kinds in run --help.
"$mbc" run --help >run-help.txt
for kind in ref: tcp:// rtu-tcp:// rtu:// mbtls:// plugin:; do
  grep -qF "$kind" run-help.txt || fail "run --help does not list $kind"
done

# -q where it was refused.
pcap=$src/conformance/tests/capture/data/modbusSmall.pcap
"$mbc" check-capture "$pcap" --map 'holding=0-199' --out cap-q -q >cap-q.txt 2>&1 || [ $? = 1 ] ||
  { cat cap-q.txt >&2; fail "check-capture -q: exit $?"; }
grep -q "^reports: cap-q" cap-q.txt || { cat cap-q.txt >&2; fail "check-capture -q: no reports line"; }
! grep -qi "pass" cap-q.txt || { cat cap-q.txt >&2; fail "check-capture -q printed the summary table"; }
"$mbc" check-capture "$pcap" --map 'holding=0-199' --out cap >cap.txt 2>&1 || [ $? = 1 ] || fail "check-capture: exit $?"
[ "$(wc -l <cap.txt)" -gt "$(wc -l <cap-q.txt)" ] || fail "check-capture without -q printed no more than with it"
# SIGTERM once it listens (a slow host, e.g. under ASan, takes seconds to get there; before
# that, SIGTERM's default action ends it with 143): it ends with 0 within 10 s.
listening() {  # a TCP socket of process $1 in the LISTEN state (/proc/net/tcp: state 0A, inode)
  local inodes
  inodes=$(for fd in /proc/"$1"/fd/*; do readlink "$fd"; done 2>/dev/null | sed -n 's/^socket:\[\([0-9]*\)\]$/\1/p' | tr '\n' ' ')
  [ -n "$inodes" ] && awk -v want=" $inodes" '$4 == "0A" && index(want, " " $10 " ") { f = 1 } END { exit !f }' /proc/net/tcp /proc/net/tcp6
}
"$mbc" serve --device modbus-standard --tcp 127.0.0.1:0 -q >serve-q.txt 2>&1 &
serve=$!
for _ in $(seq 300); do listening "$serve" && break; sleep 0.1; done
listening "$serve" || { kill -9 "$serve"; cat serve-q.txt >&2; fail "serve -q: not listening after 30 s"; }
kill -TERM "$serve"
for _ in $(seq 100); do kill -0 "$serve" 2>/dev/null || break; sleep 0.1; done
kill -0 "$serve" 2>/dev/null && { kill -9 "$serve"; fail "serve -q: still running 10 s after SIGTERM"; }
rc=0; wait "$serve" || rc=$?
[ "$rc" = 0 ] || { cat serve-q.txt >&2; fail "serve -q: exit $rc"; }
! grep -q listening serve-q.txt || fail "serve -q printed its listening lines"
rc=0; "$mbc" restore -q no-such-journal.txt >restore.txt 2>&1 || rc=$?
[ "$rc" = 2 ] && grep -q "no-such-journal.txt" restore.txt || { cat restore.txt >&2; fail "restore -q: exit $rc"; }
grep -q "unknown option" restore.txt && fail "restore refused -q"

# Two runs started together write to two new directories, reports/run/<UTC date-time>[-N].
for i in 1 2 3; do
  "$mbc" run --target ref:modbus-standard --filter 'fc03/quantity-1' -q >"run$i.txt" 2>&1 &
done
wait
dirs=$(find reports/run -mindepth 1 -maxdepth 1 -type d | sort)
[ "$(wc -l <<<"$dirs")" = 3 ] || { cat run*.txt >&2; fail "three runs wrote into $(wc -l <<<"$dirs") directories: $dirs"; }
for d in $dirs; do
  [[ $(basename "$d") =~ ^[0-9]{8}T[0-9]{6}Z(-[0-9]+)?$ ]] || fail "$d is not reports/run/<UTC date-time>[-N]"
  [ -s "$d/report.json" ] || fail "$d has no report.json"
  grep -q "\"mbconform $version\"" "$d/report.json" || fail "$d/report.json does not carry the version mbconform $version"
done
for i in 1 2 3; do grep -q "^reports: reports/run/" "run$i.txt" || fail "run $i did not print its directory"; done
[ "$(sed -n 's/^reports: //p' run*.txt | sort -u | wc -l)" = 3 ] || fail "two runs printed the same directory"

# check-capture's default directory is named like every other command's.
"$mbc" check-capture "$pcap" --map 'holding=0-199' -q >cap-default.txt 2>&1 || [ $? = 1 ] || fail "check-capture: exit $?"
grep -Eq "^reports: reports/check-capture/[0-9]{8}T[0-9]{6}Z(-[0-9]+)?$" cap-default.txt ||
  { cat cap-default.txt >&2; fail "check-capture's default directory is not reports/check-capture/<UTC date-time>"; }
[ ! -e reports/runs ] || fail "something still writes reports/runs/"
# A clean run: the last line of its terminal output is the verdict; the title shows the model.
"$mbc" run --target ref:hsc60 --out clean >clean.txt 2>clean.err || { cat clean.txt clean.err >&2; fail "run ref:hsc60: exit $?"; }
last=$(grep -v '^[[:space:]]*$' clean.txt | tail -1)
[[ $last == "PASS: "* ]] || { cat clean.txt >&2; fail "a clean run's terminal output ends on '$last', not on the verdict PASS"; }
title=$(grep -o '<section class=device-summary data-device="hsc60"><h2>[^<]*' clean/report.html | sed 's/.*<h2>//')
[[ $title == *HSC60* ]] || fail "the report's title '$title' does not name the model HSC60"
[[ $title != *"not printed"* ]] || fail "the report's title '$title' names a vendor the manual does not print"
echo "cli_test: ok"
