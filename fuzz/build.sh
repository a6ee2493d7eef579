#!/bin/bash -eu
# OSS-Fuzz / ClusterFuzzLite build script. Honours $CC $CXX $CFLAGS $CXXFLAGS
# $LIB_FUZZING_ENGINE $OUT (and $WORK for the build tree), as those engines
# set them; by hand:
#   CC=clang-14 CXX=clang++-14 CFLAGS="-fsanitize=address,fuzzer-no-link" \
#   CXXFLAGS="-fsanitize=address,fuzzer-no-link" LIB_FUZZING_ENGINE=-fsanitize=fuzzer \
#   OUT=/tmp/fuzz-out fuzz/build.sh
# Writes into $OUT, per harness: <name>_fuzzer, <name>_fuzzer.dict,
# <name>_fuzzer.options and <name>_fuzzer_seed_corpus.zip (the generated seeds
# plus corpus/regressions/<name>/). The specs are compiled into the binaries.
SRC=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
: "${OUT:?set OUT}" "${LIB_FUZZING_ENGINE:?set LIB_FUZZING_ENGINE}"
BUILD=${WORK:-/tmp}/mbconform-fuzz-build
# $MBCONFORM_CMAKE_ARGS and $MBCONFORM_BUILD_TARGETS (not set by the engines)
# let .ci/run build the whole tree here too, under the same flags: the test
# suite, the smoke runs and this packaging from one build.
# shellcheck disable=SC2086
cmake -S "$SRC" -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
  -DMBCONFORM_FUZZ_ENGINE="$LIB_FUZZING_ENGINE" ${MBCONFORM_CMAKE_ARGS:-} >/dev/null
# shellcheck disable=SC2086
cmake --build "$BUILD" --target ${MBCONFORM_BUILD_TARGETS:-fuzz_all} -j "$(nproc)"
mkdir -p "$OUT"
for bin in "$BUILD"/bin/*_fuzzer; do
  name=$(basename "$bin" _fuzzer)
  # plugin_fuzzer needs a vendor's plugin at run time ($MBCONFORM_PLUGIN):
  # it is run by the vendor (fuzz/README.md), not by a hosted engine.
  [ "$name" = plugin ] && continue
  seeds=$name
  [ "$name" = libmodbus_reply ] && seeds=differential  # same input format
  dict=$seeds; [ "$name" = plugin ] && dict=device
  cp "$bin" "$OUT/"
  cp "$SRC/fuzz/${dict}_fuzzer.dict" "$OUT/${name}_fuzzer.dict" 2>/dev/null || true
  cp "$SRC/fuzz/${name}_fuzzer.options" "$OUT/" 2>/dev/null || true
  rm -f "$OUT/${name}_fuzzer_seed_corpus.zip"
  for dir in "$SRC/corpus/$seeds" "$SRC/corpus/regressions/$name"; do
    [ -d "$dir" ] && (cd "$dir" && zip -q -r "$OUT/${name}_fuzzer_seed_corpus.zip" .)
  done
done
echo "fuzz/build.sh: $(ls "$OUT"/*_fuzzer | wc -l) harnesses in $OUT"
