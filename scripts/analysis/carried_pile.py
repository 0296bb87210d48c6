#!/usr/bin/env python3
"""The carried pile's surcharge against the simulator's (docs/soil_estimator.md, "The pile
beyond the blade's capacity").

    python3 scripts/analysis/carried_pile.py EPISODE.h5 [EPISODE.h5 ...]

Each EPISODE.h5 is from a `terramap dataset` whose pipeline counts the carried pile without a
cap (blade_sweep `carried_repose_rad: 0.05`: a capacity 13 times the blade's), e.g. for loam v2:

    D=/tmp/pile; mkdir -p $D
    sed 's#surcharge_carried: true}#surcharge_carried: true, carried_repose_rad: 0.05}#' \
        configs/dataset/strips/pipeline.yaml > $D/pipeline.yaml
    sed -e "s#^scenario: .*#scenario: $PWD/configs/scenarios/variants/soil_strip_loam_v2.yaml#" \
        -e "s#^pipeline: .*#pipeline: $D/pipeline.yaml#" configs/dataset/strips/fig12_dense_strip.yaml > $D/loam_v2.yaml
    mpirun --allow-run-as-root -np 2 build/bin/terramap dataset $D/loam_v2.yaml --out $D/loam_v2 --episodes 1 -q
    python3 scripts/analysis/carried_pile.py $D/loam_v2/episodes/ep_00000.h5

(18 s), so theta_k's q is the whole bank soil cut since the pass began, weighed with blade_sweep's unit weight. Per file, over the rows with a cut and a
simulator's Q above 0.5 kN, the ratio (and MAE) to the simulator's Q, all weighed with the truth
unit weight, of:
  capped    the blade's capacity width x height^2 / (2 tan 33 deg) (blade_sweep's default);
  uncapped  everything cut (no soil spilled);
  mid       capacity + half the excess (carried_overflow_share 0.5);
and the share of the rows over the capacity whose simulator's Q lies between the two bounds.
Needs Debian's python3-h5py.
"""
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")
import h5py  # noqa: E402
import numpy as np  # noqa: E402

G_REF, SWELL, W, H, TANR = 14636.0, 1.2, 1.85, 0.76, np.tan(0.576)
CAP = W * H * H / (2 * TANR) * G_REF / SWELL  # N, as blade_sweep weighs it


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        f = h5py.File(path)
        qm = f["theta_k"][:, :, 4].ravel()
        qs = f["truth_geometry_rows"][:, :, 4].ravel()
        d = f["theta_k"][:, :, 3].ravel()
        gam = np.repeat(f["truth"][:, 4], f["theta_k"].shape[1])
        ok = (d > 0) & np.isfinite(qs) & (qs > 500)
        models = {"capped": np.minimum(qm, CAP), "uncapped": qm, "mid": np.where(qm > CAP, 0.5 * (qm + CAP), qm)}
        print(f"{path}: {ok.sum()} rows")
        for name, q in models.items():
            qt = q * gam / G_REF
            r = qt[ok] / qs[ok]
            big = ok & (qs > 10e3)
            print(f"  {name:9s} median ratio {np.median(r):.3f} (IQR {np.percentile(r, 25):.2f}-{np.percentile(r, 75):.2f}),"
                  f" rows with Q > 10 kN {np.median(qt[big] / qs[big]):.3f}, MAE {np.mean(np.abs(qt[ok] - qs[ok])) / 1e3:.2f} kN")
        over = ok & (qm > CAP * 1.05)
        lo, hi = CAP * gam[over] / G_REF, qm[over] * gam[over] / G_REF
        inside = np.mean((qs[over] >= lo) & (qs[over] <= hi))
        print(f"  rows over the capacity {over.sum()}: simulator's Q between the bounds {inside:.3f}, below the capacity {np.mean(qs[over] < lo):.3f}")


if __name__ == "__main__":
    main()
