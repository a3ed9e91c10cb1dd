"""Environment ids. Gymnasium 1.x registers on import: ``gym.make("bogie_env:Bogie/Hunting-v0")``
imports ``bogie_env`` first; or ``import bogie_env`` then ``gym.make("Bogie/Hunting-v0")``."""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from .config import passive_actuators, semi_active_actuators
from .core import HuntingTask

ENTRY = "bogie_env.envs.hunting_env:BogieHuntingEnv"
VECTOR_ENTRY = "bogie_env.envs.vector:BogieHuntingVectorEnv"

VARIANTS = {
    # fully active: force actuators on frame lateral, frame yaw and both wheelsets' yaw
    "Bogie/Hunting-v0": {},
    "Bogie/HuntingActive-v0": {},
    # passive baseline: no actuators (the action is ignored)
    "Bogie/HuntingPassive-v0": {"actuators": passive_actuators()},
    # semi-active dampers on all four channels
    "Bogie/HuntingSemiActive-v0": {"actuators": semi_active_actuators()},
    # the paper's slow ramp, 300 -> 600 km/h at 0.1 m/s^2 (833 s), fully active
    "Bogie/HuntingSlowRamp-v0": {"speed": {"accel": 0.1}},
}


def _max_steps(config: dict) -> int:
    return HuntingTask.max_steps_for(config)


def register_envs() -> None:
    for env_id, config in VARIANTS.items():
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=ENTRY,
            vector_entry_point=VECTOR_ENTRY,
            max_episode_steps=_max_steps(config),
            kwargs={"config": config} if config else {},
        )
