"""Environment ids. ``import bogie_env`` registers them; so does ``gym.make("bogie_env:Bogie/Hunting-v0")``.

Registration uses string entry points and imports neither the env nor its compiled kernel.
Each id names a variant of :data:`bogie_env.envs.config.VARIANTS`; a user's ``config`` merges
into the variant's (``gym.make("Bogie/HuntingPassive-v0", config={"speed": {"accel": 0.1}})``
stays passive). No ``max_episode_steps`` is registered: the envs truncate themselves at the
end of the configured ramp, or after the ramp's length plus 10 % (``HuntingTask.max_episode_steps``),
so the limit follows the config. ``gym.make(..., max_episode_steps=N)`` still adds a
``TimeLimit`` of N steps.

``import bogie_env`` does not import Gymnasium: if Gymnasium is not loaded yet, the ids are
registered right after it is, whichever of the two a program imports first.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys
from typing import Callable

ENTRY = "bogie_env.envs.hunting_env:BogieHuntingEnv"
VECTOR_ENTRY = "bogie_env.envs.vector:BogieHuntingVectorEnv"

#: id -> variant (a key of ``bogie_env.envs.config.VARIANTS``; None: the defaults)
IDS: dict[str, str | None] = {
    # fully active: force actuators on frame lateral, frame yaw and both wheelsets' yaw
    "Bogie/Hunting-v0": None,
    # the same env as Bogie/Hunting-v0 under a second name (kept: v0 ids do not change)
    "Bogie/HuntingActive-v0": None,
    # passive baseline: no actuators (the action is ignored)
    "Bogie/HuntingPassive-v0": "passive",
    # semi-active dampers on all four channels
    "Bogie/HuntingSemiActive-v0": "semi_active",
    # the paper's slow ramp, 300 -> 600 km/h at 0.1 m/s^2 (833 s), fully active
    "Bogie/HuntingSlowRamp-v0": "slow_ramp",
    # v1, the realistic task: sensor noise, bias and bandwidth; one step of loop delay and
    # force-rate limits; EN 13848-5 alert-level track; per-episode conicity, suspension,
    # creep, axle load, actuator gain and faults; converged integration
    "Bogie/Hunting-v1": "v1",
    "Bogie/HuntingPassive-v1": "v1_passive",
    "Bogie/HuntingSemiActive-v1": "v1_semi_active",
    "Bogie/HuntingSlowRamp-v1": "v1_slow_ramp",
    # v1's world on the shipped routes (curves, transitions, cant) at their line speeds, with
    # wear and flange contact in the reward and a Y/Q termination
    "Bogie/HuntingRoute-v1": "v1_route",
    "Bogie/HuntingRoutePassive-v1": "v1_route_passive",
    # v1's task with the 10-stage Taylor integrator at the same accuracy criterion: 20
    # right-hand sides per env step instead of 40 (docs/studies/integrator.md)
    "Bogie/Hunting-v2": "v2",
    "Bogie/HuntingPassive-v2": "v2_passive",
    # v1's task with a 14-stage method designed for the bogie's spectrum, at the same accuracy
    # criterion: one substep, 14 right-hand sides per env step (docs/studies/integrator.md)
    "Bogie/Hunting-v3": "v3",
    "Bogie/HuntingPassive-v3": "v3_passive",
    # v3 with a 12-stage method from the same design program on inscribed polygons: one substep,
    # 12 right-hand sides per env step (docs/studies/integrator.md)
    "Bogie/Hunting-v4": "v4",
    "Bogie/HuntingPassive-v4": "v4_passive",
}


def register_envs() -> None:
    """Register every id with Gymnasium (idempotent)."""
    from gymnasium.envs.registration import register, registry

    for env_id, variant in IDS.items():
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=ENTRY,
            vector_entry_point=VECTOR_ENTRY,
            kwargs={"variant": variant} if variant else {},
        )


def register_envs_with_gymnasium() -> None:
    """Register now if Gymnasium is loaded, else as soon as it has been imported."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(finder, _AfterImport) for finder in sys.meta_path):
        sys.meta_path.insert(0, _AfterImport("gymnasium", register_envs))


class _AfterImport(importlib.abc.MetaPathFinder):
    """One-shot import hook: runs ``callback`` once the module ``name`` has been executed."""

    def __init__(self, name: str, callback: Callable[[], None]) -> None:
        self.name = name
        self.callback = callback

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)  # the real finders
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            spec.loader = _CallbackLoader(spec.loader, self.callback)
        return spec


class _CallbackLoader(importlib.abc.Loader):
    def __init__(self, loader, callback: Callable[[], None]) -> None:
        self.loader = loader
        self.callback = callback

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        module.__loader__ = module.__spec__.loader = self.loader  # the module keeps its real loader
        self.loader.exec_module(module)
        self.callback()
