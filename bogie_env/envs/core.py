"""The batched hunting-control task: one object owns N environments' arrays.

:class:`HuntingTask` builds everything from a validated config (``envs/config.py``): the
bogie model and its coefficients per row, the shared track profile, the actuator channels
and the action and observation layouts. ``reset_rows`` starts episodes, ``step`` advances
all rows through the compiled kernel (``envs/kernel.py``). The three environment classes
are thin front-ends that differ only in how they reset finished episodes.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from gymnasium import spaces

from ..dynamics import N_INPUTS, N_STATES, P_DELTA, BogieModel, state_index
from ..integrate import channel_damping_jacobian, stable_substep
from ..params import BogieParams, ConfigError, load_params
from ..track import alignment_profile, perfect_track
from . import kernel as K
from .config import CHANNELS, make_config

KMH = 3.6
# Scales of the full-state observation ("state" type): what counts as 1 for each state.
STATE_SCALES = np.array(
    [9e-3, 0.1, 1e-3, 0.05, 5e-3, 0.1, 5e-3, 0.1] * 2 + [9e-3, 0.1, 5e-3, 0.05], dtype=float
)


class HuntingTask:
    """N hunting-control episodes advanced together (the physics is in the kernel)."""

    def __init__(self, num_envs: int, config: Mapping[str, Any] | str | None = None, **overrides: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ConfigError(f"num_envs = {num_envs!r} must be an integer >= 1")
        self.num_envs = int(num_envs)
        self.config = make_config(config, **overrides)
        c = self.config
        self.base_params: BogieParams = load_params(c["bogie"], [f"{k}={v}" for k, v in c["bogie_overrides"].items()])
        self.model = BogieModel(self.base_params)
        tr = c["track"]
        self.track = (
            alignment_profile(tr["rms"], tr["wavelength_min"], tr["wavelength_max"], seed=tr["seed"])
            if tr["rms"] > 0
            else perfect_track()
        )
        # actuator channels -> action columns
        self.active_channels = [k for k, name in enumerate(CHANNELS) if c["actuators"][name]["mode"] != "off"]
        self.action_dim = max(1, len(self.active_channels))
        self.passive = not self.active_channels
        self.observation_dim = (N_STATES if c["observation"]["type"] == "state" else 6) + 1
        if c["observation"]["include_actuators"]:
            self.observation_dim += len(self.active_channels)
        self.action_space = spaces.Box(-1.0, 1.0, (self.action_dim,), np.float32)
        self.observation_space = spaces.Box(-K.OBS_BOUND, K.OBS_BOUND, (self.observation_dim,), np.float32)
        self.cfg = self._config_vector()
        self.n_sub = int(self.cfg[K.C_NSUB])
        # per-row arrays
        n = self.num_envs
        self.x = np.zeros((n, N_STATES))
        self.scal = np.zeros((n, K.N_SCALARS))
        self.act = np.zeros((n, 2 * N_INPUTS))
        self.delay = np.zeros((n, K.DELAY_SLOTS, 2 * N_INPUTS))
        self.P = np.repeat(self.model.coefficients[None, :], n, axis=0)
        self.obs = np.zeros((n, self.observation_dim), dtype=np.float32)
        self.reward = np.zeros(n)
        self.flags = np.zeros((n, 4), dtype=np.int8)
        self.info = np.zeros((n, K.N_INFO))
        self.actions = np.zeros((n, self.action_dim))
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.episode_params: list[dict[str, float]] = [{} for _ in range(n)]

    # ---- configuration ------------------------------------------------------------------
    def speed_limits(self) -> tuple[float, float]:
        """Lowest and highest speed (m/s) any episode can visit under this config."""
        sp = self.config["speed"]
        lows = [sp["start_kmh"]] + ([sp["start_kmh_range"][0]] if sp["start_kmh_range"] else [])
        highs = [sp["end_kmh"]] + ([sp["end_kmh_range"][1]] if sp["end_kmh_range"] else [])
        return min(lows) / KMH, max(highs) / KMH

    def _config_vector(self) -> np.ndarray:
        c = self.config
        cfg = np.zeros(K.N_CFG)
        cfg[K.C_DT] = c["dt"]
        cfg[K.C_INV_DX] = 1.0 / self.track.dx
        cfg[K.C_OBS_STATE] = 1.0 if c["observation"]["type"] == "state" else 0.0
        cfg[K.C_OBS_ACT] = 1.0 if c["observation"]["include_actuators"] else 0.0
        rw = c["reward"]
        cfg[K.C_W_LAT], cfg[K.C_W_YAW], cfg[K.C_W_EFF] = rw["lateral_weight"], rw["yaw_weight"], rw["effort_weight"]
        cfg[K.C_W_TIME], cfg[K.C_YAW_REF] = rw["time_weight"], rw["yaw_reference"]
        hu = c["hunting"]
        cfg[K.C_WINDOW_M], cfg[K.C_HUNT_RMS_FRACTION], cfg[K.C_BLOWUP] = hu["window_m"], hu["rms_fraction"], hu["blowup_m"]
        cfg[K.C_N_ACTIVE] = len(self.active_channels)
        max_damping = np.zeros(N_INPUTS)
        for k, name in enumerate(CHANNELS):
            spec = c["actuators"][name]
            base = K.C_CHANNELS + k * K.CH_FIELDS
            cfg[base + K.CH_MODE] = {"off": K.MODE_OFF, "force": K.MODE_FORCE, "semi_active": K.MODE_SEMI}[spec["mode"]]
            cfg[base + K.CH_MAX] = spec["max_force"]
            cfg[base + K.CH_CMIN] = spec["c_min"]
            cfg[base + K.CH_CMAX] = spec["c_max"]
            cfg[base + K.CH_DECAY] = 2 * math.pi * spec["bandwidth_hz"]  # 1/tau of a first-order lag
            cfg[base + K.CH_DELAY] = spec["delay_steps"]
            cfg[base + K.CH_ACTION] = self.active_channels.index(k) if k in self.active_channels else -1
            if spec["mode"] == "semi_active":
                max_damping[k] = spec["c_max"]
        cfg[K.C_STATE_SCALES : K.C_STATE_SCALES + N_STATES] = STATE_SCALES
        # Step size from the spectrum over the whole speed range, dampers at their stiffest.
        lo, hi = self.speed_limits()
        extra = channel_damping_jacobian(self.model, max_damping) if np.any(max_damping) else None
        self.step_choice = stable_substep(self.model, lo, hi, c["dt"], extra_jacobian=extra)
        cfg[K.C_NSUB] = self.step_choice.n_sub
        return cfg

    # ---- episodes -------------------------------------------------------------------------
    def seed_rows(self, rows: np.ndarray, seeds: list[int | None]) -> None:
        for i, s in zip(rows, seeds):
            self.rngs[i] = np.random.default_rng(s)

    def reset_rows(self, rows: np.ndarray, options: Mapping[str, Any] | None = None) -> None:
        """Start new episodes in ``rows`` (their RNGs must already be seeded)."""
        options = dict(options or {})
        unknown = set(options) - {"start_kmh", "end_kmh", "accel", "params"}
        if unknown:
            raise ConfigError(f"unknown reset option(s) {sorted(unknown)}; allowed: start_kmh, end_kmh, accel, params")
        sp = self.config["speed"]
        for i in np.atleast_1d(rows):
            rng = self.rngs[i]
            start = self._draw(rng, options.get("start_kmh"), sp["start_kmh"], sp["start_kmh_range"], "start_kmh")
            end = self._draw(rng, options.get("end_kmh"), sp["end_kmh"], sp["end_kmh_range"], "end_kmh")
            accel = self._draw(rng, options.get("accel"), sp["accel"], sp["accel_range"], "accel")
            lo, hi = self.speed_limits()
            if not (lo - 1e-9 <= start / KMH and end / KMH <= hi + 1e-9 and start <= end):
                raise ConfigError(
                    f"reset speeds start_kmh={start:g}, end_kmh={end:g} must satisfy "
                    f"{lo * KMH:g} <= start_kmh <= end_kmh <= {hi * KMH:g} (the range the step size was chosen for)"
                )
            factors = {name: float(rng.uniform(*bounds)) for name, bounds in self.config["randomize"].items()}
            factors.update(options.get("params", {}) or {})
            if factors:
                model = BogieModel(self.base_params.scaled(**factors))
                self.P[i] = model.coefficients
            else:
                model = self.model
                self.P[i] = self.model.coefficients
            self.episode_params[i] = factors
            x = model.equilibrium(start / KMH)
            sigma = self.config["initial_perturbation"]
            offsets = rng.normal(0.0, sigma, 3)
            yaws = rng.normal(0.0, sigma / (2 * self.base_params.L1), 3)
            if self.config["large_perturbation_probability"] > 0 and rng.random() < self.config["large_perturbation_probability"]:
                size = self.config["large_perturbation"]
                offsets = rng.uniform(0.5, 1.0, 3) * size * rng.choice([-1.0, 1.0], 3)
            x[[state_index("y1"), state_index("y2"), state_index("yb")]] += offsets
            x[[state_index("psi1"), state_index("psi2"), state_index("psib")]] += yaws
            self.x[i] = x
            self.scal[i] = 0.0
            self.scal[i, K.S_SPEED] = start / KMH
            self.scal[i, K.S_ACCEL] = accel
            self.scal[i, K.S_VEND] = end / KMH
            self.scal[i, K.S_DIST] = rng.uniform(0.0, self.track.length) if self.track.values.size else 0.0
            self.scal[i, K.S_ONSET] = np.nan
            self.act[i] = 0.0
            self.delay[i] = 0.0
            self.flags[i] = 0
            self.info[i] = 0.0
            self.info[i, K.I_SPEED_KMH] = start
            self.info[i, K.I_ONSET_KMH] = np.nan
        rows = np.atleast_1d(rows)
        sub_obs = np.empty((rows.size, self.observation_dim), dtype=np.float32)
        K.task_observe(self.x[rows], self.scal[rows], self.act[rows], self.P[rows], self.cfg, self.track.values, sub_obs)
        self.obs[rows] = sub_obs
        self._add_noise(rows)

    @staticmethod
    def _draw(rng, forced, value, bounds, name) -> float:
        if forced is not None:
            if isinstance(forced, bool) or not isinstance(forced, (int, float)) or not math.isfinite(forced):
                raise ConfigError(f"reset option {name!r} = {forced!r} must be a finite number")
            return float(forced)
        return float(rng.uniform(*bounds)) if bounds else float(value)

    # ---- stepping --------------------------------------------------------------------------
    def check_actions(self, actions: Any) -> np.ndarray:
        """(N, action_dim) finite actions, clipped to [-1, 1]; anything else raises."""
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, self.action_dim):
            if self.num_envs == 1 and a.shape == (self.action_dim,):
                a = a[None, :]
            else:
                raise ValueError(
                    f"action has shape {np.shape(actions)}; expected ({self.num_envs}, {self.action_dim})"
                    + (f" or ({self.action_dim},)" if self.num_envs == 1 else "")
                )
        if not np.all(np.isfinite(a)):
            bad = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(
                f"action contains NaN or inf (env {bad[0]}, component {bad[1]}: {a[tuple(bad)]!r}); "
                "actions must be finite and are clipped to [-1, 1]"
            )
        np.clip(a, -1.0, 1.0, out=self.actions)
        return self.actions

    def step(self, actions: Any) -> None:
        a = self.check_actions(actions)
        args = (self.x, self.scal, self.act, self.delay, a, self.P, self.cfg, self.track.values, self.obs, self.reward,
                self.flags, self.info)  # fmt: skip
        K.task_step(*args)
        self._add_noise(np.arange(self.num_envs))

    def _add_noise(self, rows: np.ndarray) -> None:
        noise = self.config["observation"]["noise"]
        if noise > 0:
            for i in np.atleast_1d(rows):
                self.obs[i] += (noise * self.rngs[i].standard_normal(self.observation_dim)).astype(np.float32)
            np.clip(self.obs, -K.OBS_BOUND, K.OBS_BOUND, out=self.obs)

    # ---- accessors -------------------------------------------------------------------------
    @property
    def speed_kmh(self) -> np.ndarray:
        return self.scal[:, K.S_SPEED] * KMH

    def max_episode_steps(self) -> int:
        return self.max_steps_for(self.config)

    @staticmethod
    def max_steps_for(config: Mapping[str, Any] | None) -> int:
        """Steps to ramp from the lowest start to the highest end at the slowest rate, +10 %
        (100,000 when a fixed-speed run has no natural end)."""
        c = make_config(config)
        sp = c["speed"]
        accel = min([sp["accel"]] + ([sp["accel_range"][0]] if sp["accel_range"] else []))
        lo = min([sp["start_kmh"]] + ([sp["start_kmh_range"][0]] if sp["start_kmh_range"] else []))
        hi = max([sp["end_kmh"]] + ([sp["end_kmh_range"][1]] if sp["end_kmh_range"] else []))
        if accel <= 0:
            return 100_000
        return int(math.ceil((hi - lo) / KMH / accel / c["dt"] * 1.1)) + 10

    def delta(self, row: int = 0) -> float:
        return float(self.P[row, P_DELTA])
