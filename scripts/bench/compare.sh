#!/usr/bin/env bash
# Interleaved before/after benchmark rounds of two builds on the same machine (the only fair
# comparison on a VM whose speed drifts): ROUNDS times base then new, CSV rows "tag,<benchmark csv>".
# Usage: scripts/bench/compare.sh BASE_BIN_DIR NEW_BIN_DIR [ROUNDS] > compare.csv
# (the architecture pass of 2026-11-23 was measured this way: two rounds, base = a build of 08849f9.)
set -u
base=$1; new=$2; rounds=${3:-2}
# Google Benchmark's CSV reporter stops (and fails) at a family whose user counters differ from
# the first one's, so every family is its own call.
FAMILIES=(
  "bench_core BM_CoreTileLoop/2000"
  "bench_core BM_CoreTileLoopHeavy/2000"
  "bench_blind_mapping BM_BladeSweep"
  "bench_blind_mapping BM_SoilErosion"
  "bench_lidar_fusion BM_LidarFusionSeq_Kitti_400x400_5cm_(NoCleanup|Cleanup4th|CleanupAll)/"
  "bench_lidar_fusion BM_LidarFusion_TimeUpdate"
  "bench_sim BM_SimRealtime/2"
)
round() {
  local tag=$1 bin=$2 f prog filter
  for f in "${FAMILIES[@]}"; do
    prog=${f%% *}; filter=${f#* }
    "$bin/$prog" --benchmark_filter="$filter" --benchmark_min_time=0.3 --benchmark_format=csv 2>/dev/null |
      grep -v '^name' | sed "s/^/$tag,/"
  done
}
for r in $(seq 1 "$rounds"); do
  round "base$r" "$base"
  round "new$r" "$new"
done
