#!/usr/bin/env bash
# TERA's Fig. 4 on the simulator: the excavator (and the loader) at full lever (both tracks at
# lever 1, a replayed command log) for 10 s on flat loam, gravel and loose sand, and from loam
# into a loose-sand strip at x >= 8 m (the loader has reached its full speed before it); then the
# excavator's undercarriage carrying 2, 4 and 8 times its weight (its drive force scaled alike:
# mean ground pressure 62, 124, 247 kPa) on loam, loose sand and into the strip. Prints the
# steady mean speed (2-10 s, or on the strip 1.5 m past its edge to the end), the lowest speed
# after 1 s, and for the strip the mean speed over the last metre before the tracks reach it and
# the lowest while they cross its edge (the entry dip), and how far the base sank over the run
# (docs/sim.md "TERA's Fig. 4" quotes the output). Reads the truth trajectory that
# `terramap sim --export-tum` writes (stamp x y z qx qy qz qw). What terramechanics gives for the
# same machines: build/bin/test_sim --gtest_filter=TrackSoil.SlowDownFloor*
#
#   scripts/analysis/fig4_speeds.sh OUT
#
# Environment: BUILD (build), BIN (overrides BUILD/bin/terramap), PYTHON (python3 with numpy).
set -euo pipefail
cd "$(dirname "$0")/../.."
[[ $# -eq 1 ]] || { sed -n '2,16p' "$0"; exit 2; }
OUT=$(realpath -m "$1")
BIN=$(realpath "${BIN:-${BUILD:-build}/bin/terramap}")
mkdir -p "$OUT"
# The blade (the excavator's plow) is raised to the top of its travel over the first 1.4 s: the
# ruts of the heavier machines are deeper than its 0.2 m starting clearance, and then it ploughs.
printf 't_s,left,right,lift,tilt,angle,slew,boom,arm,bucket\n0,1,1,1,0,0,0,0,0,0\n1.4,1,1,0,0,0,0,0,0,0\n10,1,1,0,0,0,0,0,0,0\n' > "$OUT/excavator.csv"
printf 't_s,left,right,lift,tilt,angle\n0,1,1,1,0,0\n1.4,1,1,0,0,0\n10,1,1,0,0,0\n' > "$OUT/ctl.csv"
printf '| machine | ground | steady speed m/s | lowest after 1 s m/s | before the strip m/s | lowest crossing its edge m/s | base sank cm |\n|---|---|---|---|---|---|---|\n'
# machine:mass factor (excavator only; 1 = as specified)
for config in excavator:1 ctl:1 excavator:2 excavator:4 excavator:8; do
  machine=${config%%:*}
  k=${config##*:}
  grounds=("loam 0.4" "gravel 0.5" "sand 0.0" "loam 0.4 into sand 0.0")
  [[ $k != 1 ]] && grounds=("loam 0.4" "sand 0.0" "loam 0.4 into sand 0.0")
  for ground in "${grounds[@]}"; do
    set -- $ground
    zones=""
    [[ $# -gt 2 ]] && zones="  zones: [{name: sand, family: $4, relative_density: $5, strip: {axis: x, range_m: [8, 30]}}]"
    type_line=""
    vehicle_line=""
    label=$machine
    if [[ $machine == excavator ]]; then
      type_line="    type: excavator"
      if [[ $k != 1 ]]; then
        vehicle_line="    vehicle: {mass_kg: $((3500 * k)), max_drive_force_n: $((30000 * k))}"
        label="excavator x $k ($((35 * k / 10)) t)"
      fi
    fi
    cat > "$OUT/s.yaml" <<YAML
version: 1
seed: 2
duration_s: 10
terrain: {size_m: [34, 8], origin_m: [-4, -4], resolution_m: 0.02, snapshot_interval_s: 10}
soil:
  default: {family: $1, relative_density: $2}
$zones
machines:
  - id: m
$type_line
$vehicle_line
    controller: {type: replay, file: $machine.csv, units: lever}
YAML
    "$BIN" sim "$OUT/s.yaml" --out "$OUT/run" --no-clouds --export-tum "$OUT/path.tum" > /dev/null
    half=$([[ $machine == excavator ]] && echo 0.925 || echo 0.95)
    "${PYTHON:-/usr/bin/python3}" - "$OUT/path.tum" "$label" "$ground" "$half" <<'PY'
import sys
import numpy as np
P = np.loadtxt(sys.argv[1])
st, x, z = P[:, 0], P[:, 1], P[:, 3]
v = np.diff(x) / np.diff(st)
tm = 0.5 * (st[1:] + st[:-1])
xm = 0.5 * (x[1:] + x[:-1])
into = "into" in sys.argv[3]
steady = (xm > 9.5) if into else (tm > 2.0)
before = crossing = "–"
if into:
    front = 8.0 - float(sys.argv[4])  # centre x at which the tracks' front reaches the strip
    before = f"{v[(xm > front - 1.0) & (xm <= front)].mean():.4f}"
    crossing = f"{v[(xm > front) & (xm <= 9.5)].min():.4f}"
print(f"| {sys.argv[2]} | {sys.argv[3]} | {v[steady].mean():.4f} | {v[tm > 1].min():.4f} | {before} | {crossing} | "
      f"{100 * (z[0] - z[-1]):.2f} |")
PY
  done
done
