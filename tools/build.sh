#!/usr/bin/env bash
# Configures and builds into build/ (or $BUILD_DIR). Extra args go to cmake.
# One line when it worked; the compiler's errors when it did not. The whole
# output is kept in $BUILD_DIR/build.log (MBCONFORM_VERBOSE=1 prints it as it comes).
# MBCONFORM_WERROR=ON makes a warning an error (.ci/run). BUILD_TYPE: Release
# (-O2, no debug info) unless given; BUILD_TYPE=RelWithDebInfo for a debugger.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
mkdir -p "$BUILD_DIR"
log="$BUILD_DIR/build.log"
start=$SECONDS
build() {
  cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE="${BUILD_TYPE:-Release}" \
    -DMBCONFORM_WERROR="${MBCONFORM_WERROR:-OFF}" "$@" &&
    cmake --build "$BUILD_DIR" -j "$(nproc)"
}
rc=0
if [ "${MBCONFORM_VERBOSE:-0}" = 1 ]; then
  build "$@" 2>&1 | tee "$log" || rc=$?  # pipefail: the build's status
else
  build "$@" >"$log" 2>&1 || rc=$?
fi
if [ "$rc" != 0 ]; then
  echo "build: $BUILD_DIR FAILED (exit $rc); the errors (whole output: $log):" >&2
  grep -E -A8 'error:|FAILED:|CMake Error' "$log" | head -200 >&2 || tail -50 "$log" >&2
  exit "$rc"
fi
warnings=$(grep -c 'warning:' "$log" || true)
note=""
if [ "$warnings" != 0 ]; then note=", $warnings warning line(s): see $log"; fi
echo "build: $BUILD_DIR ok in $((SECONDS - start)) s$note"
