#!/usr/bin/env bash
# Source coverage of the harnesses' corpora (fuzz/README.md), with clang's
# -fprofile-instr-generate and llvm-cov; the harnesses use their replay
# mains, so no libFuzzer is involved.
#   fuzz/coverage.sh [HARNESS...]     (default: every harness)
# Runs corpus/<h>/, corpus/regressions/<h>/ and campaign/<h>-merged/ when
# present; writes build-cov/coverage/<h>/index.html and prints a summary of
# the project's own sources.
set -euo pipefail
cd "$(dirname "$0")/.."
flags="-fprofile-instr-generate -fcoverage-mapping"
CC=clang-14 CXX=clang++-14 CFLAGS="$flags" CXXFLAGS="$flags" \
  cmake -S . -B build-cov -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
cmake --build build-cov --target fuzz_all
harnesses=("$@")
[ ${#harnesses[@]} -gt 0 ] || harnesses=(rtu_frame device session spec_loader reply_parser differential)
for h in "${harnesses[@]}"; do
  seeds=$h; [ "$h" = libmodbus_reply ] && seeds=differential
  dirs=("corpus/$seeds")
  for d in "corpus/regressions/$h" "campaign/$h-merged"; do [ -d "$d" ] && dirs+=("$d"); done
  out=build-cov/coverage/$h; mkdir -p "$out"
  LLVM_PROFILE_FILE="$out/run.profraw" "build-cov/bin/${h}_fuzzer" "${dirs[@]}" 2>/dev/null
  llvm-profdata-14 merge -sparse "$out/run.profraw" -o "$out/run.profdata"
  llvm-cov-14 show "build-cov/bin/${h}_fuzzer" -instr-profile="$out/run.profdata" -format=html -output-dir="$out" \
    modbus reference spec/loader conformance/targets fuzz >/dev/null
  echo "== $h ($out/index.html)"
  llvm-cov-14 report "build-cov/bin/${h}_fuzzer" -instr-profile="$out/run.profdata" modbus reference spec/loader | tail -1
done
