#!/usr/bin/env bash
# `mbconform fuzz` on a serial line (a pty at 115200 baud, `serve --line-rate`)
# against `mbconform serve --fault FAULT`: the first finding is reduced on the
# same line opened again (rtu_target.cpp's reconnect), saved, and fuzzing
# goes on after it (more than one round). Every finding printed is saved: a
# reduction that --duration's end cut off is saved as far as it got, and says
# so. A reduced reproducer fails when replayed on the broken drive and passes
# on a correct one. Usage: fuzz_serve_pty_test.sh MBCONFORM FAULT DURATION OUTDIR
set -euo pipefail
mbc=$1 fault=$2 duration=$3 out=$4
rm -rf "$out" && mkdir -p "$out"
pids=()
trap 'for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done' EXIT
serve() {  # serve NAME [ARGS...]: hsc60 as unit 1 on the pty $out/NAME
  local name=$1
  shift
  "$mbc" serve --device hsc60@1 --pty "$out/$name" --baud 115200 --line-rate 115200 "$@" \
    > "$out/$name.serve.out" 2> "$out/$name.serve.err" &
  pids+=($!)
  for _ in $(seq 100); do grep -q '^listening pty' "$out/$name.serve.out" && return; sleep 0.1; done
  echo "serve $name did not start"; cat "$out/$name.serve.err"; exit 1
}
serve broken --fault "$fault"
serve correct
uri() { echo "rtu://$out/$1?baud=115200&parity=N&unit=1"; }

set +e
"$mbc" fuzz --target "$(uri broken)" --device hsc60 --duration "$duration" --seed 7 --out "$out/fuzz" > "$out/fuzz.log" 2>&1
rc=$?
set -e
cat "$out/fuzz.log"
[ $rc -eq 1 ] || { echo "exit $rc, expected 1 (a finding on --fault $fault)"; exit 1; }
rounds=$(sed -n 's/.* frames in \([0-9]*\) round(s).*/\1/p' "$out/fuzz.log")
[ -n "$rounds" ] || { echo "no summary line"; exit 1; }
frames=$(sed -n 's/.* \([0-9]*\) frames in [0-9]* round(s).*/\1/p' "$out/fuzz.log")
first=$(sed -n 's/^FINDING [^ ]* after \([0-9]*\) steps.*/\1/p' "$out/fuzz.log" | head -1)
# It went on after the first finding: another round, and frames past it.
! grep -q 'could not be opened again' "$out/fuzz.log" || { echo "the line was not opened again"; exit 1; }
[ "$rounds" -ge 2 ] && [ "$frames" -gt "${first:-0}" ] ||
  { echo "fuzzing stopped at the first finding ($rounds round(s), $frames frames, found after ${first:-?} steps)"; exit 1; }
printed=$(grep -c '^FINDING ' "$out/fuzz.log")
shopt -s nullglob
files=("$out"/fuzz/finding-*.txt)
[ "${#files[@]}" -ge 1 ] || { echo "no reproducer saved"; exit 1; }
[ "${#files[@]}" -eq "$printed" ] || { echo "$printed finding(s) printed, ${#files[@]} saved: a finding was lost"; exit 1; }
for f in "${files[@]}"; do
  nsteps=$(grep -cE '^(rtu|raw-rtu) ' "$f" || true)
  [ "$nsteps" -ge 1 ] || { echo "$f: no steps"; exit 1; }
  if grep -q 'reduction was cut off' "$f"; then
    echo "$f: reduction cut off at the deadline, $nsteps step(s) kept"
    continue
  fi
  [ "$nsteps" -le 3 ] || { echo "$f: $nsteps steps, expected 1..3 after reduction"; exit 1; }
  set +e
  "$mbc" replay "$f" --target "$(uri broken)" > "$out/replay-broken.log" 2>&1
  rb=$?
  "$mbc" replay "$f" --target "$(uri correct)" > "$out/replay-correct.log" 2>&1
  rc_=$?
  set -e
  [ $rb -eq 1 ] && grep -q 'not met on ' "$out/replay-broken.log" ||
    { echo "replaying $f on the broken drive: exit $rb, expected 1"; cat "$out/replay-broken.log"; exit 1; }
  [ $rc_ -eq 0 ] || { echo "replaying $f on the correct drive: exit $rc_, expected 0"; cat "$out/replay-correct.log"; exit 1; }
done
echo "findings: $(sed -n 's/^# mbconform fuzz reproducer: //p' "${files[@]}" | tr '\n' ';')"
