#!/usr/bin/env python3
"""Where the mapped geometry loses the force, per soil family and density
(docs/soil_estimator.md, "The surcharge the map holds").

    python3 scripts/analysis/surcharge_gap.py DATASET_DIR [all|graded|random]

Last, the sum of mapped over simulated Q by the sample's place in its episode (samples 0-7,
8-19, 20 on): whether the mapped pile keeps up with the simulator's over a pass.

For every moving horizon row of a `terramap dataset` (all splits but held-out), the truth soil's
force through the estimator's physics (F_total at beta* plus the edge's penetration, as
soil_joint_fit.py computes it) on the simulator's geometry and on the mapped geometry, against
the simulator's noise-free force: sum of measured over modelled along x and z. Beside it, row
medians of mapped over simulated depth and width and the sum of mapped over simulated surcharge
Q. Needs Debian's python3-h5py and python3-scipy.
"""
import glob
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, "/usr/lib/python3/dist-packages")
import h5py  # noqa: E402
import numpy as np  # noqa: E402
from soil_joint_fit import force, rows_of  # noqa: E402


def density_bin(i_d):
    return "loose" if i_d < 0.4 else ("mid" if i_d < 0.7 else "dense")


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    dataset, route = sys.argv[1], (sys.argv[2] if len(sys.argv) > 2 else "all")
    gap, geo, progress = {}, {}, {}
    for fn in sorted(glob.glob(os.path.join(dataset, "episodes", "*.h5"))):
        with h5py.File(fn, "r") as f:
            if f.attrs["split"].decode() == "held_out":
                continue
            graded = bool(f["plan"][8] > 0.5)
            if (route == "graded" and not graded) or (route == "random" and graded):
                continue
            key = (f.attrs["family"].decode(), density_bin(f["plan"][3]))
            e = {k: f[k][:] for k in ("obs", "theta_k", "force_quiet", "truth", "truth_geometry_rows", "edge_vz")}
        e["force"] = e.pop("force_quiet")
        soil = e["truth"][0].astype(float)
        for g_name in ("truth", "mapped"):
            g, F = rows_of(e, g_name)
            if len(F) == 0:
                continue
            fx, fz = force(soil, g)
            a = gap.setdefault(key + (g_name,), np.zeros(5))
            a += [F[:, 0].sum(), fx.sum(), F[:, 1].sum(), fz.sum(), len(F)]
        tk, tg = e["theta_k"], e["truth_geometry_rows"]
        ok = (tk[..., 3] > 0) & (tg[..., 2] > 0) & np.isfinite(tk).all(-1) & np.isfinite(tg).all(-1)
        b = geo.setdefault(key, {"d": [], "w": [], "qm": 0.0, "qs": 0.0})
        b["d"] += list((tk[..., 3] / tg[..., 2])[ok])
        b["w"] += list((tk[..., 2] / tg[..., 3])[ok])
        b["qm"] += float(tk[..., 4][ok].sum())
        b["qs"] += float(tg[..., 4][ok].sum())
        for i in range(len(tk)):
            part = "samples 0-7" if i < 8 else ("samples 8-19" if i < 20 else "samples 20+")
            q = progress.setdefault((key[0], part), [0.0, 0.0])
            q[0] += float(tk[i, :, 4][ok[i]].sum())
            q[1] += float(tg[i, :, 4][ok[i]].sum())
    print("family  density  rows(sim)  Fx meas/model sim  mapped   Fz meas/model sim  mapped   "
          "d map/sim  w map/sim  sum Q map/sim")
    for key in sorted(geo):
        s, m, b = gap.get(key + ("truth",)), gap.get(key + ("mapped",)), geo[key]
        if s is None or m is None:
            continue
        print("%-7s %-7s %9d   %14.2f %7.2f   %14.2f %7.2f   %9.2f  %9.2f  %13.2f" % (
            key[0], key[1], s[4], s[0] / s[1], m[0] / m[1], s[2] / s[3], m[2] / m[3],
            np.median(b["d"]), np.median(b["w"]), b["qm"] / b["qs"]))

    print("\nfamily  part of the episode  sum Q map/sim")
    for key in sorted(progress):
        q = progress[key]
        if q[1] > 0:
            print("%-7s %-20s %13.2f" % (key[0], key[1], q[0] / q[1]))


if __name__ == "__main__":
    main()
