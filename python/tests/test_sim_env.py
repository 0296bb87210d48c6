"""terramap.sim's contracts: levers checked with errors naming them, reset reproducible, truncation
at the time limit, overrides, zero-copy clouds, and env k of a VectorEnv equal to env k alone."""
import os

import numpy as np
import pytest

import terramap
import terramap.sim as ts

SOURCE_DIR = os.environ.get("TERRAMAP_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
SCENARIO = os.path.join(SOURCE_DIR, "configs", "scenarios", "env_loader_cut.yaml")


def levers(rng):
    a = rng.uniform(-1.0, 1.0, size=5)
    a[:2] = 0.5 + 0.5 * np.abs(a[:2])
    return a


def test_bad_actions_raise_value_error_naming_the_lever():
    env = ts.Env(SCENARIO)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(5))
    env.reset(seed=1)
    with pytest.raises(ValueError, match=r"blade_tilt\) = 1\.2"):
        env.step(np.array([0, 0, 0, 1.2, 0]))
    with pytest.raises(ValueError, match="left_track"):
        env.step(np.array([np.nan, 0, 0, 0, 0]))
    with pytest.raises(ValueError, match="expected an array of 5 levers"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="no levers for agent loader"):
        env.step({"grader": np.zeros(5)})
    obs, rewards, terminated, truncated, info = env.step(np.zeros(5))
    assert info["episode_step"] == 1 and not terminated and not truncated


def test_reset_reproduces_the_episode_and_restores_the_world():
    env = ts.Env(SCENARIO, frame_skip=2, truth=True)

    def episode(seed):
        obs, info = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        trace = [obs]
        for _ in range(40):
            obs, rewards, terminated, truncated, info = env.step(levers(rng))
            trace.append(obs)
            trace.append(np.array([rewards[k] for k in ts.Env.reward_terms]))
        return np.concatenate(trace), env.terrain_heights()[0]

    a, ha = episode(3)
    b, hb = episode(4)
    c, hc = episode(3)
    assert np.array_equal(a, c) and np.array_equal(ha, hc)
    assert not np.array_equal(a, b)
    fresh = ts.Env(SCENARIO, frame_skip=2, truth=True)
    obs, info = fresh.reset(seed=3)
    assert np.array_equal(obs, a[:obs.size])


def test_truncated_at_the_time_limit():
    env = ts.Env(SCENARIO, frame_skip=3, time_limit_s=0.5)
    env.reset(seed=2)
    steps, truncated = 0, False
    while not truncated:
        obs, rewards, terminated, truncated, info = env.step(np.full(5, 0.3))
        steps += 1
    assert steps == 10 and info["t"] == pytest.approx(0.5) and not terminated
    with pytest.raises(RuntimeError, match="ended"):
        env.step(np.zeros(5))


def test_overrides_and_bad_overrides():
    env = ts.Env(SCENARIO)
    names = env.observation_names()
    assert env.reset(seed=1)[1]["rebuilt_terrain"]  # the first build
    obs, info = env.reset(seed=1, options={"overrides": {"machines": [{"id": "loader", "pose": {"x_m": 1.0, "y_m": -1.5}}]}})
    assert obs[names.index("base_x")] == pytest.approx(1.0, abs=0.2) and not info["rebuilt_terrain"]
    with pytest.raises(terramap.ConfigError, match="no machine 'dozer'"):
        env.reset(options={"overrides": {"machines": [{"id": "dozer"}]}})
    with pytest.raises(ValueError, match="unknown key"):
        env.reset(options={"override": {}})


def test_clouds_are_float32_arrays_over_the_cloud_memory():
    env = ts.Env(SCENARIO, frame_skip=6, clouds=True)
    env.reset(seed=1)
    obs, rewards, terminated, truncated, info = env.step(np.zeros(5))
    clouds = info["clouds"]
    assert len(clouds) == 1 and clouds[0]["frame"] == "loader/lidar_top"
    pts = clouds[0]["points"]
    assert pts.dtype == np.float32 and pts.shape[1] == 4 and pts.shape[0] > 1000
    assert not pts.flags["OWNDATA"] and pts.base is not None  # a view of the C++ vector
    assert np.isfinite(pts).all()
    assert clouds[0]["T_map_sensor"].shape == (4, 4)


def test_vector_env_k_equals_env_k_alone():
    venv = ts.VectorEnv(SCENARIO, 3, threads=2, frame_skip=2)
    vobs, info = venv.reset(seed=10)
    alone = ts.Env(SCENARIO, frame_skip=2)
    obs, _ = alone.reset(seed=12)
    assert np.array_equal(vobs[2], obs)
    rng = np.random.default_rng(5)
    for _ in range(20):
        acts = np.stack([levers(rng) for _ in range(3)])
        vobs, vrew, vterm, vtrunc, info = venv.step(acts)
        obs, rew, term, trunc, _ = alone.step(acts[2])
        assert np.array_equal(vobs[2], obs)
        assert vrew["cut_bank_m3"][2] == rew["cut_bank_m3"]
    with pytest.raises(ValueError, match=r"shape \(3, 5\)"):
        venv.step(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="environment 1"):
        bad = np.zeros((3, 5))
        bad[1, 4] = 3.0
        venv.step(bad)
