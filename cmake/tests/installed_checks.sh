#!/usr/bin/env bash
# What an installed mbconform must do from where it landed, whether from
# `cmake --install` (install_test.sh) or from the .deb (deb_test.sh):
#   - its binary is stripped and says the project's version;
#   - its man page opens with man(1), and its bash completion completes;
#   - a served qualification: `mbconform serve` a reference drive on Modbus
#     TCP, `mbconform run` against it over the socket, every MUST passes;
#   - `--quirks NAME` finds the libraries' declared deviations it installed:
#     the libmodbus client adapter fails client/reply/trailing-bytes without
#     them and passes with `--quirks libmodbus-tcp` (the CI recipe's case);
#   - a name it does not have is one line listing the ones it has, exit 2.
# usage: installed_checks.sh PREFIX VERSION WORK_DIR   (PREFIX/bin/mbconform)
set -euo pipefail
prefix=$1 version=$2 work=$3
mkdir -p "$work" && cd "$work"
unset MBCONFORM_SPEC_DIR
mbc=$prefix/bin/mbconform
serve_pid=""
cleanup() { [ -n "$serve_pid" ] && kill "$serve_pid" 2>/dev/null; wait 2>/dev/null || true; }
trap cleanup EXIT
fail() { echo "installed_checks ($prefix): FAIL: $*" >&2; exit 1; }

[ "$("$mbc" --version)" = "mbconform $version" ] || fail "--version: '$("$mbc" --version)', expected 'mbconform $version'"
if readelf -S "$mbc" | grep -qE '\.(symtab|debug_info)'; then fail "$mbc is not stripped"; fi

# The man page and the completion.
man_page=$prefix/share/man/man1/mbconform.1
[ -s "$man_page" ] || fail "no man page at $man_page"
MANWIDTH=120 MANPAGER=cat LANG=C.UTF-8 man -l "$man_page" >man.txt 2>man.err || { cat man.err >&2; fail "man -l: exit $?"; }
grep -q "^MBCONFORM RUN" man.txt && grep -q "EXIT STATUS" man.txt || fail "the man page has no 'MBCONFORM RUN' or 'EXIT STATUS'"
completion=$prefix/share/bash-completion/completions/mbconform
[ -s "$completion" ] || fail "no bash completion at $completion"
got=$(bash --norc --noprofile -c "source '$completion'; COMP_WORDS=(mbconform run --quir); COMP_CWORD=2; _mbconform; echo \"\${COMPREPLY[*]}\"")
[ "$got" = "--quirks" ] || fail "the installed completion completes 'run --quir' to '$got'"

# A served qualification, over a socket, from the installed tree.
"$mbc" serve --device hsc60@1 --tcp 127.0.0.1:0 >serve.txt 2>&1 &
serve_pid=$!
for _ in $(seq 100); do grep -q '^listening tcp' serve.txt && break; sleep 0.1; done
port=$(sed -n 's/^listening tcp .*:\([0-9]*\)$/\1/p' serve.txt)
[ -n "$port" ] || { cat serve.txt >&2; fail "serve printed no listening line"; }
rc=0
"$mbc" run --target "tcp://127.0.0.1:$port?unit=1" --device hsc60 --out qualification -q >run.txt 2>&1 || rc=$?
[ "$rc" = 0 ] || { tail -30 run.txt >&2; fail "the served qualification: exit $rc"; }
python3 - qualification/report.json <<'PY' || fail "the served qualification's report.json"
import json, sys
r = json.load(open(sys.argv[1]))
text = json.dumps(r)
assert "tcp://127.0.0.1:" in text, "no tcp target in the report"
assert text.count('"pass"') >= 50, "fewer than 50 passing cases"
PY
kill "$serve_pid"; wait "$serve_pid" 2>/dev/null || true; serve_pid=""

# The declared deviations, by name.
adapter=$prefix/share/mbconform/client/adapters/bin/libmodbus_adapter
[ -f "$prefix/share/mbconform/deviations/libmodbus-tcp.yaml" ] || fail "deviations/libmodbus-tcp.yaml is not installed"
[ -f "$prefix/share/mbconform/quirks/jsmodbus.yaml" ] || fail "quirks/jsmodbus.yaml is not installed"
[ -x "$adapter" ] || echo "installed_checks: no libmodbus adapter installed: the client quirks check is skipped"
if [ -x "$adapter" ]; then
  rc=0; "$mbc" client --adapter "$adapter" --filter client/reply/trailing-bytes --out plain -q >plain.txt 2>&1 || rc=$?
  [ "$rc" = 1 ] || { cat plain.txt >&2; fail "libmodbus without its quirks: exit $rc, expected 1 (it fails trailing-bytes)"; }
  rc=0; "$mbc" client --adapter "$adapter" --filter client/reply/trailing-bytes --quirks libmodbus-tcp --out declared -q \
    >declared.txt 2>&1 || rc=$?
  [ "$rc" = 0 ] || { cat declared.txt >&2; fail "libmodbus with --quirks libmodbus-tcp: exit $rc, expected 0"; }
  grep -q "$prefix/share/mbconform/deviations/libmodbus-tcp.yaml" declared/report.json ||
    grep -q "trailing-bytes" declared/report.json || fail "the declared quirk is not in the report"
fi
rc=0; "$mbc" run --target ref:modbus-standard --quirks jsmodbus --filter fc03/quantity-1 --out js -q >js.txt 2>&1 || rc=$?
[ "$rc" = 0 ] || { cat js.txt >&2; fail "run --quirks jsmodbus: exit $rc"; }
rc=0; "$mbc" run --target ref:modbus-standard --quirks libmodbus-tpc --out none -q >none.txt 2>&1 || rc=$?
[ "$rc" = 2 ] && [ "$(wc -l <none.txt)" = 1 ] && grep -q "libmodbus-tcp" none.txt ||
  { cat none.txt >&2; fail "--quirks with an unknown name: exit $rc, expected 2 and one line naming the known ones"; }
echo "installed_checks: ok ($prefix: version, stripped, man page, completion, served qualification, quirks by name)"
