#!/usr/bin/env bash
# CI for a Modbus master (driver) library against mbconform's reference devices.
# The GitHub Actions workflow beside this file only calls this script, and
# mbconform's own ctest (ci_script_*) runs the same script.
#
#  1. serves the reference devices (`mbconform serve`) on Modbus TCP and on a pty;
#  2. runs the library's own tests against them (LIBRARY_TEST_CMD, with the
#     endpoints in the environment, below);
#  3. runs the client conformance suite (`mbconform client`) through the
#     library's adapter (MBCONFORM_ADAPTER), when this mbconform has the
#     command and an adapter is given; otherwise the step is reported skipped;
#  4. writes $OUT/junit.xml: one test case per step, a failed step's message
#     naming what failed (the client run's failing cases by id, each also a
#     test case of its own; the library tests' last output lines in the
#     failure's text); the client run's every case is in $OUT/client/junit.xml.
#     Exits 1 if a step failed.
#
# Environment (all optional but LIBRARY_TEST_CMD):
#   LIBRARY_TEST_CMD    the library's test command, run with `sh -c`
#   MBCONFORM           the mbconform executable           (default: mbconform on PATH)
#   MBCONFORM_DEVICES   devices to serve, ID@SLAVE ...      (default: "modbus-standard@1 hsc60@2")
#   MBCONFORM_ADAPTER   the library's adapter command line for `mbconform client`
#   MBCONFORM_CLIENT_ARGS  extra arguments for `mbconform client`: --quirks NAME declares the
#                       library's known deviations, as measured and installed with mbconform
#                       (libmodbus-tcp, libmodbus-pty, pymodbus-tcp, ...: ls /usr/share/mbconform/deviations),
#                       or --quirks FILE your own; --filter ID
#   MBCONFORM_QUIRKS    the same as MBCONFORM_CLIENT_ARGS="--quirks $MBCONFORM_QUIRKS"
#   OUT                 results directory                   (default: mbconform-results)
# The library's tests see:
#   MBCONFORM_TCP_HOST, MBCONFORM_TCP_PORT   Modbus TCP endpoint
#   MBCONFORM_PTY                            RTU on a pty (a symlink to it)
#   MBCONFORM_DEVICES                        the ID@SLAVE list served
set -uo pipefail
: "${LIBRARY_TEST_CMD:?set LIBRARY_TEST_CMD to the test command of the library}"
MBCONFORM=${MBCONFORM:-mbconform}
MBCONFORM_DEVICES=${MBCONFORM_DEVICES:-modbus-standard@1 hsc60@2}
OUT=${OUT:-mbconform-results}
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
cases=()   # "name|status|seconds|file whose last lines go into the failure's text|message" (the message last: it may hold a |)
serve_pid=""
cleanup() { [ -n "$serve_pid" ] && kill "$serve_pid" 2>/dev/null; wait 2>/dev/null; }
trap cleanup EXIT

xml() { sed -e 's/&/\&amp;/g' -e 's/</\&lt;/g' -e 's/>/\&gt;/g' -e 's/"/\&quot;/g'; }
write_junit() {
  local failures=0 skipped=0 c name status secs msg log
  for c in "${cases[@]}"; do
    IFS='|' read -r name status secs log msg <<<"$c"
    [ "$status" = failed ] && failures=$((failures + 1))
    [ "$status" = skipped ] && skipped=$((skipped + 1))
  done
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    echo "<testsuites><testsuite name=\"mbconform-ci\" tests=\"${#cases[@]}\" failures=\"$failures\" skipped=\"$skipped\">"
    for c in "${cases[@]}"; do
      IFS='|' read -r name status secs log msg <<<"$c"
      echo "  <testcase classname=\"mbconform-ci\" name=\"$(xml <<<"$name")\" time=\"$secs\">"
      if [ "$status" = failed ]; then
        echo -n "    <failure message=\"$(xml <<<"$msg")\">"
        [ -n "$log" ] && [ -s "$log" ] && tail -n 40 "$log" | xml
        echo "</failure>"
      fi
      [ "$status" = skipped ] && echo "    <skipped message=\"$(xml <<<"$msg")\"/>"
      echo "  </testcase>"
    done
    echo "</testsuite></testsuites>"
  } >"$OUT/junit.xml"
  return "$failures"
}
step() {  # step NAME LOG COMMAND...: run (output also to LOG), record passed/failed with its exit code
  local name=$1 log=$2 start rc
  shift 2
  start=$(date +%s)
  echo "mbconform-ci: $name"
  "$@" 2>&1 | tee "$log"
  rc=${PIPESTATUS[0]}
  if [ "$rc" = 0 ]; then cases+=("$name|passed|$(($(date +%s) - start))||")
  else cases+=("$name|failed|$(($(date +%s) - start))|$log|exit $rc"); fi
  return "$rc"
}
# The failing cases of a junit.xml mbconform wrote, "ID|MESSAGE" one a line
# (entities decoded; `xml` encodes them again).
failing_cases() {
  [ -s "$1" ] || return 0
  awk '/<testcase /{ name = ""; if (match($0, /name="[^"]*"/)) name = substr($0, RSTART + 6, RLENGTH - 7) }
       /<(failure|error)[ >]/{ m = ""; if (match($0, /message="[^"]*"/)) m = substr($0, RSTART + 9, RLENGTH - 10); print name "|" m }' "$1" |
    sed -e 's/&quot;/"/g' -e 's/&lt;/</g' -e 's/&gt;/>/g' -e "s/&apos;/'/g" -e 's/&#10;/ /g' -e 's/&amp;/\&/g'
}

# 1. The reference devices.
serve_args=()
for d in $MBCONFORM_DEVICES; do serve_args+=(--device "$d"); done
MBCONFORM_PTY=$OUT/ttyMB0
"$MBCONFORM" serve "${serve_args[@]}" --tcp 127.0.0.1:0 --pty "$MBCONFORM_PTY" >"$OUT/serve.log" 2>&1 &
serve_pid=$!
for _ in $(seq 100); do
  grep -q '^listening pty' "$OUT/serve.log" && break
  kill -0 "$serve_pid" 2>/dev/null || break
  sleep 0.1
done
MBCONFORM_TCP_PORT=$(sed -n 's/^listening tcp .*:\([0-9]*\)$/\1/p' "$OUT/serve.log")
if [ -z "$MBCONFORM_TCP_PORT" ]; then
  cat "$OUT/serve.log" >&2
  cases+=("serve reference devices|failed|0|$OUT/serve.log|mbconform serve did not start")
  write_junit
  exit 1
fi
cases+=("serve reference devices|passed|0||")
export MBCONFORM_TCP_HOST=127.0.0.1 MBCONFORM_TCP_PORT MBCONFORM_PTY MBCONFORM_DEVICES
echo "mbconform-ci: serving $MBCONFORM_DEVICES on tcp 127.0.0.1:$MBCONFORM_TCP_PORT and pty $MBCONFORM_PTY"

# 2. The library's own tests, against them.
step "library tests" "$OUT/library-tests.log" sh -c "$LIBRARY_TEST_CMD"

# 3. The client conformance run through the library's adapter.
commands=$("$MBCONFORM" --help 2>/dev/null || true)
if ! grep -qE '^ +client( |$)' <<<"$commands"; then
  echo "mbconform-ci: skipped the client conformance run: this mbconform has no 'client' command"
  cases+=("client conformance|skipped|0||this mbconform has no client command")
elif [ -z "${MBCONFORM_ADAPTER:-}" ]; then
  echo "mbconform-ci: skipped the client conformance run: MBCONFORM_ADAPTER is not set"
  cases+=("client conformance|skipped|0||MBCONFORM_ADAPTER is not set")
else
  client_args=${MBCONFORM_CLIENT_ARGS:-}
  [ -n "${MBCONFORM_QUIRKS:-}" ] && client_args="$client_args --quirks $MBCONFORM_QUIRKS"
  # shellcheck disable=SC2086  # client_args is a list of words
  if ! step "client conformance" "$OUT/client.log" "$MBCONFORM" client --adapter "$MBCONFORM_ADAPTER" --out "$OUT/client" \
      --quiet $client_args; then
    # Name the failing cases: in the step's message, and each as a test case of its own.
    failed_ids=""
    while IFS='|' read -r id msg; do
      [ -n "$id" ] || continue
      failed_ids="${failed_ids:+$failed_ids, }$id"
      cases+=("client: $id|failed|0||$msg")
    done < <(failing_cases "$OUT/client/junit.xml")
    for i in "${!cases[@]}"; do
      IFS='|' read -r name status secs log msg <<<"${cases[$i]}"
      if [ "$name" = "client conformance" ] && [ -n "$failed_ids" ]; then
        cases[$i]="$name|$status|$secs|$log|$msg: failed: $failed_ids"
      fi
    done
  fi
fi

write_junit
failed=$?
echo "mbconform-ci: $OUT/junit.xml: ${#cases[@]} steps, $failed failed"
[ "$failed" = 0 ]
