#!/usr/bin/env python3
"""Where the loose soil lies: the map's `loose` layer against the simulator's
(docs/soil_estimator.md, "The surcharge the map holds").

    python3 scripts/analysis/pile_location.py MAP_TIF EPISODE_H5 X_PILE0 X_PILE1 Y_LANE0 Y_LANE1 [X_BEHIND0]

MAP_TIF: the GeoTIFF of an `eval-soil-map` / `run` whose outputs list `loose` as its first band
(`geotiff: [loose, ...]`); EPISODE_H5: `terramap sim` of the same scenario and duration (its last
terrain snapshot). Prints, in m³ of loose soil for each: the pile (x in [X_PILE0, X_PILE1), y in
the lane), the lane behind it (x in [X_BEHIND0, X_PILE0), default 3 m), beside the lane (1.2 m
either side, behind the pile) and in all. Needs Debian's python3-gdal and python3-h5py.
"""
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")
import h5py  # noqa: E402
import numpy as np  # noqa: E402
from osgeo import gdal  # noqa: E402


def regions(L, xs, ys, cell, xp0, xp1, yl0, yl1, xb0):
    lane = (ys >= yl0) & (ys < yl1)
    side = ((ys >= yl0 - 1.2) & (ys < yl0)) | ((ys >= yl1) & (ys < yl1 + 1.2))
    pile = (xs >= xp0) & (xs < xp1)
    behind = (xs >= xb0) & (xs < xp0)
    return (L[np.ix_(lane, pile)].sum() * cell, L[np.ix_(lane, behind)].sum() * cell,
            L[np.ix_(side, behind)].sum() * cell, L.sum() * cell)


def main():
    if len(sys.argv) < 7:
        sys.exit(__doc__)
    tif, h5 = sys.argv[1], sys.argv[2]
    xp0, xp1, yl0, yl1 = (float(a) for a in sys.argv[3:7])
    xb0 = float(sys.argv[7]) if len(sys.argv) > 7 else 3.0
    d = gdal.Open(tif)
    if d is None or d.GetRasterBand(1).GetDescription() != "loose":
        sys.exit(tif + ": no GeoTIFF with `loose` as its first band")
    gt = d.GetGeoTransform()
    L = np.nan_to_num(d.GetRasterBand(1).ReadAsArray().astype(float))
    xs = gt[0] + gt[1] * (np.arange(L.shape[1]) + 0.5)
    ys = gt[3] + gt[5] * (np.arange(L.shape[0]) + 0.5)
    rows = [("map", regions(L, xs, ys, abs(gt[1] * gt[5]), xp0, xp1, yl0, yl1, xb0))]
    with h5py.File(h5, "r") as f:
        t = f["terrain"]
        res, ox, oy = t.attrs["resolution_m"], t.attrs["origin_x_m"], t.attrs["origin_y_m"]
        Lt = np.nan_to_num(t["loose"][-1].astype(float))
    xt = ox + res * (np.arange(Lt.shape[1]) + 0.5)
    yt = oy + res * (np.arange(Lt.shape[0]) + 0.5)
    rows.append(("simulator", regions(Lt, xt, yt, res * res, xp0, xp1, yl0, yl1, xb0)))
    print("%-10s %10s %12s %12s %8s" % ("m3 loose", "pile", "lane behind", "beside lane", "in all"))
    for name, (p, b, s, a) in rows:
        print("%-10s %10.3f %12.3f %12.3f %8.3f" % (name, p, b, s, a))


if __name__ == "__main__":
    main()
