#!/usr/bin/env bash
# The main job: set up, build, check every spec, regenerate the manual
# errata reports (reports/manuals/). Exit code non-zero on any failure.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
tools/build.sh
build/bin/mbconform spec check
build/bin/mbconform spec errata --out reports/manuals
