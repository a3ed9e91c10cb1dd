"""The existing -v1 ids keep their trajectories bitwise when the route variant is added.

``tests/data/v1_golden.npz`` was written by this file's ``__main__`` from the code before
``Bogie/HuntingRoute-v1`` existed (observations, rewards, end states and actuator forces of
seeded runs with seeded random actions, in the single env and the native vector env, with the
v1 defaults: sensors, delay, alert track, per-episode scenarios). A change that moves a v1
trajectory by one bit fails here; such a change belongs in a new env id.

Rewritten once since, when the equilibrium's Newton step left LAPACK (``dynamics.solve_dense``):
LAPACK's bits followed the processor's OpenBLAS kernel, so the file pinned one machine's last
bits. Every array then moved by at most 5e-12 relative, the dynamics unchanged.

    PYTHONPATH=<tree> python tests/test_v1_golden.py   # writes the golden file (only for a new version)
"""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import bogie_env  # noqa: F401  (registers the ids)
from tests.golden_runs import assert_bitwise, runs as golden_runs

GOLDEN = Path(__file__).parent / "data" / "v1_golden.npz"
IDS = ("Bogie/Hunting-v1", "Bogie/HuntingPassive-v1")
N_STEPS = 150


def single_run(env_id: str) -> dict[str, np.ndarray]:
    env = gym.make(env_id, config={"large_perturbation_probability": 0.5})
    actions = np.random.default_rng(7).uniform(-1, 1, (N_STEPS,) + env.action_space.shape)
    obs, _ = env.reset(seed=3)
    observations, rewards, forces = [obs], [], []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        observations.append(obs)
        rewards.append(reward)
        forces.append(info["actuator_force"])
        if terminated or truncated:
            obs, _ = env.reset()
    return {"obs": np.array(observations), "reward": np.array(rewards), "force": np.array(forces),
            "x": env.unwrapped.task.states.copy()}  # fmt: skip


def runs() -> dict[str, np.ndarray]:
    return golden_runs(IDS, single_run, N_STEPS)


@pytest.mark.parametrize("env_id", IDS)
def test_v1_trajectories_are_bitwise_unchanged(env_id):
    assert_bitwise(GOLDEN, env_id, single_run, N_STEPS)


if __name__ == "__main__":
    np.savez_compressed(GOLDEN, **runs())
    print(f"wrote {GOLDEN}")
