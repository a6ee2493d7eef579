#!/usr/bin/env bash
# ctest oss_fuzz_build (libFuzzer build only, `ctest -L fuzz` in .ci/run):
# runs fuzz/build.sh the way OSS-Fuzz and ClusterFuzzLite do, then checks
# that $OUT holds every harness with its .dict, .options and seed corpus zip,
# and that each harness runs its seed corpus (with its .options' flags).
# usage: ossfuzz_build_test.sh SOURCE_DIR WORK_DIR
set -euo pipefail
src=$1 work=$2
rm -rf "$work/out" "$work/seeds" && mkdir -p "$work/out" "$work/seeds"
fail() { echo "oss_fuzz_build: FAIL: $*" >&2; exit 1; }

export CC=clang-14 CXX=clang++-14
# OSS-Fuzz's address build; .ci/run sets its own (UBSan too) and builds the
# whole tree here (fuzz/build.sh's $MBCONFORM_CMAKE_ARGS).
export CFLAGS="${CFLAGS:--O1 -fno-omit-frame-pointer -gline-tables-only -fsanitize=address -fsanitize-address-use-after-scope -fsanitize=fuzzer-no-link}"
export CXXFLAGS="${CXXFLAGS:-$CFLAGS}"
export LIB_FUZZING_ENGINE=-fsanitize=fuzzer
export OUT=$work/out SRC=$src WORK=$work
"$src/fuzz/build.sh"

# Every harness in fuzz/ but plugin_fuzzer, which needs a vendor's plugin at
# run time and is not for hosted engines (fuzz/build.sh, fuzz/README.md).
n=0
for cc in "$src"/fuzz/*_fuzzer.cc; do
  name=$(basename "$cc" .cc)
  [ "$name" = plugin_fuzzer ] && continue
  for f in "$name" "$name.dict" "$name.options" "${name}_seed_corpus.zip"; do
    [ -s "$OUT/$f" ] || fail "$OUT/$f is missing"
  done
  [ -x "$OUT/$name" ] || fail "$OUT/$name is not executable"
  seeds=$work/seeds/$name
  mkdir -p "$seeds" && (cd "$seeds" && unzip -q -o "$OUT/${name}_seed_corpus.zip")
  count=$(find "$seeds" -type f | wc -l)
  [ "$count" -gt 0 ] || fail "$name: an empty seed corpus"
  # [libfuzzer] key = value lines of the .options file become -key=value.
  flags=$(sed -n '/^\[libfuzzer\]/,/^\[/{s/^\([a-z_]*\) *= *\(.*\)$/-\1=\2/p}' "$OUT/$name.options")
  # shellcheck disable=SC2086
  "$OUT/$name" $flags -dict="$OUT/$name.dict" -runs=0 "$seeds" >"$work/$name.log" 2>&1 ||
    { tail -20 "$work/$name.log" >&2; fail "$name does not run its seed corpus"; }
  echo "oss_fuzz_build: $name: $count seeds ran"
  n=$((n + 1))
done
[ "$n" -gt 0 ] || fail "no harnesses"
extra=$(ls "$OUT" | grep -c '_fuzzer$' || true)
[ "$extra" = "$n" ] || fail "$OUT holds $extra harnesses, fuzz/ has $n"
echo "oss_fuzz_build: ok ($n harnesses)"
