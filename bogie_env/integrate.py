"""Time integration: a compiled, batched fixed-step RK4 and scipy reference runs.

The fixed-step kernel advances N bogies by one control interval ``dt`` in ``n_sub`` classic
RK4 substeps, entirely inside compiled code. Within the interval:

- the speed ramps linearly, ``V(t) = V0 + a t`` (the paper's speed-ramp runs, Section 4);
- the distance travelled ``s(t) = s0 + V0 t + a t^2 / 2`` places each wheelset on a
  shared, periodic track-alignment profile (``x = s + L1`` front, ``s - L1`` rear);
- each of the 4 actuator channels applies ``u_k = sat(F_k(t) - c_k(t) v_k(x))``: a force
  ``F_k`` and a damping coefficient ``c_k`` that both follow a first-order lag from their
  start values to their targets exactly (``exp(-t/tau)``), and ``v_k`` the channel's
  relative velocity (frame lateral, frame yaw, wheelset-minus-frame yaw 1 and 2), saturated
  at ``+-u_max``. Force actuators use ``c = 0``; semi-active dampers use ``F = 0`` and
  ``c >= 0``; saturating a damper's force keeps its sign, so it still only dissipates.

The generalised forces handed to the dynamics are ``Q = (u0, u1 - u2 - u3, u2, u3)``:
wheelset steering torques react on the frame.

The step size is chosen from the measured spectrum (:func:`stable_substep`): every
eigenvalue of the linearised model over the speed range, on and off the flange, must lie
inside RK4's stability region with a 5 % margin. Accuracy at that step is checked in
``docs/model.md`` (Section 8): limit-cycle amplitudes within 0.03 mm of a four times finer
step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.integrate import solve_ivp

from .dynamics import N_INPUTS, N_STATES, P_DELTA, P_L1, BogieModel, _rhs_row, check_speed, rhs_single_kernel

#: fastmath flags of the stepping kernels: none (IEEE arithmetic). With 'contract',
#: 'reassoc', 'arcp' or 'afn', LLVM's vectorised loops and their scalar remainders round
#: differently, and which iterations take which path depends on the arrays' memory alignment:
#: the same seed gave last-bit differences, and after 40 s on a limit cycle different phases,
#: in two clones of the repository at different paths. (And never 'nnan'/'ninf', which would
#: make the kernels' NaN checks meaningless.)
FASTMATH: set[str] = set()

STATUS_OK = 0
STATUS_NONFINITE = 1
WORK_SIZE = 110  # scratch floats per row for _advance_row
N_CHUNKS = 64  # parallel loops run over contiguous chunks of rows, one scratch buffer each


@njit(cache=True, inline="always")
def chunk_bounds(n_rows, n_chunks, c):
    """Rows [start, stop) of chunk c when n_rows are split into n_chunks."""
    return (c * n_rows) // n_chunks, ((c + 1) * n_rows) // n_chunks


@njit(cache=True, inline="always")
def _track_at(profile, inv_dx, s):
    """Linear interpolation on a periodic profile sampled every 1/inv_dx metres."""
    m = profile.shape[0]
    if m == 0:
        return 0.0
    u = s * inv_dx
    k = math.floor(u)
    w = u - k
    i0 = int(k) % m
    i1 = (i0 + 1) % m
    return (1.0 - w) * profile[i0] + w * profile[i1]


@njit(cache=True, inline="always")
def _channel_velocity(x, k):
    if k == 0:
        return x[17]  # frame lateral velocity
    if k == 1:
        return x[19]  # frame yaw rate
    return x[5 + 8 * (k - 2)] - x[19]  # wheelset yaw rate relative to the frame


@njit(cache=True, inline="always")
def _channel_output(x, k, t, f_start, f_target, c_start, c_target, decay_rate, u_max):
    """Channel k's force at time t: lagged force minus lagged damping times velocity, saturated."""
    w = math.exp(-decay_rate[k] * t)
    force = f_target[k] + (f_start[k] - f_target[k]) * w
    damping = c_target[k] + (c_start[k] - c_target[k]) * w
    value = force - damping * _channel_velocity(x, k)
    return min(max(value, -u_max[k]), u_max[k])


@njit(cache=True, inline="always")
def _stage_derivative(x, t, V0, accel, s0, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, q, yt, u, out):
    """dx/dt at time t inside the interval; also leaves the channel outputs in ``u``."""
    for k in range(N_INPUTS):
        u[k] = _channel_output(x, k, t, f_start, f_target, c_start, c_target, decay_rate, u_max)
    q[0] = u[0]
    q[1] = u[1] - u[2] - u[3]
    q[2] = u[2]
    q[3] = u[3]
    s = s0 + V0 * t + 0.5 * accel * t * t
    L1 = p[P_L1]
    yt[0] = _track_at(profile, inv_dx, s + L1)
    yt[1] = _track_at(profile, inv_dx, s - L1)
    _rhs_row(x, V0 + accel * t, q, yt, p, out)


@njit(cache=True, inline="always")
def _advance_row(x, V0, accel, s0, dt, n_sub, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, u_end, power_mean, work):
    """Advance one bogie by dt in n_sub RK4 substeps. Returns a status code.

    ``work`` is scratch space of WORK_SIZE floats, allocated once per thread by the caller:
    allocating inside a parallel loop serialises the threads on the allocator's counters.
    """
    h = dt / n_sub
    k1 = work[0:20]
    k2 = work[20:40]
    k3 = work[40:60]
    k4 = work[60:80]
    xs = work[80:100]
    q = work[100:104]
    u = work[104:108]
    yt = work[108:110]
    for k in range(N_INPUTS):
        power_mean[k] = 0.0
    for j in range(n_sub):
        t = j * h
        _stage_derivative(x, t, V0, accel, s0, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, q, yt, u, k1)
        for k in range(N_INPUTS):
            power_mean[k] += u[k] * _channel_velocity(x, k) / 6.0
        for i in range(N_STATES):
            xs[i] = x[i] + 0.5 * h * k1[i]
        _stage_derivative(xs, t + 0.5 * h, V0, accel, s0, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, q, yt, u, k2)
        for k in range(N_INPUTS):
            power_mean[k] += u[k] * _channel_velocity(xs, k) / 3.0
        for i in range(N_STATES):
            xs[i] = x[i] + 0.5 * h * k2[i]
        _stage_derivative(xs, t + 0.5 * h, V0, accel, s0, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, q, yt, u, k3)
        for k in range(N_INPUTS):
            power_mean[k] += u[k] * _channel_velocity(xs, k) / 3.0
        for i in range(N_STATES):
            xs[i] = x[i] + h * k3[i]
        _stage_derivative(xs, t + h, V0, accel, s0, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, q, yt, u, k4)
        for k in range(N_INPUTS):
            power_mean[k] += u[k] * _channel_velocity(xs, k) / 6.0
        for i in range(N_STATES):
            x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    for k in range(N_INPUTS):
        power_mean[k] /= n_sub
    # channel outputs at the end of the interval
    for k in range(N_INPUTS):
        u_end[k] = _channel_output(x, k, dt, f_start, f_target, c_start, c_target, decay_rate, u_max)
    for i in range(N_STATES):
        if not math.isfinite(x[i]):
            return STATUS_NONFINITE
    return STATUS_OK


@njit(cache=True, parallel=True, fastmath=FASTMATH)
def advance_batch_kernel(x, V, accel, s, dt, n_sub, f_start, f_target, c_start, c_target, decay_rate, u_max, profile, inv_dx, p, u_end, power_mean, status):
    """Advance N bogies in place by dt; V and s advance too. Rows run in parallel.

    Shapes: x (N, 20); V, accel, s, status (N,); f_start, f_target, c_start, c_target,
    u_end, power_mean (N, 4); decay_rate (4,) = 1/tau per channel (0: no lag); u_max (4,)
    saturation of each channel's output (inf: none);
    profile (M,) shared periodic track alignment (M = 0: perfect track).
    """
    n_rows = x.shape[0]
    n_chunks = min(n_rows, N_CHUNKS)
    for c in prange(n_chunks):
        work = np.empty(WORK_SIZE)
        start, stop = chunk_bounds(n_rows, n_chunks, c)
        for n in range(start, stop):
            status[n] = _advance_row(
                x[n], V[n], accel[n], s[n], dt, n_sub, f_start[n], f_target[n], c_start[n], c_target[n],
                decay_rate, u_max, profile, inv_dx, p, u_end[n], power_mean[n], work,
            )  # fmt: skip
            s[n] += V[n] * dt + 0.5 * accel[n] * dt * dt
            V[n] += accel[n] * dt


@njit(cache=True, fastmath=FASTMATH)
def simulate_ramp_kernel(x, V, accel, dt, n_sub, n_steps, record_every, profile, inv_dx, s, p, v_floor, v_ceiling, states_out, speeds_out):
    """One passive bogie for n_steps intervals of dt, recording every ``record_every``.

    The speed is held inside [v_floor, v_ceiling]. Returns the number of records written
    and a status code (non-finite state stops the run).
    """
    zeros = np.zeros(N_INPUTS)
    unbounded = np.full(N_INPUTS, np.inf)
    u_end = np.empty(N_INPUTS)
    power = np.empty(N_INPUTS)
    work = np.empty(WORK_SIZE)
    n_rec = 0
    for step in range(n_steps):
        if step % record_every == 0:
            for i in range(N_STATES):
                states_out[n_rec, i] = x[i]
            speeds_out[n_rec] = V
            n_rec += 1
        a = accel
        if V + a * dt > v_ceiling or V + a * dt < v_floor:
            a = 0.0
        code = _advance_row(x, V, a, s, dt, n_sub, zeros, zeros, zeros, zeros, zeros, unbounded, profile, inv_dx, p, u_end, power, work)
        s += V * dt + 0.5 * a * dt * dt
        V += a * dt
        if code != STATUS_OK:
            return n_rec, code
    for i in range(N_STATES):
        states_out[n_rec, i] = x[i]
    speeds_out[n_rec] = V
    return n_rec + 1, STATUS_OK


# ---------------------------------------------------------------------------------
# Step-size selection from the spectrum
# ---------------------------------------------------------------------------------


def rk4_amplification(z: np.ndarray) -> np.ndarray:
    """|R(z)| of classic RK4, R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24."""
    z = np.asarray(z, dtype=complex)
    return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)


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
) -> StepChoice:
    """The fewest RK4 substeps per ``dt`` that keep every eigenvalue stable with a margin.

    The eigenvalues over ``[v_min, v_max]`` (m/s), at the equilibrium and in flange contact,
    scaled by ``margin * h``, must lie in RK4's stability region ``|R(z)| <= 1`` (or grow no
    faster than the exact ``exp(z)`` for the few eigenvalues in the right half-plane).
    """
    check_speed(v_min, "v_min")
    check_speed(v_max, "v_max")
    speeds = np.linspace(v_min, v_max, n_speeds)
    eigenvalues = spectrum(model, speeds, extra_jacobian=extra_jacobian).ravel()
    for n_sub in range(1, 10_000):
        h = dt / n_sub
        z = margin * h * eigenvalues
        # Growing modes (the hunting mode above the critical speed) may grow, as they truly do.
        if np.all(rk4_amplification(z) <= np.maximum(1.0, np.exp(z.real)) + 1e-12):
            return StepChoice(h, n_sub, float(np.max(np.abs(eigenvalues))), margin)
    raise RuntimeError("stable_substep: no stable step found")


# ---------------------------------------------------------------------------------
# Python front-ends
# ---------------------------------------------------------------------------------


def channel_damping_jacobian(model: BogieModel, damping: np.ndarray) -> np.ndarray:
    """Jacobian of the channels' damping forces, -B G diag(c) V: what viscous actuators add.

    ``damping`` (4,) per channel; V maps states to channel velocities and G maps channel
    forces to the generalised forces (wheelset torques react on the frame).
    """
    velocity = np.zeros((N_INPUTS, N_STATES))
    velocity[0, 17] = 1.0
    velocity[1, 19] = 1.0
    velocity[2, 5], velocity[2, 19] = 1.0, -1.0
    velocity[3, 13], velocity[3, 19] = 1.0, -1.0
    to_generalised = np.array([[1, 0, 0, 0], [0, 1, -1, -1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    return -model.input_matrix() @ to_generalised @ np.diag(damping) @ velocity


def empty_profile() -> np.ndarray:
    """A zero-length profile: perfect track."""
    return np.zeros(0)


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
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (N_STATES,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0 must be a finite array of shape ({N_STATES},); got shape {x0.shape}")
    check_speed(speed)
    check_speed(speed + accel * (t_span[1] - t_span[0]), "final speed")
    p = model.coefficients
    zeros_q = np.zeros(N_INPUTS)
    zeros_t = np.zeros(2)
    out = np.empty(N_STATES)

    def f(t, x):
        rhs_single_kernel(x, speed + accel * (t - t_span[0]), zeros_q, zeros_t, p, out)
        return out.copy()

    return solve_ivp(f, t_span, x0, method=method, rtol=rtol, atol=atol, t_eval=t_eval, max_step=max_step)
