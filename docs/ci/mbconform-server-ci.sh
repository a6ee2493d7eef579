#!/usr/bin/env bash
# mbconform-server-ci.sh: a Modbus server (slave) library's CI step. Starts
# the library's example server, runs mbconform's conformance cases against it
# over Modbus TCP, and leaves the JUnit file for the CI to upload. The exit
# code is mbconform's: 0 PASS, 1 a failed MUST, 2 the run could not be made
# (the server did not start, a lost target), 3 a MUST case skipped (the run is
# not complete: --require-complete).
#
# Variables:
#   SERVER_CMD        (required) starts the library's server in the foreground,
#                     listening on 127.0.0.1:$MBCONFORM_PORT (exported here)
#   MBCONFORM         the mbconform binary (default: mbconform on PATH)
#   OUT               where the report goes (default: mbconform-results);
#                     $OUT/junit.xml is mbconform's JUnit, one test case per case
#   MBCONFORM_DEVICE  the spec the server implements (default: modbus-standard,
#                     the Modbus application protocol only)
#   MBCONFORM_MAP     the server's data map (default: auto, probed with reads)
#   MBCONFORM_UNIT    the unit id it answers (default: 1)
#   MBCONFORM_QUIRKS  a quirks file or a declared library's name: known
#                     deviations reported apart, not failed
#   MBCONFORM_RUN_ARGS  more `mbconform run` options (e.g. --filter, --deadline 10m)
#
# A library's example server is no live drive: the run opts in to writes to
# the probed map and to function codes whose effect the spec does not state
# (--allow-writes, --allow-disruptive), so that every MUST case runs, and
# --require-complete makes a run that still skipped one exit 3, not 0.
set -uo pipefail
: "${SERVER_CMD:?SERVER_CMD: the command that starts the server under test}"
MBCONFORM=${MBCONFORM:-mbconform}
OUT=${OUT:-mbconform-results}
MBCONFORM_DEVICE=${MBCONFORM_DEVICE:-modbus-standard}
MBCONFORM_MAP=${MBCONFORM_MAP:-auto}
MBCONFORM_UNIT=${MBCONFORM_UNIT:-1}
mkdir -p "$OUT"

MBCONFORM_PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export MBCONFORM_PORT
bash -c "$SERVER_CMD" >"$OUT/server.log" 2>&1 &
server=$!
trap 'kill "$server" 2>/dev/null; wait "$server" 2>/dev/null' EXIT

# Wait up to 30 s for the port; a server that exits or never listens is exit 2.
for _ in $(seq 300); do
  if ! kill -0 "$server" 2>/dev/null; then
    echo "mbconform-server-ci: the server exited before it listened on 127.0.0.1:$MBCONFORM_PORT ($OUT/server.log)" >&2
    exit 2
  fi
  python3 -c 'import socket,sys; socket.create_connection(("127.0.0.1", int(sys.argv[1])), 1).close()' "$MBCONFORM_PORT" 2>/dev/null && break
  sleep 0.1
done

args=(run --target "tcp://127.0.0.1:$MBCONFORM_PORT?unit=$MBCONFORM_UNIT" --device "$MBCONFORM_DEVICE"
      --map "$MBCONFORM_MAP" --allow-writes --allow-disruptive --require-complete --out "$OUT" -q)
[ -n "${MBCONFORM_QUIRKS:-}" ] && args+=(--quirks "$MBCONFORM_QUIRKS")
# shellcheck disable=SC2206  # MBCONFORM_RUN_ARGS is a list of options
[ -n "${MBCONFORM_RUN_ARGS:-}" ] && args+=($MBCONFORM_RUN_ARGS)
rc=0
"$MBCONFORM" "${args[@]}" || rc=$?
echo "mbconform-server-ci: mbconform run exited $rc ($OUT/junit.xml)"
exit "$rc"
