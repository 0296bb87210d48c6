#!/usr/bin/env python3
"""Closing the loop on the simulator: a hand-written controller cuts a strip to a target depth.

The loader of configs/scenarios/env_loader_cut.yaml is driven through terramap.sim.Env. The
controller reads only what the machine knows (the localisation's base and blade poses): it
holds the cutting edge at the map height `depth` below the ground it started on (grade
control from the estimated blade pose) with a proportional lift lever, drives straight at a
constant track lever, and stops once the blade has crossed the strip. The environment's task
terms (info["task"]: the target surface `depth` below the initial ground over the strip) say
how far the ground still lies above the target; the script prints the mean cut depth and exits
non-zero if the strip was not cut to within the tolerance.

    PYTHONPATH=build/python python3 examples/python/loader_cut.py [--depth 0.10]
"""
import argparse
import os
import sys

import numpy as np

import terramap.sim as ts

HERE = os.path.dirname(os.path.abspath(__file__))
SCENARIO = os.path.join(HERE, "..", "..", "configs", "scenarios", "env_loader_cut.yaml")


def quat_to_matrix(w, x, y, z):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=SCENARIO)
    ap.add_argument("--depth", type=float, default=0.10, help="target cut depth below the initial ground, m")
    ap.add_argument("--tolerance", type=float, default=0.02, help="mean ground left above the target, m")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()

    # The strip: from 2.5 m to 5.5 m along x, 1.2 m wide (inside the 1.85 m blade, clear of
    # the windrows it leaves at its ends), on the loader's lane (y = -1.5).
    strip = dict(x0=2.5, x1=5.5, y0=-2.1, y1=-0.9, depth_m=args.depth, tolerance_m=args.tolerance)
    env = ts.Env(args.scenario, frame_skip=6, time_limit_s=12.0, target=strip)  # 10 Hz control
    names = env.observation_names()
    i_base, i_blade = names.index("base_x"), names.index("blade_x")
    obs, info = env.reset(seed=args.seed)
    print("agent %s, %d levers (%s), %d observations" % (env.agents[0], len(env.action_names()),
                                                         ", ".join(env.action_names()), len(obs)))
    blade_reach = obs[i_blade] - obs[i_base]  # the edge's distance ahead of the base, m
    # Grade control: the edge held at a map height, `depth` below the ground the tracks stood
    # on at the start (the contact plane is the base frame's z = 0). Held against the track
    # contact plane instead, the cut would follow the tracks as they sink and pitch.
    grade = obs[i_base + 2] - args.depth
    terminated = truncated = False
    step = 0
    while not (terminated or truncated):
        p_base = obs[i_base:i_base + 3]
        R_base = quat_to_matrix(*obs[i_base + 3:i_base + 7])
        edge_in_base = R_base.T @ (obs[i_blade:i_blade + 3] - p_base)
        edge_height = edge_in_base[2]  # above the track contact plane, m
        lift = np.clip(4.0 * (grade - obs[i_blade + 2]), -1.0, 1.0)
        past = p_base[0] + blade_reach > strip["x1"] + 0.3
        drive = 0.0 if past else (0.25 if obs[i_blade + 2] > grade + 0.4 * args.depth else 0.35)
        obs, rewards, terminated, truncated, info = env.step(np.array([drive, drive, lift, 0.0, 0.0]))
        step += 1
        if step % 10 == 0:
            print("t %5.2f s  base x %5.2f m  edge %+6.3f m  cut %6.4f m3  strip: mean cut %.3f m, above target %.3f m"
                  % (info["t"], p_base[0], edge_height, rewards["cut_bank_m3"], info["task"]["cut_depth_mean_m"],
                     info["task"]["target_above_m"]))
        if past and not terminated:
            break
    task = info["task"]
    print("mean cut depth over the strip: %.3f m (target %.3f m); ground left above the target: %.3f m, "
          "cut below it: %.3f m" % (task["cut_depth_mean_m"], args.depth, task["target_above_m"], task["target_below_m"]))
    if task["target_above_m"] <= args.tolerance:
        print("reached the target depth in %.1f s of simulated time" % info["t"])
        return 0
    print("did not reach the target depth (tolerance %.3f m)" % args.tolerance)
    return 1


if __name__ == "__main__":
    sys.exit(main())
