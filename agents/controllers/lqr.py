"""Classical controllers for the hunting environments: passive, skyhook, gain-scheduled LQR/LQG.

Every controller maps a batch of observations to a batch of actions in [-1, 1] (the env's
action box), so it runs unchanged in the single env, the vector envs and the evaluation
protocol. Controllers that need more than the default sensors declare it in
``observation_type``; the evaluation builds the environment accordingly.

- :class:`PassiveController`: zero command (with force actuators, zero force).
- :class:`SkyhookController`: dampers to the "sky" on the frame's lateral and yaw motion and
  on each wheelset's yaw, from the sensors (velocities from filtered accelerations and
  differences).
- :class:`LQRController`: full-state feedback designed on the physics core's linearisation at
  each speed (discrete-time LQR with the actuators' 10 Hz lag in the design model), gains
  interpolated in speed. Needs ``observation.type = "state"``: an idealised benchmark.
- :class:`LQGController`: the same LQR gains on a steady-state Kalman-filter estimate from the
  default sensors, gain-scheduled the same way: what could be built.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are

from bogie_env.actuators import CHANNEL_NAMES, active_channels, force_matrix
from bogie_env.dynamics import LATERAL_STATES, N_STATES, BogieModel, state_index
from bogie_env.envs import task as T
from bogie_env.envs.config import bogie_params
from bogie_env.envs.task import STATE_SCALES
from bogie_env.sampled_plant import actuated, discretize, sampled_loop_plant, sensor_filters
from bogie_env.stability import KMH, linearize

LAT = list(LATERAL_STATES)
N_LAT = len(LAT)


class Controller:
    """Base class: ``act(obs) -> actions`` on batches; ``reset(rows)`` clears internal state."""

    name = "controller"
    observation_type = "sensors"

    def __init__(self, env_config: dict) -> None:
        self.config = env_config
        self.active = active_channels(env_config["actuators"])
        self.action_dim = max(1, len(self.active))
        self.max_force = np.array([env_config["actuators"][CHANNEL_NAMES[k]]["max_force"] for k in self.active])
        self.dt = env_config["dt"]

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        """Clear the internal state of all envs (rows=None) or of some rows."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def speed_kmh(self, obs: np.ndarray) -> np.ndarray:
        """The speed, read from the observation (the entry after the sensors or states)."""
        return T.speed_kmh_from_observation(obs, self.observation_type)


class PassiveController(Controller):
    name = "passive"

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((obs.shape[0], self.action_dim), dtype=np.float32)


class SkyhookController(Controller):
    """Skyhook damping from the sensors, saturated at each actuator's limit.

    frame lateral force = -c_y * (frame lateral velocity), frame yaw torque = -c_psi * (frame yaw
    rate), wheelset steering torque_i = -c_w * (absolute yaw rate of wheelset i). The frame's
    lateral velocity is the leaky integral (0.3 Hz) of its measured acceleration; a wheelset's
    absolute yaw rate is the difference quotient of its measured yaw relative to the frame plus
    the measured frame yaw rate.
    """

    name = "skyhook"

    def __init__(self, env_config: dict, c_lateral: float = 6.0e4, c_yaw: float = 3.0e5, c_wheelset: float = 3.0e5,
                 leak_hz: float = 0.3) -> None:  # fmt: skip
        super().__init__(env_config)
        self.gains = {"frame_lateral": c_lateral, "frame_yaw": c_yaw, "wheelset1_yaw": c_wheelset, "wheelset2_yaw": c_wheelset}
        self.leak = math.exp(-2 * math.pi * leak_hz * self.dt)
        self.velocity = np.zeros(0)
        self.previous_rel_yaw = np.zeros((0, 2))
        self.started = np.zeros(0, dtype=bool)

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        if rows is None or self.velocity.size != n_envs:
            self.velocity = np.zeros(n_envs)
            self.previous_rel_yaw = np.zeros((n_envs, 2))
            self.started = np.zeros(n_envs, dtype=bool)
        else:
            self.velocity[rows] = 0.0
            self.started[rows] = False

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        if self.velocity.size != n:
            self.reset(n)
        accel = obs[:, T.SENSOR_FRAME_LATERAL_ACCEL] * T.ACCEL_SCALE
        frame_yaw_rate = obs[:, T.SENSOR_FRAME_YAW_RATE] * T.YAW_RATE_SCALE
        rel_yaw = obs[:, [T.SENSOR_WHEELSET1_YAW, T.SENSOR_WHEELSET2_YAW]].astype(float) * T.REL_YAW_SCALE
        self.velocity = self.leak * self.velocity + accel * self.dt
        rel_rate = np.where(self.started[:, None], (rel_yaw - self.previous_rel_yaw) / self.dt, 0.0)
        self.previous_rel_yaw = rel_yaw
        self.started[:] = True
        rates = {"frame_lateral": self.velocity, "frame_yaw": frame_yaw_rate, "wheelset1_yaw": rel_rate[:, 0] + frame_yaw_rate,
                 "wheelset2_yaw": rel_rate[:, 1] + frame_yaw_rate}  # fmt: skip
        actions = np.zeros((n, self.action_dim))
        for j, k in enumerate(self.active):
            name = CHANNEL_NAMES[k]
            if name in self.gains:  # a channel skyhook has no law for stays at zero
                actions[:, j] = -self.gains[name] * rates[name] / self.max_force[j]
        return np.clip(actions, -1, 1).astype(np.float32)


# ---------------------------------------------------------------------------------------------
# Gain-scheduled LQR / LQG
# ---------------------------------------------------------------------------------------------


def lateral_model(model: BogieModel, lin, speed: float, active, bandwidth: np.ndarray, max_force: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(A, B) of the design model ``[x_lat (16), F (n_act)]`` at ``speed`` (m/s), the normalised
    command as input: the lateral Jacobian of ``lin`` (:func:`bogie_env.stability.linearize` of
    ``model``) and the actuators' lags (:func:`bogie_env.sampled_plant.actuated`). One
    definition for the LQR/LQG and ``robust.DesignModel``."""
    b_lat = (model.input_matrix() @ force_matrix(active))[LAT]
    return actuated(lin.lateral_jacobian(speed), b_lat, bandwidth, max_force)


def sensor_matrix(a_cont: np.ndarray, params) -> np.ndarray:
    """The six sensors of ``task.SENSORS`` (observation units) as rows over the states of a
    continuous design model ``[x_lat, F, ...]`` whose A is ``a_cont`` (the frame's lateral
    acceleration is that model's ``dyb`` row); ``params``: the bogie's (``delta``, ``L1``).
    One definition for the LQG and ``robust.DesignModel``; ``margins.observe`` is the
    independent one the tests compare with the env."""
    idx = {name: LAT.index(state_index(name)) for name in ("y1", "y2", "yb", "psi1", "psi2", "psib", "dyb", "dpsib")}
    delta, l1 = params.delta, params.L1
    c = np.zeros((len(T.SENSORS), a_cont.shape[0]))
    c[T.SENSOR_FRAME_LATERAL_ACCEL] = a_cont[idx["dyb"]] / T.ACCEL_SCALE
    c[T.SENSOR_FRAME_YAW_RATE, idx["dpsib"]] = 1.0 / T.YAW_RATE_SCALE
    for row, ws, arm in ((T.SENSOR_WHEELSET1_LATERAL, "y1", -l1), (T.SENSOR_WHEELSET2_LATERAL, "y2", l1)):
        c[row, idx[ws]], c[row, idx["yb"]], c[row, idx["psib"]] = 1 / delta, -1 / delta, arm / delta
    for row, ws in ((T.SENSOR_WHEELSET1_YAW, "psi1"), (T.SENSOR_WHEELSET2_YAW, "psi2")):
        c[row, idx[ws]], c[row, idx["psib"]] = 1 / T.REL_YAW_SCALE, -1 / T.REL_YAW_SCALE
    return c


def lqr_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Discrete LQR: ``K`` of ``u = -K x`` from the stabilising solution of the DARE."""
    p = solve_discrete_are(a, b, q, r)
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)


def lqr_gain_cross(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Discrete LQR with a cross term: cost ``z'Qz + 2 z'S u + u'Ru``, ``u = -K z``."""
    p = solve_discrete_are(a, b, q, r, s=s)
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a + s.T)


def force_rate_rows(n: int, n_x: int, delays, bandwidth: np.ndarray, held_force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M_z, M_u)``: each channel's force rate (N/s) at a sample, ``M_z z + M_u u``, on a sampled
    loop plant of ``n`` states (:func:`add_rate_cost`'s order): ``w_j (held_force_j u_held - F_j)``."""
    n_act = len(delays)
    m_z, m_u = np.zeros((n_act, n)), np.zeros((n_act, n_act))
    pos = n_x + n_act
    for j, d in enumerate(delays):
        m_z[j, n_x + j] = -bandwidth[j]
        if d == 0:
            m_u[j, j] = bandwidth[j] * held_force[j]
        else:
            m_z[j, pos + d - 1] = bandwidth[j] * held_force[j]
            pos += d
    return m_z, m_u


def add_rate_cost(q: np.ndarray, r: np.ndarray, n_x: int, delays, bandwidth: np.ndarray, held_force: np.ndarray,
                  rate_limit: np.ndarray, rate_weight: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Q, S, R)`` of a sampled loop plant's LQR cost (:func:`bogie_env.sampled_plant.sampled_loop_plant`
    order: ``n_x`` bogie states, one force per channel, then the command registers) plus
    ``rate_weight`` times each channel's squared force rate relative to its limit. The rate is
    ``w_j (held_force_j u_held - F_j)``, ``u_held`` the channel's oldest register (or, without
    delay, its command: a cross term). A channel without a rate limit (inf) adds nothing."""
    m_z, m_u = force_rate_rows(q.shape[0], n_x, delays, bandwidth, held_force)
    finite = np.isfinite(rate_limit)
    weight = np.diag(np.where(finite, rate_weight / np.where(finite, rate_limit, 1.0) ** 2, 0.0))
    return q + m_z.T @ weight @ m_z, m_z.T @ weight @ m_u, r + m_u.T @ weight @ m_u


def interpolation_weights(speeds_kmh: np.ndarray, speed_kmh: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(i0, i1, w)``: each row's speed between the design speeds ``i0`` and ``i1`` (a uniform
    grid), weight ``w`` (n, 1, 1) on ``i1``; clipped to the grid."""
    v = np.clip(speed_kmh, speeds_kmh[0], speeds_kmh[-1])
    pos = (v - speeds_kmh[0]) / (speeds_kmh[1] - speeds_kmh[0]) if len(speeds_kmh) > 1 else v * 0
    i0 = np.clip(np.floor(pos).astype(int), 0, len(speeds_kmh) - 1)
    i1 = np.clip(i0 + 1, 0, len(speeds_kmh) - 1)
    return i0, i1, (pos - i0)[:, None, None]


@dataclass
class DesignPoint:
    speed: float  # m/s
    gain: np.ndarray  # (n_act, n_aug): u = -K z
    ad: np.ndarray
    bd: np.ndarray
    kalman: np.ndarray | None = None  # (n_aug, n_meas)
    cd: np.ndarray | None = None


class LQRController(Controller):
    """Gain-scheduled discrete LQR on the lateral states plus the actuator lag states.

    Design model at speed V: ``z = [x_lat (16), F (n_act)]``,
    ``dx/dt = J_lat(V) x + B G F``, ``dF/dt = w (u max_force - F)`` with ``w = 2 pi * bandwidth``;
    ZOH at the env step. Weights: lateral wheelset displacement against the flange clearance,
    yaw against 5 mrad, frame motion, and the normalised command ``u`` with weight ``r``.
    Gains are designed every ``step_kmh`` over the env's speed range and interpolated.
    """

    name = "lqr"
    observation_type = "state"

    def __init__(self, env_config: dict, r: float = 1.0, step_kmh: float = 10.0, model: BogieModel | None = None,
                 v_range_kmh: tuple[float, float] | None = None) -> None:  # fmt: skip
        super().__init__(env_config)
        for k in self.active:
            mode = env_config["actuators"][CHANNEL_NAMES[k]]["mode"]
            if mode != "force":
                raise ValueError(f"{self.name}: config 'actuators.{CHANNEL_NAMES[k]}.mode' = {mode!r}; the LQR/LQG design "
                                 "commands forces: allowed 'force' or 'off'")  # fmt: skip
        self.model = model if model is not None else BogieModel(bogie_params(env_config))
        self.lin = linearize(self.model)
        self.r = r
        sp = env_config["speed"]
        lo, hi = v_range_kmh if v_range_kmh else (min(250.0, sp["start_kmh"]), max(700.0, sp["end_kmh"]))
        self.speeds_kmh = np.arange(lo, hi + 1e-9, step_kmh)
        self.n_act = len(self.active)
        self.bandwidth = np.array([2 * math.pi * env_config["actuators"][CHANNEL_NAMES[k]]["bandwidth_hz"] for k in self.active])
        self.points = [self._design(v / KMH) for v in self.speeds_kmh]
        self.gains = np.stack([p.gain for p in self.points])  # (n_speeds, n_act, n_aug)
        self.force_state = np.zeros((0, self.n_act))

    # ---- design -------------------------------------------------------------------------------
    def continuous_model(self, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of ``[x_lat, F]`` at ``speed`` (m/s): :func:`lateral_model`."""
        return lateral_model(self.model, self.lin, speed, self.active, self.bandwidth, self.max_force)

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        delta = self.model.params.delta
        q_state = np.zeros(N_STATES)
        for name, scale in (("y1", delta), ("y2", delta), ("yb", delta), ("psi1", 5e-3), ("psi2", 5e-3), ("psib", 5e-3),
                            ("phi1", 5e-3), ("phi2", 5e-3), ("dy1", 0.1), ("dy2", 0.1), ("dyb", 0.1),
                            ("dpsi1", 0.1), ("dpsi2", 0.1), ("dpsib", 0.1), ("dphi1", 0.1), ("dphi2", 0.1)):  # fmt: skip
            q_state[state_index(name)] = 1.0 / scale**2
        q = np.diag(np.concatenate([q_state[LAT], 1e-2 / self.max_force**2]))
        return q, self.r * np.eye(self.n_act)

    @property
    def delays(self) -> list[int]:
        """Each active channel's command delay, control steps."""
        return [int(self.config["actuators"][CHANNEL_NAMES[k]]["delay_steps"]) for k in self.active]

    @property
    def rate_limit(self) -> np.ndarray:
        """Each active channel's force-rate limit (N/s or N m/s; inf without one)."""
        limits = [self.config["actuators"][CHANNEL_NAMES[k]].get("rate_limit") for k in self.active]
        return np.array([np.inf if v is None else float(v) for v in limits])

    def _design(self, speed: float) -> DesignPoint:
        a, b = self.continuous_model(speed)
        ad, bd = discretize(a, b, self.dt)
        q, r = self.weights()
        return DesignPoint(speed, lqr_gain(ad, bd, q, r), ad, bd)

    def closed_loop_eigenvalues(self, speed_kmh: float) -> np.ndarray:
        """Discrete closed-loop eigenvalues of the design model at a design speed (|z| < 1: stable;
        the v1 LQG's sensor-bias states, which no command moves, stay at |z| = 1)."""
        k = int(np.argmin(np.abs(self.speeds_kmh - speed_kmh)))
        point = self.points[k]
        return np.linalg.eigvals(point.ad - point.bd @ point.gain)

    # ---- runtime ------------------------------------------------------------------------------
    def gain_at(self, speed_kmh: np.ndarray) -> np.ndarray:
        """Linearly interpolated gains, (n, n_act, n_aug)."""
        return self._interp(self.gains, speed_kmh)

    def _interp(self, stack: np.ndarray, speed_kmh: np.ndarray) -> np.ndarray:
        """``stack`` (one matrix per design speed) interpolated linearly at each row's speed,
        clipped to the design range."""
        i0, i1, w = interpolation_weights(self.speeds_kmh, speed_kmh)
        return (1 - w) * stack[i0] + w * stack[i1]

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        if rows is None or self.force_state.shape[0] != n_envs:
            self.force_state = np.zeros((n_envs, self.n_act))
        else:
            self.force_state[rows] = 0.0

    def _lag_update(self, actions: np.ndarray) -> None:
        """The actuators' first-order lag, replicated from the commands (known exactly)."""
        w = np.exp(-self.bandwidth * self.dt)
        self.force_state = actions * self.max_force + (self.force_state - actions * self.max_force) * w

    def state_estimate(self, obs: np.ndarray) -> np.ndarray:
        """Lateral states from the full-state observation."""
        return obs[:, :N_STATES].astype(float)[:, LAT] * STATE_SCALES[LAT]

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        if self.force_state.shape[0] != n:
            self.reset(n)
        x = self.state_estimate(obs)
        z = np.concatenate([x, self.force_state], axis=1)
        gains = self.gain_at(self.speed_kmh(obs))
        actions = np.clip(-np.einsum("nij,nj->ni", gains, z), -1.0, 1.0)
        self._lag_update(actions)
        return actions.astype(np.float32)


class LQGController(LQRController):
    """The LQR gains on a steady-state Kalman-filter estimate from the default sensors.

    Measurements (env sensors): frame lateral acceleration, frame yaw rate, wheelsets' lateral
    displacement and yaw relative to the frame. Process noise: the track alignment entering the
    wheelset lateral equations; measurement noise: 1 % of each sensor's scale (plus the env's
    configured noise). Gains and filter are scheduled on the measured speed.

    With the env's sensor model (``sensors.enabled``, the v1 ids; ``sensor_model=None`` follows
    the config) the design model is the sampled plant the env runs
    (:func:`bogie_env.sampled_plant.sampled_loop_plant`): each channel's command delay
    (``delay_steps``) as a shift register and each sensor's anti-alias filter as a state, so the
    LQR gains are designed for the loop delay; and the filter estimates each sensor's
    per-episode bias as a slow random walk (``bias_time_s``), so a constant bias (a 7.5 mg
    accelerometer offset, a 0.2 deg/s gyro offset) is not read as motion and held against by
    the actuators. Without the sensor model (v0) the design is the one above, unchanged.
    """

    name = "lqg"
    observation_type = "sensors"
    #: correlation time of the bias random walk in the filter's model, s: biases are learned
    #: over a few seconds, much slower than hunting (2-10 Hz)
    bias_time_s = 2.0

    #: weight of the force-rate cost (:func:`add_rate_cost`); 0: the design without it (``lqg``)
    rate_weight = 0.0

    def __init__(self, env_config: dict, sensor_model: bool | None = None, rate_weight: float | None = None, **kwargs) -> None:
        if rate_weight is not None:
            if not (isinstance(rate_weight, (int, float)) and math.isfinite(rate_weight) and rate_weight >= 0):
                raise ValueError(f"{self.name}: rate_weight = {rate_weight!r}; allowed: a finite number >= 0")
            self.rate_weight = float(rate_weight)
        enabled = bool(env_config.get("sensors", {}).get("enabled"))
        self.sensor_model = enabled if sensor_model is None else bool(sensor_model)
        if self.sensor_model and not enabled:
            raise ValueError("LQGController: sensor_model=True needs the env's sensor model (config 'sensors.enabled': true)")
        super().__init__(env_config, **kwargs)
        for point in self.points:
            self._design_filter(point)
        self.kalmans = np.stack([p.kalman for p in self.points])
        self.cds = np.stack([p.cd for p in self.points])
        self.ads = np.stack([p.ad for p in self.points])
        self.bds = np.stack([p.bd for p in self.points])
        self.n_aug = self.ads.shape[1]
        self.feedthrough = np.zeros((len(T.SENSORS), self.n_act))  # no direct path from command to sensor
        self.estimate = np.zeros((0, self.n_aug))
        self.last_action = np.zeros((0, self.n_act))

    def _design(self, speed: float) -> DesignPoint:
        if not self.sensor_model:
            return super()._design(speed)
        ad, bd, cd = self.sampled_model(speed)
        n_plant = ad.shape[0] - len(T.SENSORS)  # without the bias states: stabilisable
        q, r = self.weights()
        q_plant = np.zeros((n_plant, n_plant))
        q_plant[: q.shape[0], : q.shape[0]] = q
        gain = np.zeros((self.n_act, ad.shape[0]))
        if self.rate_weight > 0:
            q_plant, cross, r = add_rate_cost(q_plant, r, q.shape[0] - self.n_act, self.delays, self.bandwidth, self.max_force,
                                              self.rate_limit, self.rate_weight)  # fmt: skip
            gain[:, :n_plant] = lqr_gain_cross(ad[:n_plant, :n_plant], bd[:n_plant], q_plant, r, cross)
        else:
            gain[:, :n_plant] = lqr_gain(ad[:n_plant, :n_plant], bd[:n_plant], q_plant, r)
        return DesignPoint(speed, gain, ad, bd, cd=cd)


    def sampled_model(self, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """With the sensor model: ``(A, B, C)`` of ``[x_lat, F, command registers, sensor
        filters, sensor biases]`` at ``speed`` (m/s), sampled at the control step; ``y = C z``
        is the six sensors in observation units."""
        a_c, b_c = self.continuous_model(speed)
        c_xf = self.measurement_matrix(speed)
        rows, weights = sensor_filters(self.config)
        n_s = len(T.SENSORS)
        a, b, c, _, _ = sampled_loop_plant(a_c, b_c, c_xf, self.dt, self.delays, rows[:n_s], weights[:n_s])
        n = a.shape[0]
        ad, bd, cd = np.eye(n + n_s), np.zeros((n + n_s, self.n_act)), np.zeros((n_s, n + n_s))
        ad[:n, :n], bd[:n], cd[:, :n] = a, b, c
        cd[:, n:] = np.eye(n_s)  # each sensor reads its bias on top
        return ad, bd, cd

    def sensor_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """With the sensor model: each sensor's per-sample noise rms and bias standard
        deviation, in observation units (``bogie_env.envs.sensors``)."""
        from bogie_env.envs.sensors import SENSOR_NAMES, channel_bias, channel_noise_rms

        scales = T.sensor_scales(self.model.params.delta)[: len(T.SENSORS)]
        sensors, names = self.config["sensors"], SENSOR_NAMES[: len(T.SENSORS)]
        noise = np.array([channel_noise_rms(sensors, name) for name in names]) / scales
        bias = np.array([channel_bias(sensors, name) for name in names]) / scales
        return noise, bias

    def measurement_matrix(self, speed: float) -> np.ndarray:
        """C of ``y = C z`` for the six physical sensors (observation units) over the design
        model ``[x_lat, F]`` at ``speed`` (m/s): :func:`sensor_matrix`."""
        return sensor_matrix(self.continuous_model(speed)[0], self.model.params)

    def _design_filter(self, point: DesignPoint) -> None:
        c = point.cd if self.sensor_model else self.measurement_matrix(point.speed)
        n = point.ad.shape[0]
        # process noise: lateral forcing of the wheelsets (track alignment through creep) and
        # small white noise on every state, to keep the filter responsive
        g = np.zeros((n, 2))
        g[LAT.index(state_index("dy1")), 0] = 1.0
        g[LAT.index(state_index("dy2")), 1] = 1.0
        w = g @ g.T * (0.05**2) + np.eye(n) * 1e-10
        noise = max(0.01, float(self.config["observation"]["noise"]))
        v = np.eye(c.shape[0]) * noise**2
        if self.sensor_model:
            sensor_noise, bias = self.sensor_errors()
            n_s = len(T.SENSORS)
            w[n - n_s :, n - n_s :] += np.diag(bias**2 * self.dt / self.bias_time_s)
            v = np.diag(np.maximum(sensor_noise, noise) ** 2)
        p = solve_discrete_are(point.ad.T, c.T, w, v)
        point.kalman = p @ c.T @ np.linalg.inv(c @ p @ c.T + v)
        point.cd = c

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        super().reset(n_envs, rows)
        if rows is None or self.estimate.shape[0] != n_envs:
            self.estimate = np.zeros((n_envs, self.n_aug))
            self.last_action = np.zeros((n_envs, self.n_act))
        else:
            self.estimate[rows] = 0.0
            self.last_action[rows] = 0.0

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        if self.estimate.shape[0] != n:
            self.reset(n)
        speed = self.speed_kmh(obs)
        self.update_estimate(obs, speed)
        gains = self.gain_at(speed)
        actions = np.clip(-np.einsum("nij,nj->ni", gains, self.estimate), -1.0, 1.0)
        self.last_action = actions
        return actions.astype(np.float32)

    def update_estimate(self, obs: np.ndarray, speed_kmh: np.ndarray) -> np.ndarray:
        """The filter one step on: predicted with :attr:`last_action` (the command sent last),
        corrected with the sensors of ``obs``; returns the new estimate (n, n_aug)."""
        ad, bd = self._interp(self.ads, speed_kmh), self._interp(self.bds, speed_kmh)
        cd, kal = self._interp(self.cds, speed_kmh), self._interp(self.kalmans, speed_kmh)
        # predict with the last command, then correct with the new measurement
        prior = np.einsum("nij,nj->ni", ad, self.estimate) + np.einsum("nij,nj->ni", bd, self.last_action)
        measured = obs[:, : len(T.SENSORS)].astype(float)
        predicted = np.einsum("nij,nj->ni", cd, prior) + self.last_action @ self.feedthrough.T
        self.estimate = prior + np.einsum("nij,nj->ni", kal, measured - predicted)
        return self.estimate


class RateAwareLQGController(LQGController):
    """:class:`LQGController` whose LQR cost also weighs each actuator's force rate against its
    rate limit (:func:`add_rate_cost`): the v1 actuators' 200-400 kN/s limits bind at hunting
    frequencies (docs/studies/headroom.md), and a design that respects them keeps the loop linear
    where ``lqg`` saturates. Told and sees what ``lqg`` is told and sees (sensors, conicity class)."""

    name = "lqg_rate"
    rate_weight = 30.0
