#!/usr/bin/env bash
# Drives on one serial line (`serve --device hsc60@1 --device hsc60@2 ... --pty`):
# a frame for slave 2 is answered by slave 2, which is no fault of slave 1
# (MB-SL v1.02 §2.2: the addressed slave answers). `props` (the MUST property
# foreign-or-corrupt-ignored) and `fuzz` against
# slave 1 must pass (exit 0) and name no "answered-other-slave"; the same
# runs against the reference device alone still catch a drive that answers
# frames for other slaves (fault reply-other-slave: every reply is its own).
# Usage: multidrop_pty_test.sh MBCONFORM OUTDIR
set -euo pipefail
mbc=$1 out=$2
rm -rf "$out" && mkdir -p "$out"
pids=()
trap 'for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done' EXIT
# Slaves 2..40 beside slave 1: the properties and the fuzzer pick "another
# slave id" at random, and most of their picks must be drives that answer.
others=()
for u in $(seq 2 40); do others+=(--device "hsc60@$u"); done
"$mbc" serve --device hsc60@1 "${others[@]}" --pty "$out/line" --baud 115200 --line-rate 115200 \
  > "$out/serve.out" 2> "$out/serve.err" &
pids+=($!)
for _ in $(seq 100); do grep -q '^listening pty' "$out/serve.out" && break; sleep 0.1; done
grep -q '^listening pty' "$out/serve.out" || { echo "serve did not start"; cat "$out/serve.err"; exit 1; }
uri="rtu://$out/line?baud=115200&parity=N&unit=1"

# Slave 2 is there and answers its own frames (mbpoll, a master users have):
# the line really is a multi-drop one.
if command -v mbpoll > /dev/null; then
  mbpoll -m rtu -a 2 -r 1 -c 1 -b 115200 -P none -1 -o 2 "$out/line" > "$out/mbpoll.log" 2>&1 ||
    { echo "slave 2 does not answer mbpoll"; cat "$out/mbpoll.log"; exit 1; }
fi

run() {  # run NAME EXPECTED_RC COMMAND...
  local name=$1 want=$2
  shift 2
  set +e
  "$@" > "$out/$name.log" 2>&1
  local rc=$?
  set -e
  cat "$out/$name.log"
  [ "$rc" -eq "$want" ] || { echo "$name: exit $rc, expected $want"; exit 1; }
}
run props 0 "$mbc" props --target "$uri" --device hsc60 --only foreign-or-corrupt-ignored --cases 60 --seed 5 \
  --out "$out/props" -q
! grep -q 'was answered' "$out/props.log" || { echo "props held slave 2's reply against slave 1"; exit 1; }
grep -q 'foreign-or-corrupt-ignored.*pass' "$out/props.log" || { echo "foreign-or-corrupt-ignored did not pass"; exit 1; }
run fuzz 0 "$mbc" fuzz --target "$uri" --device hsc60 --duration 4s --seed 7 --out "$out/fuzz" -q
! grep -q 'answered-other-slave' "$out/fuzz.log" || { echo "fuzz held slave 2's reply against slave 1"; exit 1; }

# Alone on its line (in process), a drive that answers other slaves' frames is still caught.
run props-alone 1 "$mbc" props --target 'ref:hsc60?fault=reply-other-slave' --only foreign-or-corrupt-ignored \
  --cases 100 --seed 5 --out "$out/props-alone" -q
echo "multi-drop line: slave 2's replies are its own; alone, reply-other-slave is caught"
