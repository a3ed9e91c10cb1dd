"""The -v0 ids are a reproducibility contract: their trajectories are pinned bitwise.

``tests/data/v0_golden.npz`` was written by this file's ``__main__`` from the code before
``Bogie/Hunting-v1`` existed (observations, rewards and end states of seeded runs with seeded
random actions, in the single env and the native vector env). Any change that moves a v0
trajectory by one bit fails here; such a change belongs in a new env id.

Rewritten once since, when the equilibrium's Newton step left LAPACK (``dynamics.solve_dense``):
LAPACK's bits followed the processor's OpenBLAS kernel, so the file pinned one machine's last
bits. Every array then moved by at most 5e-12 relative, the dynamics unchanged.
"""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import bogie_env  # noqa: F401  (registers the ids)
from tests.golden_runs import runs as golden_runs, vector_run

GOLDEN = Path(__file__).parent / "data" / "v0_golden.npz"
IDS = ("Bogie/Hunting-v0", "Bogie/HuntingPassive-v0", "Bogie/HuntingSemiActive-v0")
N_STEPS = 200


def single_run(env_id: str) -> dict[str, np.ndarray]:
    env = gym.make(env_id, config={"large_perturbation_probability": 0.5, "observation": {"noise": 0.01}})
    actions = np.random.default_rng(7).uniform(-1, 1, (N_STEPS,) + env.action_space.shape)
    obs, _ = env.reset(seed=3)
    observations, rewards = [obs], []
    for a in actions:
        obs, reward, terminated, truncated, _ = env.step(a)
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            obs, _ = env.reset()
    return {"obs": np.array(observations), "reward": np.array(rewards), "x": env.unwrapped.task.states.copy()}


def runs() -> dict[str, np.ndarray]:
    return golden_runs(IDS, single_run, N_STEPS)


@pytest.mark.parametrize("env_id", IDS)
def test_v0_trajectories_are_bitwise_unchanged(env_id):
    golden = np.load(GOLDEN)
    for kind, run in (("single", single_run), ("vector", lambda e: vector_run(e, N_STEPS))):
        for key, value in run(env_id).items():
            expected = golden[f"{env_id}|{kind}|{key}"]
            assert value.shape == expected.shape, (env_id, kind, key)
            assert np.array_equal(value, expected), f"{env_id} {kind} {key} moved (max diff {np.max(np.abs(value - expected))})"


if __name__ == "__main__":
    np.savez_compressed(GOLDEN, **runs())
    print("wrote", GOLDEN)
