#!/usr/bin/env python3
"""Where the soil map's error lives on a strip scenario (docs/soil_estimator.md, "Where the
error lived in the soil map").

    mpirun --allow-run-as-root -np 2 build/bin/terramap dataset configs/dataset/strips/SCENARIO.yaml --out DIR
    python3 scripts/analysis/strip_zone_fit.py DIR [--geometry mapped|truth] [--gate mixture|observed]
        [--model v2|one_wedge]

Reads a `terramap dataset` of a fixed scenario (its rows, the mapped geometry and cross-section
beside the simulator's, and each row's truth soil) and prints, per episode and per truth soil
zone of the rows:
  - the mapped cut cross-section (sum of d ds) and surcharge against the simulator's (medians,
    quartiles);
  - the soil fitted jointly to every moving row of the zone (bounded soft-L1 least squares, the
    interface bounded by the soil: c_a = a c, delta = b phi), with soil_fit's physics (v2: one
    wedge holding the cut's cross-section, the pile loading the wedge over the cutting width and
    pushed elsewhere, the penetration over the cutting width; the gate a latent switch decided by
    the force with the observed speed as prior) on the mapped geometry or on the simulator's;
    its bias against the zone's truth and the FEE index at the reference cut (alpha 0, rho 80 deg,
    w 1.85 m, d 0.2 m, no surcharge) against the truth's.
A zone's fit is an upper bound of what a soil map can hold there: it pools every row the soil
gave, where the map's windows pool ten sweeps.

Needs Debian's python3-h5py and python3-scipy.
"""
import argparse
import glob
import math
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")
import h5py  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402
from scipy.stats import norm  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from soil_joint_fit import bearing, fee  # noqa: E402

DEG = math.pi / 180
VZ = 34             # blade_vz_map_mps in the observation features
EDGE_M = 0.025      # the penetration term's edge (soil_fit edge_thickness_m)
PILE_MU = math.tan(33 * DEG)
SIGMA_N, SIGMA_REL = 1500.0, 0.06   # soil_fit force_sigma_n, force_sigma_rel
GATE_SIGMA = 0.05   # soil_fit gate_speed_sigma_mps
BLADE_W = 1.85
# c, phi, gamma, a = c_a / c, b = delta / phi
LO = np.array([0.0, 10 * DEG, 12e3, 0.0, 0.0])
HI = np.array([60e3, 50 * DEG, 22e3, 1.0, 1.0])


def soil_of(x):
    c, phi, g, a, b = x
    return c, phi, a * c, b * phi, g


def episodes(ds):
    for fn in sorted(glob.glob(os.path.join(ds, "episodes", "*.h5"))):
        with h5py.File(fn, "r") as f:
            yield fn, {k: f[k][:] for k in f.keys() if isinstance(f[k], h5py.Dataset)}


def rows(e, sel, zone_phi, geometry, model):
    obs = e["obs"][sel]
    T, P = obs.shape[1], e["theta_k"].shape[1]
    hz = obs[:, T - P:, :]
    tk, pr = e["theta_k"][sel].astype(float), e["profile"][sel].astype(float)
    tg, tp = e["truth_geometry_rows"][sel].astype(float), e["truth_profile_rows"][sel].astype(float)
    F = e["force"][sel].astype(float)
    track = 0.5 * (hz[..., 26] + hz[..., 27])
    moving = ~((track > 0.1) & (hz[..., 0] < 0.2 * track))
    if geometry == "truth":
        A, M2, wcut = tp[..., 0], tp[..., 1], tg[..., 3]
        g = dict(alpha=tg[..., 0], rho=tg[..., 1], q=tg[..., 4], wcut=wcut, A=A, M2=M2)
    else:
        A, M2, wcut = pr[..., 0], pr[..., 1], tk[..., 2]
        g = dict(rho=tk[..., 0], alpha=tk[..., 1], q=tk[..., 4], wcut=wcut, A=A, M2=M2)
    if model == "one_wedge":
        d = tg[..., 2] if geometry == "truth" else tk[..., 3]
        g["d"], g["w"] = d, wcut
        g["pushed"] = np.zeros_like(d)
        g["dpen"] = d
    else:
        g["d"], g["w"] = M2 / A, A * A / M2
        share = np.clip(wcut / BLADE_W, 0, 1)
        g["pushed"] = g["q"] * (1 - share)
        g["q"] = g["q"] * share
        g["dpen"] = A / (wcut * np.cos(g["alpha"]))
    g["p"] = norm.cdf(-hz[..., VZ].astype(float) / GATE_SIGMA)
    keep = moving & (np.abs(tp[..., 4] - zone_phi) < 1e-3) & np.isfinite(F).all(-1)
    keep &= np.all([np.isfinite(v) for v in g.values()], axis=0) & (np.nan_to_num(g["d"]) > 0) & (np.nan_to_num(g["w"]) > 0)
    g = {k: v[keep] for k, v in g.items()}
    return g, F[keep]


def parts(x, g):
    th = soil_of(x)
    fx, fz = fee(th, g["rho"], g["alpha"], g["d"], g["w"], g["q"])
    ok = np.isfinite(fx) & np.isfinite(fz)
    fx = np.where(ok, fx, 0) + PILE_MU * g["pushed"]
    fz = np.where(ok, fz, 0)
    c, phi, _, _, gamma = th
    nc, nq = bearing(phi)
    pen = (c * nc + gamma * g["dpen"] * nq) * EDGE_M * g["wcut"]
    return fx, fz, pen


def fit(g, F, gate):
    """soil_fit's fitPooledMultiStart: from the middle of the ranges and the two corners of the
    (c, phi) trade, the fit of least cost."""
    best, best_cost = None, np.inf
    for c0, phi0 in ((0.5, 0.5), (0.8, 0.25), (0.1, 0.7)):
        x0 = 0.5 * (LO + HI)
        x0[0], x0[1] = LO[0] + c0 * (HI[0] - LO[0]), LO[1] + phi0 * (HI[1] - LO[1])
        x, cost = fit_from(g, F, gate, x0)
        if cost < best_cost:
            best, best_cost = x, cost
    return best


def fit_from(g, F, gate, x):
    sx = np.hypot(SIGMA_N, SIGMA_REL * F[:, 0])
    sz = np.hypot(SIGMA_N, SIGMA_REL * F[:, 1])
    om = g["p"] if gate == "mixture" else (g["p"] >= 0.5).astype(float)
    sol = None
    for _ in range(6 if gate == "mixture" else 1):
        def resid(x, om=om):
            fx, fz, pen = parts(x, g)
            prior = ((x - LO) / (HI - LO) - 0.5) / 0.5
            return np.concatenate([(fx - F[:, 0]) / sx, np.sqrt(om) * (fz - pen - F[:, 1]) / sz,
                                   np.sqrt(1 - om) * (fz - F[:, 1]) / sz, prior])
        sol = least_squares(resid, x, bounds=(LO, HI), loss="soft_l1", x_scale=HI - LO)
        x = sol.x
        if gate == "mixture":
            fx, fz, pen = parts(x, g)
            p = np.clip(g["p"], 1e-3, 1 - 1e-3)
            l_on = np.log(p) - 2 * (np.sqrt(1 + ((fz - pen - F[:, 1]) / sz) ** 2) - 1)
            l_off = np.log(1 - p) - 2 * (np.sqrt(1 + ((fz - F[:, 1]) / sz) ** 2) - 1)
            om = 1 / (1 + np.exp(np.clip(l_off - l_on, -50, 50)))
    return x, sol.cost


def index(theta):
    return fee(theta, 80 * DEG, 0.0, 0.2, 1.85, 0.0)[0]


def main():
    np.seterr(all="ignore")
    ap = argparse.ArgumentParser(description="per-zone geometry and joint soil fits of a strip scenario's rows")
    ap.add_argument("dataset")
    ap.add_argument("--geometry", choices=["mapped", "truth"], default="mapped")
    ap.add_argument("--gate", choices=["mixture", "observed"], default="mixture")
    ap.add_argument("--model", choices=["v2", "one_wedge"], default="v2")
    a = ap.parse_args()
    for fn, e in episodes(a.dataset):
        print(os.path.basename(fn))
        rp = e["truth_profile_rows"][..., 4].astype(float)
        for z in np.unique(np.round(rp[np.isfinite(rp)], 4)):
            sel = np.where((np.abs(rp - z) < 1e-3).any(-1))[0]
            if len(sel) < 5:
                continue
            tp, tg = e["truth_profile_rows"][sel].astype(float), e["truth_geometry_rows"][sel].astype(float)
            pr, tk = e["profile"][sel].astype(float), e["theta_k"][sel].astype(float)
            m = (np.abs(tp[..., 4] - z) < 1e-3) & np.isfinite(pr).all(-1) & (tp[..., 0] > 0.002) & (tg[..., 4] > 500)
            ra, rq = pr[..., 0][m] / tp[..., 0][m], tk[..., 4][m] / tg[..., 4][m]
            g, F = rows(e, sel, z, a.geometry, a.model)
            if len(F) < 20:
                continue
            x = fit(g, F, a.gate)
            t = tp[m][0, 3:8]  # c, phi, ca, delta, gamma of the zone
            print("  phi %4.1f deg zone: %4d rows | A map/sim %.2f [%.2f %.2f], Q map/sim %.2f [%.2f %.2f] | "
                  "fit: c %+6.1f kPa, phi %+5.1f deg, gamma %+5.1f kN/m3, index %6.1f / %6.1f kN" % (
                      z / DEG, len(F), np.median(ra), np.quantile(ra, .25), np.quantile(ra, .75),
                      np.median(rq), np.quantile(rq, .25), np.quantile(rq, .75),
                      (x[0] - t[0]) / 1e3, (x[1] - t[1]) / DEG, (x[2] - t[4]) / 1e3,
                      index(soil_of(x)) / 1e3, index(tuple(t)) / 1e3))


if __name__ == "__main__":
    main()
