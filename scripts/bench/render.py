#!/usr/bin/env python3
"""Renders the output folder of scripts/bench/reference.sh as the tables of BENCHMARKS.md.

Every table says which JSON it came from, the load average before and after that program and
the time it ran; ratios are computed only between rows of one JSON (one process, one run).
Usage: scripts/bench/render.py OUTDIR > tables.md
"""
import json
import os
import statistics
import sys


def load_runs(path):
    with open(path) as f:
        data = json.load(f)
    rows = {}
    for b in data["benchmarks"]:
        if b.get("run_type") == "aggregate":
            if b.get("aggregate_name") != "median":
                continue
            name = b["run_name"]
        else:
            if b.get("repetitions", 1) > 1:
                continue  # the median row stands for them
            name = b["name"]
        rows[name.replace("/real_time", "")] = b
    return data["context"], rows


def ms(b):
    scale = {"ns": 1e-6, "us": 1e-3, "ms": 1.0, "s": 1e3}[b["time_unit"]]
    return b["real_time"] * scale


def si(v, unit=""):
    if v is None:
        return "–"
    for p, s in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(v) >= s:
            return f"{v / s:.3g} {p}{unit}"
    return f"{v:.3g} {unit}".strip()


def table(header, rows):
    out = ["| " + " | ".join(header) + " |", "| --- |" + " ---: |" * (len(header) - 1)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    load = {}
    with open(os.path.join(d, "load.txt")) as f:
        for line in f:
            k, l0, l1, t = line.split()
            load[k] = (l0, l1, t)
    with open(os.path.join(d, "machine.txt")) as f:
        print("Reference run: " + "; ".join(line.strip() for line in f) + ".\n")

    def head(name, title):
        l0, l1, t = load[name]
        print(f"### {title}\n\n`{name}.json`, ended {t} UTC, load average {l0} before, {l1} after.\n")

    def have(name):
        return os.path.exists(os.path.join(d, name + ".json"))

    for name, title in (("lidar_seq_400", "lidar_fusion, moving sequences, 400 × 400 at 5 cm, with peers"),
                        ("lidar_seq_2000", "lidar_fusion, moving sequences, 2000 × 2000 at 4 cm")):
        if not have(name):
            continue
        head(name, title)
        _, rows = load_runs(os.path.join(d, name + ".json"))
        for seq in ("Kitti", "Sim64"):
            sel = {k: v for k, v in rows.items() if f"_{seq}_" in k}
            octo = next((v for k, v in sel.items() if k.startswith("BM_OctoMapSeq")), None)
            naive = next((v for k, v in sel.items() if k.startswith("BM_NaiveSeq")), None)
            body = []
            for k, b in sel.items():
                short = k.replace("BM_", "").split(f"_{seq}_")[0] + "_" + k.split("_")[-1]
                rc, rr = b.get("ray_cells"), b.get("ray_cells_read")
                body.append([f"`{k}`", f"{ms(b):.3g}", si(b.get("points_in")), si(b.get("points_fused")),
                             si(b.get("cells_fused")), f"{si(rc)} ({si(rr)})" if rc else "–",
                             f"{ms(octo) / ms(b):.0f}" if octo else "–",
                             f"{ms(naive) / ms(b):.2f}" if naive else "–"])
            print(table(["benchmark", "ms / scan", "points in /s", "points fused /s", "cells fused /s",
                         "ray cells /s (read)", "OctoMap ms / this", "naive ms / this"], body))
            print()

    if have("lidar_steady"):
        head("lidar_steady", "lidar_fusion, steady state (one cloud re-fused into a map that holds it)")
        _, rows = load_runs(os.path.join(d, "lidar_steady.json"))
        body = [[f"`{k}`", f"{ms(b):.3g}", si(b.get("items_per_second")), si(b.get("fused")) if "fused" in b else "–"]
                for k, b in rows.items()]
        print(table(["benchmark", "ms", "items /s", "points fused per cloud"], body))
        print("\nItems: input points per second, except TimeUpdate (cells of the tiles holding known cells).\n")

    if have("lidar_fresh_tree"):
        head("lidar_fresh_tree", "OctoMap, one cloud into a fresh tree (the former peer figure)")
        _, rows = load_runs(os.path.join(d, "lidar_fresh_tree.json"))
        print(table(["benchmark", "ms", "points /s"],
                    [[f"`{k}`", f"{ms(b):.4g}", si(b.get("items_per_second"))] for k, b in rows.items()]))
        print()

    if have("sim"):
        head("sim", "simulator (median of the repetitions)")
        _, rows = load_runs(os.path.join(d, "sim.json"))
        body = [[f"`{k}`", f"{ms(b):.4g}", f"{b['realtime_factor']:.1f}" if "realtime_factor" in b else "–",
                 si(b.get("rays_per_second")) if "rays_per_second" in b else si(b.get("items_per_second")),
                 f"{b['kept_share']:.3f}" if "kept_share" in b else "–"]
                for k, b in rows.items()]
        print(table(["benchmark", "ms", "real-time factor", "LiDAR rays /s", "kept share"], body))
        print()

    for name, title in (("core", "core map"), ("blind_mapping", "blind mapping"), ("readers", "readers"),
                        ("soil_pinn", "soil estimator"), ("strata", "strata"), ("traversability", "traversability")):
        if not have(name):
            continue
        head(name, title)
        _, rows = load_runs(os.path.join(d, name + ".json"))
        counters = sorted({c for b in rows.values() for c in b
                           if c not in ("name", "run_name", "run_type", "repetitions", "repetition_index",
                                        "threads", "iterations", "real_time", "cpu_time", "time_unit",
                                        "family_index", "per_family_instance_index", "aggregate_name",
                                        "aggregate_unit", "label", "error_occurred", "error_message")})
        body = [[f"`{k}`", f"{ms(b):.4g}"] + [si(b.get(c)) for c in counters] for k, b in rows.items()]
        print(table(["benchmark", "ms"] + counters, body))
        print()

    if os.path.exists(os.path.join(d, "sim_h5.txt")) and have("sim"):
        import re
        _, rows = load_runs(os.path.join(d, "sim.json"))
        runs = sorted(k for k in load if k.startswith("sim_h5_run"))
        printed = False
        for name, duration, bench_name in (("sim_h5.txt", "the file's 2 s", "BM_SimRealtime/2/"),
                                           ("sim_h5_16s.txt", "`--duration 16`", "BM_SimRealtimeSustained/2/")):
            path = os.path.join(d, name)
            if not os.path.exists(path):
                continue
            with open(path) as f:
                rtf = [float(m.group(1)) for m in re.finditer(r"\(([0-9.]+)x real time\)", f.read())]
            bench = next((b["realtime_factor"] for k, b in rows.items() if k.startswith(bench_name)), None)
            if not (rtf and bench and runs):
                continue
            if not printed:
                print("### `terramap sim` with its HDF5 writer\n")
                printed = True
            med = statistics.median(rtf)
            print(f"`terramap sim configs/scenarios/bench_ctl_os1_64.yaml --out DIR`, {duration}, "
                  f"{len(rtf)} runs ending {load[runs[-1]][2]} UTC, load {load[runs[0]][0]} → {load[runs[-1]][1]}: "
                  f"median **{med:.1f}×** real time ({', '.join(f'{x:.1f}' for x in rtf)}), "
                  f"{100 * (1 - med / bench):.0f} % below `{bench_name.rstrip('/')}`'s {bench:.1f}× in the same session.\n")

    demos = sorted(k for k in load if k.startswith("demo_run"))
    if demos:
        rtf = []
        for k in demos:
            with open(os.path.join(d, k, "report.json")) as f:
                rtf.append(json.load(f)["real_time_factor"])
        l0, l1, t = load[demos[-1]]
        print("### whole demo pipeline\n")
        print(f"`terramap run` (the embedded demo), {len(rtf)} runs ending {t} UTC, load {load[demos[0]][0]} → {l1}: "
              f"real-time factor (report.json `real_time_factor`) median **{statistics.median(rtf):.1f}×** "
              f"({', '.join(f'{x:.1f}' for x in rtf)}).\n")


if __name__ == "__main__":
    main()
