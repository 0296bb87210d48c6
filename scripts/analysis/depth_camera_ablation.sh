#!/usr/bin/env bash
# Runs configs/depth_camera.yaml three times, with the LiDAR and the depth camera, the camera
# alone and the LiDAR alone (the other sensor's line removed from a copy of its scenario), and
# prints the map's error against the simulator's truth from each report.json (docs/sim.md
# "Depth cameras" quotes the output).
#
#   scripts/analysis/depth_camera_ablation.sh OUT
#
# Environment: BUILD (build).
set -euo pipefail
cd "$(dirname "$0")/../.."
[[ $# -eq 1 ]] || { sed -n '2,9p' "$0"; exit 2; }
OUT=$(realpath -m "$1")
BIN=${BUILD:-build}/bin/terramap
mkdir -p "$OUT/configs/scenarios"
cp configs/depth_camera.yaml "$OUT/configs/"
printf '| sensors | coverage | RMSE cm | median abs cm | p95 abs cm | bias cm |\n|---|---|---|---|---|---|\n'
for variant in "LiDAR + camera:" "camera:id: lidar_top" "LiDAR:id: cam,"; do
  label=${variant%%:*}
  drop=${variant#*:}
  scen="$OUT/configs/scenarios/depth_camera.yaml"
  if [[ -n "$drop" ]]; then grep -v -- "$drop" configs/scenarios/depth_camera.yaml > "$scen"
  else cp configs/scenarios/depth_camera.yaml "$scen"; fi
  run="$OUT/${label//[ +]/_}"
  "$BIN" run "$OUT/configs/depth_camera.yaml" --out "$run" --quiet
  python3 - "$run/report.json" "$label" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))["truth"]
print(f"| {sys.argv[2]} | {t['coverage']:.3f} | {100 * t['rmse_m']:.2f} | {100 * t['median_abs_m']:.2f} | "
      f"{100 * t['p95_abs_m']:.2f} | {100 * t['bias_m']:.2f} |")
PY
done
