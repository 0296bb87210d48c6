#!/usr/bin/env python3
"""Where the FEE index's AUC is lost on a soil-map run (docs/soil_map.md, "What it says").

The AUC of a zone against the default soil is the probability that a zone cell's index exceeds
a default cell's (ties count half). Its loss, 1 - AUC, is a sum over cell pairs ranked the wrong
way; this prints, per metre of x, how many of those pairs each side's cells take part in
("loss units": per zone cell, the share of default cells at or above it; per default cell, the
share of zone cells at or below it; each side's units sum to 1 - AUC times its cell count), with
the mean index, the mean posterior cohesion and its standard deviation, and the estimates fused.

    python3 scripts/analysis/fig12_auc_breakdown.py OUT/map.tif [ZONE_ID]

OUT is the --out folder of `terramap eval-soil-map SCENARIO` (its map.tif holds fee_index,
soil_c, soil_c_var, soil_n and truth_soil_zone; -1 = default soil, ZONE_ID = the zone, 0 by
default). With OUT/report.json beside it, also the median standard deviation (`sd_total`) of
the valid soil estimates against the uniform prior's over each property's range
(plugins/soil_bayes/README.md, "Why no prior by default"). Needs Debian's python3-gdal (not a
build dependency).
"""
import json
import math
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")  # Debian's GDAL under a non-Debian python
import numpy as np  # noqa: E402
from osgeo import gdal  # noqa: E402


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    zone_id = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
    ds = gdal.Open(sys.argv[1])
    if ds is None:
        sys.exit(f"{sys.argv[1]}: cannot open as GeoTIFF")
    bands = {ds.GetRasterBand(i).GetDescription(): ds.GetRasterBand(i).ReadAsArray().astype(float)
             for i in range(1, ds.RasterCount + 1)}
    for need in ("fee_index", "truth_soil_zone", "soil_c", "soil_c_var", "soil_n"):
        if need not in bands:
            sys.exit(f"{sys.argv[1]}: no band '{need}' (run terramap eval-soil-map)")
    gt = ds.GetGeoTransform()
    f, z = bands["fee_index"], bands["truth_soil_zone"]
    h, w = f.shape
    x = np.broadcast_to(gt[0] + (np.arange(w) + 0.5) * gt[1], (h, w))
    ok = np.isfinite(f) & np.isfinite(z)
    zone, dflt = ok & (z == zone_id), ok & (z == -1.0)
    if not zone.any() or not dflt.any():
        sys.exit("no cells with an index in the zone or in the default soil")
    fz, fd = np.sort(f[zone]), np.sort(f[dflt])
    # Per zone cell: default cells above it (+ half the ties); per default cell: zone cells below.
    def below(sorted_other, values):  # other cells below each value, ties counted half
        lo, hi = np.searchsorted(sorted_other, values, "left"), np.searchsorted(sorted_other, values, "right")
        return lo + 0.5 * (hi - lo)
    loss_zone = 1.0 - below(fd, f[zone]) / fd.size
    loss_dflt = below(fz, f[dflt]) / fz.size
    print(f"AUC {1.0 - loss_zone.mean():.4f}: {fz.size} zone cells, {fd.size} default cells")
    print(f"{'side':8} {'x [m]':>6} {'cells':>6} {'loss units':>10} {'index kN':>9} {'c kPa':>6} {'sd c kPa':>8} {'fused':>6}")
    for name, mask, loss in (("zone", zone, loss_zone), ("default", dflt, loss_dflt)):
        xm = np.floor(x[mask]).astype(int)
        for m in np.unique(xm):
            s = xm == m
            print(f"{name:8} {m:6d} {s.sum():6d} {loss[s].sum():10.1f} {f[mask][s].mean() / 1e3:9.1f} "
                  f"{bands['soil_c'][mask][s].mean() / 1e3:6.1f} {np.sqrt(bands['soil_c_var'][mask][s]).mean() / 1e3:8.1f} "
                  f"{bands['soil_n'][mask][s].mean():6.2f}")
    report = os.path.join(os.path.dirname(os.path.abspath(sys.argv[1])), "report.json")
    if os.path.exists(report):
        estimate_spread(report)


# Physical ranges of [c, phi, c_a, delta, gamma] (include/terramap/soil/soil_parameters.hpp).
RANGES = [("c", 0.0, 60e3, 1e-3, "kPa"), ("phi", math.radians(10), math.radians(50), 180 / math.pi, "deg"),
          ("c_a", 0.0, 30e3, 1e-3, "kPa"), ("delta", math.radians(5), math.radians(40), 180 / math.pi, "deg"),
          ("gamma", 12e3, 22e3, 1e-3, "kN/m^3")]


def estimate_spread(report_path):
    with open(report_path) as f:
        report = json.load(f)
    sds = [[] for _ in RANGES]
    for stage in report.get("stages", []):
        for rec in stage.get("records", []):
            if rec.get("type") == "terramap.soil_estimate.v1" and rec.get("valid"):
                for k in range(len(RANGES)):
                    sds[k].append(rec["sd_total"][k])
    if not sds[0]:
        return
    print(f"median sd_total of {len(sds[0])} valid estimates against the uniform prior's sd, span / sqrt(12):")
    for (name, lo, hi, scale, unit), v in zip(RANGES, sds):
        print(f"  {name:6} {float(np.median(v)) * scale:8.2f} vs {(hi - lo) / math.sqrt(12) * scale:8.2f} {unit}")


if __name__ == "__main__":
    main()
