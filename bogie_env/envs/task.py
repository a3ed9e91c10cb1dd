"""The hunting-control task over the simulator's rows (dm_control's Physics/Task split).

:class:`HuntingTask` builds, from a validated env config (``envs/config.py``), a
:class:`bogie_env.simulator.BatchSimulator` (the physics: states, motion, actuators, track)
and the task's own per-row arrays: the hunting detector, observations, rewards, flags and
infos. One env step of N rows is one compiled call, per run of rows:

1. the actions become channel commands (:func:`bogie_env.actuators.command_from_action`);
2. the simulator's driver advances the rows (:func:`bogie_env.simulator.advance_rows`);
3. small named functions read the rows: :func:`_detect_hunting`, :func:`_reward`,
   :func:`_write_info`, :func:`_observe`.

The three environment classes are front-ends that differ only in how they reset finished
episodes. ``agents/`` and the front-ends read results through the public vocabulary below
(``observe()``, ``hunting``, ``terminated``, ``actuator_force``, ``speed_kmh`` ...), never the
packed columns.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
from gymnasium import spaces
from numba import njit, prange, types
from numba.experimental import structref

from ..actuators import (
    CH_C_MAX,
    CH_MODE,
    CHANNEL_NAMES,
    DAMPING,
    FORCE,
    H_GAIN,
    H_HELD_DAMPING,
    H_HELD_FORCE,
    MODE_SEMI,
    N_CHANNELS,
    active_channels,
    channel_table,
    command_from_action,
    damping_jacobian,
    generalised_forces,
    healthy,
    healthy_command,
    saturation,
)
from ..dynamics import N_COEFFICIENTS, N_INPUTS, N_STATES, P_DELTA, P_L1, P_WPA, BogieModel, _guiding_forces_row, equilibrium_state
from ..dynamics import frame_lateral_accel, state_index
from ..integrate import (
    FASTMATH, METHOD_STAGES, OUT_FORCE, OUT_POWER, STATUS_OK, StepChoice, accurate_substep, method_divisors, stable_substep,
)  # fmt: skip
from ..params import BogieParams, ConfigError
from ..simulator import (
    M_ACCEL,
    M_DISTANCE,
    M_END_SPEED,
    M_SPEED,
    M_START_SPEED,
    N_CHUNKS,
    BatchSimulator,
    advance_rows,
    chunk_bounds,
    LoopChooser,
)
from ..wheel_rail import DETAIL_NAMES, GUIDING, Y_L, Y_R, wheelset_details, wheelset_wear_number
from ..route import CANT_BASE_M, GRAVITY
from ..track import ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2, CANT_FRAME, CURVATURE_FRAME, TrackInput, alignment_profile, alignment_profile_at_level, perfect_track
from . import scenario as scenarios
from .draws import uniform
from .config import MAX_ACCEL, MAX_NUM_ENVS, bogie_params, make_config, max_steps_for
from .routes import RouteLayout, build_layout
from .sensors import N_SENSED, SENSOR_NAMES, bias_deviations, draw_biases, sense_row, sense_rows, sensor_table

KMH = 3.6
_FLOAT_TYPES = (np.dtype(np.float32), np.dtype(np.float64))

# ---- the task's per-row arrays -----------------------------------------------------------------
# hunting detector: exponentially weighted mean squares of the wheelsets' displacement to the rail, and the onset speed (km/h, NaN until hunting)
# relative to the rail, and the onset speed (km/h, NaN until hunting); with hunting.detrend also
# their exponentially weighted means; on routes the sliding mean of the largest wheel Y/Q and
# the distance where the episode's route ends (inf on straight track)
E_MEAN_SQUARE1, E_MEAN_SQUARE2, E_ONSET_KMH, E_MEAN1, E_MEAN2, E_Y_OVER_Q, E_END_DISTANCE = range(7)
N_EPISODE = 7
FLAGS = ("terminated", "truncated", "hunting", "blowup", "y_over_q_exceeded")
F_TERMINATED, F_TRUNCATED, F_HUNTING, F_BLOWUP, F_Y_OVER_Q = range(len(FLAGS))
# info columns: speed, onset speed, the two wheelsets' rms, then per channel force and power;
# then the curving quantities of the route variant (zero on straight track)
I_SPEED_KMH, I_ONSET_KMH, I_RMS1, I_RMS2 = range(4)
I_FORCE = 4
I_POWER = I_FORCE + N_CHANNELS
I_WEAR1 = I_POWER + N_CHANNELS  # wear number Tγ per wheelset, N
I_FLANGE1 = I_WEAR1 + 2  # flange contact per wheelset (1/0)
I_Y_OVER_Q = I_FLANGE1 + 2  # largest Y/Q of the four wheels now
I_GUIDING1 = I_Y_OVER_Q + 1  # sum of guiding forces ΣY per wheelset, N
I_CURVATURE = I_GUIDING1 + 2  # track curvature under the frame, 1/m (+ left)
I_CANT_DEFICIENCY = I_CURVATURE + 1  # m, + unbalanced acceleration towards the outside of the curve
N_INFO = I_CANT_DEFICIENCY + 1

# ---- the task's settings, one float vector for the compiled code -------------------------------
(C_OBS_STATE, C_OBS_ACT, C_W_LAT, C_W_YAW, C_W_EFF, C_W_TIME, C_YAW_REF, C_WINDOW_M, C_HUNT_RMS_FRACTION,
 C_BLOWUP, C_N_ACTIVE, C_ROUTE, C_DETREND, C_W_WEAR, C_W_FLANGE, C_WEAR_REF, C_Y_OVER_Q_LIMIT,
 C_Y_OVER_Q_WINDOW_M) = range(18)  # fmt: skip
N_TASK_SETTINGS = 18

# ---- observation ----------------------------------------------------------------------------------
OBS_BOUND = 10.0
#: The "sensors" observation: these, then the speed, then the active channels' forces.
SENSORS = ("frame_lateral_accel", "frame_yaw_rate", "wheelset1_lateral_rel", "wheelset2_lateral_rel",
           "wheelset1_yaw_rel", "wheelset2_yaw_rel")  # fmt: skip
(SENSOR_FRAME_LATERAL_ACCEL, SENSOR_FRAME_YAW_RATE, SENSOR_WHEELSET1_LATERAL, SENSOR_WHEELSET2_LATERAL,
 SENSOR_WHEELSET1_YAW, SENSOR_WHEELSET2_YAW) = range(len(SENSORS))  # fmt: skip
N_SENSORS = len(SENSORS) + 1  # and the speed
# sensor scales: what counts as "1" in the observation
ACCEL_SCALE = 5.0  # m/s^2
YAW_RATE_SCALE = 0.1  # rad/s
REL_YAW_SCALE = 5e-3  # rad
SPEED_CENTRE_KMH = 450.0
SPEED_SCALE_KMH = 150.0
#: Scales of the full-state observation ("state" type): what counts as 1 for each state.
STATE_SCALES = np.array([9e-3, 0.1, 1e-3, 0.05, 5e-3, 0.1, 5e-3, 0.1] * 2 + [9e-3, 0.1, 5e-3, 0.05], dtype=float)

assert SENSOR_NAMES == SENSORS + ("speed",)  # the sensor model's table follows the observation


def speed_index(observation_type: str) -> int:
    """Where the speed sits in an observation of this type."""
    return N_STATES if observation_type == "state" else len(SENSORS)


_SCALES_BUT_DELTA = np.array([ACCEL_SCALE, YAW_RATE_SCALE, 0.0, 0.0, REL_YAW_SCALE, REL_YAW_SCALE, SPEED_SCALE_KMH / KMH])


#: From this many rows a reset sets them with one fancy index per array, below it row by row.
FANCY_RESET_MIN_ROWS = 8


def sensor_scales(delta: float | np.ndarray) -> np.ndarray:
    """SI value of one observation unit per measured channel (the six ``SENSORS`` and the
    speed: the observation's scales); ``delta`` is the flange clearance (m), one or (N,) rows."""
    scales = _SCALES_BUT_DELTA.copy() if np.ndim(delta) == 0 else np.tile(_SCALES_BUT_DELTA, (len(delta), 1))
    scales[..., SENSOR_WHEELSET1_LATERAL] = scales[..., SENSOR_WHEELSET2_LATERAL] = delta
    return scales


def speed_kmh_from_observation(obs: np.ndarray, observation_type: str) -> np.ndarray:
    """The speed (km/h) read back from a batch of observations."""
    return obs[:, speed_index(observation_type)].astype(float) * SPEED_SCALE_KMH + SPEED_CENTRE_KMH


Y1, Y2, YB = state_index("y1"), state_index("y2"), state_index("yb")
PSI1, PSI2, PSIB = state_index("psi1"), state_index("psi2"), state_index("psib")
_OFFSET_STATES, _YAW_STATES = np.array([Y1, Y2, YB]), np.array([PSI1, PSI2, PSIB])  # a reset's perturbation
DYB, DPSIB = state_index("dyb"), state_index("dpsib")


@njit(cache=True, inline="always")
def _clip(value, bound):
    return min(max(value, -bound), bound)


@njit(cache=True, inline="always")
def _relative_lateral(x, track_sample):
    """The wheelsets' lateral displacement relative to the rail."""
    return x[Y1] - track_sample[ALIGNMENT_WHEELSET1], x[Y2] - track_sample[ALIGNMENT_WHEELSET2]


@njit(cache=True, inline="always")
def _detrend(episode, y_rel1, y_rel2, v1, dt, cfg):
    """hunting.detrend_m: update each wheelset's exponentially weighted mean displacement over
    ``detrend_m`` of track and return the displacements about it (the quasi-static offset in a
    curve removed); off (0): the displacements unchanged."""
    if cfg[C_DETREND] <= 0.0:
        return y_rel1, y_rel2
    weight = 1.0 - math.exp(-dt * v1 / cfg[C_DETREND])
    episode[E_MEAN1] += weight * (y_rel1 - episode[E_MEAN1])
    episode[E_MEAN2] += weight * (y_rel2 - episode[E_MEAN2])
    return y_rel1 - episode[E_MEAN1], y_rel2 - episode[E_MEAN2]


@njit(cache=True, inline="always")
def _detect_hunting(episode, y_rel1, y_rel2, v1, dt, delta, cfg):
    """Update the detector's mean squares over ``window_m`` of track; returns (rms1, rms2, hunting)."""
    weight = 1.0 - math.exp(-dt * v1 / cfg[C_WINDOW_M])
    episode[E_MEAN_SQUARE1] += weight * (y_rel1 * y_rel1 - episode[E_MEAN_SQUARE1])
    episode[E_MEAN_SQUARE2] += weight * (y_rel2 * y_rel2 - episode[E_MEAN_SQUARE2])
    rms1 = math.sqrt(max(episode[E_MEAN_SQUARE1], 0.0))
    rms2 = math.sqrt(max(episode[E_MEAN_SQUARE2], 0.0))
    hunting = max(rms1, rms2) > cfg[C_HUNT_RMS_FRACTION] * delta
    if hunting and math.isnan(episode[E_ONSET_KMH]):
        episode[E_ONSET_KMH] = v1 * 3.6
    return rms1, rms2, hunting


@njit(cache=True, inline="always")
def _reward(x, y_rel1, y_rel2, v0, v1, dt, delta, u_end, channels, cfg):
    """Progress (km/h gained, plus optional time) times (1 - bounded penalties)."""
    psi_ref = cfg[C_YAW_REF]
    lat_pen = 0.5 * (min((y_rel1 / delta) ** 2, 1.0) + min((y_rel2 / delta) ** 2, 1.0))
    d1 = (x[PSI1] - x[PSIB]) / psi_ref
    d2 = (x[PSI2] - x[PSIB]) / psi_ref
    yaw_pen = 0.5 * (min(d1 * d1, 1.0) + min(d2 * d2, 1.0))
    eff_pen = 0.0
    for k in range(N_CHANNELS):
        u_max = saturation(channels, k)
        if u_max > 0.0:
            eff_pen += min((u_end[k] / u_max) ** 2, 1.0)
    if cfg[C_N_ACTIVE] > 0:
        eff_pen /= cfg[C_N_ACTIVE]
    penalty = cfg[C_W_LAT] * lat_pen + cfg[C_W_YAW] * yaw_pen + cfg[C_W_EFF] * eff_pen
    progress = (v1 - v0) * 3.6 + cfg[C_W_TIME] * dt
    return progress * (1.0 - penalty)


@njit(cache=True, inline="always")
def _wear_penalty(wear1, wear2, cfg):
    """The curving reward's wear term: min(mean wheelset wear number / wear_reference, 1), in [0, 1]."""
    return min(0.5 * (wear1 + wear2) / cfg[C_WEAR_REF], 1.0)


@njit(cache=True, inline="always")
def _flange_penalty(flange1, flange2):
    """The curving reward's flange term: the share of wheelsets in flange contact, in [0, 1]."""
    return 0.5 * (flange1 + flange2)


@njit(cache=True, inline="always")
def _curving_reward(reward, wear1, wear2, flange1, flange2, progress, cfg):
    """The route variant's reward: the hunting reward less progress x (w_wear x wear term +
    w_flange x flange term), i.e. progress x (1 - all penalties)."""
    return reward - progress * (cfg[C_W_WEAR] * _wear_penalty(wear1, wear2, cfg) + cfg[C_W_FLANGE] * _flange_penalty(flange1, flange2))


@njit(cache=True, inline="always")
def _curving_quantities(x, v1, track_sample, p, details, info):
    """The wheel-rail quantities of a curving assessment at the end of the step into the info
    row (wear number, flange contact, Y/Q, ΣY per wheelset; curvature and cant deficiency),
    through :func:`bogie_env.wheel_rail.wheelset_details`. Returns the largest Y/Q."""
    inv_v = 1.0 / v1
    q = 0.5 * p[P_WPA]
    y_over_q = -1e300
    delta = p[P_DELTA]
    for i in range(2):
        row = details[i]
        wheelset_details(x, inv_v, track_sample, p, i, row)
        info[I_WEAR1 + i] = wheelset_wear_number(row)
        y_rel = x[Y1 if i == 0 else Y2] - track_sample[ALIGNMENT_WHEELSET1 + i]
        info[I_FLANGE1 + i] = 1.0 if abs(y_rel) >= delta else 0.0
        info[I_GUIDING1 + i] = row[GUIDING]
        y_over_q = max(y_over_q, row[Y_L] / q, row[Y_R] / q)
    info[I_Y_OVER_Q] = y_over_q
    kappa = track_sample[CURVATURE_FRAME]
    equilibrium = CANT_BASE_M * math.sin(math.atan(v1 * v1 * kappa / GRAVITY))
    cant = CANT_BASE_M * math.sin(track_sample[CANT_FRAME])
    side = 1.0 if (kappa > 0.0 or (kappa == 0.0 and cant >= 0.0)) else -1.0
    info[I_CURVATURE] = kappa
    info[I_CANT_DEFICIENCY] = side * (equilibrium - cant)
    return y_over_q


@njit(cache=True, inline="always")
def _y_over_q_exceeded(episode, y_over_q, v1, dt, cfg):
    """Route termination: the largest wheel Y/Q, averaged over ``y_over_q_window_m`` of track
    (exponentially weighted), above ``y_over_q_limit`` (a limit <= 0: never)."""
    weight = 1.0 - math.exp(-dt * v1 / cfg[C_Y_OVER_Q_WINDOW_M])
    episode[E_Y_OVER_Q] += weight * (y_over_q - episode[E_Y_OVER_Q])
    return cfg[C_Y_OVER_Q_LIMIT] > 0.0 and episode[E_Y_OVER_Q] > cfg[C_Y_OVER_Q_LIMIT]


@njit(cache=True, inline="always")
def _write_info(info, v1, onset_kmh, rms1, rms2, output):
    info[I_SPEED_KMH] = v1 * 3.6
    info[I_ONSET_KMH] = onset_kmh
    info[I_RMS1] = rms1
    info[I_RMS2] = rms2
    for k in range(N_CHANNELS):
        info[I_FORCE + k] = output[OUT_FORCE, k]
        info[I_POWER + k] = output[OUT_POWER, k]


@njit(cache=True, inline="always")
def _observe(obs, x, v1, p, track_sample, u_end, channels, cfg, state_scales, scratch):
    """One row's observation: sensors (or scaled states), speed, actuator forces."""
    m = 0
    if cfg[C_OBS_STATE] > 0.5:
        for i in range(N_STATES):
            obs[i] = _clip(x[i] / state_scales[i], OBS_BOUND)
        m = N_STATES
    else:
        # the frame's lateral acceleration: its equation of the right-hand side at the end state
        q = scratch[1, :N_INPUTS]
        generalised_forces(u_end, q)
        L1 = p[P_L1]
        delta = p[P_DELTA]
        psib = x[PSIB]
        obs[SENSOR_FRAME_LATERAL_ACCEL] = _clip(frame_lateral_accel(x, v1, q, track_sample, p) / ACCEL_SCALE, OBS_BOUND)
        obs[SENSOR_FRAME_YAW_RATE] = _clip(x[DPSIB] / YAW_RATE_SCALE, OBS_BOUND)
        obs[SENSOR_WHEELSET1_LATERAL] = _clip((x[Y1] - x[YB] - L1 * psib) / delta, OBS_BOUND)
        obs[SENSOR_WHEELSET2_LATERAL] = _clip((x[Y2] - x[YB] + L1 * psib) / delta, OBS_BOUND)
        obs[SENSOR_WHEELSET1_YAW] = _clip((x[PSI1] - psib) / REL_YAW_SCALE, OBS_BOUND)
        obs[SENSOR_WHEELSET2_YAW] = _clip((x[PSI2] - psib) / REL_YAW_SCALE, OBS_BOUND)
        m = len(SENSORS)
    obs[m] = _clip((v1 * 3.6 - SPEED_CENTRE_KMH) / SPEED_SCALE_KMH, OBS_BOUND)
    m += 1
    if cfg[C_OBS_ACT] > 0.5:
        for k in range(N_CHANNELS):
            u_max = saturation(channels, k)
            if u_max > 0.0:
                obs[m] = _clip(u_end[k] / u_max, OBS_BOUND)
                m += 1


@njit(cache=True, inline="always")
def _task_row(n, sim_rows, channels, dt, task_rows, cfg, state_scales, scratch, details):
    """Detector, flags, reward, info and observation of row n after its interval."""
    x, motion, coefficients, _, _, _, output, track_sample, status = sim_rows
    episode, obs, reward, flags, info = task_rows
    m = motion[n]
    p = coefficients[n]
    delta = p[P_DELTA]
    v1 = m[M_SPEED]
    y_rel1, y_rel2 = _relative_lateral(x[n], track_sample[n])
    y_osc1, y_osc2 = _detrend(episode[n], y_rel1, y_rel2, v1, dt, cfg)
    rms1, rms2, hunting = _detect_hunting(episode[n], y_osc1, y_osc2, v1, dt, delta, cfg)
    blowup = status[n] != STATUS_OK or abs(y_rel1) > cfg[C_BLOWUP] or abs(y_rel2) > cfg[C_BLOWUP]
    route = cfg[C_ROUTE] > 0.5
    y_over_q_exceeded = False
    if route and not blowup:
        y_over_q = _curving_quantities(x[n], v1, track_sample[n], p, details, info[n])
        y_over_q_exceeded = _y_over_q_exceeded(episode[n], y_over_q, v1, dt, cfg)
    terminated = hunting or blowup or y_over_q_exceeded
    truncated = (not terminated) and ((v1 >= m[M_END_SPEED] - 1e-9 and m[M_ACCEL] > 0.0)
                                      or (route and m[M_DISTANCE] >= episode[n, E_END_DISTANCE]))  # fmt: skip
    flags[n, F_TERMINATED] = 1 if terminated else 0
    flags[n, F_TRUNCATED] = 1 if truncated else 0
    flags[n, F_HUNTING] = 1 if hunting else 0
    flags[n, F_BLOWUP] = 1 if blowup else 0
    flags[n, F_Y_OVER_Q] = 1 if y_over_q_exceeded else 0
    u_end = output[n, OUT_FORCE]
    rew = _reward(x[n], y_osc1, y_osc2, m[M_START_SPEED], v1, dt, delta, u_end, channels, cfg)
    if route and not blowup:
        progress = (v1 - m[M_START_SPEED]) * 3.6 + cfg[C_W_TIME] * dt
        rew = _curving_reward(rew, info[n, I_WEAR1], info[n, I_WEAR1 + 1], info[n, I_FLANGE1], info[n, I_FLANGE1 + 1],
                              progress, cfg)  # fmt: skip
    reward[n] = rew if not blowup else 0.0
    _write_info(info[n], v1, episode[n, E_ONSET_KMH], rms1, rms2, output[n])
    _observe(obs[n], x[n], v1, p, track_sample[n], u_end, channels, cfg, state_scales, scratch)


# Not inlined: the serial call and the parallel loop run this one compilation of a run of rows.
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _step_rows(start, stop, sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing):
    """One env step of rows [start, stop): actions -> commands (through each row's actuator
    health) -> the simulator's interval -> task -> sensors (``sensing``: :meth:`HuntingTask.sensing`)."""
    _commands(start, stop, sim_rows, channels, action, health)
    advance_rows(start, stop, sim_rows, channels, track, dt, n_sub, divisors)
    scratch = np.empty((2, N_STATES))
    details = np.empty((2, len(DETAIL_NAMES)))
    _task_run(start, stop, sim_rows, channels, dt, task_rows, cfg, state_scales, scratch, details)
    _sense_run(start, stop, task_rows[1], sensing)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def _sense_run(start, stop, obs, sensing):
    """The sensor model (:func:`bogie_env.envs.sensors.sense_row`) of rows [start, stop) after their step; off: nothing."""
    enabled, filtered, bias, scale, rng_state, table, paired = sensing
    if enabled:
        for n in range(start, stop):
            sense_row(n, obs, filtered, bias, scale, rng_state, table, False, OBS_BOUND, paired)


# The row loops without reference counting (numba's _nrt=False), as bogie_env.simulator._advance_run.
@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def _commands(start, stop, sim_rows, channels, action, health):
    """The channel commands of rows [start, stop) from their actions, through each row's health."""
    command = sim_rows[5]
    for n in range(start, stop):
        for k in range(N_CHANNELS):
            command_from_action(channels, k, action[n], command[n])
            healthy_command(health[n], k, command[n])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def _task_run(start, stop, sim_rows, channels, dt, task_rows, cfg, state_scales, scratch, details):
    """:func:`_task_row` of rows [start, stop)."""
    for n in range(start, stop):
        _task_row(n, sim_rows, channels, dt, task_rows, cfg, state_scales, scratch, details)


@njit(cache=True, inline="always")
def _clip_actions(action, out):
    """out = action clipped to [-1, 1]; the flat index of the first non-finite entry, or -1
    (then out is incomplete and nothing may be stepped)."""
    for n in range(action.shape[0]):
        for j in range(action.shape[1]):
            value = action[n, j]
            if not math.isfinite(value):
                return n * action.shape[1] + j
            out[n, j] = min(max(value, -1.0), 1.0)
    return -1


@njit(cache=True, fastmath=FASTMATH)
def _step_serial(action_in, sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing):
    """Check and clip the actions, then one env step of every row on the calling thread;
    returns -1, or the flat index of a non-finite action (nothing stepped)."""
    bad = _clip_actions(action_in, action)
    if bad < 0:
        _step_rows(np.int64(0), action.shape[0], sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales,
                   health, sensing)  # int64 as in the parallel loop: one compiled signature
    return bad


#: The serial step's arguments after the actions, by name (:class:`StepArgs`).
STEP_ARG_NAMES = ("sim_rows", "channels", "track", "dt", "n_sub", "divisors", "action", "task_rows", "cfg", "state_scales", "health",
                  "sensing")  # fmt: skip


@structref.register
class _StepArgsType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class StepArgs(structref.StructRefProxy):
    """The step's fixed arguments (:data:`STEP_ARG_NAMES`) as one compiled object that holds the
    same arrays. Numba types and unboxes each array argument on every call (about 80 ns each,
    some 35 arrays here); one object instead takes about a third of that, which is most of what
    separates the single env's step from Pendulum-v1's (``benchmarks/bench_v1.py --single``)."""


structref.define_proxy(StepArgs, _StepArgsType, list(STEP_ARG_NAMES))


# numba compiles StepArgs' own constructor anew in every process (about 0.5 s at a task's first
# step); this one is cached with the other kernels.
@njit(cache=True)
def _pack_step_args(sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing):
    return StepArgs(sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing)


@njit(cache=True, fastmath=FASTMATH)
def _step_serial_packed(action_in, k):
    """:func:`_step_serial` with its fixed arguments in one :class:`StepArgs`."""
    return _step_serial(action_in, k.sim_rows, k.channels, k.track, k.dt, k.n_sub, k.divisors, k.action, k.task_rows, k.cfg,
                        k.state_scales, k.health, k.sensing)  # fmt: skip


@njit(cache=True, fastmath=FASTMATH, parallel=True)
def _step_parallel(sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing):
    n_rows = action.shape[0]
    n_chunks = min(n_rows, N_CHUNKS)
    for c in prange(n_chunks):
        start, stop = chunk_bounds(n_rows, n_chunks, c)
        _step_rows(start, stop, sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing)


@njit(cache=True, fastmath=FASTMATH)
def _step_checked_parallel(action_in, sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing):
    """:func:`_step_serial` with the rows on the thread pool."""
    bad = _clip_actions(action_in, action)
    if bad < 0:
        _step_parallel(sim_rows, channels, track, dt, n_sub, divisors, action, task_rows, cfg, state_scales, health, sensing)
    return bad


@njit(cache=True, fastmath=FASTMATH)
def _observe_rows(rows, sim_rows, channels, obs, cfg, state_scales):
    """Observations of some rows from their current state (channels at their last output)."""
    x, motion, coefficients, _, _, _, output, track_sample, _ = sim_rows
    scratch = np.empty((2, N_STATES))
    for n in rows:
        u_end = output[n, OUT_FORCE]
        _observe(obs[n], x[n], motion[n, M_SPEED], coefficients[n], track_sample[n], u_end, channels, cfg, state_scales, scratch)


# ---- per-step quantities of a stability or safety criterion (info; on demand) ---------------
#: The criterion fields of every env's info (``HuntingTask.criterion_quantities``), SI units:
#: shape per env, and what each is.
CRITERION_FIELDS: dict[str, str] = {
    "wheelset_lateral_rel_rail_m": "(2,) each wheelset's lateral displacement relative to the rail (m, + left)",
    "flange_contact": "(2,) each wheelset in flange contact: |displacement relative to the rail| >= flange clearance",
    "wheel_flange_contact": "(2, 2) [wheelset, (left, right) wheel]: left when the displacement >= +clearance, right when <= -clearance",
    "sum_y_n": "(2,) EN 14363's sum of guiding forces ΣY per wheelset: the rails' lateral force on the wheelset (N, + left)",
    "wheel_y_over_q": "(2, 2) [wheelset, (left, right) wheel] Y/Q: the wheel's lateral force on its rail (+ outwards) over Wpa/2",
    "y_over_q": "() the largest of the four wheels' Y/Q",
}


# columns of the criterion kernel's output: per wheelset the displacement relative to the rail
# and ΣY; per wheel (wheelset 1 left, right, wheelset 2 left, right) Y/Q; the largest Y/Q; the
# flags (1/0): per wheel flange contact, then per wheelset
K_REL1, K_SUM_Y1, K_Y_OVER_Q1, K_Y_OVER_Q_MAX = 0, 2, 4, 8
K_FLANGE_WHEEL1 = 9
K_FLANGE1 = K_FLANGE_WHEEL1 + 4
N_CRITERION = K_FLANGE1 + 2


@njit(cache=True, inline="always")
def _flange_contact(y_rel, delta):
    """(left, right) flange contact of a wheelset displaced ``y_rel`` from the rail: |y_rel| >=
    the flange clearance ``delta`` (the stability protocol's test), on the left wheel when
    displaced left (the side of the model's flange force, ``analysis.curving.wheelset_details``)."""
    return y_rel >= delta, y_rel <= -delta


@njit(cache=True)
def _criterion_rows(rows, x, motion, coefficients, track_sample, out):
    """The criterion quantities of ``rows`` at the end of their last interval into ``out[j]``
    (N_CRITERION,) for row ``rows[j]`` (SI units). ΣY is ``dynamics._guiding_forces_row``, the
    function behind ``analysis.en14363.running_signals_rows`` (the stability protocol's ΣY); Y
    per wheel is ``analysis.curving.wheelset_details`` over Q = Wpa/2, as the route variant's
    Y/Q. Not fastmath, like those. (The simulator's arrays one by one: a tuple argument costs
    more to dispatch than the single env's whole info.)"""
    row = np.empty(len(DETAIL_NAMES))
    sum_y = np.empty(2)
    for j in range(rows.shape[0]):
        y_over_q = -math.inf
        n = rows[j]
        p = coefficients[n]
        v = motion[n, M_SPEED]
        inv_q = 1.0 / (0.5 * p[P_WPA])
        _guiding_forces_row(x[n], v, track_sample[n], p, sum_y)
        y_rel1, y_rel2 = _relative_lateral(x[n], track_sample[n])
        for i in range(2):
            y_rel = y_rel1 if i == 0 else y_rel2
            left, right = _flange_contact(y_rel, p[P_DELTA])
            wheelset_details(x[n], 1.0 / v, track_sample[n], p, i, row)
            out[j, K_REL1 + i] = y_rel
            out[j, K_SUM_Y1 + i] = sum_y[i]
            out[j, K_Y_OVER_Q1 + 2 * i] = row[Y_L] * inv_q
            out[j, K_Y_OVER_Q1 + 2 * i + 1] = row[Y_R] * inv_q
            y_over_q = max(y_over_q, out[j, K_Y_OVER_Q1 + 2 * i], out[j, K_Y_OVER_Q1 + 2 * i + 1])
            out[j, K_FLANGE_WHEEL1 + 2 * i] = 1.0 if left else 0.0
            out[j, K_FLANGE_WHEEL1 + 2 * i + 1] = 1.0 if right else 0.0
            out[j, K_FLANGE1 + i] = 1.0 if (left or right) else 0.0
        out[j, K_Y_OVER_Q_MAX] = y_over_q


class HuntingTask:
    """N hunting-control episodes over one :class:`BatchSimulator`.

    Public vocabulary (arrays over the N rows): :attr:`obs`, :attr:`reward`, :attr:`terminated`,
    :attr:`truncated`, :attr:`hunting`, :attr:`blowup`, :attr:`speed_kmh`,
    :attr:`onset_speed_kmh`, :attr:`lateral_rms_m`, :attr:`relative_lateral_m`,
    :attr:`actuator_force`, :attr:`actuator_power`, :attr:`actuator_limits`, :attr:`states`,
    :attr:`flange_clearance`; :meth:`criterion_quantities` (the per-step criterion fields of
    the infos, :data:`CRITERION_FIELDS`), :meth:`scenario` and :meth:`scenario_summary` (what an
    episode drew); and :meth:`reset_rows`, :meth:`step`, :meth:`set_states`, :meth:`observe`.
    """

    def __init__(self, num_envs: int, config: Mapping[str, Any] | str | None = None, **overrides: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or not 1 <= num_envs <= MAX_NUM_ENVS:
            raise ConfigError(f"num_envs = {num_envs!r} is not allowed; allowed: an integer in [1, {MAX_NUM_ENVS}] "
                              "(more rows per process only cost memory and reset time; scale out with Ray)")
        self.num_envs = n = int(num_envs)
        self.config = c = make_config(config, **overrides)
        self.base_params: BogieParams = bogie_params(c)
        self.model = BogieModel(self.base_params)
        tr = c["track"]
        if tr["level"] is not None:
            alignment = alignment_profile_at_level(tr["level"], tr["wavelength_min"], tr["wavelength_max"], seed=tr["seed"])
        elif tr["rms"] > 0:
            alignment = alignment_profile(tr["rms"], tr["wavelength_min"], tr["wavelength_max"], seed=tr["seed"])
        else:
            alignment = perfect_track()
        # route variant: the configured routes laid end to end on the one track (envs/routes.py)
        self.route_layout: RouteLayout | None = build_layout(c["route"]) if c["route"]["names"] is not None else None
        self.track_input = TrackInput(alignment) if self.route_layout is None else TrackInput(alignment, self.route_layout.track)
        self.route_slot = np.full(n, -1, dtype=np.int64)  # each row's slot of the layout (-1: none)
        # actuator channels -> action columns
        self.active_channels = active_channels(c["actuators"])
        self.channel_names = tuple(CHANNEL_NAMES[k] for k in self.active_channels)
        self.action_dim = max(1, len(self.active_channels))
        self.passive = not self.active_channels
        self.observation_dim = (N_STATES if c["observation"]["type"] == "state" else N_SENSORS - 1) + 1
        if c["observation"]["include_actuators"]:
            self.observation_dim += len(self.active_channels)
        self.action_space = spaces.Box(-1.0, 1.0, (self.action_dim,), np.float32)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, (self.observation_dim,), np.float32)
        self.channels = channel_table(c["actuators"])
        self.settings = self._task_settings()
        self.state_scales = STATE_SCALES.copy()
        # Step size from the spectrum over the whole speed range, dampers at their stiffest.
        lo, hi = self.speed_limits()
        semi = self.channels[:, CH_MODE] == MODE_SEMI
        max_damping = np.where(semi, self.channels[:, CH_C_MAX], 0.0)
        extra = damping_jacobian(self.model.input_matrix(), max_damping) if np.any(max_damping) else None
        #: the integration method's stages per substep (METHOD_STAGES; 0: classic RK4)
        self.stages = METHOD_STAGES[c["integration"]["method"]]
        #: and its stage divisors (METHOD_DIVISORS; empty for RK4)
        self.divisors = method_divisors(c["integration"]["method"])
        self.step_choice = self._step_choice(lo, hi, extra)
        self.n_sub = self.step_choice.n_sub
        self.sim = BatchSimulator(self.model, n, c["dt"], (lo, hi), self.track_input, self.channels, n_sub=self.n_sub,
                                  num_threads=c["num_threads"], stages=c["integration"]["method"])  # fmt: skip
        self.loops = LoopChooser(n, self.sim.num_threads)
        self._packed_step_args: StepArgs | None = None  # built at the first serial-only step
        # the task's per-row arrays
        self.episode = np.zeros((n, N_EPISODE))
        self.obs = np.zeros((n, self.observation_dim), dtype=np.float32)
        self.reward = np.zeros(n)
        self.flags = np.zeros((n, len(FLAGS)), dtype=np.int8)
        self.info = np.zeros((n, N_INFO))
        self._task_rows = (self.episode, self.obs, self.reward, self.flags, self.info)
        self.actions = np.zeros((n, self.action_dim))
        self.rngs = [np.random.default_rng() for _ in range(n)]
        self.episode_params: list[dict[str, float]] = [{} for _ in range(n)]
        # actuator health per row (gain, held command), sensor model state per row
        self._healthy = healthy()
        self.health = np.repeat(self._healthy[None], n, axis=0)
        self.scenarios: list[scenarios.Scenario] = [scenarios.Scenario() for _ in range(n)]
        self._episode_draws: list[tuple] = [() for _ in range(n)]  # what reset_rows drew besides the scenario
        self._criterion_on = bool(c["info"]["criterion"])
        self._one_row, self._one_out = np.zeros(1, dtype=np.int64), np.empty((1, N_CRITERION))  # info_dict's buffers
        self.sensors_enabled = bool(c["sensors"]["enabled"])
        self.sensor_table = sensor_table(c["sensors"], c["dt"])
        self._bias_deviations = bias_deviations(c["sensors"])
        self.sensor_filter = np.zeros((n, N_SENSED))
        self.sensor_bias = np.zeros((n, N_SENSED))
        self.sensor_scale = np.ones((n, N_SENSED))
        self.sensor_rng = np.zeros(n, dtype=np.uint64)
        #: what the compiled step measures each row with, after its interval (sensors.sense_row)
        self.sensing = (self.sensors_enabled, self.sensor_filter, self.sensor_bias, self.sensor_scale, self.sensor_rng,
                        self.sensor_table, c["sensors"]["noise_draws"] == "paired")  # fmt: skip

    # ---- configuration ----------------------------------------------------------------------
    @property
    def on_routes(self) -> bool:
        """The route variant: episodes run routes at constant speed."""
        return self.route_layout is not None

    def speed_limits(self) -> tuple[float, float]:
        """Lowest and highest speed (m/s) any episode can visit under this config."""
        sp = self.config["speed"]
        if self.route_layout is not None:
            lo, hi = self.route_layout.speed_limits_kmh()
            lows, highs = [lo], [hi]
        else:
            lows = [sp["start_kmh"]] + ([sp["start_kmh_range"][0]] if sp["start_kmh_range"] else [])
            highs = [sp["end_kmh"]] + ([sp["end_kmh_range"][1]] if sp["end_kmh_range"] else [])
        if sp["supported_kmh"] is not None:  # widened by the config
            lows.append(sp["supported_kmh"][0])
            highs.append(sp["supported_kmh"][1])
        return min(lows) / KMH, max(highs) / KMH

    def _step_choice(self, lo: float, hi: float, extra: np.ndarray | None) -> StepChoice:
        """The RK4 substep (``integration`` config): fixed, or the fewest substeps that meet the
        criterion for every bogie the episodes can draw (the nominal one and the ends of the
        named ranges that change the dynamics)."""
        ig = self.config["integration"]
        dt = self.config["dt"]
        if ig["n_sub"] is not None:
            return StepChoice(dt / ig["n_sub"], ig["n_sub"], float("nan"), float("nan"))
        if ig["step_criterion"] == "stability":
            return stable_substep(self.model, lo, hi, dt, extra_jacobian=extra, stages=self.divisors)
        choices = [accurate_substep(m, lo, hi, dt, ig["tolerance"], extra_jacobian=extra, stages=self.divisors)
                   for m in self.criterion_models()]  # fmt: skip
        return max(choices, key=lambda choice: choice.n_sub)

    def criterion_models(self) -> list[BogieModel]:
        """The bogies the step criterion checks: the nominal one, and the ends of the randomised
        ranges that change the dynamics, all at once and one range at a time."""
        ranges = {k: v for k, v in self.config["randomize"].items() if k in scenarios.RANGES and k != "actuator_gain"}
        models = [self.model]
        for end in (0, 1):
            models.append(scenarios.scenario_model(self.base_params, scenarios.Scenario(**{k: v[end] for k, v in ranges.items()}), self.model))
            for k, v in ranges.items():
                models.append(scenarios.scenario_model(self.base_params, scenarios.Scenario(**{k: v[end]}), self.model))
        return models

    def _task_settings(self) -> np.ndarray:
        c = self.config
        cfg = np.zeros(N_TASK_SETTINGS)
        cfg[C_OBS_STATE] = 1.0 if c["observation"]["type"] == "state" else 0.0
        cfg[C_OBS_ACT] = 1.0 if c["observation"]["include_actuators"] else 0.0
        rw = c["reward"]
        cfg[C_W_LAT], cfg[C_W_YAW], cfg[C_W_EFF] = rw["lateral_weight"], rw["yaw_weight"], rw["effort_weight"]
        cfg[C_W_TIME], cfg[C_YAW_REF] = rw["time_weight"], rw["yaw_reference"]
        hu = c["hunting"]
        cfg[C_WINDOW_M], cfg[C_HUNT_RMS_FRACTION], cfg[C_BLOWUP] = hu["window_m"], hu["rms_fraction"], hu["blowup_m"]
        cfg[C_N_ACTIVE] = len(self.active_channels)
        cfg[C_ROUTE] = 1.0 if c["route"]["names"] is not None else 0.0
        cfg[C_DETREND] = hu["detrend_m"] if hu["detrend_m"] is not None else 0.0
        cfg[C_W_WEAR], cfg[C_W_FLANGE], cfg[C_WEAR_REF] = rw["wear_weight"], rw["flange_weight"], rw["wear_reference"]
        cu = c["curving"]
        cfg[C_Y_OVER_Q_LIMIT] = cu["y_over_q_limit"] if cu["y_over_q_limit"] is not None else 0.0
        cfg[C_Y_OVER_Q_WINDOW_M] = cu["y_over_q_window_m"]
        return cfg

    # ---- episodes -----------------------------------------------------------------------------
    def seed_rows(self, rows: np.ndarray, seeds: list[int | None]) -> None:
        for i, s in zip(rows, seeds):
            self.rngs[i] = np.random.default_rng(s)

    def reset_rows(self, rows: np.ndarray, options: Mapping[str, Any] | None = None) -> None:
        """Start new episodes in ``rows`` (their RNGs must already be seeded). Each row draws, in
        this order from its RNG: its speeds (and route slot), its scenario, its start state, its
        place on the track and its sensors' biases and noise seed. Every row is drawn before any
        is set, so a reset that raises (a bad option for one row) changes no row's episode (the
        rows' random streams have moved on); the scenarios' bogies are then computed for all
        rows at once (:func:`scenario.scenario_coefficient_rows`). A row given twice keeps its last draw (its first
        observation's noise is drawn once per mention). The rest (equilibria aside) is set for
        all rows at once."""
        options = self._checked_reset_options(options)
        rows = np.atleast_1d(rows)
        n = rows.size
        if n == 0:
            return
        x0 = np.empty((n, N_STATES))
        draws = np.empty((n, 4))  # start_kmh, end_kmh, accel, distance
        biases, noise_seeds = np.empty((n, N_SENSED)), np.empty(n, dtype=np.uint64)
        slots, new_scenarios, episode_draws = [], [], []
        active = list(self.channel_names)
        for j, i in enumerate(rows):
            rng = self.rngs[i]
            start, end, accel, slot = self._draw_speeds(rng, options)
            scenario = scenarios.draw_scenario(self.config["randomize"], options, rng, active)
            scenario.factors.update(options.get("params", {}) or {})
            offsets, yaws, large = self._draw_perturbation(rng)
            distance = slot.start_m if self.on_routes else self._draw_track_position(rng)
            draws[j] = start, end, accel, distance
            episode_draws.append((float(start), float(end), float(accel), float(distance), slot, offsets, yaws, large))
            if self.sensors_enabled:
                biases[j] = draw_biases(self.config["sensors"], rng, self._bias_deviations)
                noise_seeds[j] = rng.integers(1, 2**63)
            slots.append(slot)
            new_scenarios.append(scenario)
        coefficients = scenarios.scenario_coefficient_rows(self.base_params, new_scenarios, self.model)
        coefficients.setflags(write=False)  # read-only as a model's vector: one compiled signature for the equilibrium
        for j, (start, *_, offsets, yaws, _large) in enumerate(episode_draws):
            x0[j] = self._start_state(coefficients[j], start, offsets, yaws)
        last = self._last_of_each_row(rows)
        members = last.tolist()
        for j in members:
            i = rows[j]
            self.episode_params[i], self.scenarios[i] = new_scenarios[j].factors, new_scenarios[j]
            self._episode_draws[i] = episode_draws[j]
            if self.sensors_enabled:
                self.sensor_bias[i], self.sensor_rng[i] = biases[j], noise_seeds[j]
        # a few rows (a single env's reset, an autoreset's) are set one by one by basic indexing,
        # more by one fancy index each: the cheaper of the two
        by_row = len(members) < FANCY_RESET_MIN_ROWS
        for at, sel, group in [(int(rows[j]), j, (j,)) for j in members] if by_row else [(rows[last], last, members)]:
            self.sim.set_rows(at, x0[sel], draws[sel, 0] / KMH, draws[sel, 2], draws[sel, 3], end_speed=draws[sel, 1] / KMH,
                              coefficients=coefficients[sel])  # fmt: skip
            self._set_health(at, [new_scenarios[j] for j in group])
            if self.sensors_enabled:
                self.sensor_scale[at] = sensor_scales(coefficients[sel, P_DELTA])
            self._clear_episode(at, draws[sel, 0], [slots[j] for j in group])
        self.observe(rows)
        if self.sensors_enabled:
            sense_rows(rows.astype(np.int64), self.obs, self.sensor_filter, self.sensor_bias, self.sensor_scale,
                       self.sensor_rng, self.sensor_table, True, OBS_BOUND, self.sensing[-1])  # fmt: skip
        self._add_noise(rows)

    def _last_of_each_row(self, rows: np.ndarray) -> np.ndarray:
        """Positions in ``rows`` of each row's last mention (a negative index names the same row
        as its positive one), in order."""
        if rows.size == 1:
            return np.zeros(1, dtype=np.int64)
        if rows[0] >= 0 and (rows[1:] > rows[:-1]).all():  # increasing (np.nonzero's, an autoreset's): all distinct
            return np.arange(rows.size)
        canonical = np.asarray(rows, dtype=np.int64) % self.num_envs
        _, first_from_end = np.unique(canonical[::-1], return_index=True)
        return np.sort(rows.size - 1 - first_from_end)

    def _checked_reset_options(self, options: Mapping[str, Any] | None) -> dict[str, Any]:
        """``options`` as a dict, every key and the shape of ``params`` checked by name."""
        options = dict(options or {})
        route_options = ("route", "route_copy") if self.on_routes else ()
        allowed = ("start_kmh", "end_kmh", "accel", "params") + route_options + scenarios.OPTION_NAMES
        unknown = set(options) - set(allowed)
        if unknown:
            raise ConfigError(f"unknown reset option(s) {sorted(unknown)}; allowed: {', '.join(allowed)}")
        if self.on_routes and ("end_kmh" in options or "accel" in options):
            raise ConfigError("reset options 'end_kmh' and 'accel' are not allowed on routes: an episode runs its route at the "
                              "constant speed 'start_kmh' (default drawn from the route's range, config 'route.speed_kmh')")  # fmt: skip
        if not isinstance(options.get("params") or {}, Mapping):
            raise ConfigError(f"reset option 'params' = {options['params']!r} must be a mapping of parameter names "
                              "to scale factors, e.g. {'Csy': 0.5}")  # fmt: skip
        return options

    def _draw_speeds(self, rng: np.random.Generator, options: Mapping[str, Any]) -> tuple[float, float, float, Any]:
        """A row's start and end speed (km/h), its acceleration (m/s^2) and, on routes, its route
        slot (None on straight track), each given by ``options`` or drawn; checked against the
        range the integration step was chosen for."""
        sp = self.config["speed"]
        slot = None
        if self.on_routes:
            slot = self._draw_slot(rng, options)
            start = self._draw(rng, options.get("start_kmh"), 0.0, self.route_layout.speed_ranges_kmh[slot.route_index], "start_kmh")
            end, accel = start, 0.0
        else:
            start = self._draw(rng, options.get("start_kmh"), sp["start_kmh"], sp["start_kmh_range"], "start_kmh")
            end = self._draw(rng, options.get("end_kmh"), sp["end_kmh"], sp["end_kmh_range"], "end_kmh")
            accel = self._draw(rng, options.get("accel"), sp["accel"], sp["accel_range"], "accel")
        if not 0.0 <= accel <= MAX_ACCEL:
            raise ConfigError(f"reset option 'accel' = {accel:g} is not allowed; allowed: [0, {MAX_ACCEL:g}] m/s^2 "
                              "(the speed ramps up from start_kmh to end_kmh, or stays constant)")  # fmt: skip
        lo, hi = self.speed_limits()
        if not (lo - 1e-9 <= start / KMH and end / KMH <= hi + 1e-9 and start <= end):
            raise ConfigError(
                f"reset speeds start_kmh={start:g}, end_kmh={end:g} must satisfy "
                f"{lo * KMH:g} <= start_kmh <= end_kmh <= {hi * KMH:g} (the range the step size was chosen for; "
                "config 'speed.supported_kmh' widens it)"
            )
        return start, end, accel, slot

    def _draw_perturbation(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, bool]:
        """The initial perturbation: small normal offsets and yaws, or (with
        ``large_perturbation_probability``) offsets of 0.5-1 x ``large_perturbation`` with
        random signs. Returns the offsets, the yaws and whether the large perturbation was drawn."""
        sigma = self.config["initial_perturbation"]
        offsets = rng.normal(0.0, sigma, 3)
        yaws = rng.normal(0.0, sigma / (2 * self.base_params.L1), 3)
        large = False
        if self.config["large_perturbation_probability"] > 0 and rng.random() < self.config["large_perturbation_probability"]:
            size = self.config["large_perturbation"]
            offsets = rng.uniform(0.5, 1.0, 3) * size * rng.choice([-1.0, 1.0], 3)
            large = True
        return offsets, yaws, large

    @staticmethod
    def _start_state(coefficients: np.ndarray, start_kmh: float, offsets: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        """The equilibrium at the start speed plus the perturbation."""
        x = equilibrium_state(coefficients, start_kmh / KMH)
        x[_OFFSET_STATES] += offsets
        x[_YAW_STATES] += yaws
        return x

    def _draw_track_position(self, rng: np.random.Generator) -> float:
        """Where on the straight track's alignment profile a row starts (m); 0 on a perfect track."""
        alignment = self.track_input.alignment
        return uniform(rng, 0.0, alignment.length) if alignment.values.size else 0.0

    def _clear_episode(self, rows: np.ndarray | int, start_kmh: np.ndarray | float, slots: list[Any]) -> None:
        """The rows' (or one row's) episode bookkeeping, flags and info at the start of an
        episode (their start speeds and, on routes, their route slots)."""
        self.episode[rows] = 0.0
        self.episode[rows, E_ONSET_KMH] = np.nan
        if self.on_routes:
            self.episode[rows, E_END_DISTANCE] = np.reshape([slot.end_m for slot in slots], np.shape(rows))
            self.route_slot[rows] = np.reshape([self.route_layout.slots.index(slot) for slot in slots], np.shape(rows))
        else:
            self.episode[rows, E_END_DISTANCE] = np.inf
            self.route_slot[rows] = -1
        self.flags[rows] = 0
        self.info[rows] = 0.0
        self.info[rows, I_SPEED_KMH] = start_kmh
        self.info[rows, I_ONSET_KMH] = np.nan

    def ramp_rows(self, rows: np.ndarray, accel: float, end_kmh: float) -> None:
        """Change the speed ramp of running rows, e.g. ramp down (``accel`` < 0, m/s^2) to
        ``end_kmh``: the ramp-down method of the closed-loop nonlinear critical speed. The env's
        episodes only ramp up (``reset_rows``); this is for analyses."""
        if self.on_routes:
            raise ConfigError("ramp_rows is not allowed on routes: an episode runs its route at constant speed")
        if not (math.isfinite(accel) and abs(accel) <= MAX_ACCEL):
            raise ConfigError(f"ramp_rows accel = {accel!r} m/s^2 is not allowed; allowed: [-{MAX_ACCEL:g}, {MAX_ACCEL:g}]")
        lo, hi = self.speed_limits()
        if not lo * KMH - 1e-9 <= end_kmh <= hi * KMH + 1e-9:
            raise ConfigError(f"ramp_rows end_kmh = {end_kmh!r} is not allowed; allowed: the config's speed range "
                              f"[{lo * KMH:g}, {hi * KMH:g}] km/h (it sets the integration step; config "
                              "'speed.supported_kmh' widens it)")  # fmt: skip
        now = self.sim.motion[rows, M_SPEED] * KMH
        wrong = now < end_kmh - 1e-9 if accel < 0 else (now > end_kmh + 1e-9 if accel > 0 else np.zeros(now.shape, bool))
        if np.any(wrong):
            raise ConfigError(f"ramp_rows end_kmh = {end_kmh!r} is not allowed with accel = {accel!r}: the rows run at "
                              f"{float(np.atleast_1d(now)[np.atleast_1d(wrong)][0]):g} km/h, and a ramp down (accel < 0) "
                              "must end below that speed, a ramp up above it")  # fmt: skip
        self.sim.set_ramp(rows, float(accel), float(end_kmh) / KMH)

    def _draw_slot(self, rng: np.random.Generator, options: Mapping[str, Any]):
        """The layout slot of a new route episode: the route (option 'route', else uniform over the
        configured routes) and its copy (option 'route_copy', else uniform)."""
        layout = self.route_layout
        name = options.get("route")
        k = layout.index(name) if name is not None else int(rng.integers(len(layout.routes)))
        copies = self.config["route"]["copies"]
        copy = options.get("route_copy")
        if copy is None:
            copy = int(rng.integers(copies))
        elif isinstance(copy, bool) or not isinstance(copy, (int, np.integer)) or not 0 <= copy < copies:
            raise ConfigError(f"reset option 'route_copy' = {copy!r} is not allowed; allowed: an integer in [0, {copies - 1}] "
                              "(config 'route.copies')")  # fmt: skip
        return layout.slot(k, int(copy))

    def route_name(self, row: int = 0) -> str | None:
        """The route of row's episode (None on straight track)."""
        slot = self.route_slot[row]
        return None if slot < 0 else self.route_layout.routes[self.route_layout.slots[slot].route_index].name

    def _set_health(self, rows: np.ndarray | int, row_scenarios: list["scenarios.Scenario"]) -> None:
        """The rows' (or one row's) actuator health (after ``sim.set_rows``); a stuck channel
        holds its command from the first step (its lag and delay ring start at the held value)."""
        self.health[rows] = self._healthy
        self.health[rows, H_GAIN] = row_scenarios[0].actuator_gain if np.ndim(rows) == 0 else [s.actuator_gain for s in row_scenarios]
        for i, s in zip(np.atleast_1d(rows), row_scenarios):
            if s.failed_actuator is not None or s.stuck_actuator is not None:
                self._set_faulty_health(i, s)

    def _set_faulty_health(self, i: int, scenario: "scenarios.Scenario") -> None:
        self.health[i] = scenarios.scenario_health(scenario, self.channels)
        for k in range(N_CHANNELS):
            held_force, held_damping = self.health[i, H_HELD_FORCE, k], self.health[i, H_HELD_DAMPING, k]
            if not np.isnan(held_force):
                self.sim.lag[i, FORCE, k] = self.sim.delay[i, :, FORCE, k] = held_force
                self.sim.lag[i, DAMPING, k] = self.sim.delay[i, :, DAMPING, k] = held_damping

    def scenario(self, row: int = 0) -> dict[str, Any]:
        """What row's episode runs with: parameter factors, conicity, faults (JSON-friendly)."""
        return self.scenarios[row].as_dict()

    def scenario_summary(self, row: int = 0) -> dict[str, Any]:
        """Every value drawn (or pinned by a reset option) for row's episode, JSON-friendly: the
        :meth:`scenario` (parameter factors, conicity, suspension, creep, axle load, actuator
        gains and faults: ``failed_actuator`` and ``stuck_actuator`` are None when the episode has
        no such fault), then the speed ramp (``start_kmh``, ``end_kmh``, ``accel_m_per_s2``), the
        start position on the track (``track_position_m``; ``route`` and ``route_copy`` on
        routes, else None), the initial offsets and yaws added to the equilibrium
        (``initial_offset_m``, ``initial_yaw_rad``, ``large_perturbation``) and the sensor biases
        in SI units (``sensor_bias``, per channel; None with the sensor model off). The single
        and vector envs put it in the info of each reset as ``scenario``."""
        bias = dict(zip(SENSOR_NAMES, map(float, self.sensor_bias[row]))) if self.sensors_enabled else None
        return {**self.scenario(row), **self._draws_summary(row), "sensor_bias": bias}

    def _draws_summary(self, row: int) -> dict[str, Any]:
        """What ``reset_rows`` drew for row's episode besides the scenario (:meth:`scenario_summary`)."""
        if not self._episode_draws[row]:
            return {}
        start, end, accel, distance, slot, offsets, yaws, large = self._episode_draws[row]
        return {
            "start_kmh": start, "end_kmh": end, "accel_m_per_s2": accel, "track_position_m": distance,
            "route": self.route_layout.routes[slot.route_index].name if self.on_routes else None,
            "route_copy": int(slot.copy) if self.on_routes else None,
            "initial_offset_m": dict(zip(("y1", "y2", "yb"), map(float, offsets))),
            "initial_yaw_rad": dict(zip(("psi1", "psi2", "psib"), map(float, yaws))),
            "large_perturbation": large,
        }  # fmt: skip

    @staticmethod
    def _draw(rng, forced, value, bounds, name) -> float:
        if forced is not None:
            if isinstance(forced, bool) or not isinstance(forced, (int, float)) or not math.isfinite(forced):
                raise ConfigError(f"reset option {name!r} = {forced!r} must be a finite number")
            return float(forced)
        return uniform(rng, *bounds) if bounds else float(value)

    def set_states(self, states: np.ndarray, rows: np.ndarray | slice = slice(None)) -> None:
        """Replace the bogie states of some rows (e.g. starts on a limit cycle) and refresh their
        observations."""
        self.sim.x[rows] = states
        self.observe(np.arange(self.num_envs)[rows])

    def observe(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Recompute the observations of ``rows`` (default all) from the current state, without
        noise; returns :attr:`obs`."""
        rows = np.arange(self.num_envs) if rows is None else np.atleast_1d(np.asarray(rows, dtype=np.int64))
        _observe_rows(rows, self.sim.rows, self.channels, self.obs, self.settings, self.state_scales)
        return self.obs

    # ---- stepping -------------------------------------------------------------------------------
    def _action_array(self, actions: Any) -> np.ndarray:
        """The actions as an (N, action_dim) float array (a view where possible); bad shapes raise."""
        if isinstance(actions, np.ndarray) and actions.dtype in _FLOAT_TYPES:
            a = actions
        else:
            try:
                a = np.asarray(actions, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"action {actions!r:.60} is not an array of numbers; expected shape "
                                 f"({self.num_envs}, {self.action_dim}) in [-1, 1]") from None  # fmt: skip
        if a.shape != (self.num_envs, self.action_dim):
            if self.num_envs == 1 and a.shape == (self.action_dim,):
                return a[None, :]
            raise ValueError(
                f"action has shape {np.shape(actions)}; expected ({self.num_envs}, {self.action_dim})"
                + (f" or ({self.action_dim},)" if self.num_envs == 1 else "")
            )
        return a

    def _raise_non_finite(self, a: np.ndarray, flat: int) -> None:
        row, col = divmod(flat, self.action_dim)
        raise ValueError(
            f"action contains NaN or inf (env {row}, component {col}: {a[row, col]!r}); "
            "actions must be finite and are clipped to [-1, 1]"
        )

    def check_actions(self, actions: Any) -> np.ndarray:
        """(N, action_dim) finite actions, clipped to [-1, 1]; anything else raises."""
        a = self._action_array(actions)
        bad = _clip_actions(a, self.actions)
        if bad >= 0:
            self._raise_non_finite(a, bad)
        return self.actions

    def step(self, actions: Any) -> None:
        """Advance every row by one env step (nothing is stepped if an action is bad)."""
        a = self._action_array(actions)
        if self.loops.enabled:
            bad = self.loops.run(_step_serial, _step_checked_parallel, a, *self._step_args())
        else:  # always the calling thread: one packed argument is cheaper to dispatch
            if self._packed_step_args is None:
                self._packed_step_args = _pack_step_args(*self._step_args())
            bad = _step_serial_packed(a, self._packed_step_args)
        if bad >= 0:
            self._raise_non_finite(a, bad)
        if self.config["observation"]["noise"] > 0:
            self._add_noise(np.arange(self.num_envs))

    def __getstate__(self) -> dict[str, Any]:
        """Pickle and deepcopy without the packed step arguments (a compiled object; rebuilt from
        the copy's own arrays at its first step)."""
        state = self.__dict__.copy()
        state["_packed_step_args"] = None
        return state

    def _step_args(self) -> tuple:
        """The step kernels' arguments after the actions (:data:`STEP_ARG_NAMES`). Packed once, at
        the first step, for the calling thread's loop: arrays replaced after that are not seen."""
        sim = self.sim
        return (sim.rows, self.channels, sim._track, sim.dt, sim.n_sub, sim.divisors, self.actions, self._task_rows, self.settings,
                self.state_scales, self.health, self.sensing)  # fmt: skip

    def _add_noise(self, rows: np.ndarray) -> None:
        noise = self.config["observation"]["noise"]
        if noise > 0:
            for i in np.atleast_1d(rows):
                self.obs[i] += (noise * self.rngs[i].standard_normal(self.observation_dim)).astype(np.float32)
            np.clip(self.obs, -OBS_BOUND, OBS_BOUND, out=self.obs)

    # ---- vocabulary -------------------------------------------------------------------------------
    @property
    def states(self) -> np.ndarray:
        """(N, 20) bogie states (a view; ``bogie_env.STATE_NAMES``)."""
        return self.sim.x

    x = states

    @property
    def P(self) -> np.ndarray:
        """(N, K) bogie coefficients of each row (a view)."""
        return self.sim.coefficients

    @property
    def track(self):
        """The track's alignment profile."""
        return self.track_input.alignment

    @property
    def speed_kmh(self) -> np.ndarray:
        return self.sim.motion[:, M_SPEED] * KMH

    @property
    def distance_m(self) -> np.ndarray:
        return self.sim.motion[:, M_DISTANCE]

    @property
    def terminated(self) -> np.ndarray:
        return self.flags[:, F_TERMINATED].astype(bool)

    @property
    def truncated(self) -> np.ndarray:
        """Reached the end speed (the front-ends add their step limit)."""
        return self.flags[:, F_TRUNCATED].astype(bool)

    @property
    def done(self) -> np.ndarray:
        return self.terminated | self.truncated

    @property
    def hunting(self) -> np.ndarray:
        return self.flags[:, F_HUNTING].astype(bool)

    @property
    def blowup(self) -> np.ndarray:
        return self.flags[:, F_BLOWUP].astype(bool)

    @property
    def wear_number_n(self) -> np.ndarray:
        """(N, 2) wear number Tγ of each wheelset at the end of the step, N (route variant; else 0)."""
        return self.info[:, I_WEAR1 : I_WEAR1 + 2]

    @property
    def flange_contact(self) -> np.ndarray:
        """(N, 2) each wheelset in flange contact at the end of the step (route variant)."""
        return self.info[:, I_FLANGE1 : I_FLANGE1 + 2] > 0.5

    @property
    def y_over_q(self) -> np.ndarray:
        """(N,) the largest wheel Y/Q at the end of the step (route variant)."""
        return self.info[:, I_Y_OVER_Q]

    @property
    def guiding_force_n(self) -> np.ndarray:
        """(N, 2) sum of guiding forces ΣY of each wheelset, N (route variant)."""
        return self.info[:, I_GUIDING1 : I_GUIDING1 + 2]

    @property
    def curvature_1pm(self) -> np.ndarray:
        """(N,) track curvature under the frame, 1/m, + left (route variant)."""
        return self.info[:, I_CURVATURE]

    @property
    def cant_deficiency_m(self) -> np.ndarray:
        """(N,) cant deficiency at the frame, m (+ towards the outside of the curve; route variant)."""
        return self.info[:, I_CANT_DEFICIENCY]

    @property
    def onset_speed_kmh(self) -> np.ndarray:
        """Speed where hunting was detected, km/h (NaN until then)."""
        return self.info[:, I_ONSET_KMH]

    @property
    def lateral_rms_m(self) -> np.ndarray:
        """(N, 2) the detector's rms of each wheelset's displacement relative to the rail."""
        return self.info[:, I_RMS1 : I_RMS2 + 1]

    @property
    def relative_lateral_m(self) -> np.ndarray:
        """(N, 2) each wheelset's lateral displacement relative to the rail now."""
        return self.sim.x[:, [Y1, Y2]] - self.sim.track_sample[:, [ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2]]

    @property
    def actuator_force(self) -> np.ndarray:
        """(N, N_CHANNELS) channel forces at the end of the step (N or N m), all channels."""
        return self.info[:, I_FORCE : I_FORCE + N_CHANNELS]

    @property
    def actuator_power(self) -> np.ndarray:
        """(N, N_CHANNELS) mean mechanical power per channel over the step (W; < 0 dissipated)."""
        return self.info[:, I_POWER : I_POWER + N_CHANNELS]

    @property
    def actuator_limits(self) -> np.ndarray:
        """(N_CHANNELS,) each channel's max_force as configured."""
        return np.array([self.config["actuators"][name]["max_force"] for name in CHANNEL_NAMES])

    @property
    def flange_clearance(self) -> np.ndarray:
        """(N,) each row's flange clearance delta, m."""
        return self.sim.coefficients[:, P_DELTA]

    def delta(self, row: int = 0) -> float:
        return float(self.sim.coefficients[row, P_DELTA])

    def episode_end(self, row: int) -> tuple[bool, bool]:
        """(terminated, truncated at the end speed) of one row after its last step."""
        flags = self.flags[row]
        return bool(flags[F_TERMINATED]), bool(flags[F_TRUNCATED])

    def criterion_quantities(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The :data:`CRITERION_FIELDS` of ``rows`` (default all) now, each with the rows as its
        first axis: what a running-stability or safety criterion (EN 14363) is built from, from
        the simulator's state and contact (:func:`_criterion_rows`)."""
        rows = np.arange(self.num_envs) if rows is None else np.atleast_1d(np.asarray(rows, dtype=np.int64))
        out = np.empty((rows.size, N_CRITERION))
        sim = self.sim
        _criterion_rows(rows, sim.x, sim.motion, sim.coefficients, sim.track_sample, out)
        return self._criterion_columns(out)

    @staticmethod
    def _criterion_columns(out: np.ndarray) -> dict[str, np.ndarray]:
        k = out.shape[0]
        flags = out[:, K_FLANGE_WHEEL1:] > 0.5
        values = {
            "wheelset_lateral_rel_rail_m": out[:, K_REL1 : K_REL1 + 2],
            "flange_contact": flags[:, 4:6],
            "wheel_flange_contact": flags[:, :4].reshape(k, 2, 2),
            "sum_y_n": out[:, K_SUM_Y1 : K_SUM_Y1 + 2],
            "wheel_y_over_q": out[:, K_Y_OVER_Q1 : K_Y_OVER_Q1 + 4].reshape(k, 2, 2),
            "y_over_q": out[:, K_Y_OVER_Q_MAX],
        }
        assert tuple(values) == tuple(CRITERION_FIELDS)
        return values

    def _criterion_info(self, rows: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """The criterion fields for the infos (only with config ``info.criterion``); on
        routes ``flange_contact`` and ``y_over_q`` stay the route variant's own (the same
        quantities, computed in the step)."""
        if not self._criterion_on:
            return {}
        values = self.criterion_quantities(rows)
        if self.on_routes:
            del values["flange_contact"], values["y_over_q"]
        return values

    def info_dict(self, row: int) -> dict[str, Any]:
        """The step info of one environment (see ``BogieHuntingEnv``)."""
        info = self.info[row].copy()  # the arrays below are views of this copy
        values = info.tolist()
        flags = self.flags[row].tolist()
        onset = values[I_ONSET_KMH]
        return {
            "speed_kmh": values[I_SPEED_KMH],
            "hunting": bool(flags[F_HUNTING]),
            "onset_speed_kmh": None if onset != onset else onset,
            "lateral_rms_m": info[I_RMS1 : I_RMS2 + 1],
            "actuator_force": info[I_FORCE : I_FORCE + N_CHANNELS],
            "actuator_power": info[I_POWER : I_POWER + N_CHANNELS],
            "blowup": bool(flags[F_BLOWUP]),
            **(self._curving_info(info, flags) if self.on_routes else {}),
            **(self._criterion_row_info(row) if self._criterion_on else {}),
        }

    def _criterion_row_info(self, row: int) -> dict[str, Any]:
        """One row's criterion fields (:data:`CRITERION_FIELDS`; on routes without the route
        variant's own ``flange_contact`` and ``y_over_q``): the single env's per-step path."""
        sim, rows, out = self.sim, self._one_row, self._one_out
        rows[0] = row
        _criterion_rows(rows, sim.x, sim.motion, sim.coefficients, sim.track_sample, out)
        o = out[0].copy()  # the arrays below are views of this copy
        flags = o[K_FLANGE_WHEEL1:] > 0.5
        values = {
            "wheelset_lateral_rel_rail_m": o[K_REL1 : K_REL1 + 2],
            "flange_contact": flags[4:6],
            "wheel_flange_contact": flags[:4].reshape(2, 2),
            "sum_y_n": o[K_SUM_Y1 : K_SUM_Y1 + 2],
            "wheel_y_over_q": o[K_Y_OVER_Q1 : K_Y_OVER_Q1 + 4].reshape(2, 2),
            "y_over_q": float(o[K_Y_OVER_Q_MAX]),
        }
        if self.on_routes:
            del values["flange_contact"], values["y_over_q"]
        return values

    @staticmethod
    def _curving_info(info: np.ndarray, flags: list) -> dict[str, Any]:
        """The route variant's info: curving quantities at the end of the step (see
        ``BogieHuntingEnv``, "Bogie/HuntingRoute-v1")."""
        return {
            "wear_number_n": info[I_WEAR1 : I_WEAR1 + 2],
            "flange_contact": info[I_FLANGE1 : I_FLANGE1 + 2] > 0.5,
            "y_over_q": float(info[I_Y_OVER_Q]),
            "guiding_force_n": info[I_GUIDING1 : I_GUIDING1 + 2],
            "curvature_1pm": float(info[I_CURVATURE]),
            "cant_deficiency_m": float(info[I_CANT_DEFICIENCY]),
            "y_over_q_exceeded": bool(flags[F_Y_OVER_Q]),
        }

    def batched_infos(self) -> dict[str, np.ndarray]:
        """Gymnasium vector infos: arrays plus boolean ``_key`` masks (all True)."""
        values = {
            "speed_kmh": self.info[:, I_SPEED_KMH].copy(),
            "hunting": self.hunting,
            "onset_speed_kmh": self.onset_speed_kmh.copy(),
            "lateral_rms_m": self.lateral_rms_m.copy(),
            "actuator_force": self.actuator_force.copy(),
            "actuator_power": self.actuator_power.copy(),
            "blowup": self.blowup,
        }
        if self.on_routes:
            values.update({
                "wear_number_n": self.wear_number_n.copy(),
                "flange_contact": self.flange_contact.copy(),
                "y_over_q": self.info[:, I_Y_OVER_Q].copy(),
                "guiding_force_n": self.guiding_force_n.copy(),
                "curvature_1pm": self.info[:, I_CURVATURE].copy(),
                "cant_deficiency_m": self.info[:, I_CANT_DEFICIENCY].copy(),
                "y_over_q_exceeded": self.flags[:, F_Y_OVER_Q].astype(bool),
            })  # fmt: skip
        values.update(self._criterion_info())
        mask = np.ones(self.num_envs, dtype=bool)
        out: dict[str, np.ndarray] = {}
        for key, value in values.items():
            out[key] = value
            out[f"_{key}"] = mask.copy()
        return out

    def max_episode_steps(self) -> int:
        return max_steps_for(self.config)
