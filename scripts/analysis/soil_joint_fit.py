#!/usr/bin/env python3
"""Can the force tell the soil when many sweeps of one soil are fitted together?
(docs/soil_estimator.md, "Where the error lives")

    python3 scripts/analysis/soil_joint_fit.py DATASET_DIR [SPLIT] [--geometry GEOMETRY] [--chunk K]
        [--episodes all|graded|random]

Per episode of a `terramap dataset` split (one uniform soil each), fits the five soil properties
jointly to every moving horizon row of every sample (the measured force, along x and z), with
the physics of the estimator's layer made as complete as the decomposition of `eval-soil` found
it worth (F_total at beta*, plus the edge's penetration resistance on rows the observations show
descending), on the mapped geometry (theta_k) or on the simulator's own geometry of each row.
Bounded soft-L1 least squares (scipy) from the middle of the estimator's ranges. Prints per
property the MAE, bias and correlation of the fitted soils against the truth, beside a constant
(the split's median truth): whether pooling sweeps of one soil identifies what one sweep cannot
(one sweep's phi has no skill: docs/soil_estimator.md). An upper bound for a soil map that
fuses the force's likelihood rather than per-sweep estimates. `--chunk K` fits every K
consecutive samples of an episode on their own instead (what a map cell sees of a few sweeps).

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

DEG = math.pi / 180
# soil_parameters.hpp kSoilParams: c, phi, ca, delta, gamma
LO = np.array([0.0, 10 * DEG, 0.0, 5 * DEG, 12e3])
HI = np.array([60e3, 50 * DEG, 30e3, 40 * DEG, 22e3])
EDGE_M = 0.025
VZ = 34  # blade_vz_map_mps in the observation features


def beta_star(phi, delta, alpha, rho):
    """fee::betaMin's closed form, vectorised; Rankine's angle where no admissible minimum."""
    K1, K2 = np.sin(delta + rho - alpha), np.sin(rho)
    E = alpha + delta + rho + 2 * phi
    a = K1 * np.cos(rho) - K2 * np.cos(E)
    b = -K1 * np.sin(rho) + K2 * np.sin(E)
    R = np.hypot(a, b)
    ratio = np.clip(np.sin(delta - alpha) / np.maximum(R, 1e-300), -1, 1)
    t0 = np.arctan2(b, a)
    half = np.arccos(ratio)
    best = np.full_like(phi * alpha, np.nan)
    best_n = np.full_like(best, np.inf)
    for k in (-1, 0, 1):
        beta = 0.5 * (t0 + half) + math.pi * k
        eta = delta + rho + phi + beta
        apb = alpha + phi + beta
        ok = (beta > 0) & (beta < math.pi / 2) & (rho + beta < math.pi) & (eta > 0) & (eta < math.pi) & (apb > 0) & (apb < math.pi)
        with np.errstate(all="ignore"):
            ng = (1 / np.tan(rho) + 1 / np.tan(beta)) * np.sin(apb) / (2 * np.sin(eta))
        take = ok & (ng < best_n)
        best = np.where(take, beta, best)
        best_n = np.where(take, ng, best_n)
    return np.where(np.isfinite(best), best, math.pi / 4 - phi / 2)


def fee(theta, rho, alpha, d, w, q):
    """F_total of the FEE at beta* (fee::evaluateAtBetaMin), blade on soil [x, z]."""
    c, phi, ca, delta, gamma = theta
    beta = beta_star(phi, delta, alpha, rho)
    with np.errstate(all="ignore"):
        eta = delta + rho + phi + beta
        S, sA = np.sin(eta), np.sin(alpha + phi + beta)
        ng = (1 / np.tan(rho) + 1 / np.tan(beta)) * sA / (2 * S)
        nc = np.cos(phi) / (np.sin(beta) * S)
        nq = sA / S
        nca = -np.cos(rho + phi + beta) / (np.sin(rho) * S)
        f = gamma * d * d * w * ng + c * d * w * nc + q * nq + ca * d * w * nca
        th = rho + delta - alpha
        fx = f * np.sin(th) + ca * d * w / np.sin(rho) * np.cos(rho - alpha)
        fz = f * np.cos(th) - ca * d * w / np.sin(rho) * np.sin(rho - alpha)
    return fx, fz


def bearing(phi):
    t = math.tan(phi)
    nq = math.exp(math.pi * t) * math.tan(math.pi / 4 + phi / 2) ** 2
    return (nq - 1) / t, nq


def force(theta, g):
    c, phi, ca, delta, gamma = theta
    rho, alpha, w, d, q, down = g["rho"], g["alpha"], g["w"], g["d"], g["q"], g["down"]
    fx, fz = fee(theta, rho, alpha, d, w, q)
    Nc, Nq = bearing(phi)
    with np.errstate(all="ignore"):
        fz = fz - down * (c * Nc + gamma * d * Nq) * EDGE_M * w
    valid = (d > 0) & np.isfinite(fx) & np.isfinite(fz)
    return np.where(valid, fx, 0.0), np.where(valid, fz, 0.0)


def episodes(dataset, split, route="all"):
    """Episodes of a split; route: "graded" keeps the episodes a route controller graded to a
    plane (the way the soil-map scenarios work), "random" the random-walk ones."""
    for fn in sorted(glob.glob(os.path.join(dataset, "episodes", "*.h5"))):
        with h5py.File(fn, "r") as f:
            if f.attrs["split"].decode() != split:
                continue
            graded = bool(f["plan"][8] > 0.5)
            if (route == "graded" and not graded) or (route == "random" and graded):
                continue
            yield fn, {k: f[k][:] for k in ("obs", "theta_k", "force", "truth", "truth_geometry_rows", "edge_vz")}


def rows_of(e, geometry, sel=slice(None)):
    e = {k: v[sel] for k, v in e.items()}
    obs, tk, F = e["obs"], e["theta_k"], e["force"]
    T, P = obs.shape[1], tk.shape[1]
    hz = obs[:, T - P:, :]
    track = 0.5 * (hz[..., 26] + hz[..., 27])
    moving = ~((track > 0.1) & (hz[..., 0] < 0.2 * track))
    if geometry in ("truth", "truth_observed_gate", "truth_mapped_alpha_rho"):
        tg = e["truth_geometry_rows"]
        g = {"alpha": tg[..., 0], "rho": tg[..., 1], "d": tg[..., 2], "w": tg[..., 3], "q": tg[..., 4],
             "down": (e["edge_vz"] < 0).astype(float)}
        if geometry == "truth_observed_gate":
            g["down"] = (hz[..., VZ] < 0).astype(float)
        if geometry == "truth_mapped_alpha_rho":
            g["alpha"], g["rho"] = tk[..., 1], tk[..., 0]
    else:
        g = {"rho": tk[..., 0], "alpha": tk[..., 1], "w": tk[..., 2], "d": tk[..., 3], "q": tk[..., 4],
             "down": (hz[..., VZ] < 0).astype(float)}
        # The mapped geometry with one of the simulator's quantities in its place: which one
        # carries the loss.
        tg = e["truth_geometry_rows"]
        for name, col in (("q", 4), ("d", 2)):
            if geometry == "mapped_truth_" + name:
                g[name] = tg[..., col]
        if geometry == "mapped_truth_gate":
            g["down"] = (e["edge_vz"] < 0).astype(float)
    keep = moving & np.isfinite(F).all(-1) & np.all([np.isfinite(v) for v in g.values()], axis=0)
    keep &= np.nan_to_num(g["d"]) > 0
    g = {k: v[keep].astype(float) for k, v in g.items()}
    return g, F[keep].astype(float)


def main():
    ap = argparse.ArgumentParser(description="joint soil fits per episode (docs/soil_estimator.md)")
    ap.add_argument("dataset")
    ap.add_argument("split", nargs="?", default="test")
    ap.add_argument("--geometry", choices=["mapped", "truth", "mapped_truth_q", "mapped_truth_d", "mapped_truth_gate",
                                               "truth_observed_gate", "truth_mapped_alpha_rho"],
                    default="mapped")
    ap.add_argument("--chunk", type=int, default=0)
    ap.add_argument("--episodes", choices=["all", "graded", "random"], default="all",
                    help="graded: only the episodes graded to a plane by a route controller")
    a = ap.parse_args()
    dataset, split, geometry, chunk = a.dataset, a.split, a.geometry, a.chunk
    fits, truths = [], []
    for fn, e in episodes(dataset, split, a.episodes):
        n = len(e["force"])
        for s0 in (range(0, n - chunk + 1, chunk) if chunk > 0 else [0]):
            fit_rows(e, geometry, slice(s0, s0 + chunk) if chunk > 0 else slice(None), fits, truths)
    report(np.array(fits), np.array(truths), split, geometry, chunk, dataset)


def fit_rows(e, geometry, sel, fits, truths):
        g, F = rows_of(e, geometry, sel)
        if len(F) < 5:
            return

        def resid(x):
            fx, fz = force(x, g)
            return np.concatenate([fx - F[:, 0], fz - F[:, 1]]) / 1000.0
        x0 = 0.5 * (LO + HI)
        r = least_squares(resid, x0, bounds=(LO, HI), loss="soft_l1", f_scale=1.0, x_scale=HI - LO)
        fits.append(r.x)
        truths.append(e["truth"][0].astype(float))


def report(fits, truths, split, geometry, chunk, dataset):
    if len(fits) == 0:
        sys.exit(dataset + ": no episodes in split " + split)
    print("%d fits on split %s, %s geometry, %s" % (len(fits), split, geometry,
          "every %d consecutive samples" % chunk if chunk > 0 else "one joint fit per episode"))
    names, scale, unit = ["c", "phi", "ca", "delta", "gamma"], [1e-3, 1 / DEG, 1e-3, 1 / DEG, 1e-3], ["kPa", "deg", "kPa", "deg", "kN/m3"]
    for k in range(5):
        err = (fits[:, k] - truths[:, k]) * scale[k]
        const = (np.median(truths[:, k]) - truths[:, k]) * scale[k]
        r = np.corrcoef(fits[:, k], truths[:, k])[0, 1] if np.std(fits[:, k]) > 0 else float("nan")
        print("  %-6s MAE %7.2f %-6s bias %+7.2f  r %5.2f   (constant: MAE %7.2f)" % (
            names[k], np.mean(np.abs(err)), unit[k], np.mean(err), r, np.mean(np.abs(const))))


if __name__ == "__main__":
    main()
