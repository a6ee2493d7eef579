#!/usr/bin/env bash
# `mbconform fuzz` over Modbus TCP against `mbconform serve --fault FAULT`:
# pipelined (--pipeline 16, the default) it finds every distinct finding that
# one exchange at a time (--pipeline 1) finds with the same seed and duration,
# and the summary reports frames/s. Usage: fuzz_serve_tcp_test.sh MBCONFORM FAULT DURATION OUTDIR
set -euo pipefail
mbc=$1 fault=$2 duration=$3 out=$4
rm -rf "$out" && mkdir -p "$out"
"$mbc" serve --device hsc60@1 --tcp 127.0.0.1:0 --fault "$fault" > "$out/serve.out" 2> "$out/serve.err" &
serve=$!
trap 'kill $serve 2>/dev/null || true; wait $serve 2>/dev/null || true' EXIT
for _ in $(seq 100); do grep -q '^listening tcp' "$out/serve.out" && break; sleep 0.1; done
addr=$(sed -n 's/^listening tcp //p' "$out/serve.out")
[ -n "$addr" ] || { echo "serve did not start"; cat "$out/serve.err"; exit 1; }
signatures() {  # the distinct findings a run saved, one per line, sorted
  sed -n 's/^# mbconform fuzz reproducer: //p' "$1"/finding-*.txt 2>/dev/null | sort -u
}
for depth in 1 16; do
  set +e
  "$mbc" fuzz --target "tcp://$addr?unit=1" --device hsc60 --duration "$duration" --seed 7 --pipeline $depth \
    --out "$out/p$depth" > "$out/p$depth.log" 2>&1
  rc=$?
  set -e
  cat "$out/p$depth.log"
  [ $rc -eq 1 ] || { echo "--pipeline $depth: exit $rc, expected 1 (a finding on --fault $fault)"; exit 1; }
  grep -Eq '\([0-9]+ frames/s' "$out/p$depth.log" || { echo "--pipeline $depth: no frames/s in the summary"; exit 1; }
done
missing=$(comm -23 <(signatures "$out/p1") <(signatures "$out/p16"))
[ -z "$missing" ] || { echo "pipelined fuzzing missed what one exchange at a time found: $missing"; exit 1; }
[ -n "$(signatures "$out/p16")" ] || { echo "no finding saved"; exit 1; }
echo "findings: $(signatures "$out/p16" | tr '\n' ';')"
