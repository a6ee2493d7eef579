#!/usr/bin/env bash
# ctest tree_without_fuzz: the tree builds without fuzz/ (a source package or
# a vendor's copy may leave the fuzz harnesses out). Cheaper than building
# that tree, and as strict where it can fail:
#   1. the tree without fuzz/ configures (every CMakeLists outside fuzz/ holds
#      without it);
#   2. ninja's dry run of `all` there finds a rule for every source and object
#      (no target outside fuzz/ names a file in fuzz/);
#   3. no target there links a target that only fuzz/ defines (CMake would
#      pass the missing name to the linker as -l<name>);
#   4. no source outside fuzz/ includes a header that lives in fuzz/.
# usage: nofuzz_tree_test.sh SOURCE_DIR WORK_DIR
set -euo pipefail
src=$1 work=$2
fail() { echo "tree_without_fuzz: FAIL: $*" >&2; exit 1; }
rm -rf "$work" && mkdir -p "$work/src"
cd "$src"
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  git ls-files -z | grep -zv '^fuzz/' | xargs -0 cp --parents -t "$work/src"
else  # an unpacked source tree
  find . -path ./fuzz -prune -o -path './build*' -prune -o -type f -print0 | xargs -0 cp --parents -t "$work/src"
fi
[ ! -e "$work/src/fuzz" ] || fail "the copy still has fuzz/"

# 1. configure (no regeneration rule: a dry run would stop at the globs' re-check)
cmake -S "$work/src" -B "$work/build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_SUPPRESS_REGENERATION=ON >"$work/configure.log" 2>&1 ||
  { tail -30 "$work/configure.log" >&2; fail "the tree without fuzz/ does not configure"; }
# 2. every edge of `all` has its inputs
ninja -C "$work/build" -n all >"$work/dry-run.log" 2>&1 ||
  { tail -30 "$work/dry-run.log" >&2; fail "ninja -n all: a target outside fuzz/ needs a file from fuzz/"; }
grep -q "Linking CXX executable bin/mbconform" "$work/dry-run.log" || fail "the dry run does not link bin/mbconform"

# 3. links to targets only fuzz/ defines
fuzz_targets=$(sed -n 's/^[[:space:]]*add_\(library\|executable\|custom_target\)(\([A-Za-z0-9_]*\).*/\2/p' "$src/fuzz/CMakeLists.txt" | sort -u)
fuzz_targets="$fuzz_targets $(sed -n 's/^set(fuzz_harnesses \(.*\))/\1/p' "$src/fuzz/CMakeLists.txt" | tr ' ' '\n' | sed 's/$/_fuzzer/')"
for t in $fuzz_targets; do
  case $t in '${t}'|'') continue ;; esac
  if grep -E "^[[:space:]]*LINK_LIBRARIES = .*(-l$t\b|[[:space:]]$t([[:space:]]|$))" "$work/build/build.ninja" >/dev/null; then
    fail "a target outside fuzz/ links $t, which only fuzz/ defines"
  fi
done

# 4. headers from fuzz/
for h in "$src"/fuzz/*.h; do
  name=$(basename "$h")
  if hits=$(cd "$work/src" && grep -rlE "#include [\"<](fuzz/)?$name[\">]" --include='*.cpp' --include='*.cc' --include='*.h' .); then
    fail "$name lives in fuzz/ and is included by: $hits"
  fi
done
echo "tree_without_fuzz: configures, every target's inputs exist, no link to or include from fuzz/ ($(echo $fuzz_targets | wc -w) fuzz targets checked)"
