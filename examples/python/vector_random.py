#!/usr/bin/env python3
"""Many environments in one process: 8 loaders stepped together on the TBB pool with random levers.

terramap.sim.VectorEnv runs N copies of configs/scenarios/env_loader_cut.yaml (physics only:
no LiDAR cast), environment k seeded seed + k; each resets itself when its episode ends. The
script prints the aggregate environment steps per second and simulated seconds per wall second.

    PYTHONPATH=build/python python3 examples/python/vector_random.py [--envs 8] [--threads 2]
"""
import argparse
import os
import sys
import time

import numpy as np

import terramap.sim as ts

HERE = os.path.dirname(os.path.abspath(__file__))
SCENARIO = os.path.join(HERE, "..", "..", "configs", "scenarios", "env_loader_cut.yaml")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=SCENARIO)
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=240, help="steps of every environment (60 per simulated second)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    venv = ts.VectorEnv(args.scenario, args.envs, threads=args.threads, time_limit_s=2.0)
    obs, info = venv.reset(seed=args.seed)
    rng = np.random.default_rng(args.seed)
    cut = np.zeros(args.envs)
    episodes = 0
    start = time.perf_counter()
    for _ in range(args.steps):
        actions = rng.uniform(-1.0, 1.0, size=(args.envs, venv.action_width))
        obs, rewards, terminated, truncated, info = venv.step(actions)
        cut += rewards["cut_bank_m3"]
        episodes += int(np.count_nonzero(terminated | truncated))
    wall = time.perf_counter() - start
    steps = args.envs * args.steps
    print("%d environments x %d steps on %d threads: %.0f env steps/s, %.1f simulated s per wall s "
          "(%d episodes ended; bank volume cut per environment: %s m3)"
          % (args.envs, args.steps, args.threads, steps / wall, steps / 60.0 / wall, episodes,
             np.array2string(cut, precision=3)))
    assert obs.shape == (args.envs, len(venv.observation_names())) and np.isfinite(obs).all()
    return 0


if __name__ == "__main__":
    sys.exit(main())
