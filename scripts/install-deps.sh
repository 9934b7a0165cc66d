#!/usr/bin/env bash
# Installs the Debian 12 packages the project builds, tests and plots with.
# Non-interactive and idempotent: when every package is present it only runs dpkg-query and exits.
# Usage: scripts/install-deps.sh [--print]   (--print lists the packages and exits)
set -euo pipefail

packages=(
  # toolchain and test/bench frameworks
  build-essential cmake pkg-config git clang-format file
  # libFuzzer: clang and its runtime (scripts/fuzz.sh, CI's fuzzing run)
  clang libclang-rt-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  # the hardware and science stack (docs/design.md)
  libaravis-dev aravis-tools libmodbus-dev libusb-1.0-0-dev mbpoll
  libopencv-dev libceres-dev libsqlite3-dev sqlite3
  # config parsing, JSON, CLI, logging, numerics
  libtomlplusplus-dev nlohmann-json3-dev libcli11-dev libspdlog-dev libboost-dev
  # the daemon: its local HTTP API (server and gonioctl client) and systemd readiness
  libcpp-httplib-dev libsystemd-dev
  # chart scripts and benchmark peers run with /usr/bin/python3 (docs/design.md, Python helpers)
  python3 python3-numpy python3-scipy python3-matplotlib
  # the console's browser test (goniod.console_in_a_browser): headless Chromium, driven by Selenium
  chromium chromium-driver python3-selenium
  # the GigE tests' network namespaces of their own (tests/support/own_loopback.sh: unshare, ip)
  util-linux iproute2
)

if [[ "${1:-}" == "--print" ]]; then
  printf '%s\n' "${packages[@]}"
  exit 0
fi

missing=()
for p in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$p" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$p")
done

if [[ ${#missing[@]} -eq 0 ]]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "install-deps: not root and no sudo; install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
echo "install-deps: done"
