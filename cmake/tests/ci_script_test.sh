#!/usr/bin/env bash
# ctest ci_script_*: docs/ci/mbconform-ci.sh, the script the documented
# GitHub workflow calls, run here the same way. mbpoll (a real third-party
# master) stands in for the library's tests; the client step runs through
# the libmodbus adapter when this build has `mbconform client`.
# usage: ci_script_test.sh pass|fail MBCONFORM SOURCE_DIR WORK_DIR
set -euo pipefail
mode=$1 mbc=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
fail() { echo "ci_script_test: FAIL: $*" >&2; exit 1; }

export MBCONFORM=$mbc OUT=$work/results
if [ "$mode" = pass ]; then
  # FC 03 from modbus-standard@1 over TCP, and from the pty (19200 8E1, its defaults).
  export LIBRARY_TEST_CMD='mbpoll -m tcp -p "$MBCONFORM_TCP_PORT" -a 1 -t 4 -r 1 -c 2 -1 "$MBCONFORM_TCP_HOST" &&
    mbpoll -m rtu -b 19200 -P even -a 1 -t 4 -r 1 -c 2 -1 "$MBCONFORM_PTY"'
else
  export LIBRARY_TEST_CMD='mbpoll -m tcp -p "$MBCONFORM_TCP_PORT" -a 1 -t 4 -r 1 -c 2 -1 "$MBCONFORM_TCP_HOST" && false'
fi
adapter=$(dirname "$mbc")/libmodbus_adapter
commands=$("$mbc" --help 2>/dev/null || true)
if grep -qE '^ +client( |$)' <<<"$commands" && [ -x "$adapter" ]; then
  export MBCONFORM_ADAPTER=$adapter MBCONFORM_CLIENT_ARGS="--filter client/request/transaction-ids"
fi

rc=0
"$src/docs/ci/mbconform-ci.sh" >"$work/log.txt" 2>&1 || rc=$?
cat "$work/log.txt"
[ -s "$OUT/junit.xml" ] || fail "no junit.xml"
python3 - "$OUT/junit.xml" "$mode" "$rc" <<'PY' || fail "junit.xml does not match the run"
import sys, xml.etree.ElementTree as ET
suite = ET.parse(sys.argv[1]).getroot().find("testsuite")
mode, rc = sys.argv[2], int(sys.argv[3])
cases = {c.get("name"): ("failed" if c.find("failure") is not None else "skipped" if c.find("skipped") is not None
                          else "passed") for c in suite.iter("testcase")}
print(cases)
assert set(cases) == {"serve reference devices", "library tests", "client conformance"}, cases
assert cases["serve reference devices"] == "passed"
assert cases["library tests"] == ("passed" if mode == "pass" else "failed")
assert (rc != 0) == any(v == "failed" for v in cases.values()), (rc, cases)
assert int(suite.get("failures")) == sum(v == "failed" for v in cases.values())
PY
grep -q "mbconform-ci: skipped the client conformance run: \|mbconform-ci: client conformance" "$work/log.txt" ||
  fail "the log does not say what happened to the client step"
[ "$mode" = fail ] && [ "$rc" = 0 ] && fail "a failing library test did not fail the script"
echo "ci_script_test: ok ($mode, exit $rc)"
