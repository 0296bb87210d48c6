#!/usr/bin/env python3
"""Where the strata's boundary misses, from one `terramap eval-strata` output folder
(plugins/octomap_strata/README.md, "What limits the boundary").

  /usr/bin/python3 scripts/analysis/strata_boundary_breakdown.py OUT [--initial Z] [--top A B]

OUT is eval-strata's --out (map.tif, report.json, eval_strata.json). Prints:
  - the soil estimates (soil_pinn's or soil_oracle's records in report.json) whose cohesion lies
    between the two soils' (more than 10 % of their difference from either): sweeps that cut
    across the change, or noise;
  - per 0.25 m of x, over the columns with a change: the strata's first surface (change height
    + change depth) less the ground's initial height Z (default 0: the strata scenario's flat
    site), and the boundary depth's mean error and share within one voxel, the clay's top at depth
    A + B x (default 0.25 + 0.02 x, configs/scenarios/strata_loam_over_clay.yaml);
  - the same depth error per 0.25 m of y (the same in every row: the misses are sweep by sweep).
Needs GDAL's Python bindings and numpy (Debian: python3-gdal, python3-numpy).
"""
import argparse
import json
import os

import numpy as np
from osgeo import gdal


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--initial", type=float, default=0.0)
    ap.add_argument("--top", type=float, nargs=2, default=[0.25, 0.02])
    a = ap.parse_args()

    ev = json.load(open(os.path.join(a.out, "eval_strata.json")))
    c0, c1 = ev["estimator"]["properties"]["c"]["truth"]
    lo, hi = sorted((c0, c1))
    margin = 0.1 * (hi - lo)
    rep = json.load(open(os.path.join(a.out, "report.json")))
    recs = [r for s in rep["stages"] if s["type"] in ("soil_pinn", "soil_oracle") for r in s.get("records", [])
            if r.get("valid")]
    mixed = sum(1 for r in recs if lo + margin < r["mean"][0] < hi - margin)
    print(f"estimates with c between the soils' ({lo:.0f}, {hi:.0f} Pa): {mixed} of {len(recs)}")

    ds = gdal.Open(os.path.join(a.out, "map.tif"))
    bands = {ds.GetRasterBand(i + 1).GetDescription(): ds.GetRasterBand(i + 1).ReadAsArray().astype(float)
             for i in range(ds.RasterCount)}
    gt = ds.GetGeoTransform()
    xs = gt[0] + gt[1] * (np.arange(ds.RasterXSize) + 0.5)
    ys = gt[3] + gt[5] * (np.arange(ds.RasterYSize) + 0.5)
    X, Y = np.meshgrid(xs, ys)
    z, d = bands["strata_change_z_m"], bands["strata_change_depth_m"]
    have = np.isfinite(z) & np.isfinite(d)
    voxel = ev["voxel_m"]
    err = d - (a.top[0] + a.top[1] * X)
    first = z + d - a.initial
    print("x from   columns  first surface - initial (mean, sd)  depth error mean  within a voxel")
    for x0 in np.arange(np.floor(X[have].min() * 4) / 4, X[have].max(), 0.25):
        s = have & (X >= x0) & (X < x0 + 0.25)
        if s.sum():
            print(f"{x0:6.2f} {s.sum():9d}  {first[s].mean():+.4f} m {first[s].std():.4f} m"
                  f"          {err[s].mean():+.4f} m        {np.mean(np.abs(err[s]) <= voxel):.2f}")
    print("y from   columns  depth error mean  within a voxel")
    for y0 in np.arange(np.floor(Y[have].min() * 4) / 4, Y[have].max(), 0.25):
        s = have & (Y >= y0) & (Y < y0 + 0.25)
        if s.sum():
            print(f"{y0:6.2f} {s.sum():9d}  {err[s].mean():+.4f} m        {np.mean(np.abs(err[s]) <= voxel):.2f}")


if __name__ == "__main__":
    main()
