#!/usr/bin/env bash
# The main job: set up, build, check every spec, regenerate the manual
# errata reports (reports/manuals/), run every conformance case and the
# property tests against every reference device. One line per step, then the
# results; exit code non-zero on any failure.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/setup.sh
tools/build.sh
echo "main-job: spec check"
build/bin/mbconform spec check
echo "main-job: spec errata -> reports/manuals"
build/bin/mbconform spec errata --out reports/manuals
# The conformance run: every case against every reference device in-process.
# Full reports (JUnit, JSON, HTML) go to a dated directory under reports/runs/;
# the stable summary (no dates, no times) is committed as reports/reference/.
run_dir="reports/runs/$(date -u +%Y%m%dT%H%M%SZ)"
echo "main-job: run (every case, every reference device) -> $run_dir"
build/bin/mbconform run --quiet --out "$run_dir" --summary reports/reference
# The property tests of the profile invariants on every reference device (a
# fixed seed, so the main job is repeatable; `mbconform props` alone draws one).
echo "main-job: props (seed 1) -> $run_dir/props"
build/bin/mbconform props --quiet --seed 1 --out "$run_dir/props"
