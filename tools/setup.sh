#!/usr/bin/env bash
# Installs everything mbconform builds and tests with, from Debian packages.
# Safe to run again; needs root (or sudo) for apt-get.
#
# Where each dependency comes from, and what keeps a registry's next release
# from changing it (tools/check-pins.py checks the last three; ctest pins_*):
#   registry          what                                  pinned by
#   Debian (apt)      compilers, libraries, tools below     the machine's Debian release (stable
#                                                           updates only); nothing from elsewhere
#   npm               the npm peers (conformance/peers/)    package-lock.json via `npm ci`; a
#                                                           dependency declared by a dist-tag,
#                                                           '*' or an open range is pinned by an
#                                                           `overrides` entry at its locked version
#                                                           (@types/node: modbus-stream says 'latest')
#   Go                goburrow/modbus client adapter        Debian's golang-github-goburrow-modbus-dev,
#                                                           built in GOPATH mode with GO111MODULE=off
#                                                           and GOPROXY=off: no module proxy
#   Python            pymodbus, pyserial, PyYAML            Debian's python3-* packages, run by
#                                                           /usr/bin/python3; no pip
set -euo pipefail
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
packages=(
  build-essential cmake ninja-build pkg-config
  libyaml-cpp-dev libvalijson-dev nlohmann-json3-dev libcli11-dev libfmt-dev
  libmodbus-dev libgtest-dev libgmock-dev librapidcheck-dev libbenchmark-dev
  clang libfuzzer-14-dev libclang-rt-14-dev
  socat mbpoll python3 python3-pymodbus python3-serial python3-serial-asyncio python3-yaml
  libjson-c-dev
  libssl-dev openssl  # Modbus/TCP Security: serve --tls, mbtls://, the test PKI (Debian)
  golang-go golang-github-goburrow-modbus-dev  # the goburrow/modbus client adapter, built offline
  zip unzip
  libpcap-dev tshark  # check-capture reads captures with libpcap; tshark is the tests' independent decoder (Debian)
  chromium poppler-utils  # Debian: report.html rendered, printed to PDF and its pages counted (conformance/tests/report)
  fonts-wqy-zenhei        # Debian: a CJK font, so the manuals' Chinese names render in the report
  libre2-dev  # run --filter: a linear-time regex matcher (Debian)
  man-db      # the man page is opened with `man -l` in the manual and install tests (Debian)
)
# Node for the npm peers (conformance/peers: npm ci into the build tree).
# Debian's nodejs and npm only where no node is installed: a node from
# elsewhere ships its own npm, and Debian's npm conflicts with it.
if ! command -v node >/dev/null 2>&1; then packages+=(nodejs npm); fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# One line per step; a step's own output (apt's progress) only when it fails.
log=$(mktemp /tmp/mbconform-setup.XXXXXX)
trap 'rm -f "$log"' EXIT
step() {  # step WHAT COMMAND...
  local what=$1 rc=0
  shift
  "$@" >"$log" 2>&1 || rc=$?
  if [ "$rc" = 0 ]; then
    echo "setup: $what: ok"
  else
    echo "setup: $what: FAILED (exit $rc); its output:" >&2
    cat "$log" >&2
    exit "$rc"
  fi
}
if [ "${#missing[@]}" -gt 0 ]; then
  # tshark's wireshark-common asks whether non-root users may capture: no, without asking.
  echo "wireshark-common wireshark-common/install-setuid boolean false" | $SUDO debconf-set-selections 2>/dev/null || true
  step "apt-get update" $SUDO apt-get update
  step "install ${missing[*]}" $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${missing[@]}"
else
  echo "setup: all ${#packages[@]} Debian packages are installed"
fi
