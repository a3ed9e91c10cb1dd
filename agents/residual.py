"""Residual reinforcement learning: a learned correction on top of a classical controller.

The command is ``u = clip(baseline(y) + scale * pi(y), -1, 1)`` (Silver et al. 2018, "Residual
Policy Learning"; Johannink et al. 2019, "Residual Reinforcement Learning for Robot Control"):
``baseline`` is a controller of :mod:`bogie_agents.controllers` (any object with ``reset``
and ``act``), ``pi`` the network's deterministic action in [-1, 1] and ``scale`` the
network's authority, a fraction of each channel's command range.

Why: a network trained with noise and delay alone has small stability margins (v0's PPO: gain
margin 1.4-2.5, delay margin under 10 ms, docs/margins.md). The composite's small-signal
controller is ``D_baseline + scale * J_pi`` (``J_pi`` the network's Jacobian through the
observation normalisation), so with a bounded ``scale`` the loop keeps most of the baseline's
margins, whatever the network learned; the margins are measured on the composite's true
Jacobian (:meth:`ResidualPolicy.controller_model`), not assumed.

- :class:`ResidualVecEnv`: the training side, an SB3 ``VecEnvWrapper`` under ``VecNormalize``:
  the agent's action is the residual, the env receives the composite command; the baseline
  sees the raw observations and is reset with each finished episode.
- :class:`ResidualPolicy`: the deployment side, the same composite from a trained SB3 policy.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnvWrapper

from bogie_env.params import ConfigError

#: The classical controllers a residual may sit on (names for ``load_policy``); ``robust`` once
#: the robust baseline exists in :mod:`bogie_agents.controllers`.
MAX_SCALE = 1.0


def check_residual_config(residual: Any, where: str = "residual") -> dict:
    """``{"baseline": NAME, "scale": s}``: a classical controller name and 0 < s <= 1."""
    from .policies import CLASSICAL

    if not isinstance(residual, dict) or set(residual) - {"baseline", "scale"} or "baseline" not in residual:
        raise ConfigError(f"{where} = {residual!r} is not allowed; allowed: a mapping with 'baseline' (one of "
                          f"{', '.join(CLASSICAL)}) and 'scale' (a number in (0, {MAX_SCALE:g}])")  # fmt: skip
    if residual["baseline"] not in CLASSICAL:
        raise ConfigError(f"{where}.baseline = {residual['baseline']!r} is not allowed; allowed: {', '.join(CLASSICAL)}")
    scale = residual.get("scale", 0.2)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < float(scale) <= MAX_SCALE:
        raise ConfigError(f"{where}.scale = {scale!r} is not allowed; allowed: a number in (0, {MAX_SCALE:g}]")
    return {"baseline": residual["baseline"], "scale": float(scale)}


def compose(base: np.ndarray, residual: np.ndarray, scale: float) -> np.ndarray:
    """The command sent to the env: ``clip(base + scale * clip(residual, -1, 1), -1, 1)``."""
    residual = np.clip(np.asarray(residual, dtype=np.float64), -1.0, 1.0)
    return np.clip(np.asarray(base, dtype=np.float64) + scale * residual, -1.0, 1.0).astype(np.float32)


class ResidualVecEnv(VecEnvWrapper):
    """The agent acts through a baseline: ``env action = clip(baseline(obs) + scale * action)``.

    Place it directly on the native VecEnv (under VecMonitor and VecNormalize), so that the
    baseline sees raw observations. A finished episode's row of the baseline is reset after the
    step that ended it (its next observation is the new episode's first)."""

    def __init__(self, venv, baseline, scale: float) -> None:
        super().__init__(venv)
        self.baseline = baseline
        self.scale = float(scale)
        self._obs: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self.baseline.reset(self.num_envs)
        self._obs = obs
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        base = self.baseline.act(self._obs)
        self.venv.step_async(compose(base, actions, self.scale))

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        rows = np.nonzero(dones)[0]
        if rows.size:
            self.baseline.reset(self.num_envs, rows)
        self._obs = obs
        return obs, rewards, dones, infos


class ResidualPolicy:
    """A trained residual: ``act(y) = clip(baseline.act(y) + scale * network.act(y), -1, 1)``.

    ``network`` is an :class:`bogie_agents.policies.SB3Policy` (deterministic, on normalised
    observations); ``baseline`` a classical controller built for the same env config."""

    def __init__(self, baseline, network, scale: float, name: str) -> None:
        self.baseline = baseline
        self.network = network
        self.model = network.model  # shape checks (policies.check_shapes)
        self.scale = float(scale)
        self.name = name
        self.env_config = network.env_config
        self.observation_type = getattr(baseline, "observation_type", "sensors")

    def reset(self, n_envs: int, rows=None) -> None:
        self.baseline.reset(n_envs, rows)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return compose(self.baseline.act(obs), self.network.act(obs), self.scale)

    def residual_jacobian(self, y0: np.ndarray) -> np.ndarray:
        """``scale x d pi / d y`` at ``y0`` by torch autograd, through the VecNormalize scaling
        and clipping and the action-box clip (:func:`bogie_agents.margins.sb3_jacobian_autograd`)."""
        from .margins import sb3_jacobian_autograd

        return self.scale * sb3_jacobian_autograd(self.network, y0)

    def controller_model(self, n_obs: int, speed_kmh: float, y0: np.ndarray):
        """The composite's linear model at the operating observation ``y0``: the baseline's own
        model (its states, if any, unchanged) with ``scale x J_pi`` added to its feedthrough;
        a channel whose composite command is saturated at ``y0`` has zero small-signal gain."""
        from .margins import ControllerModel, controller_model, sb3_action

        base = controller_model(self.baseline, n_obs, speed_kmh, y0)
        residual = self.residual_jacobian(y0)
        self.baseline.reset(1)
        for _ in range(3):  # a stateful baseline settles at the operating point
            u_base = np.asarray(self.baseline.act(np.asarray(y0, dtype=np.float32)[None]), dtype=np.float64)[0]
        u = u_base + self.scale * sb3_action(self.network, y0)
        live = (np.abs(u) < 1.0).astype(np.float64)[:, None]
        return ControllerModel(base.a, base.b, live * base.c, live * (base.d + residual),
                               f"residual: {base.method} + {self.scale:g} x SB3 Jacobian (torch autograd)")  # fmt: skip
