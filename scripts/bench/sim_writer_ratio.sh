#!/usr/bin/env bash
# `terramap sim` measured so that the VM's drift falls on both sides alike: ROUNDS rounds, each
# one run of the reference and one `terramap sim` of configs/scenarios/bench_ctl_os1_64.yaml
# (the run's time as it prints it, the set-up apart), then the medians.
#
#   scripts/bench/sim_writer_ratio.sh [ROUNDS] [BIN_DIR]            (defaults: 7, build/bin)
#     the writer's goal, "within 20 % of the benchmark": the reference is the same workload
#     without the writer, BM_SimRealtimeSustained/2 against `--duration 16`; DURATION=2 compares
#     the file's own 2 s
#     with BM_SimRealtime/2 (a short episode carries the close's fixed cost).
#   BASE_BIN=OTHER/bin scripts/bench/sim_writer_ratio.sh [ROUNDS] [BIN_DIR]
#     before/after: the reference is `terramap sim` of another build (e.g. a `git worktree` of the
#     commit before, built with `cmake --build B --target terramap`).
#
# Also prints the medians of the writer thread's CPU seconds and of the close, as terramap sim
# reports them.
set -euo pipefail
rounds=${1:-7}
bin=${2:-build/bin}
duration=${DURATION:-16}
base_bin=${BASE_BIN:-}
case "$duration" in
  16) filter='BM_SimRealtimeSustained/2/' ;;
  2) filter='BM_SimRealtime/2/' ;;
  *) echo "sim_writer_ratio.sh: DURATION must be 16 or 2" >&2; exit 2 ;;
esac
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

# One `terramap sim` run of BIN: "run_s writer_cpu_s close_s" (nan where an older build does not
# print the last two).
sim_run() {
  "$1/terramap" sim configs/scenarios/bench_ctl_os1_64.yaml --duration "$duration" --out "$out/ep" | python3 -c '
import re, sys
t = sys.stdin.read()
f = lambda p: (re.search(p, t) or [None, "nan"])[1]
print(f(r"simulated in ([0-9.e+-]+) s wall"), f(r"writer thread used ([0-9.e+-]+) s of CPU"), f(r"to disk\) ([0-9.e+-]+) s of the run"))'
  rm -rf "$out/ep"
}

: > "$out/ref" ; : > "$out/new"
for r in $(seq 1 "$rounds"); do
  if [[ -n "$base_bin" ]]; then
    sim_run "$base_bin" >> "$out/ref"
  else
    "$bin/bench_sim" --benchmark_filter="$filter" --benchmark_format=json 2>/dev/null |
      python3 -c 'import json,sys; b=json.load(sys.stdin)["benchmarks"][0]; print(b["real_time"] / 1000.0)' >> "$out/ref"
  fi
  sim_run "$bin" >> "$out/new"
  echo "round $r: reference $(tail -1 "$out/ref"), terramap sim (run, writer CPU, close) $(tail -1 "$out/new")" >&2
done
python3 - "$out/ref" "$out/new" "$duration" "${base_bin:-${filter%/}}" "${base_bin:+builds}" <<'PY'
import statistics, sys
col = lambda path, k: statistics.median(float(line.split()[k]) for line in open(path) if line.strip())
ref, new, d, name = col(sys.argv[1], 0), col(sys.argv[2], 0), float(sys.argv[3]), sys.argv[4]
writer = f"writer thread {col(sys.argv[2], 1):.3f} s CPU, close {col(sys.argv[2], 2):.3f} s"
if sys.argv[5]:  # before/after of two builds
    print(f"terramap sim --duration {d:g}, medians: {name} {ref:.3f} s ({d / ref:.1f}x) -> this build {new:.3f} s "
          f"({d / new:.1f}x), {100 * (new / ref - 1):+.0f} % of the time; {writer}")
else:
    print(f"median {name} {ref:.3f} s ({d / ref:.1f}x), terramap sim --duration {d:g} {new:.3f} s ({d / new:.1f}x): "
          f"the writer adds {100 * (new / ref - 1):.0f} % to the time, {100 * (1 - ref / new):.0f} % below the "
          f"benchmark's real-time factor; {writer}")
PY
