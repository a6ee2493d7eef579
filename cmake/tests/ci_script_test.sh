#!/usr/bin/env bash
# ctest ci_script_*: docs/ci/mbconform-ci.sh, the script the documented
# GitHub workflow calls, run here the same way. mbpoll (a real third-party
# master) stands in for the library's tests; the client step runs through
# the libmodbus adapter when this build has `mbconform client`.
#   pass         the library's tests pass, one client scenario passes
#   fail         the library's tests fail: junit.xml says so, with their output
#   client-fail  libmodbus's known deviation (client/reply/trailing-bytes) fails
#                the client step: junit.xml names that case
#   quirks       the same, with MBCONFORM_QUIRKS=libmodbus-tcp: green
# usage: ci_script_test.sh pass|fail|client-fail|quirks MBCONFORM SOURCE_DIR WORK_DIR
set -euo pipefail
mode=$1 mbc=$2 src=$3 work=$4
rm -rf "$work" && mkdir -p "$work"
fail() { echo "ci_script_test: FAIL: $*" >&2; exit 1; }

export MBCONFORM=$mbc OUT=$work/results
if [ "$mode" != fail ]; then
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
  case $mode in
    client-fail) MBCONFORM_CLIENT_ARGS="--filter client/reply/trailing-bytes" ;;
    quirks) MBCONFORM_CLIENT_ARGS="--filter client/reply/trailing-bytes" MBCONFORM_QUIRKS=libmodbus-tcp ;;
  esac
  export MBCONFORM_QUIRKS
elif [ "$mode" = client-fail ] || [ "$mode" = quirks ]; then
  fail "this build has no client command or no libmodbus adapter"
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
failure = {c.get("name"): c.find("failure") for c in suite.iter("testcase")}
print(cases)
steps = {"serve reference devices", "library tests", "client conformance"}
named = {"client: client/reply/trailing-bytes"} if mode == "client-fail" else set()
assert set(cases) == steps | named, cases
assert cases["serve reference devices"] == "passed"
assert cases["library tests"] == ("failed" if mode == "fail" else "passed")
if mode == "fail":  # the failure carries the library tests' own output (mbpoll's)
    assert (failure["library tests"].text or "").strip(), "the library tests' failure carries no output"
if mode == "client-fail":
    assert cases["client conformance"] == "failed"
    assert "client/reply/trailing-bytes" in failure["client conformance"].get("message"), failure["client conformance"].get("message")
    assert cases["client: client/reply/trailing-bytes"] == "failed"
    assert failure["client: client/reply/trailing-bytes"].get("message"), "the case's failure has no reason"
if mode == "quirks":
    assert cases["client conformance"] == "passed", cases
assert (rc != 0) == any(v == "failed" for v in cases.values()), (rc, cases)
assert int(suite.get("failures")) == sum(v == "failed" for v in cases.values())
PY
grep -q "mbconform-ci: skipped the client conformance run: \|mbconform-ci: client conformance" "$work/log.txt" ||
  fail "the log does not say what happened to the client step"
[ "$mode" = fail ] || [ "$mode" = client-fail ] && [ "$rc" = 0 ] && fail "a failing step did not fail the script"
[ "$mode" = quirks ] && [ "$rc" != 0 ] && fail "the declared deviations did not make the script pass"
echo "ci_script_test: ok ($mode, exit $rc)"
