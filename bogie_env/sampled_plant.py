"""The sampled loop plant: the bogie's continuous linear model, its actuators' lags, the
zero-order hold of one action per control interval, each channel's command delay and the
sensors' anti-alias filters, as one discrete state space at ``dt``.

One assembly (:func:`sampled_loop_plant`) serves every linear design and analysis of the
sampled loop: the margins' plant (``bogie_agents.design.margins.plant_model``, the 20-state Jacobian),
the robust design's plant (``bogie_agents.controllers.robust.DesignModel.plant``, the 16 lateral states of
:func:`bogie_env.stability.linearize`) and the LQG's design model
(``bogie_agents.controllers.lqr.LQGController.sampled_model``). :class:`PlantModel` holds its
matrices with the continuous part, so that extra whole-step (:meth:`PlantModel.with_extra_delay`)
and fractional (:meth:`PlantModel.with_delay_s`) command delays apply to any of them.

Conventions: the input is the normalised command u (n_act, the env's action), the output the
observation y in the env's scaled units; the state is ``[bogie states, channel forces F (N, N m),
command registers, sensor filters]``. The filters are the env's (``bogie_env.envs.sensors``):
``f_n = f_{n-1} + w (y_n - f_{n-1})``, ``w = 1 - exp(-2 pi f_c dt)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import expm

from .actuators import CHANNEL_NAMES
from .dynamics import N_STATES, BogieModel
from .envs.sensors import N_SENSED, S_FILTER_WEIGHT, sensor_table


def discretize(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation via the block exponential."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = expm(block * dt)
    return e[:n, :n], e[:n, n:]



def sensor_filters(config: dict) -> tuple[tuple[int, ...], np.ndarray]:
    """The observation entries the env's sensor model filters, and each filter's weight.

    With ``sensors.enabled`` the env passes the first ``N_SENSED`` observation entries (the six
    sensors and the speed) through ``f_n = f_{n-1} + w (y_n - f_{n-1})``,
    ``w = 1 - exp(-2 pi f_c dt)`` (``bogie_env.envs.sensors.sense_rows``), and observes ``f_n``;
    the actuator-force entries are exact. Without it, nothing is filtered.
    """
    if not config.get("sensors", {}).get("enabled"):
        return (), np.zeros(0)
    weights = sensor_table(config["sensors"], config["dt"])[:, S_FILTER_WEIGHT]
    return tuple(range(N_SENSED)), np.asarray(weights, dtype=float)


@dataclass
class PlantModel:
    """The sampled plant from the normalised command u (n_act) to the observation y.

    State ``[x (20), F (n_act), command registers, sensor filters]``: the channels' command
    shift registers (``delay_steps[j]`` states for channel j, the oldest feeding the lag) and
    the anti-alias filter states of the measured observation entries (``filter_rows``), each
    holding the previous sample's filtered value. ``y_n = C s_n`` (no feedthrough: the
    observation of step n is taken at the end of the previous interval).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    dt: float
    speed: float  # m/s
    x_eq: np.ndarray  # (20,) equilibrium state
    force_eq: np.ndarray  # (n_act,) equilibrium channel forces
    active: list[int]
    max_force: np.ndarray
    bandwidth: np.ndarray  # rad/s
    delay_steps: tuple[int, ...]  # per active channel
    observation_type: str
    include_actuators: bool
    model: BogieModel = field(repr=False)
    filter_rows: tuple[int, ...] = ()  # observation entries passed through the sensor filter
    filter_weight: np.ndarray = field(default_factory=lambda: np.zeros(0))  # weight of the new sample
    c_clean: np.ndarray | None = None  # the observation before the sensor filters
    filter_start: int = 0  # index of the first filter state
    a_cont: np.ndarray | None = field(default=None, repr=False)  # continuous bogie + lag, for fractional delays
    b_cont: np.ndarray | None = field(default=None, repr=False)
    #: which of the 20 bogie states the plant's first states are (None: all 20, in order)
    bogie_states: tuple[int, ...] | None = None

    def with_delay_s(self, extra_s) -> "PlantModel":
        """The plant with ``extra_s`` (scalar: every channel; or per channel) seconds more
        command delay, not necessarily whole steps: the exact sampled model of a held command
        that reaches the lag ``tau`` later, i.e. switches to the new command a fraction ``f`` of
        the interval late (``x+ = Phi x + Gamma_a u_{n-k-1} + Gamma_b u_{n-k}``, ``Gamma_b`` the
        ZOH integral over the last ``(1 - f) dt``, ``Gamma_a`` that over the first ``f dt``
        carried to the end). Built from the plant of :func:`sampled_plant` (not from an extended one)."""
        if self.a_cont is None:
            raise ValueError("with_delay_s needs a plant from sampled_plant (its continuous part)")
        extra = np.broadcast_to(np.asarray(extra_s, dtype=float), (self.n_act,))
        if np.any(~np.isfinite(extra)) or np.any(extra < 0):
            raise ValueError(f"extra_s = {extra_s!r} must be finite and >= 0")
        dt, n, m = self.dt, self.a_cont.shape[0], self.n_act
        total = np.array(self.delay_steps) + extra / dt  # steps
        k = np.floor(total + 1e-9).astype(int)
        f = np.where(total - k > 1e-9, total - k, 0.0)
        lengths = k + (f > 0)
        n_f = len(self.filter_rows)
        n_all = n + int(lengths.sum()) + n_f
        phi, _ = discretize(self.a_cont, self.b_cont, dt)
        a = np.zeros((n_all, n_all))
        b = np.zeros((n_all, m))
        a[:n, :n] = phi

        def zoh(t: float) -> tuple[np.ndarray, np.ndarray]:
            """exp(A t) and the ZOH input integral over t."""
            e_t, g_t = discretize(self.a_cont, self.b_cont, t) if t > 0 else (np.eye(n), np.zeros((n, m)))
            return e_t, g_t

        pos = n
        for j in range(m):
            e_late, g_late = zoh((1.0 - f[j]) * dt)
            _, g_early = zoh(f[j] * dt)
            terms = {int(k[j]): g_late[:, j]}  # u_{n-k}: the last (1 - f) dt
            if f[j] > 0:
                terms[int(k[j]) + 1] = e_late @ g_early[:, j]  # u_{n-k-1}: the first f dt
            if lengths[j]:
                b[pos, j] = 1.0
                for i in range(1, lengths[j]):
                    a[pos + i, pos + i - 1] = 1.0
            for age, column in terms.items():
                if age == 0:
                    b[:n, j] += column
                else:
                    a[:n, pos + age - 1] += column
            pos += int(lengths[j])
        # the observation and the filters: core and filter columns of the original plant
        old_f = slice(self.filter_start, self.filter_start + n_f)
        c = np.zeros((self.c.shape[0], n_all))
        c[:, :n] = self.c[:, :n]
        c[:, pos:pos + n_f] = self.c[:, old_f]
        c_clean = np.zeros_like(c)
        c_clean[:, :n] = self.c_clean[:, :n]
        for i, row in enumerate(self.filter_rows):
            a[pos + i] = c[row]
        return replace(self, a=a, b=b, c=c, c_clean=c_clean, filter_start=pos, delay_steps=tuple(int(v) for v in k))

    def settled_state(self, dx: np.ndarray, dforce: np.ndarray | None = None) -> np.ndarray:
        """The plant state for a deviation ``dx`` (20,) of the bogie and ``dforce`` of the
        channel forces, with empty command registers and the sensor filters settled on it (as
        the env starts an episode: its first observation is unfiltered). A plant of fewer
        bogie states (``bogie_states``) takes those entries of ``dx``."""
        dx = np.asarray(dx, dtype=float)
        if dx.shape != (N_STATES,):
            raise ValueError(f"settled_state: dx has shape {dx.shape}; allowed: ({N_STATES},), the bogie's state deviation")
        bogie = dx if self.bogie_states is None else dx[list(self.bogie_states)]
        s = np.zeros(self.a.shape[0])
        s[:bogie.size] = bogie
        if dforce is not None:
            s[bogie.size:bogie.size + self.n_act] = dforce
        if self.filter_rows:
            start = self.filter_start
            s[start:start + len(self.filter_rows)] = (self.c_clean @ s)[list(self.filter_rows)]
        return s

    @property
    def n_act(self) -> int:
        return len(self.active)

    @property
    def channel_names(self) -> list[str]:
        return [CHANNEL_NAMES[k] for k in self.active]

    def with_extra_delay(self, extra_steps) -> "PlantModel":
        """The same plant with ``extra_steps[j]`` more whole steps of command delay in channel j
        (a shift register in front of the plant's input; new states at the end)."""
        extra = np.broadcast_to(np.asarray(extra_steps, dtype=int), (self.n_act,))
        if np.any(extra < 0):
            raise ValueError(f"extra_steps = {extra_steps!r} must be >= 0")
        n, m = self.a.shape[0], self.n_act
        total = int(extra.sum())
        a = np.zeros((n + total, n + total))
        b = np.zeros((n + total, m))
        a[:n, :n] = self.a
        pos = n
        for j, e in enumerate(extra):
            if e == 0:
                b[:n, j] = self.b[:, j]
                continue
            b[pos, j] = 1.0
            for i in range(1, e):
                a[pos + i, pos + i - 1] = 1.0
            a[:n, pos + e - 1] = self.b[:, j]
            pos += e
        c = np.hstack([self.c, np.zeros((self.c.shape[0], total))])
        c_clean = None if self.c_clean is None else np.hstack([self.c_clean, np.zeros((self.c.shape[0], total))])
        delays = tuple(int(d + e) for d, e in zip(self.delay_steps, extra))
        return replace(self, a=a, b=b, c=c, c_clean=c_clean, delay_steps=delays)


def sampled_loop_plant(a_c: np.ndarray, b_c: np.ndarray, c_xf: np.ndarray, dt: float, delays, rows, weights
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:  # fmt: skip
    """The matrices of a :class:`PlantModel` from its continuous part: ``a_c, b_c`` of
    ``[x, F]`` (bogie states and channel forces, the normalised command as input), ``c_xf`` the
    clean observation of ``[x, F]``, sampled at ``dt`` with a zero-order hold; ``delays[j]``
    whole steps of command delay in channel j (a shift register per channel, the oldest command
    driving the lag) and the sensor filters of observation ``rows`` with ``weights``. Returns
    ``(a, b, c, c_clean, filter_start)`` (:func:`sampled_plant` wraps them in a :class:`PlantModel`)."""
    n, n_act = a_c.shape[0], b_c.shape[1]
    if len(delays) != n_act or len(rows) != len(weights):
        raise ValueError(f"sampled_loop_plant: {len(delays)} delays for {n_act} channels, {len(rows)} filter rows "
                         f"for {len(weights)} weights; need one delay per channel and one weight per row")  # fmt: skip
    ad, bd = discretize(a_c, b_c, dt)
    n_reg, n_f = sum(delays), len(rows)
    n_all = n + n_reg + n_f
    a = np.zeros((n_all, n_all))
    b = np.zeros((n_all, n_act))
    a[:n, :n] = ad
    # command shift registers: the ZOH target of channel j is its command of d_j intervals ago
    pos = n
    for j, d in enumerate(delays):
        if d == 0:
            b[:n, j] = bd[:, j]
            continue
        b[pos, j] = 1.0  # the newest command
        for i in range(1, d):
            a[pos + i, pos + i - 1] = 1.0
        a[:n, pos + d - 1] = bd[:, j]  # the oldest drives the lag
        pos += d
    c = np.zeros((c_xf.shape[0], n_all))
    c[:, :n] = c_xf
    c_clean = c.copy()
    # sensor filters: y_n = (1 - w) f_{n-1} + w C s_n is observed and becomes the next state
    for i, (row, w) in enumerate(zip(rows, weights)):
        clean = c[row].copy()
        c[row] = w * clean
        c[row, n + n_reg + i] = 1.0 - w
        a[n + n_reg + i] = c[row]
    return a, b, c, c_clean, n + n_reg


def sampled_plant(a_c: np.ndarray, b_c: np.ndarray, c_xf: np.ndarray, config: dict, active, delays, speed: float,
                  x_eq: np.ndarray, force_eq: np.ndarray, model: BogieModel, bogie_states: tuple[int, ...] | None = None,
                  filters: tuple[tuple[int, ...], np.ndarray] | None = None) -> PlantModel:  # fmt: skip
    """The :class:`PlantModel` of the continuous part ``a_c, b_c, c_xf`` (see
    :func:`sampled_loop_plant`) in the loop of env ``config``: its ``dt``, the active channels'
    ``max_force`` and ``bandwidth_hz``, the observation type and, unless ``filters`` (rows,
    weights) says otherwise, its sensor filters (:func:`sensor_filters`). ``delays``: whole
    steps of command delay per active channel; ``speed`` m/s; ``x_eq, force_eq``: the operating
    point; ``bogie_states``: which of the 20 bogie states the plant's first states are (None: all)."""
    acts = [config["actuators"][CHANNEL_NAMES[k]] for k in active]
    max_force = np.array([a["max_force"] for a in acts], dtype=float)
    bandwidth = np.array([2 * np.pi * a["bandwidth_hz"] for a in acts], dtype=float)
    rows, weights = sensor_filters(config) if filters is None else filters
    delays = tuple(int(d) for d in delays)
    a, b, c, c_clean, filter_start = sampled_loop_plant(a_c, b_c, c_xf, config["dt"], delays, rows, weights)
    return PlantModel(a, b, c, config["dt"], speed, np.asarray(x_eq, float), np.asarray(force_eq, float), list(active),
                      max_force, bandwidth, delays, config["observation"]["type"], bool(config["observation"]["include_actuators"]),
                      model, tuple(rows), np.asarray(weights, float), c_clean, filter_start, a_c, b_c, bogie_states)  # fmt: skip


def actuated(j_x: np.ndarray, b_f: np.ndarray, bandwidth: np.ndarray, max_force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of ``[x, F]`` with the normalised command u as input: ``dx/dt = J x + B_F F`` (``j_x``
    the bogie's Jacobian over its chosen states, ``b_f`` the channel forces' input matrix on
    them) and each actuator's first-order lag ``dF/dt = w (u F_max - F)``, ``w = bandwidth`` (rad/s)."""
    n, m = j_x.shape[0], b_f.shape[1]
    a = np.zeros((n + m, n + m))
    a[:n, :n] = j_x
    a[:n, n:] = b_f
    a[n:, n:] = -np.diag(bandwidth)
    b = np.zeros((n + m, m))
    b[n:, :] = np.diag(bandwidth * max_force)
    return a, b
