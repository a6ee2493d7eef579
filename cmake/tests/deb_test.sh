#!/usr/bin/env bash
# ctest deb_package: `cpack -G DEB`, then: the package's dependencies are
# Debian packages found by dpkg-shlibdeps; apt resolves them (`apt-get
# install -s`, a simulation: nothing is installed); the unpacked package's
# mbconform finds its specs in /usr/share/mbconform relative to itself.
# usage: deb_test.sh BUILD_DIR WORK_DIR
set -euo pipefail
build=$1 work=$2
rm -rf "$work" && mkdir -p "$work"
fail() { echo "deb_test: FAIL: $*" >&2; exit 1; }

(cd "$build" && cpack -G DEB -B "$work" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log" >&2; fail "cpack -G DEB"; }
deb=$(ls "$work"/mbconform_*.deb 2>/dev/null | head -1)
[ -n "$deb" ] || fail "no .deb in $work"
depends=$(dpkg-deb -f "$deb" Depends)
echo "deb_test: $(basename "$deb"): Depends: $depends"
for lib in libmodbus libyaml-cpp libfmt libc6 libstdc++6; do
  grep -q "$lib" <<<"$depends" || fail "Depends lacks $lib (mbconform links it)"
done
dpkg-deb -c "$deb" >"$work/contents.txt"
for f in ./usr/bin/mbconform ./usr/share/mbconform/devices/hsc60.yaml ./usr/share/mbconform/schema/device.schema.json \
         ./usr/include/mbconform_plugin.h; do
  grep -q " $f\$" "$work/contents.txt" || fail "the package lacks $f"
done

# apt resolves every dependency from Debian's packages (simulated install).
apt-get install -s "$deb" >"$work/apt.txt" 2>&1 || { cat "$work/apt.txt" >&2; fail "apt-get install -s"; }
grep -q "^Inst mbconform " "$work/apt.txt" || { cat "$work/apt.txt" >&2; fail "apt would not install mbconform"; }

# The unpacked tree works where it lands.
dpkg-deb -x "$deb" "$work/root"
(cd "$work" && env -u MBCONFORM_SPEC_DIR "$work/root/usr/bin/mbconform" spec list >"$work/list.txt")
grep -q "^hsc60 .*$work/root/usr/share/mbconform/devices/hsc60.yaml .*(installed)$" "$work/list.txt" ||
  { cat "$work/list.txt" >&2; fail "the packaged mbconform does not find its specs"; }
echo "deb_test: ok"
