#!/usr/bin/env python3
"""Reduces a PNG to an adaptive palette of K colours (k-means on its colours), for the small
pictures committed under docs/img/ (docs/img/README.md says which command made each).

    python3 scripts/png_palette.py IN.png OUT.png [K=96]

Needs numpy and matplotlib (to read the PNG); writes an 8-bit indexed PNG with zlib.
"""
import struct
import sys
import zlib

import matplotlib.image as mpimg
import numpy as np


def chunk(kind, data):
    body = kind + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)


def main():
    src, dst = sys.argv[1], sys.argv[2]
    k = int(sys.argv[3]) if len(sys.argv) > 3 else 96
    rgb = (mpimg.imread(src)[:, :, :3] * 255 + 0.5).astype(np.uint8)
    h, w, _ = rgb.shape
    colours, inverse, counts = np.unique(rgb.reshape(-1, 3), axis=0, return_inverse=True, return_counts=True)
    u = colours.astype(np.float32)
    rng = np.random.default_rng(0)
    centres = u[rng.choice(len(u), min(k, len(u)), replace=False, p=counts / counts.sum())]
    for _ in range(25):  # k-means on the distinct colours, weighted by how often each occurs
        nearest = ((u[:, None, :] - centres[None, :, :]) ** 2).sum(-1).argmin(1)
        for j in range(len(centres)):
            m = nearest == j
            if m.any():
                centres[j] = (u[m] * counts[m, None]).sum(0) / counts[m].sum()
    nearest = ((u[:, None, :] - centres[None, :, :]) ** 2).sum(-1).argmin(1)
    index = nearest[inverse.ravel()].reshape(h, w).astype(np.uint8)
    palette = np.clip(centres + 0.5, 0, 255).astype(np.uint8)
    rows = b"".join(b"\x00" + index[r].tobytes() for r in range(h))
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 3, 0, 0, 0))
    png += chunk(b"PLTE", palette.tobytes()) + chunk(b"IDAT", zlib.compress(rows, 9)) + chunk(b"IEND", b"")
    with open(dst, "wb") as f:
        f.write(png)
    print(f"{dst}: {w}x{h}, {len(palette)} colours, {len(png)} bytes")


if __name__ == "__main__":
    main()
