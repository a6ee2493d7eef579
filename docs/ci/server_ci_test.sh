#!/usr/bin/env bash
# ctest ci_server_script_*: docs/ci/mbconform-server-ci.sh, the server
# library's recipe, run the way a library's CI runs it. `mbconform serve`
# stands in for the library's example server (SERVER_CMD).
#   pass      the reference device: exit 0, junit.xml without a failure
#   fail      the same with --fault wrong-exception-code (every exception code
#             off by one): exit 1, junit.xml counts failures
#   no-start  a server command that exits at once: exit 2, one line naming it
# usage: server_ci_test.sh pass|fail|no-start MBCONFORM WORK_DIR
set -euo pipefail
mode=$1 mbc=$2 work=$3
here=$(cd "$(dirname "$0")" && pwd)
rm -rf "$work" && mkdir -p "$work"
fail() { echo "server_ci_test: FAIL: $*" >&2; exit 1; }
export MBCONFORM=$mbc OUT=$work/results
case $mode in
  pass) export SERVER_CMD="'$mbc' serve --device modbus-standard --tcp 127.0.0.1:\$MBCONFORM_PORT" ;;
  fail) export SERVER_CMD="'$mbc' serve --device modbus-standard --fault wrong-exception-code --tcp 127.0.0.1:\$MBCONFORM_PORT" ;;
  no-start) export SERVER_CMD="echo no such server >&2; exit 3" ;;
esac
rc=0
"$here/mbconform-server-ci.sh" >"$work/log.txt" 2>&1 || rc=$?
tail -5 "$work/log.txt"
case $mode in
  pass) [ "$rc" = 0 ] || fail "the reference device: exit $rc, not 0" ;;
  fail) [ "$rc" = 1 ] || fail "a broken server: exit $rc, not 1" ;;
  no-start)
    [ "$rc" = 2 ] || fail "a server that never listened: exit $rc, not 2"
    grep -q "the server exited before it listened" "$work/log.txt" || fail "no line says the server did not start"
    echo "server_ci_test: ok ($mode, exit $rc)"; exit 0 ;;
esac
[ -s "$OUT/junit.xml" ] || fail "no junit.xml"
python3 - "$OUT/junit.xml" "$mode" <<'PY' || fail "junit.xml does not match the run"
import sys, xml.etree.ElementTree as ET
root = ET.parse(sys.argv[1]).getroot()
cases = list(root.iter("testcase"))
failed = [c.get("name") for c in cases if c.find("failure") is not None]
print(len(cases), "cases,", len(failed), "failed", failed[:3])
assert len(cases) > 100, len(cases)
assert (sys.argv[2] == "fail") == bool(failed), failed[:5]
PY
echo "server_ci_test: ok ($mode, exit $rc)"
