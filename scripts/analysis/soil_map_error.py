#!/usr/bin/env python3
"""Where the soil map's force model and geometry lose the soil, on a `terramap dataset`
(docs/soil_estimator.md, "Where the error lived in the soil map").

    python3 scripts/analysis/soil_map_error.py physics DATASET   # the FEE part: one wedge, cross-section, pushed pile
    python3 scripts/analysis/soil_map_error.py gate DATASET      # the penetration term with the observed and the true gate; the edge speed's sign, oscillation and smoothing
    python3 scripts/analysis/soil_map_error.py depth DATASET     # mapped depth / cross-section against the simulator's
    python3 scripts/analysis/soil_map_error.py fit DATASET       # joint soil fits per episode on the simulator's geometry

Every split of the dataset is read (nothing here is trained). The dataset must carry the
simulator's rows (`truth_geometry_rows`, `truth_profile_rows`, `force_parts`, `edge_vz`): any
dataset written since 2026-12-01. Needs Debian's python3-h5py and python3-scipy.
"""
import argparse
import math
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")
import h5py  # noqa: E402
import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from soil_joint_fit import bearing, fee  # noqa: E402
from strip_zone_fit import episodes  # noqa: E402

DEG = math.pi / 180
VZ = 34
EDGE_M = 0.025
REPOSE_DEG = {0: 30, 1: 32, 2: 33, 3: 36}  # the simulator's soil table, for the pushed pile
FAMILY = {0: "clay", 1: "loam", 2: "sand", 3: "gravel"}


def moving(e):
    obs = e["obs"]
    T, P = obs.shape[1], e["theta_k"].shape[1]
    hz = obs[:, T - P:, :]
    track = 0.5 * (hz[..., 26] + hz[..., 27])
    return ~((track > 0.1) & (hz[..., 0] < 0.2 * track)), hz


def physics(ds):
    acc, den = {}, 0.0
    for _, e in episodes(ds):
        tr = e["truth"][0].astype(float)
        fam = int(e["plan"][2])
        tg, tp = e["truth_geometry_rows"].astype(float), e["truth_profile_rows"].astype(float)
        parts = e["force_parts"].astype(float)
        fx_s, fz_s = parts[..., 0, 0], parts[..., 0, 1]  # the simulator's FEE part, as mobilised
        alpha, rho, d, w, q = (tg[..., k] for k in range(5))
        A, M2, qp = tp[..., 0], tp[..., 1], tp[..., 2]
        m = np.isfinite(tg).all(-1) & np.isfinite(tp[..., :3]).all(-1) & np.isfinite(parts).all((-1, -2)) & (A > 0)
        den += np.hypot(fx_s, fz_s)[m].sum()
        push = qp * math.tan(REPOSE_DEG[fam] * DEG)
        for name, (fx, fz) in (("one wedge at the mean depth over the cutting width", fee(tr, rho, alpha, d, w, q)),
                               ("one wedge holding the cut's cross-section", fee(tr, rho, alpha, M2 / A, A * A / M2, q))):
            fx, fz = np.nan_to_num(fx), np.nan_to_num(fz)
            a = acc.setdefault(name, [0.0, 0.0])
            a[0] += np.abs(fx - fx_s)[m].sum()
            a[1] += np.abs(fz - fz_s)[m].sum()
            if "cross" in name:
                a = acc.setdefault(name + ", and the pushed pile", [0.0, 0.0])
                a[0] += np.abs(fx + push - fx_s)[m].sum()
                a[1] += np.abs(fz - fz_s)[m].sum()
    print("the simulator's FEE part (as mobilised) against the truth soil through the layer, % of its sum of |F|:")
    for k, (x, z) in acc.items():
        print("  %-70s x %5.1f  z %5.1f" % (k, 100 * x / den, 100 * z / den))


SMOOTH_STEPS = (1, 2, 3, 5, 8)


def gate(ds):
    num_t = num_o = den = 0.0
    V, O = [], []
    S = {k: [] for k in SMOOTH_STEPS}   # the observed speed's centred mean over +-k observation rows
    lag = {1: [], 5: []}                # pairs of the true speed k rows apart
    for _, e in episodes(ds):
        tr = e["truth"][0].astype(float)
        tg, tp = e["truth_geometry_rows"].astype(float), e["truth_profile_rows"].astype(float)
        pen_s = e["force_parts"][..., 2, 1].astype(float)  # the simulator's penetration part (z, blade on soil)
        vz = e["edge_vz"].astype(float)
        _, hz = moving(e)
        ovz = hz[..., VZ].astype(float)
        c, phi, _, _, gamma = tr
        nc, nq = bearing(phi)
        w = tg[..., 3]
        dpen = tp[..., 0] / (w * np.cos(tg[..., 0]))
        model = (c * nc + gamma * dpen * nq) * EDGE_M * w
        m = np.isfinite(model) & np.isfinite(pen_s) & np.isfinite(vz) & np.isfinite(ovz)
        num_t += np.abs(-np.where(vz < 0, model, 0) - pen_s)[m].sum()
        num_o += np.abs(-np.where(ovz < 0, model, 0) - pen_s)[m].sum()
        den += np.abs(pen_s)[m].sum()
        V.append(vz[m])
        O.append(ovz[m])
        full = e["obs"][..., VZ].astype(float)
        T, P = full.shape[1], vz.shape[1]
        for k in SMOOTH_STEPS:
            sm = np.stack([full[:, max(0, T - P + p - k):min(T, T - P + p + k + 1)].mean(1) for p in range(P)], 1)
            S[k].append(sm[m])
        for k in lag:
            both = np.isfinite(vz[:, :-k]) & np.isfinite(vz[:, k:])
            lag[k].append(np.stack([vz[:, :-k][both], vz[:, k:][both]]))
    V, O = np.concatenate(V), np.concatenate(O)
    print("the edge's true vertical speed: |v_z| median %.3f m/s, 90th percentile %.3f m/s; correlation of rows %s" % (
        np.median(np.abs(V)), np.percentile(np.abs(V), 90),
        ", ".join("%d apart %+.2f" % (k, np.corrcoef(np.concatenate(v, 1))[0, 1]) for k, v in lag.items())))
    print("observed sign agrees with the true one on %.1f %% of the rows; its centred mean over +-k rows: %s" % (
        100 * np.mean((O < 0) == (V < 0)),
        ", ".join("k %d %.1f %%" % (k, 100 * np.mean((np.concatenate(S[k]) < 0) == (V < 0))) for k in SMOOTH_STEPS)))
    print("penetration term against the simulator's, %% of its sum: true gate %.1f, observed gate %.1f" % (
        100 * num_t / den, 100 * num_o / den))
    print("observed speed's sign wrong on %.1f %% of the rows; by |true speed|:" % (100 * np.mean((O < 0) != (V < 0))))
    for lo, hi in ((0, 0.002), (0.002, 0.005), (0.005, 0.01), (0.01, 0.02), (0.02, 0.05), (0.05, 10)):
        s = (np.abs(V) >= lo) & (np.abs(V) < hi)
        print("  [%5.3f, %5.3f) m/s: %6d rows, wrong %.1f %%" % (lo, hi, s.sum(), 100 * np.mean((O[s] < 0) != (V[s] < 0))))


def depth(ds):
    med, ratios = [], []
    for _, e in episodes(ds):
        dm, dsim = e["theta_k"][..., 3].astype(float).ravel(), e["truth_geometry_rows"][..., 2].astype(float).ravel()
        am, asim = e["profile"][..., 0].astype(float).ravel(), e["truth_profile_rows"][..., 0].astype(float).ravel()
        m = np.isfinite(dm) & np.isfinite(dsim) & (dsim > 0.02)
        if m.sum() >= 20:
            med.append(np.median(dm[m] - dsim[m]))
        n = np.isfinite(am) & np.isfinite(asim) & (asim > 0.002)
        ratios.append(am[n] / asim[n])
    r = np.concatenate(ratios)
    print("per episode, median mapped - simulated depth (cm): quartiles %s" % np.round(100 * np.quantile(med, [.1, .25, .5, .75, .9]), 2))
    print("rows, mapped / simulated cut cross-section: median %.3f, quartiles %.3f %.3f" % (
        np.median(r), np.quantile(r, .25), np.quantile(r, .75)))


def fit(ds):
    lo = np.array([0.0, 10 * DEG, 12e3, 0.0, 0.0])
    hi = np.array([60e3, 50 * DEG, 22e3, 1.0, 1.0])
    res = []
    for _, e in episodes(ds):
        tr = e["truth"][0].astype(float)
        fam = int(e["plan"][2])
        tg, tp = e["truth_geometry_rows"].astype(float), e["truth_profile_rows"].astype(float)
        F = e["force"].astype(float)
        mv, _ = moving(e)
        vz = e["edge_vz"].astype(float)
        A, M2, w = tp[..., 0], tp[..., 1], tg[..., 3]
        push = tp[..., 2] * math.tan(33 * DEG)
        keep = mv & np.isfinite(F).all(-1) & np.isfinite(tg).all(-1) & np.isfinite(tp[..., :3]).all(-1) & (A > 0)
        if keep.sum() < 20:
            continue
        g = {k: v[keep] for k, v in dict(alpha=tg[..., 0], rho=tg[..., 1], q=tg[..., 4], A=A, M2=M2, w=w, push=push,
                                             down=(vz < 0).astype(float)).items()}
        Fk = F[keep]

        def resid(x):
            c, phi, gamma, a, b = x
            th = (c, phi, a * c, b * phi, gamma)
            fx, fz = fee(th, g["rho"], g["alpha"], g["M2"] / g["A"], g["A"] ** 2 / g["M2"], g["q"])
            nc, nq = bearing(phi)
            pen = (c * nc + gamma * nq * g["A"] / (g["w"] * np.cos(g["alpha"]))) * EDGE_M * g["w"]
            fx, fz = np.nan_to_num(fx) + g["push"], np.nan_to_num(fz) - g["down"] * pen
            return np.concatenate([fx - Fk[:, 0], fz - Fk[:, 1]]) / 1500.0

        x = least_squares(resid, 0.5 * (lo + hi), bounds=(lo, hi), loss="soft_l1", x_scale=hi - lo).x
        res.append((fam, x[0] - tr[0], (x[1] - tr[1]) / DEG, x[2] - tr[4], tr[1]))
    res = np.array(res)
    print("joint fits per episode on the simulator's geometry (cross-section, pushed pile, true gate):")
    for f in range(4):
        s = res[:, 0] == f
        if s.any():
            print("  %-6s %3d episodes: c bias %+5.1f kPa, phi bias %+5.2f deg (MAE %.2f), gamma bias %+5.1f kN/m3" % (
                FAMILY[f], s.sum(), res[s, 1].mean() / 1e3, res[s, 2].mean(), np.abs(res[s, 2]).mean(), res[s, 3].mean() / 1e3))
    phi_fit = res[:, 4] + res[:, 2] * DEG
    print("  all: phi MAE %.2f deg, r %.2f" % (np.abs(res[:, 2]).mean(), np.corrcoef(res[:, 4], phi_fit)[0, 1]))


def main():
    np.seterr(all="ignore")
    ap = argparse.ArgumentParser(description="where the soil map's force model and geometry lose the soil")
    ap.add_argument("what", choices=["physics", "gate", "depth", "fit"])
    ap.add_argument("dataset")
    a = ap.parse_args()
    {"physics": physics, "gate": gate, "depth": depth, "fit": fit}[a.what](a.dataset)


if __name__ == "__main__":
    main()
