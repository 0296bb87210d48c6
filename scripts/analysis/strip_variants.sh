#!/bin/bash
# The default soil map on the eight strip variants (configs/scenarios/variants: other seeds,
# terrains, strip positions and densities than the four strip scenarios the map is tested on),
# two at a time, then a line each: the strip's FEE index against the truth soil's, its AUC, the
# map's c (kPa) and phi (deg) bias and their 1-sigma coverage (docs/soil_estimator.md).
#   scripts/analysis/strip_variants.sh OUT [eval-soil-map options, e.g. --set bayes.behind_m=0]
set -u
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
BIN=${BIN:-$ROOT/build/bin/terramap}
OUT=$1; shift
mkdir -p "$OUT"
run() { local f=$1; shift; "$BIN" eval-soil-map "$f" "$@" --out "$OUT/$(basename "$f" .yaml)" > "$OUT/$(basename "$f" .yaml).log" 2>&1; }
fs=("$ROOT"/configs/scenarios/variants/*.yaml)
for ((i = 0; i < ${#fs[@]}; i += 2)); do
  run "${fs[i]}" "$@" &
  [ -n "${fs[i+1]:-}" ] && run "${fs[i+1]}" "$@"
  wait
done
for f in "${fs[@]}"; do
  s=$(basename "$f" .yaml); log="$OUT/$s.log"
  idx=$(grep 'dense_strip .*cells' "$log" | awk '{printf "%5.1f / %5.1f kN, AUC %s", $5, $9, $NF}')
  bias=$(grep -E '^  soil_(c|phi) ' "$log" | awk '{printf "%s %s ", $1, $5}')
  cov=$(grep -E '^  soil_(c|phi) ' "$log" | awk '{printf "%s ", $9}')
  printf "%-22s | index %s | bias %s| in 1 sd %s\n" "$s" "$idx" "$bias" "$cov"
done
