"""Residual reinforcement learning: a learned correction on top of a classical controller.

The command is ``u = clip(baseline(y) + scale * pi(y), -1, 1)`` (Silver et al. 2018, "Residual
Policy Learning"; Johannink et al. 2019, "Residual Reinforcement Learning for Robot Control"):
``baseline`` is a classical controller (a name of :data:`bogie_agents.controllers.policies.CLASSICAL`, e.g.
``robust_steering`` for the shipped v1 policy; any object with ``reset`` and ``act``), ``pi`` the network's deterministic action in [-1, 1] and ``scale`` the
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

#: The largest residual authority ``scale``: a fraction of each channel's command range.
MAX_SCALE = 1.0


#: What the network sees (``residual.features``): ``observation``, the env's observation (through
#: VecNormalize); ``washed_out``, the robust baseline's zero-DC design signals (washed-out gyro and
#: accelerometer, difference quotients of the relative displacements; :func:`bogie_agents.controllers.robust.filter_bank`),
#: scaled by :data:`FEATURE_SCALES`, and the same signals times the measured speed / 600 km/h.
FEATURES = ("observation", "washed_out")
#: Typical hunting amplitudes of the design signals (1 mm, 1 mrad at 3 Hz): wheelset and frame yaw
#: rates (rad/s), frame lateral velocity (m/s), wheelset lateral rates (clearance units per s).
FEATURE_SCALES = np.array([0.02, 0.02, 0.02, 0.02, 3.0, 3.0])
FEATURE_SPEED_KMH = 600.0
FEATURE_CLIP = 10.0


def check_residual_config(residual: Any, where: str = "residual") -> dict:
    """``{"baseline": NAME, "scale": s, "features": F}``: a classical controller name, 0 < s <= 1
    and one of :data:`FEATURES` (default ``observation``)."""
    from .classical import CLASSICAL

    if not isinstance(residual, dict) or set(residual) - {"baseline", "scale", "features"} or "baseline" not in residual:
        raise ConfigError(f"{where} = {residual!r} is not allowed; allowed: a mapping with 'baseline' (one of "
                          f"{', '.join(CLASSICAL)}) and 'scale' (a number in (0, {MAX_SCALE:g}])")  # fmt: skip
    if residual["baseline"] not in CLASSICAL:
        raise ConfigError(f"{where}.baseline = {residual['baseline']!r} is not allowed; allowed: {', '.join(CLASSICAL)}")
    scale = residual.get("scale", 0.2)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < float(scale) <= MAX_SCALE:
        raise ConfigError(f"{where}.scale = {scale!r} is not allowed; allowed: a number in (0, {MAX_SCALE:g}]")
    features = residual.get("features", "observation")
    if features not in FEATURES:
        raise ConfigError(f"{where}.features = {features!r} is not allowed; allowed: {', '.join(FEATURES)}")
    return {"baseline": residual["baseline"], "scale": float(scale), "features": features}


class WashedOutFeatures:
    """The network's input for ``features: washed_out``: zero for any constant observation.

    ``[s / FEATURE_SCALES, s / FEATURE_SCALES x speed / 600 km/h]``, clipped to +-10, with ``s``
    the six design signals of the robust baseline's filter bank (its own filter states, reset per
    row; a row's filters start as ``robust_damping``'s do, settled on the first observation with
    the accelerometer chain at rest: :func:`bogie_agents.controllers.robust.start_state`). With an actor that has no
    biases and an odd activation (tanh), the residual is an odd function of these features:
    zero at rest, zero in a steady curve, zero for a constant sensor bias."""

    def __init__(self, env_config: dict) -> None:
        from .robust import RobustDampingController

        self.filters = RobustDampingController(env_config)
        self.dim = 2 * len(FEATURE_SCALES)

    def reset(self, n_envs: int, rows=None) -> None:
        self.filters.reset(n_envs, rows)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Advance each row's filters on its observation; the features (n, 12)."""
        return self._features(self.filters.signals(obs), obs)

    def peek(self, obs: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """The features the given rows would have for ``obs``, without advancing their filters."""
        f, bank = self.filters, self.filters.bank
        y = np.asarray(obs, dtype=float)
        state = np.where(f.started[rows, None], f.state[rows], y @ f.settle.T)
        return self._features(state @ bank.c.T + y @ bank.d.T, obs)

    def _features(self, signals: np.ndarray, obs: np.ndarray) -> np.ndarray:
        signals = signals / FEATURE_SCALES
        speed = self.filters.speed_kmh(np.asarray(obs))[:, None] / FEATURE_SPEED_KMH
        return np.clip(np.concatenate([signals, signals * speed], axis=1), -FEATURE_CLIP, FEATURE_CLIP).astype(np.float32)

    def linear_map(self, speed_kmh: float):
        """(a, b, c, d) with ``f+ = a f + b y``, ``features = c f + d y`` at a fixed speed (no clip)."""
        bank = self.filters.bank
        gain = np.concatenate([np.eye(len(FEATURE_SCALES)), np.eye(len(FEATURE_SCALES)) * speed_kmh / FEATURE_SPEED_KMH])
        gain = gain / np.tile(FEATURE_SCALES, 2)[:, None]
        return bank.a, bank.b, gain @ bank.c, gain @ bank.d


def odd_actor(model) -> None:
    """Zero and freeze the biases of an SB3 actor-critic's policy layers and action head, so that
    with tanh the deterministic action is an odd function of the input (zero at zero)."""
    import torch

    layers = list(model.policy.mlp_extractor.policy_net.modules()) + [model.policy.action_net]
    with torch.no_grad():
        for layer in layers:
            if isinstance(layer, torch.nn.Linear) and layer.bias is not None:
                layer.bias.zero_()
                layer.bias.requires_grad_(False)


def compose(base: np.ndarray, residual: np.ndarray, scale: float) -> np.ndarray:
    """The command sent to the env: ``clip(base + scale * clip(residual, -1, 1), -1, 1)``."""
    residual = np.clip(np.asarray(residual, dtype=np.float64), -1.0, 1.0)
    return np.clip(np.asarray(base, dtype=np.float64) + scale * residual, -1.0, 1.0).astype(np.float32)


class ResidualVecEnv(VecEnvWrapper):
    """The agent acts through a baseline: ``env action = clip(baseline(obs) + scale * action)``.

    Place it directly on the native VecEnv (under VecMonitor and VecNormalize), so that the
    baseline sees raw observations. A finished episode's row of the baseline is reset after the
    step that ended it (its next observation is the new episode's first)."""

    def __init__(self, venv, baseline, scale: float, features=None) -> None:
        from gymnasium import spaces

        space = None
        if features is not None:
            space = spaces.Box(-FEATURE_CLIP, FEATURE_CLIP, (features.dim,), np.float32)
        super().__init__(venv, observation_space=space)
        self.baseline = baseline
        self.scale = float(scale)
        self.features = features
        self._obs: np.ndarray | None = None

    def _agent_obs(self, obs: np.ndarray) -> np.ndarray:
        return obs if self.features is None else self.features(obs)

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self.baseline.reset(self.num_envs)
        if self.features is not None:
            self.features.reset(self.num_envs)
        self._obs = obs
        return self._agent_obs(obs)

    def step_async(self, actions: np.ndarray) -> None:
        base = self.baseline.act(self._obs)
        self.venv.step_async(compose(base, actions, self.scale))

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        rows = np.nonzero(dones)[0]
        if self.features is not None:
            for i in rows:  # the last observation, in the agent's terms (for bootstrapping)
                terminal = infos[i].get("terminal_observation")
                if terminal is not None:
                    infos[i]["terminal_observation"] = self.features.peek(terminal[None], np.array([i]))[0]
        if rows.size:
            self.baseline.reset(self.num_envs, rows)
            if self.features is not None:
                self.features.reset(self.num_envs, rows)
        self._obs = obs
        return self._agent_obs(obs), rewards, dones, infos


class ResidualPolicy:
    """A trained residual: ``act(y) = clip(baseline.act(y) + scale * network.act(x), -1, 1)``, with
    ``x`` the observation ``y`` or, for ``features: washed_out``, :class:`WashedOutFeatures` of it.

    ``network`` is an :class:`bogie_agents.controllers.policies.SB3Policy` (deterministic, on normalised
    observations); ``baseline`` a classical controller built for the same env config."""

    def __init__(self, baseline, network, scale: float, name: str, features=None) -> None:
        self.baseline = baseline
        self.network = network
        self.model = network.model
        self.scale = float(scale)
        self.name = name
        self.features = features
        self.env_config = network.env_config
        self.observation_type = getattr(baseline, "observation_type", "sensors")

    def reset(self, n_envs: int, rows=None) -> None:
        self.baseline.reset(n_envs, rows)
        if hasattr(self.network, "reset"):  # a network with memory (bogie_agents.controllers.memory)
            self.network.reset(n_envs, rows)
        if self.features is not None:
            self.features.reset(n_envs, rows)

    def act(self, obs: np.ndarray) -> np.ndarray:
        x = obs if self.features is None else self.features(obs)
        return compose(self.baseline.act(obs), self.network.act(x), self.scale)

    def controller_model(self, n_obs: int, speed_kmh: float, y0: np.ndarray):
        """The composite's linear model at the operating observation ``y0``: the baseline's own
        model beside the network's, ``scale x J`` (``J`` its Jacobian by torch autograd, through
        its input normalisation; with frame stacking, a shift register of the earlier inputs; with
        an LSTM, its state) fed by the feature filters (if any); a channel whose composite command
        is clipped at ``y0`` has zero small-signal gain."""
        from ..design.margins import ControllerModel, controller_model, frames_of, parallel, sb3_action, sb3_controller_model, series

        y0 = np.asarray(y0, dtype=np.float64)
        base = controller_model(self.baseline, n_obs, speed_kmh, y0)
        self.reset(1)
        for _ in range(3):  # stateful parts settle at the operating point
            u_base = np.asarray(self.baseline.act(y0.astype(np.float32)[None]), dtype=np.float64)[0]
            x0 = y0 if self.features is None else self.features(y0.astype(np.float32)[None])[0].astype(np.float64)
        frames = frames_of(self.network)
        live = (np.abs(u_base + self.scale * sb3_action(self.network, x0)) < 1.0).astype(np.float64)[:, None]
        inputs = "observation" if self.features is None else "washed-out features"
        memory = f", {frames} stacked frames" if frames > 1 else (", LSTM state" if getattr(self.network, "recurrent", None) is not None else "")
        method = f"residual: {base.method} + {self.scale:g} x NN Jacobian (torch autograd; network input: {inputs}{memory})"
        network = sb3_controller_model(self.network, x0)
        network = ControllerModel(network.a, network.b, self.scale * network.c, self.scale * network.d, method)
        if self.features is not None:
            network = series(ControllerModel(*self.features.linear_map(speed_kmh), method), network, method)
        total = parallel(base, network, method)
        return ControllerModel(total.a, total.b, live * total.c, live * total.d, method)
