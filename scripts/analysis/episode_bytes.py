#!/usr/bin/env python3
"""Where the bytes of a simulator episode go: every dataset of at least 0.1 MB with its shape,
type, filter and the bytes it takes in the file (h5py's storage size), largest first.

    python3 scripts/analysis/episode_bytes.py DIR/episode.h5

BENCHMARKS.md ("Simulator and writer") reads it on `terramap sim
configs/scenarios/bench_ctl_os1_64.yaml --out DIR --duration 16`. Needs Debian's python3-h5py
(not a build dependency).
"""
import os
import sys

sys.path.insert(0, "/usr/lib/python3/dist-packages")  # Debian's h5py under a non-Debian python
import h5py  # noqa: E402


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    path = sys.argv[1]
    rows = []
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                rows.append((obj.id.get_storage_size(), name, obj.shape, obj.dtype, obj.compression))
        f.visititems(visit)
    total = os.path.getsize(path)
    print(f"{path}: {total / 1e6:.1f} MB")
    for size, name, shape, dtype, comp in sorted(rows, reverse=True):
        if size >= 1e5:
            print(f"  {size / 1e6:8.1f} MB  {name}  {shape} {dtype} {comp or 'raw'}")


if __name__ == "__main__":
    main()
