"""A robust classical baseline for ``Bogie/Hunting-v1``: washed-out active yaw damping.

The controller sees only the v1 observation (the sensors, the measured speed and the actuators'
forces) and is scheduled on the measured speed only. It is one fixed design for every
conicity from 0.025 to 0.3: no wheel-profile input.

Structure (every signal in SI units before the gains; ``dt`` = the env step):

- ``r_i``, the absolute yaw rate of wheelset i: the difference quotient of its measured yaw
  relative to the frame plus the washed-out frame yaw rate (gyro);
- ``r_b``, the washed-out frame yaw rate;
- ``v_b``, the frame's lateral velocity: the leaky integral of the washed-out lateral
  acceleration.

Each washout is a first-order discrete high-pass of corner ``washout_hz`` (or, with the gain
table's ``washout_order`` 2, a second-order one: :func:`filter_bank`); the difference
quotients are zero at DC by construction. So a constant observation (a steady curve: constant
wheelset offsets, relative yaws, frame yaw rate ``V/R`` and unbalanced lateral acceleration;
or a sensor bias) gives zero steady command: the controller damps hunting and leaves curving
to the passive suspension. After ``reset`` the filters start settled on the first observation,
except the accelerometer chain, which starts at rest (:func:`start_state`).

Commands (normalised, ``u = torque / max_force``): ``u = -G(V) s`` with ``s = [r_1, r_2, r_b,
v_b]`` and G a gain matrix per design speed, interpolated linearly in the measured speed.
The gains come from :func:`tune` (see docs/controllers.md): a multi-model search over the
conicity grid and the speed range on the sampled design model (:meth:`DesignModel.plant`: the
bogie's linearisation, the actuators' lag, zero-order hold, the loop delay and the sensors'
anti-alias filters), with the margin floors as constraints; then from the second stage of
:mod:`bogie_agents.controllers.robust_track` (a track-forced re-tune of the 90-270 km/h rows and the
command lead :func:`lead_command` at 240-270 km/h, zero from 300 km/h).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES, active_channels
from bogie_env.dynamics import LATERAL_STATES, BogieModel
from bogie_env.envs import task as T
from bogie_env.envs.config import bogie_params
from bogie_env.envs.scenario import CONICITY_GRID
from bogie_env.params import ConfigError
from bogie_env.sampled_plant import PlantModel, sampled_plant
from bogie_env.stability import KMH, linearize

from .lqr import Controller, lateral_model, sensor_matrix

LAT = list(LATERAL_STATES)
N_LAT = len(LAT)
#: The design signals, in order (SI units: rad/s, rad/s, rad/s, m/s).
SIGNALS = ("wheelset1_yaw_rate", "wheelset2_yaw_rate", "frame_yaw_rate", "frame_lateral_velocity",
           "wheelset1_lateral_rate", "wheelset2_lateral_rate")
#: States of the order-1 filter bank; order 2 adds the second washout stages and four washed-out
#: displacements (:func:`filter_states`).
N_FILTER_STATES = 9
#: The allowed ``washout_order`` of a gain table (absent: 1, the shipped v1 table's bank).
WASHOUT_ORDERS = (1, 2)


def filter_states(washout_order: int = 1) -> int:
    """The number of filter-bank states for ``washout_order``."""
    return N_FILTER_STATES if washout_order == 1 else N_FILTER_STATES + 6
N_SIG = len(SIGNALS)
#: The conicity grid of the multi-model design and of the tests.
DESIGN_CONICITIES = CONICITY_GRID


# =============================================================================================
# The sampled design model: bogie + actuator lag + ZOH + delay + sensor filters
# =============================================================================================


class DesignModel:
    """The design model of one bogie (one conicity) at any speed: exact in speed through
    :func:`bogie_env.stability.linearize` (J = J0 + J1/V + J2 V about the straight-track equilibrium)."""

    def __init__(self, env_config: dict, conicity: float | None = None) -> None:
        params = bogie_params(env_config)
        if conicity is not None:
            params = params.replace(lam=float(conicity))
        self.conicity = params.lam
        self.model = BogieModel(params)
        self.lin = linearize(self.model)
        self.config = env_config
        self.active = active_channels(env_config["actuators"])
        acts = [env_config["actuators"][CHANNEL_NAMES[k]] for k in self.active]
        self.max_force = np.array([a["max_force"] for a in acts])
        self.bandwidth = np.array([2 * math.pi * a["bandwidth_hz"] for a in acts])
        delays = {a["delay_steps"] for a in acts}
        if len(delays) != 1:
            raise ValueError(f"robust: all active channels must share one delay_steps; got {sorted(delays)}")
        self.delay = delays.pop()
        self.dt = env_config["dt"]
        self.include_actuators = bool(env_config["observation"]["include_actuators"])

    @property
    def n_act(self) -> int:
        return len(self.active)

    @property
    def n_obs(self) -> int:
        return len(T.SENSORS) + 1 + (self.n_act if self.include_actuators else 0)

    def continuous(self, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of ``[x_lat, F]`` with the normalised command as input, at ``speed`` (m/s)
        (:func:`bogie_agents.controllers.lqr.lateral_model`)."""
        return lateral_model(self.model, self.lin, speed, self.active, self.bandwidth, self.max_force)

    def observation_matrix(self, a_cont: np.ndarray) -> np.ndarray:
        """The clean observation (before the sensor filters) from ``[x_lat, F]``: the six sensors
        (:func:`bogie_agents.controllers.lqr.sensor_matrix`), the speed row 0, the channel forces."""
        c = np.zeros((self.n_obs, N_LAT + self.n_act))
        c[: len(T.SENSORS)] = sensor_matrix(a_cont, self.model.params)
        if self.include_actuators:
            first = len(T.SENSORS) + 1
            c[first:, N_LAT:] = np.diag(1.0 / self.max_force)
        return c

    def plant(self, speed_kmh: float) -> PlantModel:
        """The sampled plant at ``speed_kmh`` (:func:`bogie_env.sampled_plant.sampled_plant`:
        ZOH, a command register per channel, the env's sensor filters), from the normalised
        command to the observation. Its bogie state is the 16 lateral states
        (``LATERAL_STATES``, its ``bogie_states``), not 20; ``x_eq`` is the straight-track
        equilibrium of the linearisation. ``bogie_agents.design.margins.LinearLoop`` and
        ``loop_margins`` (extra whole-step and fractional delays per channel) apply to it."""
        a_c, b_c = self.continuous(speed_kmh / KMH)
        return sampled_plant(a_c, b_c, self.observation_matrix(a_c), self.config, self.active, (self.delay,) * self.n_act,
                             speed_kmh / KMH, self.lin.equilibrium, np.zeros(self.n_act), self.model, bogie_states=tuple(LAT))


# =============================================================================================
# The controller's filter bank: observation -> design signals
# =============================================================================================


@dataclass
class FilterBank:
    """``f+ = a f + b y``, ``s = c f + d y``: the design signals (SI) from the observation."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray


def filter_bank(n_obs: int, dt: float, washout_hz: float, leak_hz: float, washout_order: int = 1) -> FilterBank:
    """The washouts, difference quotients and the leaky integrator as one discrete state space.

    ``washout_order`` 1 (the shipped v1 table): first-order washouts of the gyro and of the
    acceleration; the difference quotients as they are. States (SI units): previous gyro,
    washed-out gyro, previous relative yaw 1 and 2, previous acceleration, washed-out
    acceleration, lateral velocity, previous wheelset lateral displacement 1 and 2 (relative to
    the frame).

    ``washout_order`` 2: each washout is two cascaded first-order high-passes of corner
    ``washout_hz`` (``(s / (s + a))^2``), and each difference quotient is followed by one
    first-order high-pass of the same corner. Then every design signal has zero steady response
    to a *ramp* of the observation, not only to a constant: in a clothoid transition the frame yaw
    rate (V times the curvature), the unbalanced lateral acceleration and the wheelsets' relative
    yaws and offsets ramp, and a first-order washout passes a ramp as a constant (slope x time
    constant), so the damping would resist the whole transition. States: order 1's, then the
    second gyro stage, the second acceleration stage and the four washed-out difference quotients.
    """
    if washout_order not in WASHOUT_ORDERS:
        raise ConfigError(f"washout_order = {washout_order!r} is not allowed; allowed: {', '.join(map(str, WASHOUT_ORDERS))}")
    alpha = math.exp(-2 * math.pi * washout_hz * dt)  # high-pass: h+ = alpha (h + x - x_prev)
    beta = math.exp(-2 * math.pi * leak_hz * dt)  # leaky integrator: v+ = beta v + dt h
    g, acc = T.SENSOR_FRAME_YAW_RATE, T.SENSOR_FRAME_LATERAL_ACCEL
    r1, r2 = T.SENSOR_WHEELSET1_YAW, T.SENSOR_WHEELSET2_YAW
    l1, l2 = T.SENSOR_WHEELSET1_LATERAL, T.SENSOR_WHEELSET2_LATERAL
    n = filter_states(washout_order)
    PG, HG, PR1, PR2, PA, HA, V, PL1, PL2 = range(N_FILTER_STATES)
    a = np.zeros((n, n))
    b = np.zeros((n, n_obs))
    # gyro washout: hg_new = alpha hg - alpha pg + alpha gyro
    a[HG, HG], a[HG, PG], b[HG, g] = alpha, -alpha, alpha * T.YAW_RATE_SCALE
    b[PG, g] = T.YAW_RATE_SCALE
    b[PR1, r1] = b[PR2, r2] = T.REL_YAW_SCALE
    b[PA, acc] = T.ACCEL_SCALE
    a[HA, HA], a[HA, PA], b[HA, acc] = alpha, -alpha, alpha * T.ACCEL_SCALE
    b[PL1, l1] = b[PL2, l2] = 1.0  # times delta: set by the caller's scale (observation units here)
    # difference quotients (new value as a row over [state, observation]): (x - x_prev) / dt
    dq_c = np.zeros((4, n))
    dq_d = np.zeros((4, n_obs))
    for i, (prev, col, scale) in enumerate(((PR1, r1, T.REL_YAW_SCALE), (PR2, r2, T.REL_YAW_SCALE), (PL1, l1, 1.0), (PL2, l2, 1.0))):
        dq_c[i, prev], dq_d[i, col] = -1.0 / dt, scale / dt
    gyro_c, gyro_d, acc_c, acc_d = a[HG].copy(), b[HG].copy(), a[HA].copy(), b[HA].copy()
    if washout_order == 2:
        HG2, HA2 = N_FILTER_STATES, N_FILTER_STATES + 1
        for stage, (first, row_a, row_b) in ((HG2, (HG, gyro_c, gyro_d)), (HA2, (HA, acc_c, acc_d))):
            # second stage: h2_new = alpha (h2 + h1_new - h1), h1 = the first stage's state
            a[stage] = alpha * row_a
            a[stage, stage] += alpha
            a[stage, first] -= alpha
            b[stage] = alpha * row_b
        gyro_c, gyro_d, acc_c, acc_d = a[HG2].copy(), b[HG2].copy(), a[HA2].copy(), b[HA2].copy()
        for i, (prev, col, scale) in enumerate(((PR1, r1, T.REL_YAW_SCALE), (PR2, r2, T.REL_YAW_SCALE), (PL1, l1, 1.0), (PL2, l2, 1.0))):
            # the quotient of the washed-out displacement (the two commute): h_new = alpha (h + x - x_prev),
            # signal (h_new - h) / dt; state h
            h = N_FILTER_STATES + 2 + i
            a[h, h], a[h, prev], b[h, col] = alpha, -alpha, alpha * scale
            dq_c[i] = (a[h] - np.eye(n)[h]) / dt
            dq_d[i] = b[h] / dt
    a[V, V] = beta  # v_new = beta v + dt ha_new
    a[V] += dt * acc_c
    b[V] = dt * acc_d
    c = np.zeros((N_SIG, n))
    d = np.zeros((N_SIG, n_obs))
    for i in range(2):
        c[i], d[i] = dq_c[i] + gyro_c, dq_d[i] + gyro_d
    c[2], d[2] = gyro_c, gyro_d
    c[3], d[3] = a[V], b[V]
    for i in range(2):
        c[4 + i], d[4 + i] = dq_c[2 + i], dq_d[2 + i]
    return FilterBank(a, b, c, d)


def start_state(bank: FilterBank) -> np.ndarray:
    """(n_states, n_obs): a row's filter state from its first observation after reset.

    The steady state of a constant observation, ``(I - A)^-1 B`` (so the gyro's and the
    displacement transducers' biases, and a start inside a curve, give no start transient),
    except that the accelerometer chain starts from zero acceleration. At reset the bogie is at
    rest but displaced (the initial perturbation), so the first acceleration sample is the
    suspension's real pull, up to tens of m/s², not a bias: settled on it, the washed-out
    acceleration would see the bogie's return as a step and its leaky integral would report a
    lateral velocity of about that acceleration times the washout's time constant, saturating
    every actuator for 2-3 s. Started at rest, the velocity estimate integrates the real
    acceleration; the accelerometer's bias then gives a small transient (bias x time constant).
    """
    settle = np.linalg.solve(np.eye(bank.a.shape[0]) - bank.a, bank.b)
    settle[:, T.SENSOR_FRAME_LATERAL_ACCEL] = 0.0
    return settle


# =============================================================================================
# The gain table and the controller
# =============================================================================================

#: The shipped gain table (written by ``python -m bogie_agents.controllers.robust``; see docs/controllers.md).
GAINS_FILE = Path(__file__).resolve().parent / "robust_gains.json"
#: The largest command lead a gain table may ask for (s): five control steps of the v1 env.
MAX_LEAD_S = 0.05


def lead_alpha(lowpass_hz: float | None, dt: float) -> float:
    """The pole of the lead's first-order low-pass (0: no low-pass)."""
    return 0.0 if not lowpass_hz else math.exp(-2 * math.pi * lowpass_hz * dt)


def lead_command(u: np.ndarray, u_prev: np.ndarray, d_prev: np.ndarray, lead_s, dt: float,
                 lowpass_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The command with a discrete lead, and the lead's new state: ``(u + k d, d)`` with
    ``d = alpha d_prev + (1 - alpha) (u - u_prev)`` (the step's command change, low-passed at
    ``lowpass_hz``; alpha = 0 without), ``k = lead_s / dt`` (per row, or scalar).

    Why: at large amplitude the actuators' rate limits turn a saturated command into a
    triangle that lags it (at conicity 0.1 and 230-250 km/h, a 5 Hz limit cycle with every
    channel saturated: docs/controllers.md); the lead moves the command's reversals earlier.
    The low-pass keeps it from amplifying the loop's gain at high frequencies. Applied before
    the clip. Zero lead returns ``u`` unchanged."""
    k = np.asarray(lead_s, dtype=float) / dt
    if k.ndim == 1:
        k = k[:, None]
    alpha = lead_alpha(lowpass_hz, dt)
    d = alpha * d_prev + (1.0 - alpha) * (u - u_prev)
    return u + k * d, d


def _table_numbers(data: dict, key: str, path: str | Path, default: list | None = None) -> np.ndarray:
    """``data[key]`` of a gain table as a float array: a number or (nested, rectangular) lists of
    numbers; anything else (strings, booleans, objects, ragged lists, a missing key without
    ``default``) is a :class:`ConfigError` naming the file, the field and its value."""
    value = data.get(key, default)

    def numeric(v) -> bool:
        if isinstance(v, list):
            return all(numeric(x) for x in v)
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if numeric(value):
        try:
            return np.asarray(value, dtype=float)
        except ValueError:  # ragged lists
            pass
    shown = repr(value)
    shown = shown if len(shown) <= 200 else shown[:200] + "..."
    raise ConfigError(f"{str(path)!r}: {key} = {shown} is not allowed; allowed: numbers (a list, or nested lists of equal length)")


def load_gains(path: str | Path = GAINS_FILE) -> dict:
    """The gain table: design speeds (km/h), gains (n_speeds, 4 channels, N_SIG signals) in
    normalised command per SI signal unit, the filter corners, the washout order (``washout_order``,
    1 when absent: :func:`filter_bank`), and how it was made."""
    data = json.loads(Path(path).read_text())
    if tuple(data.get("signals", ())) != SIGNALS or tuple(data.get("channels", ())) != tuple(CHANNEL_NAMES):
        raise ConfigError(f"{str(path)!r}: the gain table's signals/channels are not {SIGNALS} / {tuple(CHANNEL_NAMES)}")
    speeds = _table_numbers(data, "speeds_kmh", path)
    gains = _table_numbers(data, "gains", path)
    if gains.shape != (speeds.size, len(CHANNEL_NAMES), N_SIG) or not np.all(np.diff(speeds) > 0):
        raise ConfigError(f"{str(path)!r}: gains must be (n_speeds, {len(CHANNEL_NAMES)}, {N_SIG}) over increasing speeds")
    if not (np.all(np.isfinite(gains)) and np.all(np.isfinite(speeds))):
        raise ConfigError(f"{str(path)!r}: gains and speeds must be finite")
    order = data.get("washout_order", 1)
    if isinstance(order, bool) or order not in WASHOUT_ORDERS:
        raise ConfigError(f"{str(path)!r}: washout_order = {order!r} is not allowed; allowed: {', '.join(map(str, WASHOUT_ORDERS))}")
    lead = _table_numbers(data, "lead_s", path, [0.0] * speeds.size)
    if lead.shape != speeds.shape or not np.all(np.isfinite(lead)) or np.any(lead < 0) or np.any(lead > MAX_LEAD_S):
        raise ConfigError(f"{str(path)!r}: lead_s = {data.get('lead_s')!r} is not allowed; allowed: one value per design speed, "
                          f"each in [0, {MAX_LEAD_S:g}] s")  # fmt: skip
    lowpass = data.get("lead_lowpass_hz")
    if lowpass is not None and (isinstance(lowpass, bool) or not isinstance(lowpass, (int, float)) or not 0.0 < lowpass < 50.0):
        raise ConfigError(f"{str(path)!r}: lead_lowpass_hz = {lowpass!r} is not allowed; allowed: absent, null or a number in (0, 50) Hz")
    return {**data, "speeds_kmh": speeds, "gains": gains, "lead_s": lead}


class RobustDampingController(Controller):
    """Washed-out active damping, multi-model tuned over conicity 0.025-0.3, scheduled on the
    measured speed (module docstring; docs/controllers.md).

    API (the residual-policy helper's base): ``RobustDampingController(env_config)``,
    ``reset(n_envs, rows=None)``, ``act(obs) -> (n, n_active) float32 in [-1, 1]`` on batches
    of v1 observations (each row keeps its own filter state; a row's first observation after
    ``reset`` initialises its filters (:func:`start_state`: settled on it, so the gyro's and the
    displacement sensors' biases give no start transient; the accelerometer chain at rest),
    ``controller_model(n_obs, speed_kmh, y0)`` for ``bogie margins``.
    """

    name = "robust_damping"
    observation_type = "sensors"

    def __init__(self, env_config: dict, gains: dict | str | Path | None = None) -> None:
        super().__init__(env_config)
        if env_config["observation"]["type"] != "sensors":
            raise ConfigError(f"robust_damping needs observation.type = 'sensors'; got {env_config['observation']['type']!r}")
        table = gains if isinstance(gains, dict) else load_gains(GAINS_FILE if gains is None else gains)
        self.speeds_kmh = np.asarray(table["speeds_kmh"], dtype=float)
        self.gains = np.asarray(table["gains"], dtype=float)[:, self.active, :]  # active channels only
        self.washout_hz, self.leak_hz = float(table["washout_hz"]), float(table["leak_hz"])
        self.washout_order = int(table.get("washout_order", 1))
        self.lead_s = np.asarray(table.get("lead_s", np.zeros(self.speeds_kmh.size)), dtype=float)
        self.lead_lowpass_hz = table.get("lead_lowpass_hz")
        self.n_obs = len(T.SENSORS) + 1 + (len(self.active) if env_config["observation"]["include_actuators"] else 0)
        self.bank = filter_bank(self.n_obs, self.dt, self.washout_hz, self.leak_hz, self.washout_order)
        self.n_filter_states = self.bank.a.shape[0]
        self.settle = start_state(self.bank)
        self.state = np.zeros((0, self.n_filter_states))
        self.started = np.zeros(0, dtype=bool)
        self.u_prev = np.zeros((0, len(self.active)))  # the lead's state: the previous unled command
        self.d_prev = np.zeros((0, len(self.active)))  # and its low-passed command change

    def lead_at(self, speed_kmh: np.ndarray) -> np.ndarray:
        """(n,): the command lead (s), interpolated linearly in speed (held at the table's ends)."""
        return np.interp(np.asarray(speed_kmh, dtype=float), self.speeds_kmh, self.lead_s)

    def gain_at(self, speed_kmh: np.ndarray) -> np.ndarray:
        """(n, n_act, N_SIG): the gain table interpolated linearly in speed (held at its ends)."""
        v = np.clip(np.asarray(speed_kmh, dtype=float), self.speeds_kmh[0], self.speeds_kmh[-1])
        i1 = np.clip(np.searchsorted(self.speeds_kmh, v, side="right"), 1, len(self.speeds_kmh) - 1)
        i0 = i1 - 1
        w = ((v - self.speeds_kmh[i0]) / (self.speeds_kmh[i1] - self.speeds_kmh[i0]))[:, None, None]
        return (1 - w) * self.gains[i0] + w * self.gains[i1]

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        if rows is None or self.state.shape[0] != n_envs:
            self.state = np.zeros((n_envs, self.n_filter_states))
            self.started = np.zeros(n_envs, dtype=bool)
            self.u_prev = np.zeros((n_envs, len(self.active)))
            self.d_prev = np.zeros((n_envs, len(self.active)))
        else:
            self.state[rows] = 0.0
            self.started[rows] = False
            self.u_prev[rows] = 0.0
            self.d_prev[rows] = 0.0

    def signals(self, obs: np.ndarray) -> np.ndarray:
        """Advance the filters on one observation per row; the design signals (n, N_SIG), SI."""
        y = np.asarray(obs, dtype=float)
        if y.ndim != 2 or y.shape[1] != self.n_obs:
            raise ConfigError(f"robust_damping takes observations of shape (n, {self.n_obs}); got {y.shape}")
        if self.state.shape[0] != y.shape[0]:
            self.reset(y.shape[0])
        fresh = ~self.started
        self._fresh = fresh
        if np.any(fresh):
            self.state[fresh] = y[fresh] @ self.settle.T
            self.started[fresh] = True
        s = self.state @ self.bank.c.T + y @ self.bank.d.T
        self.state = self.state @ self.bank.a.T + y @ self.bank.b.T
        return s

    def act(self, obs: np.ndarray) -> np.ndarray:
        s = self.signals(obs)
        speed = self.speed_kmh(np.asarray(obs))
        u = -np.einsum("nij,nj->ni", self.gain_at(speed), s)
        if np.any(self.lead_s):
            fresh = self._fresh
            if self.u_prev.shape != u.shape:
                self.u_prev, self.d_prev = u.copy(), np.zeros_like(u)
            self.u_prev[fresh] = u[fresh]  # a row's first command after reset has no lead (no kick)
            self.d_prev[fresh] = 0.0
            led, self.d_prev = lead_command(u, self.u_prev, self.d_prev, self.lead_at(speed), self.dt, self.lead_lowpass_hz)
            self.u_prev = u
            u = led
        return np.clip(u, -1.0, 1.0).astype(np.float32)

    def controller_model(self, n_obs: int, speed_kmh: float, y0: np.ndarray):
        """The exact linear model at a fixed speed (``bogie_agents.design.margins.ControllerModel``):
        the filter bank's state space with the interpolated gains on its output."""
        from ..design.margins import ControllerModel

        if n_obs != self.n_obs:
            raise ConfigError(f"robust_damping: n_obs = {n_obs}, the controller takes {self.n_obs}")
        g = self.gain_at(np.array([speed_kmh]))[0]
        a, b, c, d = lead_model(self.bank, g, float(self.lead_at(np.array([speed_kmh]))[0]), self.dt, self.lead_lowpass_hz)
        return ControllerModel(a, b, c, d, "robust_damping: filter bank and interpolated gains"
                               + (" with the command lead" if a.shape[0] > self.bank.a.shape[0] else "") + " (exact)")  # fmt: skip


# =============================================================================================
# The multi-model design
# =============================================================================================

#: Passive linear critical speeds of the v1 bogie by conicity (km/h; docs/environment.md), the
#: base of the design's stability requirement per conicity.
PASSIVE_CRITICAL_KMH = {0.025: 358.6, 0.05: 237.0, 0.1: 141.0, 0.2: 87.0, 0.3: 66.0}


@dataclass
class DesignSettings:
    """What :func:`tune` asks of the gains at each design speed V.

    The model set at V: every conicity of the grid whose required range reaches V (0.025: up to
    ``top_kmh``; 0.05 and 0.1: passive critical speed + ``extra_kmh``; 0.2 and 0.3: + ``extra_high_kmh``),
    each nominal, with every command scaled by each of ``gain_factors``, and with ``extra_delay_steps``
    more steps of loop delay. The objective is the worst damping ratio of the oscillatory
    closed-loop modes (above ``min_mode_hz``) over the set, with a penalty when a spectral radius
    exceeds ``max_radius``.
    """

    speeds_kmh: tuple[float, ...] = tuple(float(v) for v in range(60, 601, 30))
    top_kmh: float = 600.0
    extra_kmh: float = 130.0
    extra_high_kmh: float = 40.0
    gain_factors: tuple[float, ...] = (1.0, 2.0, 0.7)
    extra_delay_steps: int = 1
    min_mode_hz: float = 0.8
    max_radius: float = 0.998
    washout_hz: float = 0.5
    leak_hz: float = 0.3
    washout_order: int = 1
    max_evaluations: int = 2500
    smoothness: float = 1e-4  # weight of |x - x_previous speed|^2 (scaled gains)
    shrinkage: float = 1e-5  # weight of |x|^2
    conicities: tuple[float, ...] = DESIGN_CONICITIES

    def required(self, conicity: float, speed_kmh: float) -> bool:
        top = self.top_kmh if conicity <= min(self.conicities) else PASSIVE_CRITICAL_KMH.get(conicity, 0.0) + (
            self.extra_kmh if conicity <= 0.1 else self.extra_high_kmh)  # fmt: skip
        return speed_kmh <= top


#: Scale of each signal's gain in the search (normalised command per SI unit): skyhook-sized
#: values, so that the search variables are O(1).
GAIN_SCALE = np.array([20.0, 20.0, 20.0, 6.0, 0.1, 0.1])


def lead_model(bank: FilterBank, gains: np.ndarray, lead_s: float, dt: float,
               lowpass_hz: float | None = None) -> tuple[np.ndarray, ...]:  # fmt: skip
    """(a, b, c, d): the controller ``observation -> command`` as one discrete state space, with
    the command lead (:func:`lead_command`) when ``lead_s`` > 0: the state is then the filter
    bank's followed by the previous unled command ``u_{n-1}`` and the lead's low-passed change
    ``d_{n-1}`` (``u_n = -G s_n``; ``d_n = alpha d_{n-1} + (1 - alpha)(u_n - u_{n-1})``; command
    ``u_n + k d_n``, ``k = lead_s / dt``). Without lead: the bank with ``-G`` on its output."""
    c, d = -gains @ bank.c, -gains @ bank.d
    if lead_s <= 0.0:
        return bank.a.copy(), bank.b.copy(), c, d
    k, alpha = lead_s / dt, lead_alpha(lowpass_hz, dt)
    n, m = bank.a.shape[0], gains.shape[0]
    eye, zero = np.eye(m), np.zeros((m, m))
    a = np.block([[bank.a, np.zeros((n, 2 * m))], [c, zero, zero], [(1 - alpha) * c, -(1 - alpha) * eye, alpha * eye]])
    b = np.vstack([bank.b, d, (1 - alpha) * d])
    gain = 1 + k * (1 - alpha)
    return a, b, np.hstack([gain * c, -k * (1 - alpha) * eye, k * alpha * eye]), gain * d


def closed_loop(plant: PlantModel, bank: FilterBank, gains: np.ndarray, factor: float = 1.0, lead_s: float = 0.0,
                dt: float = 0.01, lead_lowpass_hz: float | None = None) -> np.ndarray:  # fmt: skip
    """The closed-loop state matrix of the design plant with ``u = -factor G s`` (and the command
    lead ``lead_s``, :func:`lead_model`, with the control step ``dt``)."""
    if lead_s > 0.0:
        a, b, c, d = lead_model(bank, gains, lead_s, dt, lead_lowpass_hz)
        c, d = factor * c, factor * d
        return np.block([[plant.a + plant.b @ d @ plant.c, plant.b @ c], [b @ plant.c, a]])
    cc, dc = -factor * gains @ bank.c, -factor * gains @ bank.d
    return np.block([[plant.a + plant.b @ dc @ plant.c, plant.b @ cc], [bank.b @ plant.c, bank.a]])


def mode_score(a_cl: np.ndarray, dt: float, min_mode_hz: float, max_radius: float) -> float:
    """Minus the least damping ratio of the oscillatory modes, plus a penalty on the spectral radius."""
    z = np.linalg.eigvals(a_cl)
    z = z[np.abs(z) > 1e-6]  # the delay and difference states sit at 0
    s = np.log(z.astype(complex)) / dt
    osc = np.abs(s.imag) > 2 * math.pi * min_mode_hz
    zeta = -s.real[osc] / np.abs(s[osc]) if np.any(osc) else np.array([1.0])
    return float(-np.min(zeta) + 100.0 * max(0.0, float(np.max(np.abs(z))) - max_radius))


def tune(env_config: dict, settings: DesignSettings | None = None, progress=None) -> dict:
    """The gain table by multi-model search (Nelder-Mead per design speed, warm-started from the
    previous speed, from skyhook-like gains at the first); returns :func:`load_gains`'s dict."""
    from scipy.optimize import minimize

    from bogie_env.envs.config import merge_config

    settings = settings or DesignSettings()
    delayed = merge_config(env_config, {"actuators": {name: {"delay_steps": env_config["actuators"][name]["delay_steps"]
                                                             + settings.extra_delay_steps} for name in CHANNEL_NAMES}})  # fmt: skip
    nominal = {c: DesignModel(env_config, c) for c in settings.conicities}
    late = {c: DesignModel(delayed, c) for c in settings.conicities}
    n_obs = next(iter(nominal.values())).n_obs
    bank = filter_bank(n_obs, env_config["dt"], settings.washout_hz, settings.leak_hz, settings.washout_order)
    x = np.zeros((len(CHANNEL_NAMES), N_SIG))
    for ch, sig in (("frame_lateral", 3), ("frame_yaw", 2), ("wheelset1_yaw", 0), ("wheelset2_yaw", 1)):
        x[CHANNEL_NAMES.index(ch), sig] = 1.0
    x = x.ravel()
    table = []
    for v in settings.speeds_kmh:
        cs = [c for c in settings.conicities if settings.required(c, v)] or [min(settings.conicities)]
        plants = [(nominal[c].plant(v), late[c].plant(v)) for c in cs]
        previous = x.copy()

        def objective(x: np.ndarray) -> float:
            g = x.reshape(len(CHANNEL_NAMES), N_SIG) * GAIN_SCALE
            worst = -math.inf
            for p, p_late in plants:
                loops = [closed_loop(p, bank, g, f) for f in settings.gain_factors]
                if settings.extra_delay_steps:
                    loops.append(closed_loop(p_late, bank, g))
                for a_cl in loops:
                    worst = max(worst, mode_score(a_cl, env_config["dt"], settings.min_mode_hz, settings.max_radius))
            smooth = settings.smoothness * float(np.sum((x - previous) ** 2))
            return worst + smooth + settings.shrinkage * float(np.sum(x**2))

        simplex = np.vstack([x] + [x + 0.3 * e for e in np.eye(x.size)])
        result = minimize(objective, x, method="Nelder-Mead", options={"maxfev": settings.max_evaluations, "xatol": 1e-3,
                                                                       "fatol": 1e-6, "adaptive": True, "initial_simplex": simplex})  # fmt: skip
        x = result.x
        table.append(x.reshape(len(CHANNEL_NAMES), N_SIG) * GAIN_SCALE)
        if progress:
            progress(f"{v:g} km/h: conicities {cs}, worst damping ratio {-result.fun:.4f}")
    return {"signals": list(SIGNALS), "channels": list(CHANNEL_NAMES), "speeds_kmh": np.array(settings.speeds_kmh),
            "gains": np.stack(table), "washout_hz": settings.washout_hz, "leak_hz": settings.leak_hz,
            "washout_order": settings.washout_order,
            "design": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()}}  # fmt: skip


def save_gains(table: dict, path: str | Path) -> None:
    """Write a gain table as JSON (atomically)."""
    from bogie_env.fileio import write_text_atomic

    out = {**table, "speeds_kmh": [float(v) for v in table["speeds_kmh"]], "gains": np.asarray(table["gains"]).tolist()}
    if "lead_s" in table:
        out["lead_s"] = [float(v) for v in table["lead_s"]]
    write_text_atomic(Path(path), json.dumps(out, indent=1))


def linear_onsets(controller: "RobustDampingController", env_config: dict, conicities=DESIGN_CONICITIES,
                  speeds_kmh=tuple(float(v) for v in range(50, 601, 5))) -> dict[float, dict]:  # fmt: skip
    """Per conicity: the first speed of the grid where the design-model closed loop is unstable
    (None: stable over the whole grid) and every unstable grid speed."""
    out = {}
    for c in conicities:
        model = DesignModel(env_config, c)
        unstable = []
        for v in speeds_kmh:
            k = controller.controller_model(model.n_obs, v, None)
            p = model.plant(v)
            a = np.block([[p.a + p.b @ k.d @ p.c, p.b @ k.c], [k.b @ p.c, k.a]])
            if np.max(np.abs(np.linalg.eigvals(a))) >= 1.0:
                unstable.append(float(v))
        out[float(c)] = {"first_unstable_kmh": unstable[0] if unstable else None, "unstable_kmh": unstable}
    return out


def design_margins(controller: "RobustDampingController", env_config: dict, speeds_kmh=(300.0, 350.0, 400.0, 450.0, 500.0),
                   conicity: float | None = None) -> list[dict]:  # fmt: skip
    """Per-loop margins (``bogie_agents.design.margins.loop_margins``, python-control) of the design
    model with the sensor filters and the loop delay (:meth:`DesignModel.plant`), at the
    given speeds."""
    from ..design.margins import LinearLoop, loop_margins

    model = DesignModel(env_config, conicity)
    out = []
    for v in speeds_kmh:
        ctrl = controller.controller_model(model.n_obs, v, None)
        out.append(loop_margins(LinearLoop(model.plant(v), ctrl, v, np.zeros(model.n_act))))
    return out


def report(env_config: dict) -> str:
    """The design figures: linear onsets by conicity and the margins at nominal conicity."""
    controller = RobustDampingController(env_config)
    lines = ["linear closed-loop onset by conicity (design model, 5 km/h grid 50-600 km/h):"]
    for c, r in linear_onsets(controller, env_config).items():
        bands = r["unstable_kmh"]
        lines.append(f"  conicity {c:g}: first unstable {r['first_unstable_kmh'] or '> 600'} km/h"
                     + (f" (unstable at {len(bands)} grid speeds, {bands[0]:g}-{bands[-1]:g})" if bands else ""))  # fmt: skip
    lines.append("margins at nominal conicity, per loop (gain margin upper, delay margin beyond the loop delay):")
    for row in design_margins(controller, env_config):
        if not row["closed_loop_stable"]:
            lines.append(f"  {row['speed_kmh']:g} km/h: unstable")
            continue
        cells = []
        for name, m in row["loops"].items():
            gm = "inf" if m["gain_margin"] is None else f"{m['gain_margin']:.2f}"
            dm = "inf" if m["delay_margin_s"] is None else f"{1e3 * m['delay_margin_s']:.1f} ms"
            cells.append(f"{name} GM {gm} DM {dm}")
        disk = row["simultaneous_disk_margin"]
        lines.append(f"  {row['speed_kmh']:g} km/h: " + "; ".join(cells)
                     + ("" if disk is None else f"; all loops disk margin {disk['disk_margin']:.2f}"))  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":  # the command line is bogie_agents.design.robust_cli; the older name still runs it
    import runpy

    runpy.run_module("bogie_agents.design.robust_cli", run_name="__main__")
