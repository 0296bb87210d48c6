#!/usr/bin/env bash
# One CTL on flat ground driving a 10 m route at a 1 m/s set-point for 8 s, with the blade up
# (depth -0.2 m) and cutting 0.1 m, on four soils, without and with `vehicle.track_soil: bekker`;
# prints distance, mean speed, deepest drop of the surface and the compacted volume per run
# (docs/sim.md "Track–soil interaction" quotes the output). Needs python3-h5py.
#
#   scripts/analysis/track_soil_speeds.sh OUT
#
# Environment: BUILD (build), PYTHON (/usr/bin/python3, the interpreter python3-h5py is for).
set -euo pipefail
cd "$(dirname "$0")/../.."
[[ $# -eq 1 ]] || { sed -n '2,9p' "$0"; exit 2; }
OUT=$(realpath -m "$1")
BIN=$(realpath "${BUILD:-build}/bin/terramap")
mkdir -p "$OUT"
printf '| soil | model | blade | distance m | mean speed m/s | deepest drop cm | compacted m³ |\n|---|---|---|---|---|---|---|\n'
for soil in "sand, relative_density: 0.0" "sand, relative_density: 1.0" "clay, relative_density: 0.1" "loam, relative_density: 0.5"; do
  for model in none bekker; do
    for depth in -0.2 0.1; do
      cat > "$OUT/s.yaml" <<YAML
version: 1
seed: 2
duration_s: 8
terrain: {size_m: [16, 8], origin_m: [-4, -4], resolution_m: 0.02, snapshot_interval_s: 8}
soil: {default: {family: $soil}}
machines:
  - id: ctl1
    vehicle: {track_soil: $model}
    controller: {type: route, start_m: [0, 0], length_m: 10, passes: 1, depth_m: $depth, speed_mps: 1.0}
YAML
      "$BIN" sim "$OUT/s.yaml" --out "$OUT/run" > /dev/null
      "${PYTHON:-/usr/bin/python3}" - "$OUT/run/episode.h5" "$soil" "$model" "$depth" <<'PY'
import sys
import h5py
f = h5py.File(sys.argv[1])
T = f["machines/ctl1/T_map_base"][:]
st = f["machines/ctl1/stamp"][:]
dist = T[-1, 0, 3] - T[0, 0, 3]
drop = (f["terrain/initial_height"][:] - f["terrain/height"][-1]).max()
blade = "up" if float(sys.argv[4]) < 0 else "cutting 0.1 m"
print(f"| {sys.argv[2].replace(', relative_density: ', ' I_d ')} | {sys.argv[3]} | {blade} | {dist:.2f} | "
      f"{dist / (st[-1] - st[0]):.3f} | {100 * drop:.2f} | {f.attrs['compacted_volume_m3']:.4f} |")
PY
    done
  done
done
