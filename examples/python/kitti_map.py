#!/usr/bin/env python3
"""Fuse the six KITTI HDL-64E frames through configs/kitti.yaml and plot the smoothed elevation
with matplotlib: title, colour bar in metres, axes in map metres.

    PYTHONPATH=build/python python3 examples/python/kitti_map.py --out out/kitti_py.png

(after `make demo` or `make test`; with `make install` the package is importable directly).
The frames are not in the repository (KITTI is CC BY-NC-SA 3.0, and the picture inherits that
licence): configs/kitti.yaml finds them at $TERRAMAP_KITTI_DIR, by default
../shared/data/kitti_hdl64 beside the checkout (data/README.md). Without them the script says
where it looked and exits with 77, which CTest counts as skipped.
"""
import argparse
import os
import sys

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import terramap  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.normpath(os.path.join(HERE, "..", ".."))
DEFAULT_PIPELINE = os.path.join(REPO, "configs", "kitti.yaml")
SKIPPED = 77  # the exit code CTest is told means "skipped"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pipeline", default=DEFAULT_PIPELINE)
    ap.add_argument("--layer", default="elevation_smooth")
    ap.add_argument("--out", default="kitti_elevation.png")
    ap.add_argument("--threads", type=int, default=0)
    args = ap.parse_args()

    if args.pipeline == DEFAULT_PIPELINE:
        kitti = os.environ.get("TERRAMAP_KITTI_DIR") or os.path.join(REPO, "..", "shared", "data", "kitti_hdl64")
        probe = os.path.join(os.path.abspath(kitti), "000000.bin")
        if not os.path.isfile(probe):
            print(f"SKIP: KITTI frames not found: {probe} is missing (set TERRAMAP_KITTI_DIR; data/README.md)")
            return SKIPPED

    engine = terramap.Engine.from_file(args.pipeline, threads=args.threads)
    events = engine.play()
    engine.finish()
    snap = engine.snapshot()
    h = snap.layer(args.layer)
    g = snap.geometry
    unit = snap.layer_info(args.layer)["unit"]

    # North-up like terramap's own PNG and GeoTIFF exports: logical rows i run towards -x and
    # columns j towards -y, so x to the right and y up is the array transposed, columns reversed.
    (rows, cols), (cx, cy), res = g.size, g.center, g.resolution
    h = h.T[:, ::-1]
    extent = [cx - rows / 2 * res, cx + rows / 2 * res, cy - cols / 2 * res, cy + cols / 2 * res]
    lo, hi = np.nanpercentile(h, [1, 99])
    fig, ax = plt.subplots(figsize=(7, 6), dpi=110)
    im = ax.imshow(h, extent=extent, cmap="viridis", vmin=lo, vmax=hi, interpolation="nearest")
    ax.set_xlabel("x (m, map frame)")
    ax.set_ylabel("y (m, map frame)")
    known = np.isfinite(h).mean()
    ax.set_title(f"{args.layer} ({unit}) from {events} events, {known:.0%} of cells known")
    fig.colorbar(im, ax=ax, label=f"{args.layer} [{unit}]")
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out}: {args.layer} {rows}x{cols} at {res} m, {known:.1%} known, "
          f"range {np.nanmin(h):.2f} .. {np.nanmax(h):.2f} {unit}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
