"""Seeded runs that the golden tests pin bitwise (tests/test_v0_golden.py, tests/test_v1_golden.py)."""

from __future__ import annotations

from typing import Callable

import gymnasium as gym
import numpy as np

import bogie_env  # noqa: F401  (registers the ids)


def vector_run(env_id: str, n_steps: int) -> dict[str, np.ndarray]:
    """The native vector env (3 rows, seed 11) under seeded random actions."""
    env = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    actions = np.random.default_rng(8).uniform(-1, 1, (n_steps, 3) + env.single_action_space.shape)
    obs, _ = env.reset(seed=11)
    observations, rewards = [obs], []
    for a in actions:
        obs, reward, *_ = env.step(a)
        observations.append(obs)
        rewards.append(reward)
    return {"obs": np.array(observations), "reward": np.array(rewards), "x": env.unwrapped.task.states.copy()}


def runs(ids, single_run: Callable, n_steps: int) -> dict[str, np.ndarray]:
    """Every array of the single-env and vector-env runs of ``ids``, keyed ``id|kind|name``."""
    out = {}
    for env_id in ids:
        for kind, run in (("single", single_run), ("vector", lambda e: vector_run(e, n_steps))):
            for key, value in run(env_id).items():
                out[f"{env_id}|{kind}|{key}"] = value
    return out


def assert_bitwise(golden_path, env_id: str, single_run: Callable, n_steps: int) -> None:
    """``env_id``'s single-env and vector-env runs equal, bit for bit, what ``golden_path`` holds."""
    golden = np.load(golden_path)
    for kind, run in (("single", single_run), ("vector", lambda e: vector_run(e, n_steps))):
        for key, value in run(env_id).items():
            name = f"{env_id}|{kind}|{key}"
            np.testing.assert_array_equal(value, golden[name], err_msg=name)
