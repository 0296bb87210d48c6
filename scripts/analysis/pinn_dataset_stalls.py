#!/usr/bin/env python3
"""How many soil_pinn samples have a horizon in which the machine stood stalled.

When the CTL stops against the soil, the force sensor reads only what the tracks mobilise to
hold it (engine/sim/ctl.cpp: applied = m v_trial / dt - rolling resistance), not the soil's
failure force the FEE describes, so such samples cannot be explained by the physics layer.
A row counts as stalled the way the simulator flags it (ctl.cpp): mean track speed > 0.1 m/s
and base speed < 0.2 x track speed. Reads the dataset written by `terramap dataset`.

    python3 scripts/analysis/pinn_dataset_stalls.py DATASET_DIR [P]

Needs Debian's python3-h5py (`apt-get install python3-h5py`; not a build dependency).
"""
import glob
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")  # Debian's h5py under a non-Debian python
import h5py  # noqa: E402
import numpy as np  # noqa: E402


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    P = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    files = sorted(glob.glob(os.path.join(sys.argv[1], "episodes", "*.h5")))
    if not files:
        sys.exit(sys.argv[1] + ": no episodes/*.h5")
    n = any_stall = rows = stalled_rows = 0
    mag_stalled, mag_moving, per_family = [], [], {}
    for path in files:
        with h5py.File(path, "r") as f:
            names = f.attrs["obs_features"].decode().split(",")
            vx, tl, tr = names.index("base_vx_mps"), names.index("track_left_mps"), names.index("track_right_mps")
            obs, force = f["obs"][:], f["force"][:]
            if obs.shape[0] == 0:
                continue
            h = obs[:, -P:, :]
            track = 0.5 * (h[:, :, tl] + h[:, :, tr])
            st = (track > 0.1) & (h[:, :, vx] < 0.2 * track)
            n += obs.shape[0]
            any_stall += int(st.any(axis=1).sum())
            rows += st.size
            stalled_rows += int(st.sum())
            mag = np.hypot(force[:, :, 0], force[:, :, 1])
            mag_stalled += list(mag[st])
            mag_moving += list(mag[~st])
            fam = per_family.setdefault(f.attrs["family"].decode(), [0, 0])
            fam[0] += obs.shape[0]
            fam[1] += int(st.any(axis=1).sum())
    print("samples %d, with a stalled row in the last %d rows: %d (%.1f %%); stalled rows %.1f %%"
          % (n, P, any_stall, 100.0 * any_stall / n, 100.0 * stalled_rows / rows))
    print("median |F| on stalled rows %.0f N, on the others %.0f N"
          % (np.median(mag_stalled) if mag_stalled else float("nan"), np.median(mag_moving)))
    for fam, (k, s) in sorted(per_family.items()):
        print("  %-7s %5d samples, %.1f %% with a stall" % (fam, k, 100.0 * s / k))


if __name__ == "__main__":
    main()
