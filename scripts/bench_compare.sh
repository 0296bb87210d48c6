#!/usr/bin/env bash
# Interleaved before/after benchmark rounds of two builds on the same machine (the only fair
# comparison on a VM whose speed drifts): ROUNDS times base then new, CSV rows "tag,<benchmark csv>".
# Usage: scripts/bench_compare.sh BASE_BIN_DIR NEW_BIN_DIR [ROUNDS] > compare.csv
# (BENCHMARKS.md "Architecture pass" was measured with it: two rounds, base = a build of 08849f9.)
set -euo pipefail
base=$1; new=$2; rounds=${3:-2}
round() {
  local tag=$1 bin=$2
  "$bin/bench_core" --benchmark_filter='BM_CoreTileLoop/2000|BM_CoreTileLoopHeavy/2000|BM_CoreSnapshot|BM_CoreMove/10' \
    --benchmark_min_time=0.3 --benchmark_format=csv 2>/dev/null | grep -v '^name' | sed "s/^/$tag,/"
  "$bin/bench_blind_mapping" --benchmark_min_time=0.3 --benchmark_format=csv 2>/dev/null | grep -v '^name' | sed "s/^/$tag,/"
  "$bin/bench_lidar_fusion" --benchmark_filter='BM_LidarFusion_Kitti_400x400_5cm_(NoCleanup|Cleanup)/|BM_LidarFusion_TimeUpdate' \
    --benchmark_min_time=0.3 --benchmark_format=csv 2>/dev/null | grep -v '^name' | sed "s/^/$tag,/"
  "$bin/bench_sim" --benchmark_filter='BM_SimRealtime/2' --benchmark_format=csv 2>/dev/null | grep -v '^name' | sed "s/^/$tag,/"
}
for r in $(seq 1 "$rounds"); do
  round "base$r" "$base"
  round "new$r" "$new"
done
