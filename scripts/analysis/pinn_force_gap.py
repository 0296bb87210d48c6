#!/usr/bin/env python3
"""Where the soil estimator's physics misses the measured blade force (docs/soil_estimator.md).

Analyses, all with the truth soil (so only geometry, physics and observations are in question):

  python3 scripts/analysis/pinn_force_gap.py geometry DATASET_DIR [SPLIT]
      Per sample of a `terramap dataset` (split default: test), the force of the last horizon
      row against F_total at beta* of the truth soil on the mapped geometry, then with each
      mapped FEE parameter (alpha, rho, d, w, Q) replaced by the simulator's own: which one
      closes the gap; last, the mapped Q weighed with the truth gamma (q*gamma). Prints the force error (sum |dF| / sum |F|) and the median measured /
      predicted horizontal force per substitution.

  python3 scripts/analysis/pinn_force_gap.py episode EPISODE_H5
      On one `terramap sim` episode: first the blade's vertical speed as the machine reports it
      against the truth (map frame; noise and sign agreement); then, with the truth geometry
      and soil logged per step (stalled steps left out), F_total at beta* against the measured
      force on steps where the cutting edge descends and where it does not, and with the edge's
      penetration resistance (terramap.fee's soil, q_b = c N_c + gamma d N_q over 0.025 m x w)
      added on descending steps.

  python3 scripts/analysis/pinn_force_gap.py gate DATASET_DIR [SPLIT]
      Per horizon row of a `terramap dataset` split: whether the observations tell when the
      cutting edge descends. The edge's vertical speed in the map frame from the row's observed
      blade twist and attitudes; F_total at beta* of the truth soil on the mapped geometry, plus
      the edge's penetration resistance on the rows where that speed is negative. Prints the
      force error (and its parts along x and z) without and with the penetration so gated, and
      the median measured vertical force on rows observed descending and rising.

  [ROWS=N] python3 scripts/analysis/pinn_force_gap.py phifit DATASET_DIR [SPLIT]
      How much the horizontal force tells about phi when everything else is known: per sample
      (its last N horizon rows, default 1; every row's FEE valid), the phi in 10..50 deg whose F_total at beta*, with the
      truth c, c_a, delta and gamma, best matches the measured force along x (least absolute
      error summed over the rows), on the mapped geometry (each row's) and on the simulator's
      own (logged once per sample). Prints the fitted phi's MAE and correlation with the
      truth beside a constant's (the split's median truth): an upper bound of what an estimator
      of phi could do from that force with that geometry.

  python3 scripts/analysis/pinn_force_gap.py phisens
      How much the FEE's horizontal force moves per degree of phi, for the three soils
      docs/soil_estimator.md quotes.

  python3 scripts/analysis/pinn_force_gap.py noise EPISODE_H5 QUIET_EPISODE_H5
      The soil's coloured noise of the horizontal force on an episode's cutting steps, against
      the same scenario run with `force_noise: {abs_n: 0, rel: 0}` on its machine.

Needs Debian's python3-h5py and terramap's Python module (build/python; PYTHONPATH or run from
the repository root after `make`).
"""
import glob
import math
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")  # Debian's h5py under a non-Debian python
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "build", "python"))
import h5py  # noqa: E402
import numpy as np  # noqa: E402
import terramap as tm  # noqa: E402

EDGE_M = 0.025
SWEEP_UNIT_WEIGHT = 14636.0  # blade_sweep's default unit_weight_n_m3, which the mapped Q is weighed with  # the simulator's default blade edge thickness (docs/sim.md)


def force_error(pred, meas):
    return 100 * np.sum(np.hypot(pred[:, 0] - meas[:, 0], pred[:, 1] - meas[:, 1])) / np.sum(np.hypot(meas[:, 0], meas[:, 1]))


def split_episodes(dataset, split, names):
    """The named datasets (and the observation feature names) of every episode file of a split."""
    for fn in sorted(glob.glob(os.path.join(dataset, "episodes", "*.h5"))):
        with h5py.File(fn, "r") as f:
            if f.attrs["split"].decode() == split:
                yield [f[n][:] for n in names], f.attrs["obs_features"].decode().split(",")


def geometry(dataset, split):
    rows = []
    for (tk, force, truth, tg), _ in split_episodes(dataset, split, ["theta_k", "force", "truth", "truth_geometry"]):
        for i in range(len(tk)):
            rows.append((tuple(map(float, truth[i])), tuple(map(float, tk[i, -1])), tuple(map(float, tg[i])), force[i, -1]))
    if not rows:
        sys.exit(dataset + ": no samples in split " + split)
    print("%d samples of split %s" % (len(rows), split))
    # "q*gamma": the mapped Q weighed with the truth gamma instead of blade_sweep's fixed one.
    for sub in [[], ["alpha"], ["rho"], ["d"], ["w"], ["q"], ["alpha", "rho", "w", "q"], ["alpha", "rho", "d", "w", "q"],
                ["q*gamma"]]:
        pred, meas, ratio = [], [], []
        for (c, phi, ca, delta, gamma), (rho, alpha, w, d, q, _v), (a2, r2, d2, w2, q2), fm in rows:
            if not (np.isfinite([a2, r2, d2, w2, q2]).all() and d > 0 and d2 > 0):
                continue
            g = {"alpha": alpha, "rho": rho, "d": d, "w": w, "q": q}
            t = {"alpha": a2, "rho": r2, "d": d2, "w": w2, "q": q2}
            for k in sub:
                if k == "q*gamma":
                    g["q"] = q * gamma / SWEEP_UNIT_WEIGHT
                else:
                    g[k] = t[k]
            r = tm.fee(c, phi, gamma, ca, delta, g["alpha"], g["rho"], g["d"], g["w"], g["q"], beta="min")
            f = r["F_total_N"] if r["valid"] else (0.0, 0.0)
            pred.append(f)
            meas.append(fm)
            if r["valid"]:
                ratio.append(fm[0] / f[0])
        print("  truth %-22s samples %5d  force error %5.1f %%  median measured/predicted Fx %.2f" % (
            "+".join(sub) or "(mapped only)", len(pred), force_error(np.array(pred), np.array(meas)), np.median(ratio)))


PHI_GRID = np.radians(np.arange(10.0, 50.01, 0.5))


def fit_phi(c, gamma, ca, delta, geometries, fx):
    """The phi of PHI_GRID whose F_total at beta* (soil c, gamma, ca, delta; geometries (alpha, rho,
    d, w, q), one per measured horizontal force in fx) has the least absolute error summed over
    them; NaN when no phi gives a valid FEE for them all."""
    err = []
    for p in PHI_GRID:
        e = 0.0
        for g, f in zip(geometries, fx):
            r = tm.fee(c, p, gamma, ca, delta, *g, beta="min")
            e += abs(r["F_total_N"][0] - f) if r["valid"] else np.inf
        err.append(e)
    return PHI_GRID[int(np.argmin(err))] if np.isfinite(np.min(err)) else np.nan


def phifit(dataset, split, rows):
    truth_phi, fitted = [], {"mapped": [], "truth": []}
    for (tk, force, truth, tg), _ in split_episodes(dataset, split, ["theta_k", "force", "truth", "truth_geometry"]):
        for i in range(len(tk)):
            c, phi, ca, delta, gamma = map(float, truth[i])
            a2, r2, d2, w2, q2 = map(float, tg[i])
            fx = force[i, -rows:, 0].astype(float)
            mapped = [(a, r, ww, dd, qq) for r, a, ww, dd, qq, _v in tk[i, -rows:].astype(float)]
            if not (np.isfinite([a2, r2, d2, w2, q2]).all() and d2 > 0 and min(g[3] for g in mapped) > 0):
                continue
            # Mapped: each row's own geometry; truth: the simulator's, logged once per sample.
            best = {"mapped": fit_phi(c, gamma, ca, delta, [(a, r, dd, ww, qq) for a, r, ww, dd, qq in mapped], fx),
                    "truth": fit_phi(c, gamma, ca, delta, [(a2, r2, d2, w2, q2)] * rows, fx)}
            if not np.isfinite([best["mapped"], best["truth"]]).all():
                continue
            truth_phi.append(phi)
            for name in fitted:
                fitted[name].append(best[name])
    t = np.degrees(np.array(truth_phi))
    if len(t) == 0:
        sys.exit(dataset + ": no samples in split " + split)
    print("%d samples of split %s, the last %d horizon row(s); a constant (the median truth, %.1f deg): phi MAE %.2f deg" % (
        len(t), split, rows, np.median(t), np.mean(np.abs(t - np.median(t)))))
    for name in ("mapped", "truth"):
        f = np.degrees(np.array(fitted[name]))
        print("  phi fitted to Fx on the %-6s geometry (truth c, c_a, delta, gamma): MAE %.2f deg, r %.2f" % (
            name, np.mean(np.abs(f - t)), np.corrcoef(f, t)[0, 1]))


def phisens():
    # The soils of docs/soil_estimator.md ("How much the force says about phi"): c (Pa), phi (deg),
    # gamma (N/m^3), c_a (Pa), delta (deg); the loam is pinn_episode.yaml's truth soil.
    soils = {"loam": (14500, 31.0, 16500, 7250, 17.05), "sand": (0, 35.0, 16000, 0, 23.0),
             "clay": (40000, 22.0, 17500, 24000, 10.0)}
    for name, (c, phi, gamma, ca, delta) in soils.items():
        f = lambda p: tm.fee(c, math.radians(p), gamma, ca, math.radians(delta), 0.0, math.radians(80), 0.1, 1.85,
                             2000.0, beta="min")["F_total_N"][0]
        print("%s (phi %.1f deg): F_total along x changes %.1f %% per degree of phi (d 0.1 m, rho 80 deg, w 1.85 m, "
              "Q 2 kN, level ground)" % (name, phi, 100 * (f(phi + 1) / f(phi) - 1)))


def noise(path, quiet_path):
    """The soil's coloured force noise along the travel on the cutting steps of an episode,
    against the same scenario run without it (force_noise {abs_n: 0, rel: 0}): the same motion,
    so the difference of the truth forces is the noise."""
    with h5py.File(path, "r") as a, h5py.File(quiet_path, "r") as b:
        m = "machines/" + sorted(a["machines"].keys())[0] + "/"
        if not np.array_equal(a[m + "T_map_base"][:], b[m + "T_map_base"][:]):
            sys.exit("the two episodes did not move alike: not the same scenario with and without the noise")
        fa, fb, h = a[m + "truth/force_map_N"][:], b[m + "truth/force_map_N"][:], a[m + "T_map_base"][:][:, :2, 0]
        cut = a[m + "truth/fee"][:][:, 2] > 0
    along = lambda F: -(F[:, 0] * h[:, 0] + F[:, 1] * h[:, 1])
    n, fx = along(fa - fb)[cut], along(fb)[cut]
    print("%d cutting steps: horizontal noise mean %.0f N, sd %.0f N on a mean horizontal force of %.0f N (%.0f %%)" % (
        cut.sum(), n.mean(), n.std(), fx.mean(), 100 * n.std() / np.abs(fx).mean()))


def bearing(phi):
    t = math.tan(math.pi / 4 + phi / 2)
    nq = math.exp(math.pi * math.tan(phi)) * t * t
    return (nq - 1) / math.tan(phi), nq


def episode(path):
    with h5py.File(path, "r") as f:
        m = "machines/" + sorted(f["machines"].keys())[0] + "/"
        F = f[m + "truth/force_map_N"][:]
        fee, soil, stalled = f[m + "truth/fee"][:], f[m + "truth/soil"][:], f[m + "truth/stalled"][:]
        T_blade, T_base, stamp = f[m + "T_map_blade"][:], f[m + "T_map_base"][:], f[m + "stamp"][:]
        measured, truth_base = f[m + "force_base_N"][:][:, [0, 2]], f[m + "truth/force_base_N"][:][:, [0, 2]]
        tw_true, tw_est = f[m + "twist_blade"][:], f[m + "estimate/twist_blade"][:]
        T_blade_est = f[m + "estimate/T_map_blade"][:]
    # The blade's vertical speed in the map frame, as the machine reports it and as it was.
    vz_true = np.einsum("kij,kj->ki", T_blade[:, :3, :3], tw_true[:, :3])[:, 2]
    vz_est = np.einsum("kij,kj->ki", T_blade_est[:, :3, :3], tw_est[:, :3])[:, 2]
    print("blade vertical speed (map frame), reported - true: sd %.3f m/s (true RMS %.3f m/s), same sign %.1f %%" % (
        np.std(vz_est - vz_true), np.sqrt(np.mean(vz_true ** 2)), 100 * np.mean(np.sign(vz_est) == np.sign(vz_true))))
    # The truth force (the soil's response with its coloured noise) is compared below; the
    # force sensor adds its own noise on top, a floor no estimator of the sensor reading passes.
    contact = np.hypot(truth_base[:, 0], truth_base[:, 1]) > 500
    print("force sensor noise on %d contact steps: %.1f %% of the reading" % (
        contact.sum(), force_error(truth_base[contact], measured[contact])))
    vz = np.gradient(T_blade[:, 2, 3], stamp)
    rows, steps = [], []  # steps: every cutting, moving step's (geometry, soil, measured Fx)
    for k in range(len(F)):
        alpha, rho, d, w, q, _beta = fee[k]
        if not d > 0 or stalled[k]:
            continue
        c, phi, gamma, ca, delta = soil[k][:5]
        heading = T_base[k, :2, 0]
        fx = -(F[k, 0] * heading[0] + F[k, 1] * heading[1])  # blade on soil, along travel
        steps.append(((alpha, rho, d, w, q), (c, phi, gamma, ca, delta), fx))
        r = tm.fee(c, phi, gamma, ca, delta, alpha, rho, d, w, q, beta="min")
        if not r["valid"]:
            continue
        fz = -F[k, 2]
        nc, nq = bearing(phi)
        pen = (c * nc + gamma * d * nq) * EDGE_M * w if vz[k] < 0 else 0.0
        rows.append((fx, fz, r["F_total_N"][0], r["F_total_N"][1], r["F_total_N"][1] - pen, vz[k] < 0))
    R = np.array(rows)
    down = R[:, 5] > 0
    meas, fee_only = R[:, 0:2], R[:, 2:4]
    with_pen = np.stack([R[:, 2], R[:, 4]], 1)
    print("%d cutting steps (not stalled, FEE valid), %d with the edge descending" % (len(R), down.sum()))
    print("  F_total at beta*: force error %.1f %% (descending %.1f %%, not %.1f %%)" % (
        force_error(fee_only, meas), force_error(fee_only[down], meas[down]), force_error(fee_only[~down], meas[~down])))
    print("  median measured / FEE vertical force on descending steps: %.0f N / %.0f N" % (
        np.median(meas[down, 1]), np.median(fee_only[down, 1])))
    print("  + penetration on descending steps: force error %.1f %%" % force_error(with_pen, meas))
    # What one step's horizontal force says about phi, all else (geometry, c, c_a, delta, gamma)
    # the truth: the phi in 10..50 deg whose F_total at beta* matches it best.
    fits, truth_phi = [], []
    for (alpha, rho, d, w, q), (c, phi, gamma, ca, delta), fx in steps:
        p = fit_phi(c, gamma, ca, delta, [(alpha, rho, d, w, q)], [fx])
        if np.isfinite(p):
            fits.append(math.degrees(p))
            truth_phi.append(math.degrees(phi))
    fits, truth_phi = np.array(fits), np.array(truth_phi)
    print("  phi fitted to each step's horizontal force (truth geometry, c, c_a, delta, gamma): "
          "median %.1f deg (truth %.1f), quartiles %.1f-%.1f, MAE %.2f deg; measured / F_total along x: median %.2f (quartiles %.2f-%.2f)" % (
              np.median(fits), np.median(truth_phi), *np.percentile(fits, [25, 75]), np.mean(np.abs(fits - truth_phi)),
              np.median(meas[:, 0] / fee_only[:, 0]), *np.percentile(meas[:, 0] / fee_only[:, 0], [25, 75])))

def rot_rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def gate(dataset, split):
    rows = []
    for (obs, tk, force, truth), names in split_episodes(dataset, split, ["obs", "theta_k", "force", "truth"]):
        col = {n: i for i, n in enumerate(names)}
        P, T = tk.shape[1], obs.shape[1]
        for i in range(len(tk)):
            c, phi, ca, delta, gamma = map(float, truth[i])
            nc, nq = bearing(phi)
            for p in range(P):
                rho, alpha, w, d, q, _v = map(float, tk[i, p])
                o = obs[i, T - P + p]
                # Yaw does not change a vertical component: the base's roll and pitch, then the
                # blade's attitude in the base frame, rotate the blade-frame velocity. (Datasets
                # since 2026-11-27 carry this as blade_vz_map_mps; recomputing it reads older ones.)
                R = rot_rpy(o[col["base_roll_rad"]], o[col["base_pitch_rad"]], 0.0) @ rot_rpy(
                    o[col["blade_roll_rad"]], o[col["blade_pitch_rad"]], o[col["blade_yaw_rad"]])
                vz = (R @ np.array([o[col["blade_vx_mps"]], o[col["blade_vy_mps"]], o[col["blade_vz_mps"]]]))[2]
                fee, pen = (0.0, 0.0), 0.0
                if d > 0:
                    r = tm.fee(c, phi, gamma, ca, delta, alpha, rho, d, w, q, beta="min")
                    if r["valid"]:
                        fee, pen = r["F_total_N"], (c * nc + gamma * d * nq) * EDGE_M * w
                rows.append((force[i, p, 0], force[i, p, 1], fee[0], fee[1], pen, vz))
    if not rows:
        sys.exit(dataset + ": no samples in split " + split)
    R = np.array(rows, dtype=float)
    meas, down = R[:, 0:2], R[:, 5] < 0
    norm = np.sum(np.hypot(meas[:, 0], meas[:, 1]))

    def parts(fz):
        return (100 * np.sum(np.hypot(R[:, 2] - meas[:, 0], fz - meas[:, 1])) / norm,
                100 * np.sum(np.abs(R[:, 2] - meas[:, 0])) / norm, 100 * np.sum(np.abs(fz - meas[:, 1])) / norm)
    print("%d horizon rows of split %s, %d observed descending" % (len(R), split, down.sum()))
    print("  F_total at beta*: force error %.1f %% (along x %.1f, z %.1f)" % parts(R[:, 3]))
    print("  + penetration where the observed edge descends: %.1f %% (along x %.1f, z %.1f)" % parts(R[:, 3] - down * R[:, 4]))
    print("  median measured vertical force, observed descending / rising: %.0f N / %.0f N" % (
        np.median(meas[down, 1]), np.median(meas[~down, 1])))


def main():
    if len(sys.argv) >= 2 and sys.argv[1] == "phisens":
        return phisens()
    if len(sys.argv) < 3 or sys.argv[1] not in ("geometry", "episode", "gate", "phifit", "noise"):
        sys.exit(__doc__)
    if sys.argv[1] == "geometry":
        geometry(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else "test")
    elif sys.argv[1] == "gate":
        gate(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else "test")
    elif sys.argv[1] == "noise":
        noise(sys.argv[2], sys.argv[3])
    elif sys.argv[1] == "phifit":
        phifit(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else "test", int(os.environ.get("ROWS", "1")))
    else:
        episode(sys.argv[2])


if __name__ == "__main__":
    main()
