#!/usr/bin/env bash
# #15's "terramap sim within 20 % of the benchmark", measured so that the VM's drift falls on both
# sides alike: ROUNDS rounds, each one BM_SimRealtimeSustained/2 (the 16 s workload without the
# writer) and one `terramap sim --duration 16` of the same scenario file (the run's time as it
# prints it, the set-up apart), then the medians and their ratio. DURATION=2 compares the
# scenario file's own 2 s with BM_SimRealtime/2 instead (a short episode carries the close's fixed
# cost: the last snapshot, the seal's checksum and fsync).
#
# Usage: [DURATION=16|2] scripts/bench/sim_writer_ratio.sh [ROUNDS] [BIN_DIR]     (defaults: 7, build/bin)
set -euo pipefail
rounds=${1:-7}
bin=${2:-build/bin}
duration=${DURATION:-16}
case "$duration" in
  16) filter='BM_SimRealtimeSustained/2/' ;;
  2) filter='BM_SimRealtime/2/' ;;
  *) echo "sim_writer_ratio.sh: DURATION must be 16 or 2" >&2; exit 2 ;;
esac
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
bench=() sim=()
for r in $(seq 1 "$rounds"); do
  b=$("$bin/bench_sim" --benchmark_filter="$filter" --benchmark_format=json 2>/dev/null |
      python3 -c 'import json,sys; b=json.load(sys.stdin)["benchmarks"][0]; print(b["real_time"])  # per iteration, ms')
  s=$("$bin/terramap" sim configs/scenarios/bench_ctl_os1_64.yaml --duration "$duration" --out "$out/ep" |
      sed -n 's/.*simulated in \([0-9.]*\) s wall.*/\1/p')
  rm -rf "$out/ep"
  bench+=("$b") sim+=("$s")
  echo "round $r: ${filter%/} ${b} ms, terramap sim ${s} s" >&2
done
python3 - "${bench[*]}" "${sim[*]}" "$duration" "${filter%/}" <<'PY'
import statistics, sys
b = statistics.median(float(x) for x in sys.argv[1].split()) / 1000.0
s = statistics.median(float(x) for x in sys.argv[2].split())
d, name = float(sys.argv[3]), sys.argv[4]
print(f"median {name} {b:.3f} s ({d / b:.1f}x), terramap sim --duration {d:g} {s:.3f} s "
      f"({d / s:.1f}x): the writer costs {100 * (s / b - 1):.0f} % of the time, "
      f"{100 * (1 - b / s):.0f} % below the benchmark's real-time factor")
PY
