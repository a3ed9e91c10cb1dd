"""An adaptive classical baseline: multiple-model LQG that estimates the equivalent conicity online.

:class:`AdaptiveLQGController` (policy name ``adaptive_lqg``) is told no conicity. It carries a
bank of the v1 LQG designs (:class:`bogie_agents.controllers.lqr.LQGController` with the sensor
model: loop delay registers, 40 Hz sensor filters, sensor-bias states), one per conicity of
:data:`BANK_CONICITIES`, runs every design's steady-state Kalman filter on the same sensor
stream and the same applied commands, scores each model by its exponentially forgotten
innovation likelihood (a multiple-model adaptive estimator), and commands with the LQG of the model that predicts best (switching with
hysteresis). The conicity estimate is the vertex of the parabola through the best model's score
and its neighbours' in log-conicity. Everything is batched over rows.
"""

from __future__ import annotations

import copy
import json
import math
from typing import Sequence

import numpy as np

from bogie_env.envs import task as T
from bogie_env.envs.config import make_config, merge_config

from .lqr import Controller, LQGController, RateAwareLQGController

#: The bank: the protocol's conicity grid (a conicity between two values is estimated by the
#: score's parabola in log-conicity, ``estimate_conicity``).
BANK_CONICITIES: tuple[float, ...] = (0.025, 0.05, 0.1, 0.2, 0.3)

#: LQG designs by (config without the bogie's conicity, conicity, design step): the protocol
#: builds one controller per told conicity and loop; the bank is the same for all of them.
_DESIGN_CACHE: dict[tuple[str, float, float], LQGController] = {}


def _config_key(env_config: dict) -> str:
    """The config as a key, without the bogie's conicity (which the bank replaces)."""
    cfg = copy.deepcopy(env_config)
    cfg.get("bogie_overrides", {}).pop("lam", None)
    return json.dumps(cfg, sort_keys=True, default=str)


def bank_design(env_config: dict, conicity: float, step_kmh: float, rate_weight: float = 0.0) -> LQGController:
    """The v1 LQG designed for ``env_config``'s bogie with its conicity replaced by ``conicity``
    (``rate_weight`` > 0: with the force-rate cost of ``lqg_rate``; cached per process)."""
    key = (_config_key(env_config), round(float(conicity), 12), float(step_kmh), float(rate_weight))
    if key not in _DESIGN_CACHE:
        overrides = {**env_config.get("bogie_overrides", {}), "lam": float(conicity)}
        cfg = make_config(merge_config(env_config, {"bogie_overrides": overrides}))
        _DESIGN_CACHE[key] = LQGController(cfg, sensor_model=True, step_kmh=step_kmh, rate_weight=rate_weight)
    return _DESIGN_CACHE[key]


class AdaptiveLQGController(Controller):
    """Multiple-model adaptive LQG on the v1 sensors: estimates the conicity, told none.

    **What it is told**: the env config, with its bogie's conicity *discarded*: the bank is built
    from the config's bogie with ``lam`` replaced by each value of ``conicities`` (the protocol's
    told conicity class has no effect on it); the sensors' datasheet noise and bias spreads and
    the actuators' delays and bandwidths, as :class:`LQGController` is. Nothing about degraded
    parts or faults. **What it sees**: the six v1 sensors and the measured speed (observation
    type ``sensors``), on which every model's gains and filter are scheduled.

    Per step and row, model ``i`` (its sampled plant ``A_i, B_i, C_i``, Kalman gain ``K_i`` and
    LQR gain ``G_i`` at the measured speed, interpolated between design speeds) filters on the
    command ``u`` actually applied: ``z_i^- = A_i z_i + B_i u``, ``e_i = y - C_i z_i^-``,
    ``z_i = z_i^- + K_i e_i``. Its score (``score="likelihood"``, the default) is the negative
    log-likelihood of its innovations under the covariance its filter assumes, ``S_i = (I - C_i
    K_i)^-1 R`` (``R``: the sensor noise of the LQG design), exponentially forgotten:
    ``J_i <- a J_i + e_i' S_i^-1 e_i + log det S_i``, ``a = exp(-dt / memory_s)`` (2 s: the
    conicity changes over months, the forgetting lets a wrong start be left). ``posterior``:
    ``exp(-(J_i - min J) / 2)`` normalised and floored at ``floor``, the multiple-model
    adaptive estimator's weights with the forgetting. ``score="prediction"`` scores instead the
    error of a free-running ``horizon_s`` (0.3 s) predictor restarted from each filter's
    estimate, weighted by ``R^-1`` (``score_sensors``: only those sensors).

    The command is ``-G_s z_s`` of the selected model ``s``: the most probable one, switched to
    only when its posterior odds against the selected one exceed ``switch_odds`` (100: ``J_s -
    J_best > 2 ln 100``; with ``score="prediction"``, when its score is below ``1 -
    hysteresis`` times the selected one's): no chattering between neighbours; each filter keeps running when not selected, so a switch starts from its
    own converged estimate. Before any evidence (after a reset) the selected model is
    ``initial_conicity``'s nearest. ``estimate_conicity``: the vertex, in log-conicity, of the
    parabola through the best model's score and its neighbours' (clipped to those neighbours).
    """

    name = "adaptive_lqg"
    observation_type = "sensors"
    knows = "no conicity"  # what the results table says it is told
    #: the bank's force-rate weight (0: ``lqg``'s designs)
    rate_weight = 0.0

    def __init__(self, env_config: dict, conicities: Sequence[float] = BANK_CONICITIES, memory_s: float = 2.0,
                 hysteresis: float = 0.05, initial_conicity: float = 0.1, step_kmh: float = 10.0,
                 speed_tolerance_kmh: float = 2.0, floor: float = 1e-6, horizon_s: float = 0.3,
                 score_sensors: Sequence[str] | None = None, score: str = "likelihood", switch_odds: float = 100.0) -> None:  # fmt: skip
        super().__init__(env_config)
        if not env_config.get("sensors", {}).get("enabled"):
            raise ValueError("AdaptiveLQGController: config 'sensors.enabled' = False; the bank is the v1 LQG on "
                             "the sensor model: allowed True (the -v1 ids)")  # fmt: skip
        lams = np.asarray(sorted(float(c) for c in conicities))
        if lams.size < 2 or np.any(lams <= 0) or np.any(np.diff(lams) <= 0):
            raise ValueError(f"AdaptiveLQGController: conicities = {list(conicities)!r}; allowed: at least two distinct "
                             "positive values")  # fmt: skip
        if memory_s <= 0 or not 0 <= hysteresis < 1 or not 0 <= floor < 1.0 / lams.size:
            raise ValueError(f"AdaptiveLQGController: memory_s = {memory_s!r} (allowed > 0), hysteresis = "
                             f"{hysteresis!r} (allowed [0, 1)), floor = {floor!r} (allowed [0, 1/n_models))")  # fmt: skip
        if score not in ("prediction", "likelihood"):
            raise ValueError(f"AdaptiveLQGController: score = {score!r}; allowed 'prediction' or 'likelihood'")
        self.score = score
        if not switch_odds >= 1.0:
            raise ValueError(f"AdaptiveLQGController: switch_odds = {switch_odds!r}; allowed >= 1")
        self.switch_odds = switch_odds
        self.conicities = lams
        self.log_lam = np.log(lams)
        self.forget = math.exp(-self.dt / memory_s)
        self.horizon_steps = max(1, int(round(horizon_s / self.dt)))
        self.hysteresis = hysteresis
        self.floor = floor
        self.speed_tolerance_kmh = speed_tolerance_kmh
        self.initial_index = int(np.argmin(np.abs(self.log_lam - math.log(initial_conicity))))
        self.models = [bank_design(env_config, lam, step_kmh, self.rate_weight) for lam in lams]
        ref = self.models[0]
        self.speeds_kmh = ref.speeds_kmh
        self.n_act, self.n_aug = ref.n_act, ref.n_aug
        self.n_meas = len(T.SENSORS)
        noise, _ = ref.sensor_errors()
        noise = np.maximum(noise, max(0.01, float(env_config["observation"]["noise"])))
        self.weight = 1.0 / noise**2  # (n_meas,)
        if score_sensors is not None:
            unknown = sorted(set(score_sensors) - set(T.SENSORS))
            if unknown or not score_sensors:
                raise ValueError(f"AdaptiveLQGController: score_sensors = {list(score_sensors)!r}; allowed: a non-empty "
                                 f"subset of {', '.join(T.SENSORS)}")  # fmt: skip
            self.weight = self.weight * np.isin(np.asarray(T.SENSORS), list(score_sensors))
        n_speeds = len(self.speeds_kmh)
        for model in self.models:
            if not np.allclose(model.speeds_kmh, self.speeds_kmh):
                raise ValueError("AdaptiveLQGController: the bank's designs have different speed grids")
        # per model and design speed: [A B] (one step of the plant), C, the Kalman gain, the LQR gain
        self.ab_stack = np.stack([np.concatenate([model.ads, model.bds], axis=2) for model in self.models])
        self.c_stack = np.stack([model.cds for model in self.models])
        self.k_stack = np.stack([model.kalmans for model in self.models])
        self.gain_stack = np.stack([model.gains for model in self.models])
        # the innovation covariance each filter assumes: C K = I - R S^-1, so S = (I - C K)^-1 R
        r = np.diag(noise**2)
        s_cov = np.linalg.solve(np.eye(self.n_meas) - self.c_stack @ self.k_stack, r)
        s_cov = 0.5 * (s_cov + s_cov.swapaxes(-1, -2))
        self.sinv_stack = np.linalg.inv(s_cov)
        self.logdet_stack = np.linalg.slogdet(s_cov)[1]
        assert self.ab_stack.shape[:2] == (len(lams), n_speeds)
        self.reset(0)

    # ---- state --------------------------------------------------------------------------------
    _STACKS = ("ab", "c", "k", "gain", "sinv", "logdet")

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        m = len(self.conicities)
        if rows is None or self.estimates.shape[0] != n_envs:
            self.estimates = np.zeros((n_envs, m, self.n_aug))
            self.predictions = np.zeros((n_envs, m, self.n_aug))
            self.scores = np.zeros((n_envs, m))
            self.selected = np.full(n_envs, self.initial_index, dtype=int)
            self.last_action = np.zeros((n_envs, self.n_act))
            self.clock = np.zeros(n_envs, dtype=int)
            self.cached_speed = np.full(n_envs, np.nan)
            self.rows_of = {name: np.zeros((n_envs,) + getattr(self, f"{name}_stack").shape[:1]
                                           + getattr(self, f"{name}_stack").shape[2:]) for name in self._STACKS}  # fmt: skip
        else:
            for array in (self.estimates, self.predictions, self.scores, self.last_action, self.clock):
                array[rows] = 0
            self.selected[rows] = self.initial_index
            self.cached_speed[rows] = np.nan

    def _schedule(self, speed_kmh: np.ndarray) -> None:
        """Interpolate every model's matrices at the rows whose speed moved beyond the tolerance."""
        stale = ~(np.abs(speed_kmh - self.cached_speed) <= self.speed_tolerance_kmh)
        if not stale.any():
            return
        rows = np.nonzero(stale)[0]
        grid = self.speeds_kmh
        v = np.clip(speed_kmh[rows], grid[0], grid[-1])
        pos = (v - grid[0]) / (grid[1] - grid[0])
        i0 = np.clip(np.floor(pos).astype(int), 0, len(grid) - 1)
        i1 = np.clip(i0 + 1, 0, len(grid) - 1)
        for name in self._STACKS:
            stack = getattr(self, f"{name}_stack")
            w = (pos - i0).reshape((-1,) + (1,) * (stack.ndim - 1))
            self.rows_of[name][rows] = (1 - w) * stack[:, i0].swapaxes(0, 1) + w * stack[:, i1].swapaxes(0, 1)
        self.cached_speed[rows] = speed_kmh[rows]

    # ---- outputs ------------------------------------------------------------------------------
    @property
    def posterior(self) -> np.ndarray:
        """(n, n_models): each model's tempered likelihood over the memory, normalised, floored."""
        w = np.exp(-0.5 * (self.scores - self.scores.min(axis=1, keepdims=True)))
        w = np.maximum(w / w.sum(axis=1, keepdims=True), self.floor)
        return w / w.sum(axis=1, keepdims=True)

    @property
    def estimate_conicity(self) -> np.ndarray:
        """(n,): the conicity estimate per row (the selected model's before any evidence)."""
        n = self.scores.shape[0]
        best = np.argmin(self.scores, axis=1)
        no_evidence = np.all(self.scores == self.scores[:, :1], axis=1)
        j = np.clip(best, 1, len(self.conicities) - 2)
        x = self.log_lam[np.stack([j - 1, j, j + 1], axis=1)]
        y = self.scores[np.arange(n)[:, None], np.stack([j - 1, j, j + 1], axis=1)]
        # vertex of the parabola through (x0, y0), (x1, y1), (x2, y2)
        d01, d12 = (y[:, 1] - y[:, 0]) / (x[:, 1] - x[:, 0]), (y[:, 2] - y[:, 1]) / (x[:, 2] - x[:, 1])
        curv = (d12 - d01) / (x[:, 2] - x[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            vertex = 0.5 * (x[:, 0] + x[:, 1]) - d01 / (2 * curv)
        vertex = np.where(curv > 0, vertex, self.log_lam[best])
        lo, hi = self.log_lam[np.maximum(best - 1, 0)], self.log_lam[np.minimum(best + 1, len(self.conicities) - 1)]
        out = np.exp(np.clip(vertex, lo, hi))
        return np.where(no_evidence, self.conicities[self.selected], out)

    @property
    def selected_conicity(self) -> np.ndarray:
        """(n,): the conicity of the model each row commands with."""
        return self.conicities[self.selected]

    # ---- runtime ------------------------------------------------------------------------------
    def observe(self, obs: np.ndarray) -> None:
        """Run every model's filter and predictor one step on ``obs`` with the last applied
        command; update the scores and the selection."""
        n = obs.shape[0]
        if self.estimates.shape[0] != n:
            self.reset(n)
        self._schedule(self.speed_kmh(obs))
        m = len(self.conicities)
        y = obs[:, : self.n_meas].astype(float)
        u = np.broadcast_to(self.last_action[:, None, :, None], (n, m, self.n_act, 1))
        ab, c, k = self.rows_of["ab"], self.rows_of["c"], self.rows_of["k"]
        prior = np.matmul(ab, np.concatenate([self.estimates[..., None], u], axis=2))
        innovation = y[:, None, :, None] - np.matmul(c, prior)
        self.estimates = (prior + np.matmul(k, innovation))[..., 0]
        self.innovation = innovation[..., 0]  # (n, n_models, n_meas): this step's, for studies and tests
        # the multi-step predictor: free-running from the filter's estimate, restarted every horizon
        self.predictions = np.matmul(ab, np.concatenate([self.predictions[..., None], u], axis=2))[..., 0]
        error = y[:, None, :] - np.matmul(c, self.predictions[..., None])[..., 0]
        if self.score == "likelihood":
            e = innovation[..., 0]
            term = np.einsum("nmp,nmpq,nmq->nm", e, self.rows_of["sinv"], e) + self.rows_of["logdet"]
        else:
            term = np.einsum("nmp,p->nm", error**2, self.weight)
        self.scores = self.forget * self.scores + term
        self.clock += 1
        restart = self.clock % self.horizon_steps == 0
        self.predictions[restart] = self.estimates[restart]
        best = np.argmin(self.scores, axis=1)
        rows = np.arange(n)
        current = self.scores[rows, self.selected]
        if self.score == "likelihood":  # the posterior odds of the best model against the selected one
            switch = current - self.scores[rows, best] > 2.0 * math.log(self.switch_odds)
        else:
            switch = self.scores[rows, best] < (1.0 - self.hysteresis) * current
        self.selected = np.where(switch, best, self.selected)

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.observe(obs)
        n = obs.shape[0]
        rows = np.arange(n)
        gain, z = self.rows_of["gain"][rows, self.selected], self.estimates[rows, self.selected]
        actions = np.clip(-np.einsum("nij,nj->ni", gain, z), -1.0, 1.0)
        self.last_action = actions
        return actions.astype(np.float32)


class AdaptiveRateLQGController(AdaptiveLQGController):
    """:class:`AdaptiveLQGController` with a bank of ``lqg_rate`` designs (the force-rate cost,
    :class:`bogie_agents.controllers.lqr.RateAwareLQGController`): told no conicity."""

    name = "adaptive_lqg_rate"
    rate_weight = RateAwareLQGController.rate_weight
