"""Time integration: one RK4 interval of a block of bogies, step-size choice, scipy reference runs.

:func:`_advance_lanes` advances a block of bogies, one per SIMD lane (:mod:`bogie_env.lanes`),
by one control interval ``dt`` in ``n_sub`` classic RK4 substeps. Within the interval:

- the speed ramps linearly, ``V(t) = V0 + a t`` (the paper's speed-ramp runs, Section 4);
- the distance travelled ``s(t) = s0 + V0 t + a t^2 / 2`` places each wheelset on the track
  input (:func:`bogie_env.track.sample_track`);
- the actuator channels act as :mod:`bogie_env.actuators` says: lagged force minus lagged
  damping times the channel's relative velocity, saturated, mapped to the generalised forces.

:func:`_advance_lanes_taylor` does the same with an S-stage explicit method whose stability
polynomial is exp's degree-S Taylor polynomial (``integration.method: taylor10``,
``Bogie/Hunting-v2``; ``docs/studies/integrator.md``), or any stage divisors (``METHOD_DIVISORS``:
v3's ``poly14``); the criteria below take the method.

The one batch driver over rows is :mod:`bogie_env.simulator`. The step size is chosen from
the measured spectrum (:func:`stable_substep`): every eigenvalue of the linearised model over
the speed range, on and off the flange, must lie inside RK4's stability region with a 5 %
margin. Accuracy at that step is checked in ``docs/model.md`` (Section 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .actuators import (
    CH_DECAY_RATE, N_CHANNELS, channel_lags, channel_output, channel_velocity, generalised_forces, saturated_output,
)  # fmt: skip
from .dynamics import N_INPUTS, N_STATES, P_DELTA, P_L1, BogieModel, _cant_trig, _rhs_lanes, check_speed, rhs_single_kernel
from .track import N_TRACK_SAMPLES, sample_track

#: fastmath flags of the stepping kernels: none (IEEE arithmetic). With 'contract',
#: 'reassoc', 'arcp' or 'afn', LLVM's vectorised loops and their scalar remainders round
#: differently, and which iterations take which path depends on the arrays' memory alignment:
#: the same seed gave last-bit differences, and after 40 s on a limit cycle different phases,
#: in two clones of the repository at different paths. (And never 'nnan'/'ninf', which would
#: make the kernels' NaN checks meaningless.)
FASTMATH: set[str] = set()

STATUS_OK = 0
STATUS_NONFINITE = 1

# Scratch rows of _advance_lanes (a (N_SCRATCH, N_STATES, lanes) lane block of the caller):
# RK4 stages, stage state, channel outputs, inputs, track samples, cos/sin of the cants, stage speed,
# the frame reactions, the channels' lagged force (rows 0..) and damping (rows N_CHANNELS..)
K1, K2, K3, K4, XS, U, Q, YT, TRIG, SPEED, FRAME, LAGGED = range(12)
N_SCRATCH = 12
# Rows of a bogie's channel outputs: force at the end of the interval, mean power over it.
OUT_FORCE, OUT_POWER = 0, 1
assert 2 * N_CHANNELS <= N_STATES and N_INPUTS <= N_STATES and N_TRACK_SAMPLES <= N_STATES and 6 <= N_STATES


@njit(cache=True, inline="always")
def _add_power(power, u, x, divisor):
    for k in range(N_CHANNELS):
        power[k] += u[k] * channel_velocity(x, k) / divisor


@njit(cache=True, inline="always")
def _same_row(weights, a, b):
    for k in range(N_CHANNELS):
        if weights[a, k] != weights[b, k]:
            return False
    return True


#: The 14-stage method of ``Bogie/Hunting-v3``: its stage divisors d_0 .. d_13 (below). They
#: define the stability polynomial ``1 + z/d_13 (1 + z/d_12 (... (1 + z/d_0)))`` =
#: ``1 + z + z^2/2 + c_3 z^3 + ... + c_14 z^14``, whose coefficients c_3 .. c_14 a linear program
#: chose for the step criterion's spectrum at one 10-ms substep (``python
#: studies/stability_polynomial.py --growth 1.0 --n-sub 1 --show``, docs/studies/integrator.md),
#: as it printed them. d_13 = 1 and d_12 = 2 make the method of second order on nonlinear terms.
POLY14_DIVISORS: tuple[float, ...] = (
    25.026362970100465, 19.113937938097123, 14.728832171587397, 12.211491423537817, 10.675076582224392,
    9.234679006962972, 8.141568362944335, 7.034681039723269, 6.023502038517225, 5.002896328157643,
    4.00277186388854, 2.999922128425904, 2.0, 1.0,
)  # fmt: skip

#: The 12-stage method of ``Bogie/Hunting-v4``: its stage divisors d_0 .. d_11, as
#: :data:`POLY14_DIVISORS`. Its coefficients c_3 .. c_12 are the linear program's on inscribed
#: polygons (exactly stable, no cuts) for the same spectrum and rule at one 10-ms substep
#: (``python studies/stability_polynomial.py --growth 1.0 --n-sub 1 --inner 64 --show``), as it
#: printed them; 11 stages cannot meet the accuracy criterion, to first order (docs/studies/integrator.md).
POLY12_DIVISORS: tuple[float, ...] = (
    26.120004276457852, 17.20539907244046, 13.064193358267092, 10.385650390475956, 8.737496552083883,
    7.290793190783834, 6.1447385669169625, 5.039416466473353, 4.020227500558831, 2.999424407972828, 2.0, 1.0,
)  # fmt: skip

#: Integration methods (``integration.method``) and their stage divisors: classic RK4 (v0, v1;
#: no divisors), or an S-stage explicit method in Jameson's form, ``y_0 = x``,
#: ``y_{k+1} = x + h / d_k f(y_k)``, ``x <- y_S`` (:func:`_advance_lanes_taylor`): "taylor10", whose
#: divisors 10, 9, ..., 1 make its stability polynomial exp's degree-10 Taylor polynomial (v2), and
#: "poly14", 14 stages with a polynomial designed for the bogie's spectrum (v3), and "poly12", 12
#: (v4). The kernels take the divisors (an empty array for RK4).
METHOD_DIVISORS: dict[str, tuple[float, ...]] = {
    "rk4": (),
    "taylor10": tuple(float(10 - k) for k in range(10)),
    "poly14": POLY14_DIVISORS,
    "poly12": POLY12_DIVISORS,
}
#: Stages per substep of each method (0: classic RK4, which the kernels treat apart).
METHOD_STAGES: dict[str, int] = {name: len(d) for name, d in METHOD_DIVISORS.items()}


def method_divisors(method: int | str | tuple[float, ...] | np.ndarray) -> np.ndarray:
    """The stage divisors (float64 array) of ``method``: a name of :data:`METHOD_DIVISORS`, the
    divisors themselves, or an int S, the S-stage Taylor method (0: classic RK4, no divisors)."""
    if isinstance(method, str):
        if method not in METHOD_DIVISORS:
            raise ValueError(f"integration method {method!r} is not known; known: {', '.join(METHOD_DIVISORS)}")
        return np.array(METHOD_DIVISORS[method], dtype=np.float64)
    if isinstance(method, (int, np.integer)) and not isinstance(method, bool):
        if method != 0 and not 2 <= method <= 64:
            raise ValueError(f"stages = {method!r} must be 0 (RK4) or an integer in [2, 64] (the Taylor method's stages)")
        return np.array([float(method - k) for k in range(method)], dtype=np.float64)
    divisors = np.asarray(method, dtype=np.float64).ravel()
    if divisors.size and not (2 <= divisors.size <= 64 and np.all(np.isfinite(divisors)) and np.all(divisors > 0)
                              and divisors[-1] == 1.0 and divisors[-2] == 2.0):  # fmt: skip
        raise ValueError(f"stage divisors {divisors.tolist()!r} must be 2-64 finite positive numbers ending in 2, 1 "
                         "(second order)")  # fmt: skip
    return divisors


@njit(cache=True, inline="always")
def taylor_stage_time(stage, divisors):
    """The time, in substeps, at which stage ``stage`` (0 .. S - 1) of the method with stage
    ``divisors`` evaluates the right-hand side: 0, then ``1 / d_{stage - 1}`` (for the Taylor
    method 1/S, 1/(S-1), ..., 1/2; :func:`_advance_lanes_taylor`)."""
    if stage == 0:
        return 0.0
    return 1.0 / divisors[stage - 1]


@njit(cache=True)
def taylor_lag_weights(table, dt, n_sub, divisors, weights):
    """:func:`bogie_env.actuators.lag_weights` for the S-stage method with stage ``divisors``: row
    ``S j + k`` at the time of stage k of substep j, row ``S n_sub`` at dt."""
    h = dt / n_sub
    stages = divisors.shape[0]
    for k in range(N_CHANNELS):
        rate = table[k, CH_DECAY_RATE]
        for j in range(n_sub):
            for stage in range(stages):
                weights[stages * j + stage, k] = math.exp(-rate * (j * h + taylor_stage_time(stage, divisors) * h))
        weights[stages * n_sub, k] = math.exp(-rate * dt)


@njit(cache=True, inline="always")
def _step_scratch(scratch, out, lanes):
    """The scratch rows an env step works in (states of a stage, channel outputs, generalised
    forces, track samples, cant, speed, lagged channel states), with the step's mean power zeroed."""
    for lane in range(lanes):
        for k in range(N_CHANNELS):
            out[lane, OUT_POWER, k] = 0.0
    return scratch[XS], scratch[U], scratch[Q], scratch[YT], scratch[TRIG], scratch[SPEED, 0], scratch[LAGGED]


@njit(cache=True, inline="always")
def _stage_inputs(xs, ts, weights, w_row, w_lagged, t_sampled, lag, target, channels, track, s0, v0, accel, p, lagged, u, q, yt,
                  trig, speed):  # fmt: skip
    """A stage's inputs on every lane at time ``ts`` with lag weights of row ``w_row``: the
    channels' lagged force and damping (unless row ``w_lagged`` has the same weights), their
    saturated outputs and generalised forces, the track samples and cant (unless they are of
    time ``t_sampled``) and the speed. Returns the new ``(w_lagged, t_sampled)``."""
    weight = weights[w_row]
    relag = w_lagged < 0 or (w_row != w_lagged and not _same_row(weights, w_row, w_lagged))
    resample = ts != t_sampled
    for lane in range(xs.shape[1]):
        for k in range(N_CHANNELS):
            if relag:
                lagged[k, lane], lagged[N_CHANNELS + k, lane] = channel_lags(k, weight, lag[lane], target[lane], channels)
            u[k, lane] = saturated_output(xs[:, lane], k, lagged[k, lane], lagged[N_CHANNELS + k, lane], channels)
        generalised_forces(u[:, lane], q[:, lane])
        if resample:
            sample_track(track, s0[lane] + v0[lane] * ts + 0.5 * accel[lane] * ts * ts, p[P_L1, lane], yt[:, lane])
            cos_sin = _cant_trig(yt[:, lane])
            for k in range(6):
                trig[k, lane] = cos_sin[k]
        speed[lane] = v0[lane] + accel[lane] * ts
    return w_row, ts


@njit(cache=True, inline="always")
def _advance_lanes(x, v0, accel, s0, dt, n_sub, lag, target, weights, channels, track, p, out, status, scratch):
    """Advance a lane block of bogies (:mod:`bogie_env.lanes`) by dt in n_sub RK4 substeps.

    Lane-major, ``[..., lane]``: the states ``x`` (20, lanes), in place; the start speed ``v0``,
    ramp rate ``accel`` and distance ``s0`` (lanes,): within the interval the speed is
    ``v0 + accel t`` and the distance ``s0 + v0 t + accel t^2 / 2``; the coefficients ``p``
    (N_COEFFICIENTS, lanes); ``scratch`` (N_SCRATCH, 20, lanes). Row-major, ``[lane, ...]``: the
    channels' lag states at the start ``lag`` and their targets ``target`` (lanes, 2,
    N_CHANNELS); ``out`` (lanes, 2, N_CHANNELS) receives the channel outputs at the end of the
    interval and the mean power over it, ``status`` (lanes,) the status codes. ``weights`` are
    the lag weights at the stage times (:func:`bogie_env.actuators.lag_weights`), ``channels``
    the channel table, ``track`` the track input (:mod:`bogie_env.track`).

    The lane-major arrays must be lane blocks of a compile-time width (``stack_array`` in the
    calling function, into which this is inlined): then the right-hand side, the stage states
    and the RK4 update compile to SIMD instructions across the lanes. What holds calls runs one
    lane at a time: the channel outputs (the rate limiter's log and exp), the track samples
    (segment search, interpolation, the cants' cos and sin) and the power. A row's arithmetic is
    the same in any lane of a block of any width, operation for operation: the classic RK4's.

    The four RK4 stages are one loop over a single copy of the stage code, not four inlined
    copies: the compiled code is four times smaller, which cut the first compilation of the
    drivers several-fold (docs/performance.md). A stage at the time of the stage before it (the
    two middle stages; a substep's first stage and the previous substep's last one, when their
    times round alike) reuses that stage's track samples, which depend on the time only, and a stage
    whose lag weights equal the stage before's reuses the channels' lagged force and damping.
    """
    lanes = x.shape[1]
    h = dt / n_sub
    xs, u, q, yt, trig, speed, lagged = _step_scratch(scratch, out, lanes)
    t_sampled = -1.0  # the stage time of the track samples in yt and trig (none yet: times are >= 0)
    w_lagged = -1  # the row of weights of the lagged forces and dampings in lagged (none yet)
    for j in range(n_sub):
        t = j * h
        for stage in range(4):
            # the stage's state and time: x, x + h/2 k1, x + h/2 k2, x + h k3 at t, t + h/2, t + h/2, t + h
            if stage == 0:
                for i in range(N_STATES):
                    for lane in range(lanes):
                        xs[i, lane] = x[i, lane]
                ts = t
            else:
                step = h if stage == 3 else 0.5 * h
                for i in range(N_STATES):
                    for lane in range(lanes):
                        xs[i, lane] = x[i, lane] + step * scratch[K1 + stage - 1, i, lane]
                ts = t + h if stage == 3 else t + 0.5 * h
            w_row = 3 * j + (stage + 1) // 2
            # The channels' lagged force and damping depend on the weights only: stage 2 has stage
            # 1's row, and a substep's first stage the previous last one's values when they agree.
            # The track under the bogie depends on the stage time only: stage 2 is at stage 1's
            # time, and a substep's first stage is at the last one's time whenever j h + h rounds
            # to (j + 1) h (9 of 9 boundaries at 10 substeps per 10 ms): the same samples.
            w_lagged, t_sampled = _stage_inputs(xs, ts, weights, w_row, w_lagged, t_sampled, lag, target, channels, track,
                                                s0, v0, accel, p, lagged, u, q, yt, trig, speed)  # fmt: skip
            _rhs_lanes(xs, speed, q, yt, trig, p, scratch[K1 + stage], scratch[FRAME])
            for lane in range(lanes):
                _add_power(out[lane, OUT_POWER], u[:, lane], xs[:, lane], 6.0 if stage == 0 or stage == 3 else 3.0)
        for i in range(N_STATES):
            for lane in range(lanes):
                x[i, lane] += h / 6.0 * (scratch[K1, i, lane] + 2.0 * scratch[K2, i, lane] + 2.0 * scratch[K3, i, lane]
                                         + scratch[K4, i, lane])  # fmt: skip
    for lane in range(lanes):
        for k in range(N_CHANNELS):
            out[lane, OUT_POWER, k] /= n_sub
        for k in range(N_CHANNELS):
            out[lane, OUT_FORCE, k] = channel_output(x[:, lane], k, weights[3 * n_sub], lag[lane], target[lane], channels)
        status[lane] = STATUS_OK
        for i in range(N_STATES):
            if not math.isfinite(x[i, lane]):
                status[lane] = STATUS_NONFINITE


@njit(cache=True, inline="always")
def _advance_lanes_taylor(x, v0, accel, s0, dt, n_sub, divisors, lag, target, weights, channels, track, p, out, status, scratch):
    """:func:`_advance_lanes` with an S-stage method in Jameson's form (stage ``divisors`` d_0 ..
    d_{S-1}, :data:`METHOD_DIVISORS`) instead of RK4.

    Each substep of h is ``y_0 = x``, ``y_{k+1} = x + h / d_k f(y_k)`` (k = 0 .. S - 1), and
    ``x <- y_S``: on a linear system ``x' = J x`` that is ``x <- R(h J) x`` with the stability
    polynomial ``R(z) = 1 + z/d_{S-1} (1 + z/d_{S-2} (... (1 + z/d_0)))``. The Taylor method's
    divisors S, S-1, ..., 1 make R exp's Taylor polynomial of degree S, which keeps the lightly
    damped wheelset modes' decay rates within 10 % at 2 substeps per 10 ms for S = 10 (RK4 needs
    10: ``docs/studies/integrator.md``); v3's 14 divisors do at one substep. With d_{S-1} = 1 and
    d_{S-2} = 2 the method is of second order on nonlinear and time-dependent terms. Stage k
    evaluates the right-hand side at ``t + c_k h``, ``c_k`` = :func:`taylor_stage_time`, with the
    channels' lag weights of row ``S j + k`` (:func:`taylor_lag_weights`). The mean power is the
    midpoint rule: the last stage's, at ``t + h / 2``. One stage derivative (``scratch[K1]``) is
    all the method stores.
    """
    stages = divisors.shape[0]
    lanes = x.shape[1]
    h = dt / n_sub
    xs, u, q, yt, trig, speed, lagged = _step_scratch(scratch, out, lanes)
    k1 = scratch[K1]
    t_sampled = -1.0
    w_lagged = -1
    for j in range(n_sub):
        t = j * h
        for i in range(N_STATES):
            for lane in range(lanes):
                xs[i, lane] = x[i, lane]
        for stage in range(stages):
            ts = t + taylor_stage_time(stage, divisors) * h
            w_row = stages * j + stage
            w_lagged, t_sampled = _stage_inputs(xs, ts, weights, w_row, w_lagged, t_sampled, lag, target, channels, track,
                                                s0, v0, accel, p, lagged, u, q, yt, trig, speed)  # fmt: skip
            _rhs_lanes(xs, speed, q, yt, trig, p, k1, scratch[FRAME])
            if stage == stages - 1:
                for lane in range(lanes):
                    _add_power(out[lane, OUT_POWER], u[:, lane], xs[:, lane], 1.0)
            step = h / divisors[stage]
            for i in range(N_STATES):
                for lane in range(lanes):
                    xs[i, lane] = x[i, lane] + step * k1[i, lane]
        for i in range(N_STATES):
            for lane in range(lanes):
                x[i, lane] = xs[i, lane]
    last = weights.shape[0] - 1
    for lane in range(lanes):
        for k in range(N_CHANNELS):
            out[lane, OUT_POWER, k] /= n_sub
        for k in range(N_CHANNELS):
            out[lane, OUT_FORCE, k] = channel_output(x[:, lane], k, weights[last], lag[lane], target[lane], channels)
        status[lane] = STATUS_OK
        for i in range(N_STATES):
            if not math.isfinite(x[i, lane]):
                status[lane] = STATUS_NONFINITE


# ---------------------------------------------------------------------------------
# Step-size selection from the spectrum
# ---------------------------------------------------------------------------------


def rk4_amplification(z: np.ndarray) -> np.ndarray:
    """|R(z)| of classic RK4, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24."""
    z = np.asarray(z, dtype=complex)
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


def taylor_polynomial(z: np.ndarray, stages: int | str | tuple[float, ...] | np.ndarray) -> np.ndarray:
    """R(z) of the method in Jameson's form with the stage divisors of ``stages``
    (:func:`method_divisors`; an int S: the S-stage Taylor method, ``sum_{k <= S} z^k / k!``),
    ``1 + z/d_{S-1} (1 + z/d_{S-2} (... (1 + z/d_0)))`` (Horner)."""
    z = np.asarray(z, dtype=complex)
    r = np.ones_like(z)
    for d in method_divisors(stages):
        r = 1 + z / d * r
    return r


def amplification(z: np.ndarray, stages: int | str | tuple[float, ...] | np.ndarray = 0) -> np.ndarray:
    """|R(z)| of the method ``stages`` (:func:`method_divisors`; 0: classic RK4)."""
    if method_divisors(stages).size == 0:
        return rk4_amplification(z)
    return np.abs(taylor_polynomial(z, stages))


def spectrum(model: BogieModel, speeds: np.ndarray, flange: bool = True, extra_jacobian: np.ndarray | None = None) -> np.ndarray:
    """Eigenvalues (n_speeds, 20 or 40) at equilibrium and, with ``flange``, in flange contact.

    ``extra_jacobian`` (20 x 20) is added to every Jacobian: e.g. the damping of semi-active
    actuators at their largest setting, which makes the system stiffer.
    """
    x_eq = model.equilibrium(float(np.max(speeds)))
    states = [x_eq]
    if flange:
        engaged = x_eq.copy()
        engaged[[0, 8, 16]] = model.coefficients[P_DELTA] + 1e-3  # both wheelsets on the flange
        states.append(engaged)
    rows = []
    for v in np.atleast_1d(speeds):
        extra = 0.0 if extra_jacobian is None else extra_jacobian
        rows.append(np.concatenate([np.linalg.eigvals(model.jacobian(xx, float(v)) + extra) for xx in states]))
    return np.array(rows)


@dataclass(frozen=True)
class StepChoice:
    """The RK4 substep chosen for a speed range, with the evidence."""

    substep: float  # s
    n_sub: int
    spectral_radius: float  # 1/s, the largest |lambda| seen
    margin: float  # the chosen step keeps |R(margin * h * lambda)| <= 1


def stable_substep(
    model: BogieModel,
    v_min: float,
    v_max: float,
    dt: float,
    margin: float = 1.05,
    n_speeds: int = 7,
    extra_jacobian: np.ndarray | None = None,
    stages: int | str | tuple[float, ...] | np.ndarray = 0,
) -> StepChoice:
    """The fewest RK4 substeps per ``dt`` that keep every eigenvalue stable with a margin.

    The eigenvalues over ``[v_min, v_max]`` (m/s), at the equilibrium and in flange contact,
    scaled by ``margin * h``, must lie in RK4's stability region ``|R(z)| <= 1`` (or grow no
    faster than the exact ``exp(z)`` for the few eigenvalues in the right half-plane).
    ``stages`` other than 0: the same for that method (:func:`method_divisors`: a name of
    :data:`METHOD_DIVISORS`, stage divisors, or S for the S-stage Taylor method).
    """
    check_speed(v_min, "v_min")
    check_speed(v_max, "v_max")
    speeds = np.linspace(v_min, v_max, n_speeds)
    eigenvalues = spectrum(model, speeds, extra_jacobian=extra_jacobian).ravel()
    for n_sub in range(1, 10_000):
        h = dt / n_sub
        z = margin * h * eigenvalues
        # Growing modes (the hunting mode above the critical speed) may grow, as they truly do.
        if np.all(amplification(z, stages) <= np.maximum(1.0, np.exp(z.real)) + 1e-12):
            return StepChoice(h, n_sub, float(np.max(np.abs(eigenvalues))), margin)
    raise RuntimeError("stable_substep: no stable step found")


# ---------------------------------------------------------------------------------
# Python front-ends
# ---------------------------------------------------------------------------------


def reference_solution(
    model: BogieModel,
    x0: np.ndarray,
    speed: float,
    t_span: tuple[float, float],
    accel: float = 0.0,
    method: str = "DOP853",
    rtol: float = 1e-9,
    atol: float = 1e-12,
    t_eval: np.ndarray | None = None,
    max_step: float = np.inf,
):
    """A scipy ``solve_ivp`` reference run of one passive bogie on perfect track.

    The speed is ``speed + accel * (t - t_span[0])`` (m/s). Returns scipy's OdeResult.
    """
    from scipy.integrate import solve_ivp  # here: the simulator imports this module, and scipy.integrate is slow to import

    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (N_STATES,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0 must be a finite array of shape ({N_STATES},); got shape {x0.shape}")
    check_speed(speed)
    check_speed(speed + accel * (t_span[1] - t_span[0]), "final speed")
    p = model.coefficients
    zeros_q = np.zeros(N_INPUTS)
    zeros_t = np.zeros(N_TRACK_SAMPLES)
    out = np.empty(N_STATES)

    def f(t, x):
        rhs_single_kernel(x, speed + accel * (t - t_span[0]), zeros_q, zeros_t, p, out)
        return out.copy()

    return solve_ivp(f, t_span, x0, method=method, rtol=rtol, atol=atol, t_eval=t_eval, max_step=max_step)


# ---------------------------------------------------------------------------------
# Step-size selection for accuracy
# ---------------------------------------------------------------------------------


def rk4_effective_eigenvalue(eigenvalues: np.ndarray, h: float) -> np.ndarray:
    """The eigenvalue RK4 with step h actually reproduces: ``log(R(h lambda)) / h``."""
    z = h * np.asarray(eigenvalues, dtype=complex)
    return np.log(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) / h


def taylor_effective_eigenvalue(eigenvalues: np.ndarray, h: float, stages: int | str | tuple[float, ...] | np.ndarray) -> np.ndarray:
    """The eigenvalue the method ``stages`` (:func:`taylor_polynomial`) with step h reproduces, ``log(R(h lambda)) / h``,
    on the branch nearest ``lambda``: a mode above half the substep's sampling rate
    (``|Im(lambda)| h > pi``, e.g. 100 Hz at 5-ms substeps) is aliased by the principal logarithm."""
    lam = np.asarray(eigenvalues, dtype=complex)
    lam_h = np.log(taylor_polynomial(h * lam, stages)) / h
    turns = np.round((lam.imag - lam_h.imag) * h / (2 * np.pi))
    return lam_h + 2j * np.pi * turns / h


def eigenvalue_errors(eigenvalues: np.ndarray, h: float, zeta_max: float = 0.5,
                      stages: int | str | tuple[float, ...] | np.ndarray = 0) -> tuple[float, float]:
    """Largest relative errors of RK4's decay rate and frequency over the lightly damped modes.

    A mode counts if its damping ratio is below ``zeta_max``. The decay-rate error is
    ``|Re(l_h) - Re(l)| / max(|Re(l)|, 0.01 |l|)`` (a mode at the edge of stability is held to
    1 % of its frequency), the frequency error ``|Im(l_h) - Im(l)| / |Im(l)|``. ``stages`` other
    than 0: that method's errors instead (:func:`method_divisors`, :func:`taylor_effective_eigenvalue`).
    """
    lam = np.asarray(eigenvalues, dtype=complex)
    lam = lam[(np.abs(lam.imag) > 0) & (-lam.real < zeta_max * np.abs(lam))]
    if lam.size == 0:
        return 0.0, 0.0
    rk4 = method_divisors(stages).size == 0
    lam_h = rk4_effective_eigenvalue(lam, h) if rk4 else taylor_effective_eigenvalue(lam, h, stages)
    lam_h = np.where(np.sign(lam_h.imag) == np.sign(lam.imag), lam_h, np.conj(lam_h))
    decay = np.abs(lam_h.real - lam.real) / np.maximum(np.abs(lam.real), 0.01 * np.abs(lam))
    freq = np.abs(lam_h.imag - lam.imag) / np.abs(lam.imag)
    return float(np.max(decay)), float(np.max(freq))


def accurate_substep(
    model: BogieModel,
    v_min: float,
    v_max: float,
    dt: float,
    tolerance: float = 0.1,
    n_speeds: int = 7,
    extra_jacobian: np.ndarray | None = None,
    stages: int | str | tuple[float, ...] | np.ndarray = 0,
) -> StepChoice:
    """The fewest RK4 substeps per ``dt`` that are stable (:func:`stable_substep`) and keep the
    decay rate and frequency of every lightly damped mode (damping ratio < 0.5) within
    ``tolerance`` (relative) over ``[v_min, v_max]``, at the equilibrium and in flange contact.

    Stability alone lets RK4 damp the lightly damped wheelset modes (about 85 Hz) several times
    more than they are damped, which hides instabilities of a loop with delay or gain error;
    this criterion bounds that error. ``stages`` other than 0: the same criterion for that method
    (:func:`method_divisors`).
    """
    stable = stable_substep(model, v_min, v_max, dt, n_speeds=n_speeds, extra_jacobian=extra_jacobian, stages=stages)
    speeds = np.linspace(v_min, v_max, n_speeds)
    eigenvalues = spectrum(model, speeds, extra_jacobian=extra_jacobian).ravel()
    for n_sub in range(stable.n_sub, 10_000):
        h = dt / n_sub
        if max(eigenvalue_errors(eigenvalues, h, stages=stages)) <= tolerance:
            return StepChoice(h, n_sub, stable.spectral_radius, stable.margin)
    raise RuntimeError("accurate_substep: no accurate step found")
