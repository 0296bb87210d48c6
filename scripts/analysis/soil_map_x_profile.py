#!/usr/bin/env python3
"""The soil map along x, per truth soil zone (docs/soil_estimator.md, "The pile beyond the
blade's capacity"): where along the passes the estimates drift from the truth.

    python3 scripts/analysis/soil_map_x_profile.py OUT [STEP_M]

OUT is the --out folder of `terramap eval-soil-map SCENARIO` (map.tif and report.json). Per
STEP_M (0.5 m) of x and zone (-1 the default soil, 0 the strip), the median c (kPa), φ (deg) and
γ (kN/m^3), the median |estimate - truth| / published σ of c and φ ("zc", "zphi": about 0.67
when the variances are calibrated), the FEE index against the truth's and the estimates fused
per cell. The zone's truth is its cells' mean estimate minus report.json's bias for the zone.
Needs Debian's python3-gdal.
"""
import json
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")
import numpy as np  # noqa: E402
from osgeo import gdal  # noqa: E402


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    step = float(sys.argv[2]) if len(sys.argv) > 2 else 0.5
    ds = gdal.Open(out + "/map.tif")
    if ds is None:
        sys.exit(f"{out}/map.tif: cannot open as GeoTIFF")
    b = {ds.GetRasterBand(i).GetDescription(): ds.GetRasterBand(i).ReadAsArray().astype(float)
         for i in range(1, ds.RasterCount + 1)}
    by_zone = json.load(open(out + "/report.json"))["truth"]["soil"]["properties_by_zone"]
    gt = ds.GetGeoTransform()
    h, w = b["soil_c"].shape
    x = np.broadcast_to(gt[0] + (np.arange(w) + 0.5) * gt[1], (h, w))
    zone = b["truth_soil_zone"]
    ok = np.isfinite(b["soil_c"]) & np.isfinite(b["fee_index"])
    print(f"{'x m':>5} {'zone':>4} {'cells':>5} {'c':>6} {'zc':>5} {'phi':>6} {'zphi':>5} {'gamma':>5} {'index':>6} {'truth':>6} {'n':>4}")
    for zid in sorted(by_zone, key=float):
        inz = ok & (zone == float(zid))
        truth = {p: np.mean(b["soil_" + p][inz]) - by_zone[zid]["soil_" + p]["bias"] for p in ("c", "phi")}
        for x0 in np.arange(np.floor(x[inz].min()), x[inz].max(), step):
            m = inz & (x >= x0) & (x < x0 + step)
            if m.sum() < 20:
                continue
            c, phi = b["soil_c"][m], b["soil_phi"][m]
            zc = np.median(np.abs(c - truth["c"]) / np.sqrt(b["soil_c_var"][m]))
            zphi = np.median(np.abs(phi - truth["phi"]) / np.sqrt(b["soil_phi_var"][m]))
            print(f"{x0:5.2f} {int(zid):4d} {m.sum():5d} {np.median(c) / 1e3:6.1f} {zc:5.2f} {np.degrees(np.median(phi)):6.1f}"
                  f" {zphi:5.2f} {np.median(b['soil_gamma'][m]) / 1e3:5.1f} {np.median(b['fee_index'][m]) / 1e3:6.1f}"
                  f" {np.median(b['truth_fee_index'][m]) / 1e3:6.1f} {np.median(b['soil_n'][m]):4.1f}")


if __name__ == "__main__":
    main()
