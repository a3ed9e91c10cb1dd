"""Actuator channels: the one place that says what an actuator is.

A *channel* is a force (N) or torque (N m) that acts between two bodies of the bogie, or
between a body and the car body above it (treated as fixed: the model has no car body).
:data:`CHANNELS` lists them. For each channel it says:

- ``input``: the generalised input of the dynamics (:data:`bogie_env.dynamics.INPUT_NAMES`)
  on which the channel's force acts;
- ``reaction``: the input on which the equal and opposite reaction acts (``None``: the car body);
- ``velocity`` / ``relative_to``: the states whose difference is the channel's relative
  velocity (``relative_to = None``: absolute velocity). With the action-reaction pair this
  makes ``force * velocity`` the mechanical power the channel delivers;
- defaults of its settings (limits, damping range, bandwidth, delay) for the env config.

Everything else derives from that table: the velocity map ``v = V x``, the generalised-force
map ``Q = G u``, the damping Jacobian ``-B G diag(c) V`` of viscous channels, and the compiled
helpers the integrator and the env task use (:func:`channel_velocity`,
:func:`generalised_forces`, :func:`channel_output`, :func:`delayed_targets`).

A channel has one of three modes (``MODE_*``): ``force`` (commanded force ``a * max_force``),
``semi_active`` (a damper ``-c v`` with ``c`` commanded in ``[c_min, c_max]``; it only
dissipates, also when saturated) or ``off``. Its command passes through a delay of whole
control steps and a first-order lag (exact ``exp(-t/tau)`` within the interval), and its
output saturates at ``max_force``. A force channel's lagged force can also be rate-limited
(``rate_limit``, N/s or N m/s; ``None``: no limit): the lag then slews at the limit until its
own rate falls below it, solved exactly within the interval (:func:`lagged_force`), like the
lag itself. Semi-active channels' damping coefficients are not rate-limited (their valve
response is the lag).

Per-row command health (:func:`healthy_command`): the task may scale a row's commands (an
actuator gain error), zero them (a failed actuator) or replace them by a held value (a stuck
actuator); a row with gain 1 and no fault takes its commands unchanged.

Adding a channel is one entry in :data:`CHANNELS` (see ``docs/extending.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from .dynamics import INPUT_NAMES, N_INPUTS, N_STATES, state_index


@dataclass(frozen=True)
class Channel:
    """One actuator channel: where it acts, what velocity it sees, and its default settings."""

    name: str
    input: str  # generalised input the force acts on (dynamics.INPUT_NAMES)
    reaction: str | None  # generalised input the reaction acts on (None: the car body)
    velocity: str  # state of the acting body's velocity
    relative_to: str | None  # state of the reacting body's velocity (None: the car body, at rest)
    unit: str  # "N" or "N m"
    defaults: dict[str, Any] = field(default_factory=dict)


# Defaults (sources in docs/environment.md): force limits of order 10 kN lateral, 15 kN m yaw
# (Fu et al., Railway Engineering Science 28(1), 2020: secondary yaw/lateral actuators of 5-20 kN);
# 10 Hz first-order bandwidth (hunting sits at 2-10 Hz); semi-active damping ranges that reach
# the force limit at typical hunting velocities.
def _defaults(max_force: float, c_max: float) -> dict[str, Any]:
    return {"mode": "force", "max_force": max_force, "c_min": 0.0, "c_max": c_max, "bandwidth_hz": 10.0, "delay_steps": 0,
            "rate_limit": None}


CHANNELS: tuple[Channel, ...] = (
    Channel("frame_lateral", "frame_lateral_force", None, "dyb", None, "N", _defaults(10e3, 1.0e5)),
    Channel("frame_yaw", "frame_yaw_torque", None, "dpsib", None, "N m", _defaults(15e3, 5.0e5)),
    Channel("wheelset1_yaw", "wheelset1_yaw_torque", "frame_yaw_torque", "dpsi1", "dpsib", "N m", _defaults(15e3, 1.0e6)),
    Channel("wheelset2_yaw", "wheelset2_yaw_torque", "frame_yaw_torque", "dpsi2", "dpsib", "N m", _defaults(15e3, 1.0e6)),
)
CHANNEL_NAMES: tuple[str, ...] = tuple(c.name for c in CHANNELS)
N_CHANNELS = len(CHANNELS)

MODES = ("off", "force", "semi_active")
MODE_OFF, MODE_FORCE, MODE_SEMI = range(3)
MAX_DELAY_STEPS = 10
DELAY_SLOTS = MAX_DELAY_STEPS + 1

# The compiled form of the table: index arrays (numba reads module-level arrays as constants).
_INPUT = np.array([INPUT_NAMES.index(c.input) for c in CHANNELS], dtype=np.int64)
_REACTION = np.array([-1 if c.reaction is None else INPUT_NAMES.index(c.reaction) for c in CHANNELS], dtype=np.int64)
_VELOCITY = np.array([state_index(c.velocity) for c in CHANNELS], dtype=np.int64)
_RELATIVE_TO = np.array([-1 if c.relative_to is None else state_index(c.relative_to) for c in CHANNELS], dtype=np.int64)

# ---- per-channel settings, one row per channel (float64 so one array carries them all) -----
CHANNEL_FIELDS = ("mode", "max_force", "c_min", "c_max", "decay_rate", "delay_steps", "action", "rate_limit")
CH_MODE, CH_MAX_FORCE, CH_C_MIN, CH_C_MAX, CH_DECAY_RATE, CH_DELAY_STEPS, CH_ACTION, CH_RATE_LIMIT = range(len(CHANNEL_FIELDS))

# ---- the actuator state of one row: lagged force targets and damping ------------------------
FORCE, DAMPING = 0, 1


def channel_table(settings: dict[str, dict[str, Any]] | None = None) -> np.ndarray:
    """(N_CHANNELS, len(CHANNEL_FIELDS)) settings for the compiled code.

    ``settings[name]`` holds the env config's keys (``mode``, ``max_force``, ``c_min``, ``c_max``,
    ``bandwidth_hz``, ``delay_steps``). ``None``: every channel accepts force and damping targets
    unsaturated and unlagged-from-rest (the analyses' passive bogie with optional inputs).
    Active channels get action columns in table order.
    """
    table = np.zeros((N_CHANNELS, len(CHANNEL_FIELDS)))
    if settings is None:
        table[:, CH_MODE] = MODE_FORCE
        table[:, CH_MAX_FORCE] = np.inf
        table[:, CH_ACTION] = -1
        table[:, CH_RATE_LIMIT] = np.inf
        return table
    column = 0
    for k, name in enumerate(CHANNEL_NAMES):
        spec = settings[name]
        mode = MODES.index(spec["mode"])
        table[k, CH_MODE] = mode
        table[k, CH_MAX_FORCE] = spec["max_force"]
        table[k, CH_C_MIN] = spec["c_min"]
        table[k, CH_C_MAX] = spec["c_max"]
        table[k, CH_DECAY_RATE] = 2 * math.pi * spec["bandwidth_hz"]  # 1/tau of a first-order lag
        table[k, CH_DELAY_STEPS] = spec["delay_steps"]
        table[k, CH_ACTION] = column if mode != MODE_OFF else -1
        rate = spec.get("rate_limit")
        table[k, CH_RATE_LIMIT] = np.inf if rate is None else rate
        column += mode != MODE_OFF
    return table


def active_channels(settings: dict[str, dict[str, Any]]) -> list[int]:
    """Indices of the channels that are not off, in action order."""
    return [k for k, name in enumerate(CHANNEL_NAMES) if settings[name]["mode"] != "off"]


# ---- the linear maps, as matrices (design models, Jacobians) -------------------------------
def velocity_matrix(channels: tuple[Channel, ...] = CHANNELS) -> np.ndarray:
    """V (n_channels, N_STATES): channel relative velocities ``v = V x``."""
    v = np.zeros((len(channels), N_STATES))
    for k, c in enumerate(channels):
        v[k, state_index(c.velocity)] += 1.0
        if c.relative_to is not None:
            v[k, state_index(c.relative_to)] -= 1.0
    return v


def force_matrix(columns: list[int] | None = None, channels: tuple[Channel, ...] = CHANNELS) -> np.ndarray:
    """G (N_INPUTS, n): generalised inputs per unit channel force, ``Q = G u`` (reactions
    included); ``columns`` selects channels (e.g. the active ones)."""
    g = np.zeros((N_INPUTS, len(channels)))
    for k, c in enumerate(channels):
        g[INPUT_NAMES.index(c.input), k] += 1.0
        if c.reaction is not None:
            g[INPUT_NAMES.index(c.reaction), k] -= 1.0
    return g if columns is None else g[:, columns]


def damping_jacobian(input_matrix: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """-B G diag(c) V: what viscous channels of coefficients ``damping`` add to the Jacobian."""
    return -input_matrix @ force_matrix() @ np.diag(damping) @ velocity_matrix()


# ---- compiled helpers --------------------------------------------------------------------------
@njit(cache=True, inline="always")
def channel_velocity(x, k):
    """Channel k's relative velocity in state x."""
    if _RELATIVE_TO[k] < 0:
        return x[_VELOCITY[k]]
    return x[_VELOCITY[k]] - x[_RELATIVE_TO[k]]


@njit(cache=True, inline="always")
def generalised_forces(u, q):
    """Q = G u into q (N_INPUTS): each channel's force on its input, its reaction on the other."""
    for i in range(N_INPUTS):
        q[i] = 0.0
    for k in range(N_CHANNELS):
        q[_INPUT[k]] += u[k]
        if _REACTION[k] >= 0:
            q[_REACTION[k]] -= u[k]


@njit(cache=True, inline="always")
def lagged(start, target, weight):
    """A first-order lag from ``start`` towards ``target``; ``weight = exp(-t / tau)``."""
    return target + (start - target) * weight


@njit(cache=True, inline="always")
def lagged_force(start, target, weight, decay_rate, rate_limit):
    """A first-order lag whose rate is limited to ``rate_limit``, exactly, where the plain lag
    has weight ``weight = exp(-decay_rate t)``.

    The lag's rate ``decay_rate * |target - f|`` is largest at the start; if it exceeds the
    limit, the force slews at the limit until ``|target - f| = rate_limit / decay_rate``
    (at ``t1``), then follows the lag. Without a binding limit it is :func:`lagged`, bit for
    bit; with one, ``t = -log(weight) / decay_rate``.
    """
    gap = target - start
    if abs(gap) * decay_rate <= rate_limit:
        return lagged(start, target, weight)
    t = -math.log(weight) / decay_rate
    sign = 1.0 if gap > 0.0 else -1.0
    t1 = abs(gap) / rate_limit - 1.0 / decay_rate
    if t <= t1:
        return start + sign * rate_limit * t
    return target - sign * (rate_limit / decay_rate) * math.exp(-decay_rate * (t - t1))


@njit(cache=True, inline="always")
def saturation(table, k):
    """Channel k's output limit: its max_force, 0 when off."""
    return table[k, CH_MAX_FORCE] if int(table[k, CH_MODE]) != MODE_OFF else 0.0


@njit(cache=True, inline="always")
def lag_weights(table, dt, n_sub, weights):
    """``exp(-t / tau)`` of every channel at the times an RK4 interval of n_sub substeps
    evaluates: row 3j + (0, 1, 2) at the start, middle and end of substep j, row 3 n_sub at dt.
    The same for every row of a batch, so the driver computes them once per run of rows."""
    h = dt / n_sub
    for k in range(N_CHANNELS):
        rate = table[k, CH_DECAY_RATE]
        for j in range(n_sub):
            t = j * h
            weights[3 * j, k] = math.exp(-rate * t)
            weights[3 * j + 1, k] = math.exp(-rate * (t + 0.5 * h))
            weights[3 * j + 2, k] = math.exp(-rate * (t + h))
        weights[3 * n_sub, k] = math.exp(-rate * dt)


@njit(cache=True, inline="always")
def channel_lags(k, weight, lag, target, table):
    """Channel k's lagged (force, damping) where the lag has weight ``exp(-t / tau)``: they depend
    on the time only, not on the state."""
    w = weight[k]
    force = lagged_force(lag[FORCE, k], target[FORCE, k], w, table[k, CH_DECAY_RATE], table[k, CH_RATE_LIMIT])
    return force, lagged(lag[DAMPING, k], target[DAMPING, k], w)


@njit(cache=True, inline="always")
def saturated_output(x, k, force, damping, table):
    """Channel k's output from its lagged force and damping: force minus damping times its
    velocity, saturated (a saturated damper keeps its sign, so it still only dissipates)."""
    value = force - damping * channel_velocity(x, k)
    limit = saturation(table, k)
    return min(max(value, -limit), limit)


@njit(cache=True, inline="always")
def channel_output(x, k, weight, lag, target, table):
    """Channel k's output where the lag has weight ``exp(-t / tau)`` (:func:`channel_lags`,
    :func:`saturated_output`)."""
    force, damping = channel_lags(k, weight, lag, target, table)
    return saturated_output(x, k, force, damping, table)


@njit(cache=True, inline="always")
def advance_lag(lag, target, weight, table):
    """The lag states at the end of the interval (weights at dt; exact first order, and exact
    under a rate limit), in place."""
    for k in range(N_CHANNELS):
        w = weight[k]
        lag[FORCE, k] = lagged_force(lag[FORCE, k], target[FORCE, k], w, table[k, CH_DECAY_RATE], table[k, CH_RATE_LIMIT])
        lag[DAMPING, k] = lagged(lag[DAMPING, k], target[DAMPING, k], w)


@njit(cache=True, inline="always")
def command_from_action(table, k, action_row, command):
    """Channel k's (force, damping) command from the agent's action in [-1, 1], into command[:, k]."""
    j = int(table[k, CH_ACTION])
    a = action_row[j] if j >= 0 else 0.0
    mode = int(table[k, CH_MODE])
    command[FORCE, k] = a * table[k, CH_MAX_FORCE] if mode == MODE_FORCE else 0.0
    command[DAMPING, k] = 0.0
    if mode == MODE_SEMI:
        command[DAMPING, k] = table[k, CH_C_MIN] + 0.5 * (a + 1.0) * (table[k, CH_C_MAX] - table[k, CH_C_MIN])


# ---- per-row command health: gain error, failed or stuck channels ------------------------------
#: Rows of a row's health array (3, N_CHANNELS): command gain, held force, held damping.
HEALTH_FIELDS = ("gain", "held_force", "held_damping")
H_GAIN, H_HELD_FORCE, H_HELD_DAMPING = range(len(HEALTH_FIELDS))
#: The held value is used where it is not NaN (a stuck channel); a failed channel has gain 0.


def healthy() -> np.ndarray:
    """(3, N_CHANNELS) health of a sound row: gain 1, nothing held."""
    h = np.full((len(HEALTH_FIELDS), N_CHANNELS), np.nan)
    h[H_GAIN] = 1.0
    return h


@njit(cache=True, inline="always")
def healthy_command(health, k, command):
    """Apply channel k's health to its command (in place): a held value replaces it, else it is
    scaled by the gain (gain 1: unchanged, bit for bit)."""
    if not math.isnan(health[H_HELD_FORCE, k]):
        command[FORCE, k] = health[H_HELD_FORCE, k]
        command[DAMPING, k] = health[H_HELD_DAMPING, k]
    elif health[H_GAIN, k] != 1.0:
        command[FORCE, k] *= health[H_GAIN, k]
        command[DAMPING, k] *= health[H_GAIN, k]


@njit(cache=True, inline="always")
def delayed_targets(delay, steps, command, table, target):
    """Push this step's command into the row's delay ring and read each channel's target.

    ``delay`` (DELAY_SLOTS, 2, N_CHANNELS) holds the recent commands; a channel delayed by d
    steps gets the command of d steps ago, and before it had one what the ring held at the
    row's start: zero (holding still; ``BatchSimulator.set_rows`` clears it) or, for a stuck
    channel, its held value.
    """
    head = steps % DELAY_SLOTS
    for k in range(N_CHANNELS):
        delay[head, FORCE, k] = command[FORCE, k]
        delay[head, DAMPING, k] = command[DAMPING, k]
        slot = (head - int(table[k, CH_DELAY_STEPS])) % DELAY_SLOTS
        target[FORCE, k] = delay[slot, FORCE, k]
        target[DAMPING, k] = delay[slot, DAMPING, k]
