#!/usr/bin/env bash
# Installs the Debian 12 packages terramap builds against, only those missing,
# so a second `make test` costs nothing. Needs root (or sudo) only when something is missing.
set -euo pipefail
PKGS=(build-essential cmake ninja-build pkg-config
  libtbb-dev libeigen3-dev liboctomap-dev libyaml-cpp-dev libboost-dev libboost-filesystem-dev
  libbenchmark-dev libgtest-dev googletest libpcl-dev libgdal-dev gdal-bin libhdf5-dev libdeflate-dev
  libtorch-dev libopenblas0-openmp nlohmann-json3-dev libcli11-dev libopenmpi-dev openmpi-bin
  pybind11-dev python3-dev python3-numpy python3-pytest python3-matplotlib
  libfreetype-dev fonts-dejavu-core chromium
  libzstd-dev liblz4-dev lz4)
# `install_deps.sh fuzz` (make fuzz): Debian's clang and its libFuzzer/sanitizer runtimes too.
if [ "${1:-}" = fuzz ]; then PKGS+=(clang libclang-rt-14-dev); fi
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# node and npm build the live view's page (three.js from the npm registry at build time); any
# node >= 18 on PATH will do, else Debian's.
if ! command -v npm >/dev/null 2>&1 || ! command -v node >/dev/null 2>&1; then missing+=(nodejs npm); fi
if [ ${#missing[@]} -eq 0 ]; then
  echo "install_deps: all ${#PKGS[@]} packages and node/npm present"
  exit 0
fi
echo "install_deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
$SUDO apt-get update
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends \
  -o DPkg::Lock::Timeout=600 "${missing[@]}"
