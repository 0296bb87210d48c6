#!/usr/bin/env bash
# The accuracy tables docs/sim.md quotes, measured the honest way (realistic localisation and
# occlusion, the defaults, track–soil on) with the ablations beside them (perfect localisation,
# no occlusion, no track–soil).
#   scripts/accuracy_tables.sh [BUILD_DIR]      (default: build)
# Prints Markdown; every number comes from the commands it runs (seconds each, one KITTI test).
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BUILD=${1:-$ROOT/build}
BIN=$BUILD/bin/terramap
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

demo() {  # $1 = localisation or "" ; $2 = lidar_sees_machines or "" ; $3 = track_soil or ""
  local extra=""
  [ -n "$1" ] && extra+=", localisation: $1"
  [ -n "$2" ] && extra+=", lidar_sees_machines: $2"
  [ -n "${3:-}" ] && extra+=", track_soil: $3"
  sed -e "s|source: {type: sim, scenario: scenarios/dense_strip.yaml}|source: {type: sim, scenario: $ROOT/configs/scenarios/dense_strip.yaml$extra}|" \
      -e "s|model: ../models/soil_pinn.pt|model: $ROOT/models/soil_pinn.pt|" \
    "$ROOT/configs/demo.yaml" > "$TMP/demo.yaml"
  rm -rf "$TMP/demo_out"
  "$BIN" run "$TMP/demo.yaml" --out "$TMP/demo_out" > /dev/null || exit 1
  python3 - "$TMP/demo_out/report.json" <<'PY'
import json, sys
t = json.load(open(sys.argv[1]))["truth"]
print("%.2f cm | %.2f cm | %.2f cm | %.3f" % (100 * t["rmse_m"], 100 * t["median_abs_m"], 100 * t["p95_abs_m"], t["coverage"]))
PY
}

fig10() {  # $1 = localisation ; $2 = track-soil model or ""
  rm -rf "$TMP/fig10"
  "$BIN" eval "$ROOT/configs/scenarios/fig10_berm_cut.yaml" --out "$TMP/fig10" --localisation "$1" \
    ${2:+--track-soil "$2"} > /dev/null || exit 1
  python3 - "$TMP/fig10/eval.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
h = j["height_error"]
d = [p for p in j["extraction"]["parameters"] if p["name"] == "d"][0]
print("%.2f cm (bias %+.2f) | %.2f cm | %+.2f cm" % (100 * h["cut"]["rmse_m"], 100 * h["cut"]["bias_m"],
      100 * h["outside"]["rmse_m"], 100 * d["bias"]))
PY
}

extraction() {  # $1 = localisation ; $2 = track-soil model or ""
  rm -rf "$TMP/ex"
  "$BIN" eval "$ROOT/configs/scenarios/extraction_random_walk.yaml" --out "$TMP/ex" --localisation "$1" \
    ${2:+--track-soil "$2"} > /dev/null || exit 1
  python3 - "$TMP/ex/eval.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
p = {q["name"]: q for q in j["extraction"]["parameters"]}
print("%d | %+.2f cm (std %.2f) | %+.2f deg | %+.2f deg | %+.3f m" % (p["d"]["n"], 100 * p["d"]["bias"], 100 * p["d"]["std"],
      p["alpha"]["bias"], p["rho"]["bias"], p["w"]["bias"]))
PY
}

echo "| demo (\`terramap run\`) | truth RMSE | median abs | p95 abs | coverage |"
echo "| --- | ---: | ---: | ---: | ---: |"
echo "| realistic (rtk_imu, occlusion) | $(demo "" "")"
echo "| perfect localisation, occlusion | $(demo perfect "")"
echo "| perfect localisation, no occlusion | $(demo perfect false)"
echo "| realistic, no occlusion | $(demo "" false)"
echo "| realistic without track–soil (\`track_soil: none\`) | $(demo "" "" none)"
echo
echo "| Fig. 10 (\`terramap eval fig10_berm_cut.yaml\`) | RMSE inside the cut | RMSE outside | bias of d |"
echo "| --- | ---: | ---: | ---: |"
echo "| realistic (rtk_imu) | $(fig10 rtk_imu)"
echo "| perfect localisation | $(fig10 perfect)"
echo "| realistic without track–soil (\`--track-soil none\`) | $(fig10 rtk_imu none)"
echo
echo "| extraction (\`terramap eval extraction_random_walk.yaml\`) | sweeps | d bias | alpha bias | rho bias | w bias |"
echo "| --- | ---: | ---: | ---: | ---: | ---: |"
echo "| realistic (rtk_imu) | $(extraction rtk_imu)"
echo "| perfect localisation | $(extraction perfect)"
echo "| realistic without track–soil (\`--track-soil none\`) | $(extraction rtk_imu none)"
echo
echo "KITTI held-out frame (real data; no simulator, so no localisation model applies):"
"$BUILD/bin/test_plugin_lidar_fusion" --gtest_filter='LidarFusionRealData.KittiFramesZeroToFourPredictFrameFiveGround' 2>&1 \
  | grep -o 'frame 5:.*' || echo "(KITTI data not found)"
