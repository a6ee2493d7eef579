#!/usr/bin/env bash
# ctest install_from_prefix: `cmake --install` into a scratch prefix outside
# the source tree, then use the installed mbconform from there: its specs are
# found relative to the executable, --spec-dir and $MBCONFORM_SPEC_DIR add a
# user's own, a duplicate id names both files, and `spec check`, `run` and
# `serve` work; then installed_checks.sh (stripped, version, man page,
# completion, a served qualification, quirks by name).
# usage: install_test.sh BUILD_DIR SOURCE_DIR VERSION
set -euo pipefail
build=$1 src=$2 version=$3
scratch=$(mktemp -d /tmp/mbconform-install-test.XXXXXX)
serve_pid=""
cleanup() {
  [ -n "$serve_pid" ] && kill "$serve_pid" 2>/dev/null || true
  rm -rf "$scratch"
}
trap cleanup EXIT
fail() { echo "install_test: FAIL: $*" >&2; exit 1; }

prefix=$scratch/prefix
cmake --install "$build" --prefix "$prefix" >/dev/null
cd "$scratch"  # nothing below may depend on the working directory
unset MBCONFORM_SPEC_DIR
mbc=$prefix/bin/mbconform

for f in bin/mbconform share/mbconform/schema/device.schema.json include/mbconform_plugin.h \
         share/mbconform/plugin/example/libmodbus_slave_plugin.c share/doc/mbconform/LICENSE share/doc/mbconform/copyright; do
  [ -e "$prefix/$f" ] || fail "$f is not installed"
done
if [ -e "$build/bin/mbconform-plugin-host" ]; then
  [ -x "$prefix/bin/mbconform-plugin-host" ] || fail "the plugin host is built but not installed"
fi
if [ -d "$src/conformance/peers/adapters" ]; then
  [ -d "$prefix/share/mbconform/client/adapters" ] || fail "the client adapters are not installed"
fi
if [ -e "$src/conformance/peers/package-lock.json" ]; then
  [ -e "$prefix/share/mbconform/client/peers/package-lock.json" ] || fail "the npm lock file is not installed"
fi

# Every spec of the source tree, found in the prefix, marked as installed.
"$mbc" spec list >list.txt || fail "spec list: exit $?"
n=0
for yaml in "$src"/spec/devices/*.yaml; do
  id=$(basename "$yaml" .yaml)
  want="$prefix/share/mbconform/devices/$id.yaml"
  grep -Eq "^$id +$want +\(installed\)$" list.txt || { cat list.txt >&2; fail "spec list: no '$id $want (installed)'"; }
  n=$((n + 1))
done
[ "$(wc -l <list.txt)" = "$n" ] || { cat list.txt >&2; fail "spec list: expected $n lines"; }
"$mbc" spec check --quiet || fail "spec check of the installed specs: exit $?"

# A user's own drive, from --spec-dir (before or after the subcommand) and
# from $MBCONFORM_SPEC_DIR; the built-in specs stay listed.
mkdir -p mine dup
sed 's/^  id: modbus-standard$/  id: my-drive/' "$src/spec/devices/modbus-standard.yaml" >mine/my-drive.yaml
"$mbc" spec list --spec-dir mine >list.txt || fail "spec list --spec-dir: exit $?"
grep -Eq '^my-drive +mine/my-drive.yaml +\(--spec-dir\)$' list.txt || { cat list.txt >&2; fail "--spec-dir: my-drive not listed"; }
grep -q '^hsc60 .*(installed)$' list.txt || fail "--spec-dir hid the installed specs"
MBCONFORM_SPEC_DIR=$scratch/mine "$mbc" spec list >list.txt || fail "spec list with MBCONFORM_SPEC_DIR: exit $?"
grep -Eq "^my-drive +$scratch/mine/my-drive.yaml +\(MBCONFORM_SPEC_DIR\)$" list.txt || { cat list.txt >&2; fail "MBCONFORM_SPEC_DIR: my-drive not listed"; }
"$mbc" --spec-dir mine spec check --quiet || fail "spec check with --spec-dir: exit $?"
"$mbc" --spec-dir mine spec dump my-drive >/dev/null || fail "spec dump my-drive: exit $?"

# Two specs with one id: an error that names both files.
cp "$src/spec/devices/hsc60.yaml" dup/
rc=0; "$mbc" spec list --spec-dir dup >/dev/null 2>err.txt || rc=$?
[ "$rc" = 2 ] || fail "duplicate id: exit $rc, expected 2"
grep -q "dup/hsc60.yaml" err.txt && grep -q "$prefix/share/mbconform/devices/hsc60.yaml" err.txt ||
  { cat err.txt >&2; fail "duplicate id: the error does not name both files"; }

# run: a device's conformance cases in-process, reports written.
"$mbc" run --target ref:hsc60 --device hsc60 --out run --quiet >run.txt 2>&1 || { cat run.txt >&2; fail "run: exit $?"; }
[ -s run/junit.xml ] && [ -s run/report.json ] || fail "run wrote no reports"

# serve: Modbus TCP on a free port; one FC 03 request over a plain socket.
"$mbc" serve --device modbus-standard --tcp 0 >serve.txt 2>&1 &
serve_pid=$!
for _ in $(seq 100); do grep -q '^listening tcp' serve.txt && break; sleep 0.1; done
port=$(sed -n 's/^listening tcp .*:\([0-9]*\)$/\1/p' serve.txt)
[ -n "$port" ] || { cat serve.txt >&2; fail "serve printed no listening line"; }
python3 - "$port" <<'PY' || fail "serve did not answer FC 03"
import socket, struct, sys
s = socket.create_connection(("127.0.0.1", int(sys.argv[1])), timeout=5)
s.sendall(struct.pack(">HHHBBHH", 7, 0, 6, 1, 3, 0, 1))  # MBAP + read 1 holding register at 0
reply = s.recv(64)
tid, proto, length, unit, fc, count = struct.unpack(">HHHBBB", reply[:9])
sys.exit(0 if (tid, proto, unit, fc, count, len(reply)) == (7, 0, 1, 3, 2, 11) else 1)
PY
kill "$serve_pid"; wait "$serve_pid" 2>/dev/null || true; serve_pid=""
"$src/cmake/tests/installed_checks.sh" "$prefix" "$version" "$scratch/checks" || fail "installed_checks.sh"
echo "install_test: ok ($n specs installed in $prefix, run and serve from $scratch)"
