#!/usr/bin/env bash
# A long campaign of one harness on this machine (fuzz/README.md).
#   fuzz/campaign.sh HARNESS [SECONDS=3600] [JOBS=$(nproc)] [BUILD=build-fuzz]
# Fork mode (-fork=JOBS) from the seeds, going on past findings
# (-ignore_crashes=1); new inputs in campaign/HARNESS/, reproducers in
# campaign/HARNESS-artifacts/; then the corpus is merged to a minimal set in
# campaign/HARNESS-merged/. Needs a -DMBCONFORM_FUZZ=ON build.
set -euo pipefail
cd "$(dirname "$0")/.."
h=${1:?usage: fuzz/campaign.sh HARNESS [SECONDS] [JOBS] [BUILD]}
secs=${2:-3600}; jobs=${3:-$(nproc)}; build=${4:-build-fuzz}
bin=$build/bin/${h}_fuzzer
[ -x "$bin" ] || { echo "no $bin: CC=clang-14 CXX=clang++-14 cmake -S . -B $build -G Ninja -DMBCONFORM_FUZZ=ON && cmake --build $build --target fuzz_all" >&2; exit 2; }
seeds=$h; [ "$h" = libmodbus_reply ] && seeds=differential
dict=fuzz/${seeds}_fuzzer.dict; [ "$h" = plugin ] && dict=fuzz/device_fuzzer.dict
max_len=512; [ "$h" = spec_loader ] && max_len=8192
mkdir -p "campaign/$h" "campaign/$h-artifacts" "campaign/$h-merged"
dirs=("campaign/$h" "corpus/$seeds")
[ -d "corpus/regressions/$h" ] && dirs+=("corpus/regressions/$h")
"$bin" -fork="$jobs" -ignore_crashes=1 -max_total_time="$secs" -max_len="$max_len" -dict="$dict" \
  -artifact_prefix="campaign/$h-artifacts/" "${dirs[@]}" || true
"$bin" -merge=1 -max_len="$max_len" "campaign/$h-merged" "${dirs[@]}"
echo "campaign: $(ls "campaign/$h-merged" | wc -l) inputs in campaign/$h-merged, $(ls "campaign/$h-artifacts" | wc -l) reproducers in campaign/$h-artifacts"
