#!/usr/bin/env bash
# ctest deb_package: `cpack -G DEB`, then: the package's dependencies are
# the Debian packages that hold the shared libraries its binaries need on
# this machine (dpkg-shlibdeps, not a list of one release's names); apt
# resolves them (`apt-get install -s`, a simulation: nothing is installed);
# it has a copyright file and a real maintainer; unpacked into an empty root
# (dpkg -x), its mbconform finds its specs in /usr/share/mbconform relative
# to itself and passes installed_checks.sh (version, man page, completion, a
# served qualification, quirks by name).
# usage: deb_test.sh BUILD_DIR WORK_DIR SOURCE_DIR VERSION
set -euo pipefail
build=$1 work=$2 src=$3 version=$4
rm -rf "$work" && mkdir -p "$work"
fail() { echo "deb_test: FAIL: $*" >&2; exit 1; }

(cd "$build" && cpack -G DEB -B "$work" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log" >&2; fail "cpack -G DEB"; }
deb=$(ls "$work"/mbconform_*.deb 2>/dev/null | head -1)
[ -n "$deb" ] || fail "no .deb in $work"
depends=$(dpkg-deb -f "$deb" Depends)
echo "deb_test: $(basename "$deb"): Depends: $depends"
# Each library the packaged binaries need, by the package that holds it here.
dpkg-deb -x "$deb" "$work/root"
multiarch=$(dpkg-architecture -qDEB_HOST_MULTIARCH 2>/dev/null || gcc -print-multiarch)
for exe in "$work"/root/usr/bin/*; do
  for so in $(readelf -d "$exe" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p'); do
    pkg=$(dpkg -S "*/$multiarch/$so" 2>/dev/null | head -1 | cut -d: -f1) || true
    [ -n "$pkg" ] || fail "$(basename "$exe") needs $so, which no package of this machine holds"
    [[ ", $depends," == *", $pkg "* || ", $depends," == *", $pkg,"* ]] || fail "Depends lacks $pkg ($(basename "$exe") needs $so)"
  done
done
maintainer=$(dpkg-deb -f "$deb" Maintainer)
grep -q "localhost" <<<"$maintainer" && fail "Maintainer is $maintainer"
[ -s "$work/root/usr/share/doc/mbconform/copyright" ] || fail "the package has no /usr/share/doc/mbconform/copyright"
grep -q "^License: Apache-2.0" "$work/root/usr/share/doc/mbconform/copyright" || fail "the copyright file states no licence"
dpkg-deb -c "$deb" >"$work/contents.txt"
for f in ./usr/bin/mbconform ./usr/share/mbconform/devices/hsc60.yaml ./usr/share/mbconform/schema/device.schema.json \
         ./usr/include/mbconform_plugin.h; do
  grep -q " $f\$" "$work/contents.txt" || fail "the package lacks $f"
done

# apt resolves every dependency from Debian's packages (simulated install).
apt-get install -s "$deb" >"$work/apt.txt" 2>&1 || { cat "$work/apt.txt" >&2; fail "apt-get install -s"; }
grep -q "^Inst mbconform " "$work/apt.txt" || { cat "$work/apt.txt" >&2; fail "apt would not install mbconform"; }

# The unpacked tree works where it lands.
(cd "$work" && env -u MBCONFORM_SPEC_DIR "$work/root/usr/bin/mbconform" spec list >"$work/list.txt")
grep -q "^hsc60 .*$work/root/usr/share/mbconform/devices/hsc60.yaml .*(installed)$" "$work/list.txt" ||
  { cat "$work/list.txt" >&2; fail "the packaged mbconform does not find its specs"; }
"$src/cmake/tests/installed_checks.sh" "$work/root/usr" "$version" "$work/checks" || fail "installed_checks.sh"
echo "deb_test: ok ($(basename "$deb"), Depends: $depends)"
