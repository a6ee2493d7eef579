#!/bin/sh
# smoke.sh WORK_DIR FUZZER [libFuzzer flags...] -- SEED_DIR...
# Fuzzes from the seed directories with new inputs going to WORK_DIR (a
# scratch corpus in the build tree, emptied first) and crash reproducers to
# WORK_DIR/artifacts/. Exits non-zero on any finding, as libFuzzer does.
set -eu
work=$1; fuzzer=$2; shift 2
flags=""
while [ $# -gt 0 ] && [ "$1" != "--" ]; do flags="$flags $1"; shift; done
[ $# -gt 0 ] && shift
rm -rf "$work"
mkdir -p "$work/new" "$work/artifacts"
# shellcheck disable=SC2086
exec "$fuzzer" $flags -artifact_prefix="$work/artifacts/" -print_final_stats=1 "$work/new" "$@"
