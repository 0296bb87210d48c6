#!/usr/bin/env python3
"""lidar_fusion against its peers on the moving sequences, in one run of bench_lidar_fusion.

Runs the sequence benchmarks (BM_LidarFusionSeq_*, BM_OctoMapSeq_*, BM_NaiveSeq_*) of one
map size once, in one process, interleaved by nothing but their registration order, and prints
the BENCHMARKS.md table: wall time per scan, the counters as rates, and every ratio against the
OctoMap and naive rows of the same run. The machine's load average before and after is printed
with it (the VM is shared: a figure means something only with the load it was taken at).

Usage: scripts/bench/lidar_table.py [BENCH_BINARY] [--map 400x400_5cm] [--min-time 1]
       [--json OUT.json]   (keep Google Benchmark's raw JSON as well)
"""
import argparse
import datetime
import json
import os
import subprocess
import sys


def run(binary, pattern, min_time):
    out = subprocess.run(
        [binary, f"--benchmark_filter={pattern}", f"--benchmark_min_time={min_time}",
         "--benchmark_format=json"],
        check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def rate(b, name):
    v = b.get(name)
    return None if v is None else float(v)


def fmt_rate(v):
    if v is None:
        return "–"
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if v >= scale:
            return f"{v / scale:.3g} {unit}"
    return f"{v:.3g}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binary", nargs="?", default="build/bin/bench_lidar_fusion")
    ap.add_argument("--map", default="400x400_5cm")
    ap.add_argument("--min-time", default="1")
    ap.add_argument("--json")
    a = ap.parse_args()
    if not os.path.exists(a.binary):
        sys.exit(f"lidar_table: no benchmark program at {a.binary} (build with -DTERRAMAP_BUILD_BENCHMARKS=ON)")
    load0 = os.getloadavg()
    t0 = datetime.datetime.now(datetime.timezone.utc)
    data = run(a.binary, f"BM_(LidarFusionSeq|OctoMapSeq|NaiveSeq)_.*_{a.map}", a.min_time)
    load1 = os.getloadavg()
    if a.json:
        with open(a.json + ".tmp", "w") as f:
            json.dump(data, f, indent=1)
        os.replace(a.json + ".tmp", a.json)
    rows = [b for b in data["benchmarks"] if b.get("run_type", "iteration") == "iteration"]
    ctx = data["context"]
    print(f"Run {t0:%Y-%m-%d %H:%M} UTC, {ctx.get('num_cpus')} CPUs at {ctx.get('mhz_per_cpu')} MHz, "
          f"load average {load0[0]:.2f} before, {load1[0]:.2f} after; "
          f"`{' '.join(sys.argv)}`\n")
    for seq in ("Kitti", "Sim64"):
        sel = [b for b in rows if f"_{seq}_" in b["name"]]
        if not sel:
            continue

        def wall(b):
            return b["real_time"] if b["time_unit"] == "ms" else b["real_time"] / 1e3

        octo = next((b for b in sel if b["name"].startswith("BM_OctoMapSeq")), None)
        naive = next((b for b in sel if b["name"].startswith("BM_NaiveSeq")), None)
        print(f"| {seq} ({a.map}) | ms / scan | points in /s | points fused /s | cells fused /s "
              f"| ray cells /s (read) | OctoMap ms / this | naive ms / this |")
        print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
        for b in sel:
            name = b["name"].replace("BM_", "").replace(f"_{seq}_{a.map}", "").replace("/real_time", "")
            w = wall(b)
            rc, rr = rate(b, "ray_cells"), rate(b, "ray_cells_read")
            rays = f"{fmt_rate(rc)} ({fmt_rate(rr)})" if rc else "–"
            vs_o = f"{wall(octo) / w:.0f}" if octo else "–"
            vs_n = f"{wall(naive) / w:.2f}" if naive else "–"
            print(f"| {name} | {w:.3g} | {fmt_rate(rate(b, 'points_in'))} | {fmt_rate(rate(b, 'points_fused'))} "
                  f"| {fmt_rate(rate(b, 'cells_fused'))} | {rays} | {vs_o} | {vs_n} |")
        print()


if __name__ == "__main__":
    main()
