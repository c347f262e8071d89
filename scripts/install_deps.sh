#!/usr/bin/env bash
# Installs the Debian 12 packages pcr_pro needs to build, test and run its demo.
# Idempotent: asks apt only for packages that are not installed yet, and runs
# `apt-get update` only when something is missing. Must run as root (or via sudo).
#
# Usage: scripts/install_deps.sh [build|bench|bundles]
#   build (default)  everything `make build`, `make test` and `make demo` need
#   bench            additionally what `make bench` needs
#   bundles          additionally what scripts/make_bundles.py needs (Debian's Python 3)
set -euo pipefail

profile="${1:-build}"

packages=(
  # toolchain
  cmake g++ make pkg-config
  # catkin (devel space, package.xml handling) and its Python side
  catkin python3-catkin-pkg
  # core library
  libeigen3-dev libnanoflann-dev libyaml-cpp-dev libopencv-dev libopengv-dev
  # tests
  libgtest-dev
)
case "$profile" in
  build) ;;
  bench) packages+=(libpcl-dev) ;;
  bundles) packages+=(python3 python3-numpy python3-opencv python3-yaml) ;;
  *) echo "install_deps: unknown profile '$profile' (build|bench|bundles)" >&2; exit 2 ;;
esac

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#packages[@]} Debian packages present"
  exit 0
fi

echo "install_deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "install_deps: not root and no sudo; install these packages: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
