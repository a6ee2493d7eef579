#!/usr/bin/env bash
# Set up, build and run every test under ctest but the conformance matrix
# (label `matrix`, about 5 minutes run serially: .ci/run runs it, and so does
# `ctest --test-dir build -L matrix`).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
tools/build.sh
# Most tests wait on lines, servers and peers (the CPU is about a third busy
# at -j nproc), so they run two per CPU; the timing checks, which measure
# microseconds on a served line, then run one at a time.
ctest --test-dir "${BUILD_DIR:-build}" --output-on-failure -j "$((2 * $(nproc)))" -LE "matrix|timing"
ctest --test-dir "${BUILD_DIR:-build}" --output-on-failure -L timing -LE matrix
