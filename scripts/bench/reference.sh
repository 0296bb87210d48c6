#!/usr/bin/env bash
# The reference run behind BENCHMARKS.md: every benchmark program once, in one session, each with
# its raw Google Benchmark JSON, the load average before and after it, the commit and the machine;
# then scripts/bench/render.py turns OUTDIR into the tables of BENCHMARKS.md.
#
# Usage: scripts/bench/reference.sh [OUTDIR] [BIN_DIR]     (defaults: out/bench, build/bin)
#        REPS=3 (repetitions where the figure is a median), MIN_TIME=1 (seconds per benchmark),
#        ONLY='sim sim_h5' (a space-separated subset of the entry names below, plus demo and
#        sim_h5, for a targeted re-measurement; render.py prints what the folder holds)
# Needs a Release build with -DTERRAMAP_BUILD_BENCHMARKS=ON (the default build of `make`).
# Takes about 10 minutes on the 2-core VM; run it with nothing else on the machine.
set -euo pipefail
out=${1:-out/bench}
bin=${2:-build/bin}
reps=${REPS:-3}
min_time=${MIN_TIME:-1}
mkdir -p "$out"
{
  echo "commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown)$(git diff --quiet 2>/dev/null || echo ' (modified)')"
  echo "date $(date -u '+%Y-%m-%d %H:%M UTC')"
  echo "cpu $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//') x $(nproc)"
  echo "memory $(awk '/MemTotal/ {printf "%.1f GiB", $2 / 1048576}' /proc/meminfo)"
} > "$out/machine.txt"
: > "$out/load.txt"

# name program filter extra-args...: one JSON per entry, the load average around it.
wanted() { [[ -z "${ONLY:-}" || " $ONLY " == *" $1 "* ]]; }
bench() {
  local name=$1 prog=$2 filter=$3
  shift 3
  wanted "$name" || return 0
  if [[ ! -x "$bin/$prog" ]]; then
    echo "reference.sh: $bin/$prog missing (build with -DTERRAMAP_BUILD_BENCHMARKS=ON)" >&2
    exit 1
  fi
  local l0 l1
  l0=$(cut -d' ' -f1 /proc/loadavg)
  echo "== $name ($prog --benchmark_filter='$filter' $*)" >&2
  "$bin/$prog" --benchmark_filter="$filter" --benchmark_out="$out/$name.json.tmp" \
    --benchmark_out_format=json "$@" > /dev/null
  mv "$out/$name.json.tmp" "$out/$name.json"
  l1=$(cut -d' ' -f1 /proc/loadavg)
  echo "$name $l0 $l1 $(date -u +%H:%M)" >> "$out/load.txt"
}

# lidar_fusion: moving sequences and their peers in one run per map (the ratios come from one
# process), then the steady-state and fresh-tree figures kept for comparison with older notes.
bench lidar_seq_400 bench_lidar_fusion 'BM_(LidarFusionSeq|OctoMapSeq|NaiveSeq)_.*_400x400_5cm' --benchmark_min_time="$min_time"
bench lidar_seq_2000 bench_lidar_fusion 'BM_(LidarFusionSeq|NaiveSeq)_.*_2000x2000_4cm' --benchmark_min_time="$min_time"
bench lidar_steady bench_lidar_fusion 'BM_(LidarFusionSteady|LidarFusion_TimeUpdate|NaiveSteady)_' --benchmark_min_time="$min_time"
bench lidar_fresh_tree bench_lidar_fusion 'BM_OctoMapFreshTree_.*_400x400'
# Simulator: the issue's figure is the median of 3 (each run a whole 2 s or 16 s episode).
bench sim bench_sim 'BM_Sim' --benchmark_repetitions="$reps"
bench core bench_core '.' --benchmark_min_time="$min_time"
bench blind_mapping bench_blind_mapping '.' --benchmark_min_time="$min_time"
bench readers bench_readers '.' --benchmark_min_time="$min_time"
bench traversability bench_traversability '.' --benchmark_min_time="$min_time"
if [[ -x "$bin/bench_soil_pinn" ]]; then bench soil_pinn bench_soil_pinn '.' --benchmark_min_time="$min_time"; fi
if [[ -x "$bin/bench_strata" ]]; then bench strata bench_strata '.'; fi

# The whole demo pipeline (simulator + lidar + blade + erosion + soil chain), as `make demo`
# runs it: simulated seconds per wall second from report.json, three runs.
for r in $(seq 1 "$reps"); do
  wanted demo || break
  l0=$(cut -d' ' -f1 /proc/loadavg)
  "$bin/terramap" run --out "$out/demo_run$r" -q > /dev/null
  l1=$(cut -d' ' -f1 /proc/loadavg)
  echo "demo_run$r $l0 $l1 $(date -u +%H:%M)" >> "$out/load.txt"
done
# `terramap sim` on the simulator benchmark's own scenario file, HDF5 episode and clouds written
# as a user runs it: its "x real time" for the run (the set-up is printed apart) against the same
# workload without the writer, the file's 2 s against BM_SimRealtime/2 and 16 s against
# BM_SimRealtimeSustained/2 (a short episode carries the close's fixed cost: the last snapshot,
# the seal's checksum and fsync).
if wanted sim_h5; then : > "$out/sim_h5.txt"; : > "$out/sim_h5_16s.txt"; fi
for r in $(seq 1 "$reps"); do
  wanted sim_h5 || break
  l0=$(cut -d' ' -f1 /proc/loadavg)
  "$bin/terramap" sim configs/scenarios/bench_ctl_os1_64.yaml --out "$out/sim_h5_run$r" >> "$out/sim_h5.txt"
  "$bin/terramap" sim configs/scenarios/bench_ctl_os1_64.yaml --duration 16 --out "$out/sim_h5_16s_run$r" >> "$out/sim_h5_16s.txt"
  l1=$(cut -d' ' -f1 /proc/loadavg)
  echo "sim_h5_run$r $l0 $l1 $(date -u +%H:%M)" >> "$out/load.txt"
done
echo "reference.sh: wrote $out (render with scripts/bench/render.py $out)" >&2
