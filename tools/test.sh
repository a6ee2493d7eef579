#!/usr/bin/env bash
# Set up, build and run every test under ctest but the conformance matrix
# (label `matrix`, about 5 minutes run serially: .ci/run runs it, and so does
# `ctest --test-dir build -L matrix`).
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
tools/build.sh
ctest --test-dir "${BUILD_DIR:-build}" --output-on-failure -j "$(nproc)" -LE matrix
