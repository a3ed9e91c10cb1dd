"""The compiled task step shared by every environment front-end.

One call advances N environments by one control interval: actions to actuator targets
(with per-channel delay), the RK4 interval of :mod:`bogie_env.integrate` (speed ramp, track
alignment, lagged and saturated actuators), then the observation, reward, hunting detector
and episode flags. The single env, the Gymnasium vector env and the SB3 VecEnv all call
this kernel, so their trajectories are identical for the same seeds.

Per-row arrays (N rows):
- ``x`` (N, 20): bogie states.
- ``scal`` (N, N_SCALARS): speed, ramp rate, distance, end speed, the two wheelsets'
  mean-square relative displacement (exponentially weighted over ``window_m`` of track),
  onset speed (km/h, NaN until hunting) and the step counter.
- ``act`` (N, 8): the channels' current lagged force targets (0:4) and damping (4:8).
- ``delay`` (N, MAX_DELAY + 1, 8): recent (force, damping) targets, for command delays.
- ``action`` (N, n_actions) float64 in [-1, 1] (checked and clipped by the caller).
- ``P`` (N, K): bogie coefficients per row (parameter randomisation).
Shared: ``cfg`` (layout below) and the track ``profile``.
Outputs: ``obs`` (N, n_obs) float32, ``reward`` (N,), ``flags`` (N, 4) int8 =
(terminated, truncated, hunting, blow-up), ``info`` (N, N_INFO) float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ..dynamics import N_INPUTS, N_STATES, P_DELTA, P_L1, _rhs_row
from ..integrate import FASTMATH, N_CHUNKS, STATUS_OK, WORK_SIZE, _advance_row, _track_at, chunk_bounds
from .config import MAX_DELAY_STEPS

# ---- per-row scalar columns ------------------------------------------------------------
S_SPEED, S_ACCEL, S_DIST, S_VEND, S_MS1, S_MS2, S_ONSET, S_STEPS = range(8)
N_SCALARS = 8
DELAY_SLOTS = MAX_DELAY_STEPS + 1

# ---- info columns --------------------------------------------------------------------------
I_SPEED_KMH, I_ONSET_KMH, I_RMS1, I_RMS2 = range(4)
I_FORCE = 4  # 4 columns: channel forces (N or N m)
I_POWER = 8  # 4 columns: mean mechanical power delivered by each channel over the step (W)
N_INFO = 12

# ---- shared config vector ------------------------------------------------------------------
(C_DT, C_NSUB, C_INV_DX, C_OBS_STATE, C_OBS_ACT, C_W_LAT, C_W_YAW, C_W_EFF, C_W_TIME, C_YAW_REF,
 C_WINDOW_M, C_HUNT_RMS_FRACTION, C_BLOWUP, C_N_ACTIVE) = range(14)  # fmt: skip
C_CHANNELS = 14  # then per channel k: CH_FIELDS values at C_CHANNELS + k * CH_FIELDS
CH_MODE, CH_MAX, CH_CMIN, CH_CMAX, CH_DECAY, CH_DELAY, CH_ACTION = range(7)
CH_FIELDS = 7
C_STATE_SCALES = C_CHANNELS + N_INPUTS * CH_FIELDS  # 20 state scales (state observation)
N_CFG = C_STATE_SCALES + N_STATES

MODE_OFF, MODE_FORCE, MODE_SEMI = 0, 1, 2
OBS_BOUND = 10.0
N_SENSORS = 7  # frame lateral accel, frame yaw rate, 2 relative lateral, 2 relative yaw, speed

# sensor scales: what counts as "1" in the observation
ACCEL_SCALE = 5.0  # m/s^2
YAW_RATE_SCALE = 0.1  # rad/s
REL_YAW_SCALE = 5e-3  # rad
SPEED_CENTRE_KMH = 450.0
SPEED_SCALE_KMH = 150.0


@njit(cache=True, inline="always")
def _clip(value, bound):
    return min(max(value, -bound), bound)


@njit(cache=True, inline="always")
def _task_row(n, x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info, work):
    tmp20 = work[WORK_SIZE : WORK_SIZE + 20]
    q4 = work[WORK_SIZE + 20 : WORK_SIZE + 24]
    yt2 = work[WORK_SIZE + 24 : WORK_SIZE + 26]
    f_t = work[WORK_SIZE + 26 : WORK_SIZE + 30]
    c_t = work[WORK_SIZE + 30 : WORK_SIZE + 34]
    u_max = work[WORK_SIZE + 34 : WORK_SIZE + 38]
    decay = work[WORK_SIZE + 38 : WORK_SIZE + 42]
    u_end = work[WORK_SIZE + 42 : WORK_SIZE + 46]
    power = work[WORK_SIZE + 46 : WORK_SIZE + 50]
    p = P[n]
    dt = cfg[C_DT]
    n_sub = int(cfg[C_NSUB])
    inv_dx = cfg[C_INV_DX]
    steps = int(scal[n, S_STEPS])
    head = steps % DELAY_SLOTS
    # 1. actions -> this step's targets, into the delay ring buffer
    for k in range(N_INPUTS):
        base = C_CHANNELS + k * CH_FIELDS
        mode = int(cfg[base + CH_MODE])
        j = int(cfg[base + CH_ACTION])
        a = action[n, j] if j >= 0 else 0.0
        force = 0.0
        damping = 0.0
        if mode == MODE_FORCE:
            force = a * cfg[base + CH_MAX]
        elif mode == MODE_SEMI:
            damping = cfg[base + CH_CMIN] + 0.5 * (a + 1.0) * (cfg[base + CH_CMAX] - cfg[base + CH_CMIN])
        delay[n, head, k] = force
        delay[n, head, 4 + k] = damping
        slot = (head - int(cfg[base + CH_DELAY])) % DELAY_SLOTS
        if steps < int(cfg[base + CH_DELAY]):
            f_t[k] = 0.0  # nothing commanded yet: the actuator holds still
            c_t[k] = 0.0
        else:
            f_t[k] = delay[n, slot, k]
            c_t[k] = delay[n, slot, 4 + k]
        u_max[k] = cfg[base + CH_MAX] if mode != MODE_OFF else 0.0
        decay[k] = cfg[base + CH_DECAY]
    # 2. the interval: speed ramp capped at the end speed
    v0 = scal[n, S_SPEED]
    a_lin = scal[n, S_ACCEL]
    room = (scal[n, S_VEND] - v0) / dt
    if a_lin > room:
        a_lin = max(room, 0.0)
    s0 = scal[n, S_DIST]
    f_start = act[n, 0:4]
    c_start = act[n, 4:8]
    status = _advance_row(x[n], v0, a_lin, s0, dt, n_sub, f_start, f_t, c_start, c_t, decay, u_max, profile, inv_dx, p, u_end, power, work)
    v1 = v0 + a_lin * dt
    s1 = s0 + v0 * dt + 0.5 * a_lin * dt * dt
    scal[n, S_SPEED] = v1
    scal[n, S_DIST] = s1
    scal[n, S_STEPS] = steps + 1
    for k in range(N_INPUTS):  # lag states at the end of the interval (exact first order)
        w = math.exp(-decay[k] * dt)
        act[n, k] = f_t[k] + (f_start[k] - f_t[k]) * w
        act[n, 4 + k] = c_t[k] + (c_start[k] - c_t[k]) * w
    # 3. hunting detector: exponentially weighted mean square over window_m of track
    L1 = p[P_L1]
    delta = p[P_DELTA]
    yt2[0] = _track_at(profile, inv_dx, s1 + L1)
    yt2[1] = _track_at(profile, inv_dx, s1 - L1)
    y_rel1 = x[n, 0] - yt2[0]
    y_rel2 = x[n, 8] - yt2[1]
    weight = 1.0 - math.exp(-dt * v1 / cfg[C_WINDOW_M])
    scal[n, S_MS1] += weight * (y_rel1 * y_rel1 - scal[n, S_MS1])
    scal[n, S_MS2] += weight * (y_rel2 * y_rel2 - scal[n, S_MS2])
    rms1 = math.sqrt(max(scal[n, S_MS1], 0.0))
    rms2 = math.sqrt(max(scal[n, S_MS2], 0.0))
    blowup = status != STATUS_OK or abs(y_rel1) > cfg[C_BLOWUP] or abs(y_rel2) > cfg[C_BLOWUP]
    hunting = max(rms1, rms2) > cfg[C_HUNT_RMS_FRACTION] * delta
    if hunting and math.isnan(scal[n, S_ONSET]):
        scal[n, S_ONSET] = v1 * 3.6
    terminated = hunting or blowup
    truncated = (not terminated) and v1 >= scal[n, S_VEND] - 1e-9 and scal[n, S_ACCEL] > 0.0
    flags[n, 0] = 1 if terminated else 0
    flags[n, 1] = 1 if truncated else 0
    flags[n, 2] = 1 if hunting else 0
    flags[n, 3] = 1 if blowup else 0
    # 4. reward: progress (km/h gained, plus optional time) times (1 - bounded penalties)
    psi_ref = cfg[C_YAW_REF]
    lat_pen = 0.5 * (min((y_rel1 / delta) ** 2, 1.0) + min((y_rel2 / delta) ** 2, 1.0))
    d1 = (x[n, 4] - x[n, 18]) / psi_ref
    d2 = (x[n, 12] - x[n, 18]) / psi_ref
    yaw_pen = 0.5 * (min(d1 * d1, 1.0) + min(d2 * d2, 1.0))
    eff_pen = 0.0
    n_active = cfg[C_N_ACTIVE]
    for k in range(N_INPUTS):
        if u_max[k] > 0.0:
            eff_pen += min((u_end[k] / u_max[k]) ** 2, 1.0)
    if n_active > 0:
        eff_pen /= n_active
    penalty = cfg[C_W_LAT] * lat_pen + cfg[C_W_YAW] * yaw_pen + cfg[C_W_EFF] * eff_pen
    progress = (v1 - v0) * 3.6 + cfg[C_W_TIME] * dt
    reward[n] = progress * (1.0 - penalty) if not blowup else 0.0
    # 5. info
    info[n, I_SPEED_KMH] = v1 * 3.6
    info[n, I_ONSET_KMH] = scal[n, S_ONSET]
    info[n, I_RMS1] = rms1
    info[n, I_RMS2] = rms2
    for k in range(N_INPUTS):
        info[n, I_FORCE + k] = u_end[k]
        info[n, I_POWER + k] = power[k]
    # 6. observation
    _observe(n, x, v1, p, yt2, u_end, u_max, cfg, obs, tmp20, q4)


@njit(cache=True, inline="always")
def _observe(n, x, v1, p, yt2, u_end, u_max, cfg, obs, tmp20, q4):
    m = 0
    if cfg[C_OBS_STATE] > 0.5:
        for i in range(N_STATES):
            obs[n, i] = _clip(x[n, i] / cfg[C_STATE_SCALES + i], OBS_BOUND)
        m = N_STATES
    else:
        # frame lateral acceleration needs the right-hand side at the end state
        q4[0] = u_end[0]
        q4[1] = u_end[1] - u_end[2] - u_end[3]
        q4[2] = u_end[2]
        q4[3] = u_end[3]
        _rhs_row(x[n], v1, q4, yt2, p, tmp20)
        L1 = p[P_L1]
        delta = p[P_DELTA]
        psib = x[n, 18]
        obs[n, 0] = _clip(tmp20[17] / ACCEL_SCALE, OBS_BOUND)
        obs[n, 1] = _clip(x[n, 19] / YAW_RATE_SCALE, OBS_BOUND)
        obs[n, 2] = _clip((x[n, 0] - x[n, 16] - L1 * psib) / delta, OBS_BOUND)
        obs[n, 3] = _clip((x[n, 8] - x[n, 16] + L1 * psib) / delta, OBS_BOUND)
        obs[n, 4] = _clip((x[n, 4] - psib) / REL_YAW_SCALE, OBS_BOUND)
        obs[n, 5] = _clip((x[n, 12] - psib) / REL_YAW_SCALE, OBS_BOUND)
        m = 6
    obs[n, m] = _clip((v1 * 3.6 - SPEED_CENTRE_KMH) / SPEED_SCALE_KMH, OBS_BOUND)
    m += 1
    if cfg[C_OBS_ACT] > 0.5:
        for k in range(N_INPUTS):
            if u_max[k] > 0.0:
                obs[n, m] = _clip(u_end[k] / u_max[k], OBS_BOUND)
                m += 1


# Two batch loops over one compiled run-of-rows function. The parallel one serves large batches;
# below PARALLEL_MIN_ROWS rows the serial one runs on the calling thread, because waking the
# worker threads costs more than a few rows and, when another process keeps the cores busy
# (training beside an evaluation), the OpenMP barrier can take milliseconds instead of
# microseconds. Inlining the rows into each loop would let fastmath order the row arithmetic
# differently in the two compilations (it did: trajectories differed in the last bits);
# tests/test_envs.py checks that a row's trajectory is bitwise the same in a 4-row (serial) and
# a 64-row (parallel) batch.
PARALLEL_MIN_ROWS = 32


# Not inlined at numba level: both batch loops below call this one compilation of a run of
# rows, so a row's arithmetic is the same whichever loop runs it. It takes a run of rows, not
# one row, because every call increments and decrements the shared arrays' reference counts,
# and per row those atomic updates made the threads fight over the same cache lines.
# error_model="numpy": no division-by-zero checks (a zero divisor gives inf/nan, which the row's
# finiteness check turns into a blow-up); measured about 10 % faster at N = 4096.
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _task_rows(start, stop, x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info, work):
    for n in range(start, stop):
        _task_row(n, x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info, work)


@njit(cache=True, fastmath=FASTMATH, parallel=True)
def task_step_parallel(x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info):
    n_rows = x.shape[0]
    n_chunks = min(n_rows, N_CHUNKS)
    for c in prange(n_chunks):
        work = np.empty(WORK_SIZE + 50)  # one scratch buffer per chunk (see integrate._advance_row)
        start, stop = chunk_bounds(n_rows, n_chunks, c)
        _task_rows(start, stop, x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info, work)


@njit(cache=True, fastmath=FASTMATH)
def task_step_serial(x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info):
    work = np.empty(WORK_SIZE + 50)
    _task_rows(0, x.shape[0], x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info, work)


def task_step(x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info) -> None:
    """Advance every row by one env step (actions -> actuators -> RK4 interval -> observation,
    reward, hunting detector, flags), in place."""
    kernel = task_step_parallel if x.shape[0] >= PARALLEL_MIN_ROWS else task_step_serial
    kernel(x, scal, act, delay, action, P, cfg, profile, obs, reward, flags, info)


@njit(cache=True, fastmath=FASTMATH)
def task_observe(x, scal, act, P, cfg, profile, obs):
    """Observations without stepping (after a reset); actuators at rest."""
    tmp20 = np.empty(N_STATES)
    q4 = np.empty(N_INPUTS)
    yt2 = np.empty(2)
    u_end = np.zeros(N_INPUTS)
    u_max = np.empty(N_INPUTS)
    for n in range(x.shape[0]):
        for k in range(N_INPUTS):
            base = C_CHANNELS + k * CH_FIELDS
            u_max[k] = cfg[base + CH_MAX] if int(cfg[base + CH_MODE]) != MODE_OFF else 0.0
        p = P[n]
        inv_dx = cfg[C_INV_DX]
        yt2[0] = _track_at(profile, inv_dx, scal[n, S_DIST] + p[P_L1])
        yt2[1] = _track_at(profile, inv_dx, scal[n, S_DIST] - p[P_L1])
        _observe(n, x, scal[n, S_SPEED], p, yt2, u_end, u_max, cfg, obs, tmp20, q4)

