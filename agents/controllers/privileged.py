"""The privileged reference: how far a controller with the same actuators could go if it knew everything.

:class:`PrivilegedController` (``privileged``) is **not a baseline to beat** and not buildable
in service. It is the headroom: the closed-loop critical speed that a model-based design reaches
with the v1 actuators (force and rate limits, lag, loop delay) when it is told the true
scenario and sees the full state. A sensor-only controller that comes close to it has little
left to gain; a large gap says a better design could exist.

**What it is told**: the row's true scenario (:class:`bogie_env.envs.scenario.Scenario`: the
exact conicity, the degraded stiffnesses, dampers, creep and axle load, each channel's gain
and a failed channel) and the task's loop (its command delay per channel), through
:meth:`PrivilegedController.tell`, which the protocol calls for every group of rows with the
same scenario. **What it sees**: the full state (``observation.type = "state"``), no sensor
noise, bias or filter.

**Design.** Discrete LQR at each design speed on the sampled loop plant the env runs
(:func:`bogie_env.sampled_plant.sampled_loop_plant`): the lateral states of the scenario's bogie,
each actuator's 10 Hz lag, the zero-order hold and the command shift registers of the loop
delay. The actuators' limits enter the cost as soft constraints, each relative to its limit:

- the normalised command ``u`` (``|u| <= 1`` is the force limit), weight ``r``;
- each channel's force rate, ``dF/dt = w (g F_max u_held - F)`` (a function of the lag and the
  oldest command register, or of the command itself without delay), relative to the channel's
  ``rate_limit``, weight ``rate_weight``;
- the state weights of :class:`bogie_agents.controllers.lqr.LQRController`.

``r`` and ``rate_weight`` are scheduled on the true conicity (:data:`WEIGHTS_BY_CONICITY`) unless given.

The commands, their registers and the lag are replicated inside the controller from the
commands it gave (it knows them exactly; the env's rate limit may make the true force lag
further behind). Gains are designed every ``step_kmh`` and interpolated in speed.

:class:`SensorPrivilegedController` (``privileged_sensors``) is the same told everything but
seeing only the sensors (:class:`SensorFed`: a Kalman filter designed on the told scenario), which
measures what the sensors cost.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.dynamics import BogieModel
from bogie_env.envs.config import bogie_params, merge_config
from bogie_env.envs.scenario import Scenario, scenario_model
from bogie_env.sampled_plant import sampled_loop_plant

from .lqr import N_LAT, DesignPoint, LQGController, LQRController, add_rate_cost, lateral_model, lqr_gain_cross

#: The weights ``(r, rate_weight)`` by true conicity: ``(upper conicity, weights)``, the first
#: row whose bound exceeds the conicity. Chosen per conicity class on the protocol's seeds over
#: r in {1, 3, 10} x rate_weight in {10, 30} (docs/studies/headroom.md): the reference may be
#: tuned where it is judged, since it is a bound, not a baseline.
WEIGHTS_BY_CONICITY: tuple[tuple[float, tuple[float, float]], ...] = ((0.15, (1.0, 30.0)), (math.inf, (10.0, 10.0)))


def scheduled_weights(conicity: float, schedule: tuple = WEIGHTS_BY_CONICITY) -> tuple[float, float]:
    """``(r, rate_weight)`` for the true ``conicity`` (``schedule``: :data:`WEIGHTS_BY_CONICITY`)."""
    return next(w for bound, w in schedule if conicity < bound)


class PrivilegedController(LQRController):
    """LQR on the true scenario's sampled, delay-augmented loop plant, with the actuators'
    force and rate limits as soft constraints (module docstring). Full-state observation."""

    name = "privileged"
    observation_type = "state"
    #: the protocol tells a privileged controller the true scenario of its rows (``tell``)
    privileged = True
    knows = "true scenario"  # what the results table says it is told
    #: ``(r, rate_weight)`` by true conicity when not given
    weights_by_conicity = WEIGHTS_BY_CONICITY

    def __init__(self, env_config: dict, r: float | None = None, rate_weight: float | None = None,
                 step_kmh: float = 10.0, scenario: Scenario | None = None, loop_config: Mapping[str, Any] | None = None,
                 v_range_kmh: tuple[float, float] | None = None) -> None:  # fmt: skip
        self.scenario = scenario if scenario is not None else Scenario()
        self.weights_given = (r, rate_weight)  # None: scheduled on the true conicity
        lam = self.scenario.conicity if self.scenario.conicity is not None else bogie_params(env_config).lam
        scheduled = scheduled_weights(lam, self.weights_by_conicity)
        r = scheduled[0] if r is None else r
        rate_weight = scheduled[1] if rate_weight is None else rate_weight
        for field, value in (("r", r), ("rate_weight", rate_weight)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0 and (field != "r" or value > 0)):
                raise ValueError(f"PrivilegedController: {field} = {value!r}; allowed: a finite number "
                                 f"{'> 0' if field == 'r' else '>= 0'}")  # fmt: skip
        self.rate_weight = float(rate_weight)
        loop = loop_config if loop_config is not None else env_config
        base = bogie_params(env_config)
        model = scenario_model(base, self.scenario, BogieModel(base))
        self._v_range = v_range_kmh
        # the design reads the delays and rate limits from the loop (the task's config)
        super().__init__(merge_config(env_config, {"actuators": {n: {k: loop["actuators"][n][k] for k in ("delay_steps", "rate_limit")}
                                                                 for n in CHANNEL_NAMES}}),
                         r=r, step_kmh=step_kmh, model=model, v_range_kmh=v_range_kmh)  # fmt: skip
        self.max_delay = max(self.delays) if self.delays else 0
        self.history = np.zeros((0, max(1, self.max_delay), self.n_act))

    # ---- what it is told -----------------------------------------------------------------------
    def tell(self, scenario: Scenario, loop_config: Mapping[str, Any]) -> "PrivilegedController":
        """A controller designed for ``scenario`` in the loop of ``loop_config`` (the task's config:
        its command delays), with this one's given weights (or those scheduled on the scenario's conicity)."""
        return type(self)(self.config, *self.weights_given, float(self.speeds_kmh[1] - self.speeds_kmh[0])
                          if len(self.speeds_kmh) > 1 else 10.0, scenario, loop_config, self._v_range)  # fmt: skip

    @property
    def channel_gain(self) -> np.ndarray:
        """Each active channel's true command gain (0 for the failed channel)."""
        gain = np.array([float(self.scenario.actuator_gain[k]) for k in self.active])
        if self.scenario.failed_actuator is not None:
            gain[[CHANNEL_NAMES[k] for k in self.active].index(self.scenario.failed_actuator)] = 0.0
        return gain

    # ---- design -------------------------------------------------------------------------------
    def continuous_model(self, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of ``[x_lat, F]``: the scenario's bogie, the lags, the true channel gains."""
        a, b = lateral_model(self.model, self.lin, speed, self.active, self.bandwidth, self.max_force)
        return a, b * self.channel_gain[None, :]

    def loop_problem(self, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, Q, S, R)`` at ``speed`` (m/s): the sampled loop plant and the design's cost
        ``z'Qz + 2 z'S u + u'Ru`` with the soft force-rate term."""
        a_c, b_c = self.continuous_model(speed)
        n_x = a_c.shape[0] - self.n_act
        a, b, _, _, _ = sampled_loop_plant(a_c, b_c, np.zeros((0, a_c.shape[0])), self.dt, self.delays, (), np.zeros(0))
        q_xf, r = self.weights()
        n = a.shape[0]
        q = np.zeros((n, n))
        q[: q_xf.shape[0], : q_xf.shape[0]] = q_xf
        q, s, r = add_rate_cost(q, r, n_x, self.delays, self.bandwidth, self.channel_gain * self.max_force,
                                self.rate_limit, self.rate_weight)  # fmt: skip
        return a, b, q, s, r

    def _design(self, speed: float) -> DesignPoint:
        a, b, q, s, r = self.loop_problem(speed)
        return DesignPoint(speed, lqr_gain_cross(a, b, q, r, s), a, b)

    # ---- runtime ------------------------------------------------------------------------------
    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        super().reset(n_envs, rows)
        shape = (n_envs, max(1, self.max_delay), self.n_act)
        if rows is None or self.history.shape != shape:
            self.history = np.zeros(shape)
        else:
            self.history[rows] = 0.0

    def registers(self) -> np.ndarray:
        """The command registers in the plant's order: per channel, newest to oldest command."""
        parts = [self.history[:, :d, j] for j, d in enumerate(self.delays) if d > 0]
        return np.concatenate(parts, axis=1) if parts else np.zeros((self.history.shape[0], 0))

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        if self.force_state.shape[0] != n:
            self.reset(n)
        actions = self.planned_command(self.state_estimate(obs), np.asarray(self.speed_kmh(obs), dtype=float).reshape(-1))
        self._advance(actions)
        return actions.astype(np.float32)

    def planned_command(self, x_lat: np.ndarray, speed_kmh: np.ndarray) -> np.ndarray:
        """The commands :meth:`act` sends for lateral states ``x_lat`` (n, 16) at the rows' speeds
        ``speed_kmh`` (n,): the linear law at the interpolated gains (an MPC plans instead)."""
        return self.command(x_lat, self.gain_at(speed_kmh))

    def command(self, x_lat: np.ndarray, gains: np.ndarray) -> np.ndarray:
        """The commands for lateral states ``x_lat`` (n, 16) with ``gains`` (n, n_act, n_z) and the
        loop states as they stand (nothing advances: :meth:`advance` does)."""
        z = np.concatenate([x_lat, self.force_state, self.registers()], axis=1)
        return np.clip(-np.einsum("nij,nj->ni", gains, z), -1.0, 1.0)

    def advance(self, actions: np.ndarray, channel_gain: np.ndarray | None = None) -> None:
        """The loop states one step on after the env was sent ``actions`` (which may be another
        controller's: a teacher labelling a student's run follows the commands actually sent)."""
        self._advance(actions, channel_gain)

    def _advance(self, actions: np.ndarray, channel_gain: np.ndarray | None = None) -> None:
        """The loop states one step on, as the design plant has them: each channel's lag driven
        by its oldest register (or, without delay, the new command), then the registers shift."""
        held = np.stack([self.history[:, d - 1, j] if d > 0 else actions[:, j] for j, d in enumerate(self.delays)], axis=1)
        w = np.exp(-self.bandwidth * self.dt)
        target = held * self.max_force * (self.channel_gain if channel_gain is None else channel_gain)
        self.force_state = target + (self.force_state - target) * w
        if self.max_delay:
            self.history = np.concatenate([actions[:, None, :], self.history[:, :-1]], axis=1)


class ScenarioFilter(LQGController):
    """The LQG's steady-state Kalman filter (:class:`LQGController`: the sampled loop plant with
    the command registers, each sensor's filter and bias) designed on a told scenario's bogie
    ``model`` with its channels' true command gains ``channel_gain``. Only its estimate is used."""

    name = "scenario_filter"

    def __init__(self, env_config: dict, model: BogieModel, channel_gain: np.ndarray, v_range_kmh: tuple[float, float]) -> None:
        self._channel_gain = np.asarray(channel_gain, dtype=float)
        super().__init__(env_config, model=model, v_range_kmh=v_range_kmh)

    def continuous_model(self, speed: float) -> tuple[np.ndarray, np.ndarray]:
        a, b = super().continuous_model(speed)
        return a, b * self._channel_gain[None, :]


class SensorFed:
    """Mixin for a privileged reference (first base): told the true scenario as before, but it
    sees only the sensors (v1's noise, bias, filters). Its lateral states are the estimate of a
    :class:`ScenarioFilter` designed on the told scenario and driven by the commands it sent; the
    lag and command registers are replicated from those commands as before. Against the
    full-state reference it measures what seeing only the sensors costs when everything else is known."""

    observation_type = "sensors"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        speeds = self.speeds_kmh
        self.filter = ScenarioFilter(self.config, self.model, self.channel_gain, (float(speeds[0]), float(speeds[-1])))

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        super().reset(n_envs, rows)
        if hasattr(self, "filter"):  # not yet built while a base class constructs
            self.filter.reset(n_envs, rows)

    def state_estimate(self, obs: np.ndarray) -> np.ndarray:
        """The filter's lateral states after this step's sensors (the filter advances)."""
        if self.filter.estimate.shape[0] != obs.shape[0]:
            self.filter.reset(obs.shape[0])
        return self.filter.update_estimate(obs, np.asarray(self.speed_kmh(obs), dtype=float).reshape(-1))[:, :N_LAT].copy()

    def _advance(self, actions: np.ndarray, channel_gain: np.ndarray | None = None) -> None:
        super()._advance(actions, channel_gain)
        self.filter.last_action = np.asarray(actions, dtype=float).copy()


class SensorPrivilegedController(SensorFed, PrivilegedController):
    """``privileged`` seeing only the sensors (:class:`SensorFed`); not a baseline."""

    name = "privileged_sensors"
