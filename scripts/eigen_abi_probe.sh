#!/usr/bin/env bash
# What compile flags do to the plugin ABI: compiles a probe against terramap's headers with the
# given flags and prints Eigen's alignment, the allocator Eigen picks and where events keep their
# poses. Usage: scripts/eigen_abi_probe.sh [CXXFLAGS...]
#   scripts/eigen_abi_probe.sh                                  # the host's defaults
#   scripts/eigen_abi_probe.sh -march=native -UEIGEN_MAX_ALIGN_BYTES   # a plugin without the pin
#   scripts/eigen_abi_probe.sh -march=native -DEIGEN_MAX_ALIGN_BYTES=16  # with it (the package's)
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
dir="$(mktemp -d)"
trap 'rm -rf "$dir"' EXIT
cat > "$dir/probe.cpp" <<'CPP'
#include <terramap/core/events.hpp>
#include <cstddef>
#include <cstdio>
int main() {
  std::printf("EIGEN_MAX_ALIGN_BYTES=%d EIGEN_MAX_STATIC_ALIGN_BYTES=%d malloc_already_aligned=%d "
              "alignof(Isometry3d)=%zu offsetof(Observation,T_map_base)=%zu offsetof(PointCloud,T_map_sensor)=%zu "
              "sizeof(Event)=%zu\n",
              EIGEN_MAX_ALIGN_BYTES, EIGEN_MAX_STATIC_ALIGN_BYTES, EIGEN_MALLOC_ALREADY_ALIGNED,
              alignof(Eigen::Isometry3d), offsetof(terramap::Observation, T_map_base),
              offsetof(terramap::PointCloud, T_map_sensor), sizeof(terramap::Event));
}
CPP
# offsetof on these standard-layout-enough structs is what the compiler lays out; silence its note.
c++ -std=c++17 -Wno-invalid-offsetof -I"$root/include" -I/usr/include/eigen3 "$@" "$dir/probe.cpp" -o "$dir/probe"
"$dir/probe"
