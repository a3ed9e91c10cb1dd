"""The existing -v1 ids keep their trajectories bitwise when the route variant is added.

``tests/data/v1_golden.npz`` was written by this file's ``__main__`` from the code before
``Bogie/HuntingRoute-v1`` existed (observations, rewards, end states and actuator forces of
seeded runs with seeded random actions, in the single env and the native vector env, with the
v1 defaults: sensors, delay, alert track, per-episode scenarios). A change that moves a v1
trajectory by one bit fails here; such a change belongs in a new env id.

    PYTHONPATH=<tree> python tests/test_v1_golden.py   # writes the golden file (only for a new version)
"""

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import bogie_env  # noqa: F401  (registers the ids)

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


def vector_run(env_id: str) -> dict[str, np.ndarray]:
    env = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point")
    actions = np.random.default_rng(8).uniform(-1, 1, (N_STEPS, 3) + env.single_action_space.shape)
    obs, _ = env.reset(seed=11)
    observations, rewards = [obs], []
    for a in actions:
        obs, reward, *_ = env.step(a)
        observations.append(obs)
        rewards.append(reward)
    return {"obs": np.array(observations), "reward": np.array(rewards), "x": env.unwrapped.task.states.copy()}


def runs() -> dict[str, np.ndarray]:
    out = {}
    for env_id in IDS:
        for kind, run in (("single", single_run), ("vector", vector_run)):
            for key, value in run(env_id).items():
                out[f"{env_id}|{kind}|{key}"] = value
    return out


@pytest.mark.parametrize("env_id", IDS)
def test_v1_trajectories_are_bitwise_unchanged(env_id):
    golden = np.load(GOLDEN)
    for kind, run in (("single", single_run), ("vector", vector_run)):
        for key, value in run(env_id).items():
            name = f"{env_id}|{kind}|{key}"
            np.testing.assert_array_equal(value, golden[name], err_msg=name)


if __name__ == "__main__":
    np.savez_compressed(GOLDEN, **runs())
    print(f"wrote {GOLDEN}")
