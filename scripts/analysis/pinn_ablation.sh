#!/usr/bin/env bash
# Trains and evaluates the soil estimator once per variant on one dataset and prints one table
# row per variant from its eval_soil.json (docs/soil_estimator.md and plugins/soil_pinn/README.md
# quote the output). A variant is LABEL:KEY=VALUE;KEY=VALUE... with top-level keys of the
# training config replacing those of configs/train/pinn.yaml, e.g.
#
#   scripts/analysis/pinn_ablation.sh /work/data/pinn_v2 out/ablation \
#     'beta*:beta_base=min' 'Rankine:beta_base=nominal;mask_stalled=false' \
#     'T10:history={T: 10, P: 10}'
#
# Every variant also gets dataset, out and, unless it sets them, members (MEMBERS, 5) and
# loss (LOSS, '{lambda_Fr: 0.00002}'). Trains one variant after the other (one core each).
# Environment: BUILD (build), MEMBERS, LOSS.
set -euo pipefail
cd "$(dirname "$0")/../.."
[[ $# -ge 3 ]] || { sed -n '2,13p' "$0"; exit 2; }
DATA=$(realpath "$1"); OUT=$(realpath -m "$2"); shift 2
BIN=${BUILD:-build}/bin/terramap
mkdir -p "$OUT"
labels=()
for v in "$@"; do
  label=${v%%:*}; spec=${v#*:}
  [[ $label != "$v" ]] || { echo "variant '$v': expected LABEL:KEY=VALUE;..." >&2; exit 2; }
  dir=$OUT/$(echo "$label" | tr -c 'A-Za-z0-9_.-' '_')
  mkdir -p "$dir"
  declare -A set=([dataset]=$DATA [out]=$dir/model.pt [members]=${MEMBERS:-5} [loss]=${LOSS:-"{lambda_Fr: 0.00002}"})
  IFS=';' read -ra kvs <<< "$spec"
  for kv in "${kvs[@]}"; do
    [[ -n $kv ]] || continue
    set[${kv%%=*}]=${kv#*=}
  done
  # The repository's config without the replaced keys (and without comment-only lines).
  pattern=$(IFS='|'; echo "${!set[*]}")
  grep -Ev "^($pattern):" configs/train/pinn.yaml | grep -Ev '^ *#' > "$dir/train.yaml"
  for k in "${!set[@]}"; do echo "$k: ${set[$k]}" >> "$dir/train.yaml"; done
  unset set
  echo "== $label: $BIN train $dir/train.yaml" >&2
  /usr/bin/time -f "%e" -o "$dir/train_time.txt" "$BIN" train -q "$dir/train.yaml" > "$dir/train.log"
  "$BIN" eval-soil "$dir/model.pt" "$DATA" --out "$dir" > "$dir/eval.log"
  labels+=("$label:$dir")
done
python3 - "${labels[@]}" <<'PY'
import json, math, os, sys
deg = 180 / math.pi
print("| variant | train s | test force err % (moving rows) | held-out force err % | test φ MAE ° | held-out φ MAE ° | test c MAE kPa | test 1σ coverage φ / c (total) | epistemic ratio φ / c |")
print("|---|---|---|---|---|---|---|---|---|")
for arg in sys.argv[1:]:
    label, d = arg.split(":", 1)
    j = json.load(open(os.path.join(d, "eval_soil.json")))
    t, h = j["splits"]["test"], j["splits"].get("held_out")
    secs = float(open(os.path.join(d, "train_time.txt")).read().split()[0])
    r = j["epistemic_variance_ratio_held_out_over_test"]
    fmt = lambda x: "n/a" if x is None else "%.2f" % x
    print("| %s | %.0f | %.1f (%.1f) | %s | %.1f | %s | %.1f | %.2f / %.2f | %s / %s |" % (
        label, secs, t["force_error_pct"], t["force_error_moving_rows_pct"],
        "%.1f" % h["force_error_pct"] if h else "n/a",
        t["properties"]["phi"]["mae"] * deg, "%.1f" % (h["properties"]["phi"]["mae"] * deg) if h else "n/a",
        t["properties"]["c"]["mae"] / 1e3,
        t["properties"]["phi"]["coverage_1sigma_total"], t["properties"]["c"]["coverage_1sigma_total"],
        fmt(r["phi"]), fmt(r["c"])))
PY
