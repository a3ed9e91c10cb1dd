"""The one owner of per-bogie state and the one batch driver.

:class:`BatchSimulator` holds, per bogie (row): the 20 states, the motion (speed, ramp rate,
end speed, distance travelled, step count), the bogie coefficients (rows may differ:
parameter randomisation), the actuator channels' lag states, delay ring, commands and
outputs, the track under the wheelsets, and a status code. :func:`advance_rows` is the one
compiled function that advances rows by one control interval; every user steps through it:
:meth:`BatchSimulator.step` (analyses), :meth:`BatchSimulator.run` (recorded runs, e.g. speed
ramps) and the environments' task step (:mod:`bogie_env.envs.task`).

Per interval and row: the channel commands pass through their delays
(:func:`bogie_env.actuators.delayed_targets`); the speed ramps at the row's rate and stops at
its end speed; :func:`bogie_env.integrate._advance_lanes` integrates the interval (blocks of
:data:`bogie_env.lanes.LANES` rows in SIMD lanes); the lag
states, speed, distance and track samples move to the end of the interval.

Thread use (:class:`LoopChooser`): below :data:`PARALLEL_MIN_ROWS` rows a batch runs on the
calling thread; above, on the calling thread or on numba's thread pool of ``num_threads``
threads (argument, env config key ``num_threads``, environment variable ``BOGIE_NUM_THREADS``;
default the usable cores), whichever has been faster lately. A row's arithmetic is the same
whichever loop runs it, so trajectories do not depend on the batch size, the loop or the
thread count (``tests/test_integrate.py``, ``tests/test_envs.py``).
"""

from __future__ import annotations

import math
import os
import time

import numba
import numpy as np
from numba import njit, prange

from .actuators import CH_DECAY_RATE, DAMPING, DELAY_SLOTS, FORCE, N_CHANNELS, advance_lag, channel_table, delayed_targets, lag_weights
from .dynamics import N_COEFFICIENTS, N_STATES, P_L1, BogieModel, check_speed
from .integrate import (
    FASTMATH, METHOD_DIVISORS, N_SCRATCH, STATUS_OK, _advance_lanes, _advance_lanes_taylor, method_divisors, stable_substep,
    taylor_lag_weights,
)  # fmt: skip
from .lanes import LANES, stack_array
from .track import ALIGNMENT_SAMPLES, N_TRACK_SAMPLES, TrackInput, TrackProfile, prefetch_track, sample_track

# ---- columns of a row's motion -----------------------------------------------------------------
MOTION_FIELDS = ("speed", "accel", "end_speed", "distance", "steps", "start_speed")
M_SPEED, M_ACCEL, M_END_SPEED, M_DISTANCE, M_STEPS, M_START_SPEED = range(len(MOTION_FIELDS))
# speed (m/s) now; nominal ramp rate (m/s^2); speed where the ramp stops (m/s); distance travelled
# (m); intervals run since the row was set; speed at the start of the last interval (m/s).

# ---- the per-row arrays, in the order of the compiled ``rows`` tuple ---------------------------
ROW_ARRAYS = ("x", "motion", "coefficients", "lag", "delay", "command", "output", "track_sample", "status")

# ---- threads -------------------------------------------------------------------------------------
#: Batches smaller than this run on the calling thread: waking the pool costs more than a few
#: rows, and on a busy host a barrier can take milliseconds (docs/performance.md).
PARALLEL_MIN_ROWS = 256
N_CHUNKS = 64  # parallel loops run over contiguous chunks of rows


def default_num_threads() -> int:
    """``BOGIE_NUM_THREADS`` if set, else numba's pool size capped at the usable cores."""
    value = os.environ.get("BOGIE_NUM_THREADS")
    if value is not None:
        try:
            n = int(value)
        except ValueError:
            raise ValueError(f"BOGIE_NUM_THREADS = {value!r} must be an integer >= 1") from None
        if n < 1:
            raise ValueError(f"BOGIE_NUM_THREADS = {value!r} must be an integer >= 1")
        return min(n, numba.config.NUMBA_NUM_THREADS)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, numba.config.NUMBA_NUM_THREADS))


class LoopChooser:
    """Runs a batch on the calling thread or on the thread pool, whichever has been faster.

    Below :data:`PARALLEL_MIN_ROWS` rows, or with one thread, always the calling thread. Above:

    - the first call loads both loops' kernels (the calling thread's by its signature, without
      running it) and runs on the pool, untimed: kernel loading and the pool's start are paid
      there, by the call a user treats as the warm-up, not by the calls after it;
    - the next :attr:`CALIBRATION_ROUNDS` pairs of calls alternate the calling thread and the
      pool, each loop's figure the fastest of its calls (a busy host slows single calls, not
      the loop);
    - then it keeps the faster loop, trying the other one every :attr:`PROBE_EVERY` calls.

    On an idle 2-core host the pool wins at large batches, on a busy one its barriers can make it
    several times slower than the calling thread. Results do not depend on the choice (a row's
    arithmetic is the same in both loops).
    """

    PROBE_EVERY = 100
    CALIBRATION_ROUNDS = 2  # pairs of timed calls (calling thread, pool) after the warm-up call

    def __init__(self, n_rows: int, num_threads: int) -> None:
        self.num_threads = int(num_threads)
        self.enabled = n_rows >= PARALLEL_MIN_ROWS and self.num_threads > 1
        self.seconds = [math.nan, math.nan]  # recent seconds per call: calling thread, pool
        self.loop_calls = [0, 0]
        self.calls = 0

    @property
    def calibrating(self) -> bool:
        return self.calls <= 1 + 2 * self.CALIBRATION_ROUNDS

    def choose(self) -> int:
        """0: the calling thread, 1: the pool (``calls`` counts this call)."""
        if self.calls <= 1:
            return 1  # the warm-up call
        if self.calibrating:
            return self.calls % 2  # calls 2, 4, ...: the calling thread; 3, 5, ...: the pool
        best = 1 if self.seconds[1] < self.seconds[0] else 0
        return 1 - best if self.calls % self.PROBE_EVERY == 0 else best

    def record(self, loop: int, elapsed: float) -> None:
        """The warm-up call is not timed; while calibrating a loop keeps its fastest call; then a
        probe's time replaces the other loop's old estimate (probes are rare, and a stale slow
        figure must not outlive a change of load) and the loop in use is smoothed."""
        self.loop_calls[loop] += 1
        if self.calls <= 1:
            return
        old = self.seconds[loop]
        if self.calibrating:
            self.seconds[loop] = elapsed if math.isnan(old) else min(old, elapsed)
            return
        in_use = not math.isnan(self.seconds[1 - loop]) and not math.isnan(old) and old <= self.seconds[1 - loop]
        self.seconds[loop] = 0.7 * old + 0.3 * elapsed if in_use else elapsed

    def run(self, serial, parallel, *args):
        """``serial(*args)`` or ``parallel(*args)`` (numba dispatchers); returns what it returns."""
        if not self.enabled:
            return serial(*args)
        self.calls += 1
        if self.calls == 1:  # load the calling thread's kernel now; the pool's loads as it runs
            serial.compile(tuple(numba.typeof(a) for a in args))
        loop = self.choose()
        if loop:
            numba.set_num_threads(self.num_threads)
        start = time.perf_counter()
        result = (parallel if loop else serial)(*args)
        self.record(loop, time.perf_counter() - start)
        return result

    @property
    def parallel_share(self) -> float:
        """How the pool compares lately: seconds per call on the pool / on the calling thread."""
        return self.seconds[1] / self.seconds[0]


@njit(cache=True, inline="always")
def chunk_bounds(n_rows, n_chunks, c):
    """Rows [start, stop) of chunk c when n_rows are split into n_chunks at multiples of LANES,
    so that the chunks fill lane blocks (some chunks are empty when there are fewer blocks)."""
    n_blocks = (n_rows + LANES - 1) // LANES
    return min(LANES * ((c * n_blocks) // n_chunks), n_rows), min(LANES * (((c + 1) * n_blocks) // n_chunks), n_rows)


@njit(cache=True, inline="always")
def interval_accel(motion, dt):
    """This interval's ramp rate: the nominal one, cut so the speed stops at the end speed."""
    a = motion[M_ACCEL]
    room = (motion[M_END_SPEED] - motion[M_SPEED]) / dt
    if a > 0.0 and a > room:
        a = max(room, 0.0)
    elif a < 0.0 and a < room:
        a = min(room, 0.0)
    return a


# Not inlined: the serial and the parallel loop call this one compilation of a run of rows. It
# takes a run, not one row, because each call increments and decrements the shared arrays'
# reference counts, and per row those atomic updates made the threads fight over cache lines.
# error_model="numpy": no division-by-zero checks (a zero divisor gives inf/nan, which the
# row's finiteness check reports).
@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def advance_rows(start, stop, rows, channels, track, dt, n_sub, divisors):
    """Advance rows [start, stop) by one interval dt (see the module docstring) in n_sub substeps
    of classic RK4 (no stage ``divisors``) or of the S-stage method with those S stage divisors
    (:data:`bogie_env.integrate.METHOD_DIVISORS`, :func:`bogie_env.integrate._advance_lanes_taylor`)."""
    stages = divisors.shape[0]
    if stages == 0:
        weights = np.empty((3 * n_sub + 1, N_CHANNELS))
        lag_weights(channels, dt, n_sub, weights)
    else:
        weights = np.empty((stages * n_sub + 1, N_CHANNELS))
        taylor_lag_weights(channels, dt, n_sub, divisors, weights)
    _advance_run(start, stop, rows, channels, track, dt, n_sub, divisors, weights)


# numba's private option _nrt=False: the row loops are compiled without reference counting. numba
# counts references to arrays atomically whenever a view or tuple of arrays is bound, also inside
# inlined functions, and per RK4 stage those counts were about a sixth of the interval's time
# (perf, docs/performance.md). They allocate nothing (lane blocks live on the stack); advance_rows,
# which allocates the lag weights, holds the references. Arithmetic is untouched.
@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def _advance_run(start, stop, rows, channels, track, dt, n_sub, divisors, weights):
    """The rows' loop of :func:`advance_rows`: blocks of LANES rows in SIMD lanes, the last
    rows (fewer than LANES) one at a time."""
    n0 = start
    while n0 + LANES <= stop:
        _advance_block(LANES, n0, stop, rows, channels, track, dt, n_sub, divisors, weights)
        n0 += LANES
    for n in range(n0, stop):
        _advance_block(1, n, stop, rows, channels, track, dt, n_sub, divisors, weights)


# One compilation per block width: the callers pass the width as a constant, which numba types as
# a literal (the lane blocks' shapes must be compile-time constants).
@njit(cache=True, fastmath=FASTMATH, error_model="numpy", _nrt=False)
def _advance_block(lanes, n0, stop, rows, channels, track, dt, n_sub, divisors, weights):
    """Rows [n0, n0 + lanes) as one lane block: gathered into lanes, advanced by
    :func:`bogie_env.integrate._advance_lanes`, scattered back. While they are advanced, the
    alignment under the next block's rows (up to ``stop``) is fetched into the cache."""
    x, motion, coefficients, lag, delay, command, output, track_sample, status = rows
    end = n0 + lanes
    xb = stack_array((N_STATES, lanes))
    pb = stack_array((N_COEFFICIENTS, lanes))
    start_motion = stack_array((3, lanes))
    target = stack_array((lanes, 2, N_CHANNELS))
    scratch = stack_array((N_SCRATCH, N_STATES, lanes))
    v0, a, s0 = start_motion[0], start_motion[1], start_motion[2]
    for n in range(end, min(end + lanes, stop)):
        prefetch_track(track, motion[n, M_DISTANCE], coefficients[n, P_L1])
    for lane in range(lanes):
        n = n0 + lane
        m = motion[n]
        delayed_targets(delay[n], int(m[M_STEPS]), command[n], channels, target[lane])
        v0[lane] = m[M_SPEED]
        a[lane] = interval_accel(m, dt)
        s0[lane] = m[M_DISTANCE]
        for i in range(N_STATES):
            xb[i, lane] = x[n, i]
        for i in range(N_COEFFICIENTS):
            pb[i, lane] = coefficients[n, i]
    if divisors.shape[0] == 0:
        _advance_lanes(xb, v0, a, s0, dt, n_sub, lag[n0:end], target, weights, channels, track, pb, output[n0:end],
                       status[n0:end], scratch)  # fmt: skip
    else:
        _advance_lanes_taylor(xb, v0, a, s0, dt, n_sub, divisors, lag[n0:end], target, weights, channels, track, pb,
                              output[n0:end], status[n0:end], scratch)  # fmt: skip
    last = weights.shape[0] - 1  # the weights at dt
    for lane in range(lanes):
        n = n0 + lane
        for i in range(N_STATES):
            x[n, i] = xb[i, lane]
        m = motion[n]
        m[M_START_SPEED] = v0[lane]
        m[M_SPEED] = v0[lane] + a[lane] * dt
        m[M_DISTANCE] = s0[lane] + v0[lane] * dt + 0.5 * a[lane] * dt * dt
        m[M_STEPS] = int(m[M_STEPS]) + 1
        advance_lag(lag[n], target[lane], weights[last], channels)
        sample_track(track, m[M_DISTANCE], coefficients[n, P_L1], track_sample[n])


@njit(cache=True, fastmath=FASTMATH)
def _advance_serial(rows, channels, track, dt, n_sub, divisors):
    advance_rows(np.int64(0), rows[0].shape[0], rows, channels, track, dt, n_sub, divisors)  # int64, not Literal[0]: one compiled signature


@njit(cache=True, fastmath=FASTMATH, parallel=True)
def _advance_parallel(rows, channels, track, dt, n_sub, divisors):
    n_rows = rows[0].shape[0]
    n_chunks = min(n_rows, N_CHUNKS)
    for c in prange(n_chunks):
        start, stop = chunk_bounds(n_rows, n_chunks, c)
        advance_rows(start, stop, rows, channels, track, dt, n_sub, divisors)


@njit(cache=True, fastmath=FASTMATH)
def _sample_rows(rows, motion, coefficients, track, track_sample):
    """The track under the wheelsets of some rows, where they are now."""
    for n in rows:
        sample_track(track, motion[n, M_DISTANCE], coefficients[n, P_L1], track_sample[n])


@njit(cache=True, fastmath=FASTMATH)
def _run(rows, channels, track, dt, n_sub, divisors, n_steps, record_every, states_out, speeds_out):
    """n_steps intervals on the calling thread, recording every ``record_every`` (before the
    step) and at the end; stops after a step that leaves any row non-finite. Returns the
    number of records."""
    x, motion, _, _, _, _, _, _, status = rows
    n_rec = 0
    for step in range(n_steps):
        if step % record_every == 0:
            states_out[n_rec] = x
            speeds_out[n_rec] = motion[:, M_SPEED]
            n_rec += 1
        advance_rows(np.int64(0), x.shape[0], rows, channels, track, dt, n_sub, divisors)  # int64, not Literal[0]: one compiled signature
        for n in range(x.shape[0]):
            if status[n] != STATUS_OK:
                return n_rec
    states_out[n_rec] = x
    speeds_out[n_rec] = motion[:, M_SPEED]
    return n_rec + 1


class BatchSimulator:
    """N bogies advanced together, passive or with actuator channels.

    Args:
        model: the bogie physics (every row starts with its coefficients).
        n: number of bogies.
        dt: control interval, s.
        speed_range: (min, max) speed in m/s that the runs will visit; sets the substep.
        track: the track input (a :class:`TrackInput`, or an alignment :class:`TrackProfile`);
            default perfect track.
        channels: the channel table (:func:`bogie_env.actuators.channel_table`); default every
            channel takes force and damping targets, unsaturated, with ``lag_tau``.
        lag_tau: first-order lag time constant of each channel, s, for the default table.
        n_sub: substeps per interval; default from the spectrum over ``speed_range``.
        stages: the integration method (:func:`bogie_env.integrate.method_divisors`): 0 classic
            RK4, S the S-stage Taylor method, or a name of :data:`bogie_env.integrate.METHOD_DIVISORS`.
        num_threads: threads for large batches (default :func:`default_num_threads`).
    """

    def __init__(
        self,
        model: BogieModel,
        n: int,
        dt: float = 0.01,
        speed_range: tuple[float, float] = (250 / 3.6, 650 / 3.6),
        track: TrackInput | TrackProfile | None = None,
        channels: np.ndarray | None = None,
        lag_tau: np.ndarray | float = 0.0,
        n_sub: int | None = None,
        num_threads: int | None = None,
        stages: int | str = 0,
    ) -> None:
        if int(n) < 1:
            raise ValueError(f"BatchSimulator: n = {n} must be >= 1")
        if not (math.isfinite(dt) and 0 < dt <= 0.1):
            raise ValueError(f"BatchSimulator: dt = {dt!r} s must be in (0, 0.1]")
        lo, hi = (float(v) for v in speed_range)
        check_speed(lo, "speed_range[0]")
        check_speed(hi, "speed_range[1]")
        if lo > hi:
            raise ValueError(f"BatchSimulator: speed_range {speed_range} must be (min, max)")
        self.model = model
        self.n = int(n)
        self.dt = float(dt)
        self.speed_range = (lo, hi)
        if not isinstance(stages, (int, str)) or isinstance(stages, bool):
            raise ValueError(f"BatchSimulator: stages = {stages!r} must be 0 (RK4), an integer in [2, 64] (the Taylor "
                             f"method) or a method name ({', '.join(METHOD_DIVISORS)})")  # fmt: skip
        try:
            #: the method's stage divisors (float64; empty for RK4), which the kernels take
            self.divisors = method_divisors(stages)
        except ValueError as error:
            raise ValueError(f"BatchSimulator: {error}") from None
        #: stages per substep (0: classic RK4)
        self.stages = int(self.divisors.size)
        self.step_choice = stable_substep(model, lo, hi, dt, stages=self.divisors) if n_sub is None else None
        self.n_sub = int(n_sub) if n_sub is not None else self.step_choice.n_sub
        self.track = track if isinstance(track, TrackInput) else TrackInput() if track is None else TrackInput(track)
        self._track = self.track.compiled()
        if channels is None:
            tau = np.broadcast_to(np.asarray(lag_tau, dtype=float), (N_CHANNELS,))
            if np.any(~np.isfinite(tau)) or np.any(tau < 0):
                raise ValueError(f"BatchSimulator: lag_tau = {lag_tau!r} must be finite and >= 0")
            channels = channel_table()
            channels[:, CH_DECAY_RATE] = np.where(tau > 0, 1.0 / np.maximum(tau, 1e-300), 0.0)
        self.channels = np.ascontiguousarray(channels, dtype=np.float64)
        self.num_threads = default_num_threads() if num_threads is None else int(num_threads)
        self.loops = LoopChooser(self.n, self.num_threads)
        n = self.n
        self.x = np.zeros((n, N_STATES))
        self.motion = np.zeros((n, len(MOTION_FIELDS)))
        self.coefficients = np.repeat(model.coefficients[None, :], n, axis=0)
        self.lag = np.zeros((n, 2, N_CHANNELS))
        self.delay = np.zeros((n, DELAY_SLOTS, 2, N_CHANNELS))
        self.command = np.zeros((n, 2, N_CHANNELS))
        self.output = np.zeros((n, 2, N_CHANNELS))
        self.track_sample = np.zeros((n, N_TRACK_SAMPLES))
        self.status = np.zeros(n, dtype=np.int64)
        self.rows = (self.x, self.motion, self.coefficients, self.lag, self.delay, self.command, self.output,
                     self.track_sample, self.status)  # fmt: skip

    # ---- named views ------------------------------------------------------------------------
    @property
    def speed(self) -> np.ndarray:
        """Speed of each bogie now, m/s (a view)."""
        return self.motion[:, M_SPEED]

    @property
    def distance(self) -> np.ndarray:
        return self.motion[:, M_DISTANCE]

    @property
    def channel_output(self) -> np.ndarray:
        """(N, N_CHANNELS) channel forces at the end of the last interval (N or N m)."""
        return self.output[:, 0]

    @property
    def channel_power(self) -> np.ndarray:
        """(N, N_CHANNELS) mean mechanical power each channel delivered over the last interval (W)."""
        return self.output[:, 1]

    @property
    def force(self) -> np.ndarray:
        """(N, N_CHANNELS) lagged force targets now."""
        return self.lag[:, FORCE]

    @property
    def damping(self) -> np.ndarray:
        return self.lag[:, DAMPING]

    # ---- state management ------------------------------------------------------------------
    def set_rows(
        self,
        rows: np.ndarray | slice,
        x0: np.ndarray,
        speed: np.ndarray | float,
        accel: np.ndarray | float = 0.0,
        distance: np.ndarray | float = 0.0,
        end_speed: np.ndarray | float | None = None,
        coefficients: np.ndarray | None = None,
    ) -> None:
        """(Re)initialise some bogies; actuator channels start at rest.

        ``end_speed`` (m/s): where the ramp stops (default: no stop).
        """
        self.x[rows] = x0
        m = self.motion[rows]
        m[..., M_SPEED] = check_speed(speed)
        m[..., M_ACCEL] = accel
        m[..., M_END_SPEED] = np.where(np.asarray(accel) < 0, -np.inf, np.inf) if end_speed is None else end_speed
        m[..., M_DISTANCE] = distance
        m[..., M_STEPS] = 0.0
        m[..., M_START_SPEED] = m[..., M_SPEED]
        self.motion[rows] = m
        if coefficients is not None:
            self.coefficients[rows] = coefficients
        self.lag[rows] = 0.0
        self.delay[rows] = 0.0
        self.command[rows] = 0.0
        self.output[rows] = 0.0
        self.status[rows] = STATUS_OK
        _sample_rows(self._row_indices(rows), self.motion, self.coefficients, self._track, self.track_sample)

    def _row_indices(self, rows: np.ndarray | slice | int) -> np.ndarray:
        """``rows`` as int64 indices; one row (a reset's) without building every row's index."""
        if isinstance(rows, (int, np.integer)) and -self.n <= rows < self.n:
            return np.array([rows % self.n], dtype=np.int64)
        if isinstance(rows, np.ndarray) and rows.dtype == np.int64 and rows.ndim == 1 and rows.size and 0 <= rows.min() and rows.max() < self.n:
            return rows
        return np.atleast_1d(np.arange(self.n)[rows])

    def set_ramp(self, rows: np.ndarray | slice, accel: float, end_speed: float) -> None:
        """Change the speed ramp of running bogies (their states and actuators carry on):
        ``accel`` (m/s^2, negative ramps down) until ``end_speed`` (m/s)."""
        check_speed(end_speed, "end_speed")
        if not math.isfinite(accel):
            raise ValueError(f"accel = {accel!r} m/s^2 is not allowed; allowed: a finite number")
        self.motion[rows, M_ACCEL] = accel
        self.motion[rows, M_END_SPEED] = end_speed

    def track_displacement(self) -> np.ndarray:
        """Track alignment under each wheelset now, (N, 2) m."""
        return self.track.under_wheelsets(self.distance, self.model.params.L1)[:, list(ALIGNMENT_SAMPLES)]

    # ---- stepping ----------------------------------------------------------------------------
    def advance(self) -> np.ndarray:
        """Advance every bogie by ``dt`` with the commands in :attr:`command`; returns the status."""
        self.loops.run(_advance_serial, _advance_parallel, self.rows, self.channels, self._track, self.dt, self.n_sub,
                       self.divisors)  # fmt: skip
        return self.status

    def step(self, force_target: np.ndarray | None = None, damping_target: np.ndarray | None = None) -> np.ndarray:
        """Advance every bogie by ``dt`` towards these channel targets, (N, N_CHANNELS) each
        (default 0); returns the status codes."""
        self.command[:, FORCE] = 0.0 if force_target is None else force_target
        self.command[:, DAMPING] = 0.0 if damping_target is None else damping_target
        return self.advance()

    def run(self, n_steps: int, record_every: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """``n_steps`` passive intervals on the calling thread, recording states and speeds every
        ``record_every`` steps and at the end. Stops after a step that leaves a row non-finite.

        Returns (states (n_records, N, 20), speeds (n_records, N)).
        """
        record_every = max(1, int(record_every))
        n_records = n_steps // record_every + 2
        states = np.empty((n_records, self.n, N_STATES))
        speeds = np.empty((n_records, self.n))
        self.command[:] = 0.0
        count = _run(self.rows, self.channels, self._track, self.dt, self.n_sub, self.divisors, int(n_steps), record_every, states,
                     speeds)  # fmt: skip
        return states[:count], speeds[:count]
