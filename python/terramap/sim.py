"""terramap.sim: the simulator as an environment for closed-loop control (Gymnasium's
conventions, without depending on it). docs/sim.md, "Driving the simulator from your code".

    import numpy as np, terramap.sim as ts
    env = ts.Env("configs/scenarios/env_loader_cut.yaml", frame_skip=6, time_limit_s=10)
    obs, info = env.reset(seed=1)             # obs: np.ndarray, env.observation_names()
    obs, rewards, terminated, truncated, info = env.step(np.array([0.5, 0.5, 0, 0, 0]))

Agents are the scenario's machines with `controller: {type: external}`; with one agent the
observation is an array and the action an array of its levers (env.action_names(): left_track,
right_track, blade_lift, blade_tilt, blade_angle, and for an excavator slew, boom, arm, bucket),
each in [-1, 1] (ValueError naming the lever otherwise); with several, dicts keyed by agent id.
`rewards` holds measured terms (Env.reward_terms: cut_bank_m3, bucket volumes, distance_m,
blade_work_j, arm_work_j), never a fixed reward; info["task"] the target-surface terms
(Env.task_terms) when Env(target={x0, y0, x1, y1, depth_m | height_m, tolerance_m}) is given.
Env(clouds=True) casts the LiDARs: info["clouds"] lists dicts whose "points" is an (n, 4)
float32 array (x, y, z, intensity in the sensor frame) over the cloud's own memory (no copy);
Env(truth=True) adds info["truth"]. reset(seed, options={"overrides": {...}}) merges scenario
keys (dict or YAML text; `machines` entries by id) for this and later episodes.

VectorEnv(scenario, num_envs, threads=2, ...) steps N environments on the TBB pool:
step(actions[N, A]) -> obs[N, D], {term: [N]}, terminated[N], truncated[N], info; environment
k is seeded seed + k and resets itself when its episode ends (info["final_observation"][k]
holds the ended one's last (obs, info)). Environment k gives the same bits as an Env alone.
Errors: terramap.ConfigError for scenarios and overrides, ValueError for actions, RuntimeError
for a step before reset() or after the episode ended.
"""
from ._terramap import sim as _sim

Env = _sim.Env
VectorEnv = _sim.VectorEnv

__all__ = ["Env", "VectorEnv"]
