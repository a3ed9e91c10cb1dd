"""The 20-state right-hand side of the 10-DOF bogie, batched and compiled.

State order (the paper's, Section 4)::

    y1, dy1, z1, dz1, psi1, dpsi1, phi1, dphi1,     front wheelset (i = 1, at x = +L1)
    y2, dy2, z2, dz2, psi2, dpsi2, phi2, dphi2,     rear wheelset  (i = 2, at x = -L1)
    yb, dyb, psib, dpsib                            bogie frame

Axes: x forward, y left, z up; yaw positive nose-left, roll positive right side down
(left side up). SI units throughout; speed ``V`` in m/s.

The right-hand side is assembled from the force and moment balances Eqs. (1)-(6) with the
creep forces Eqs. (16)-(25), saturation Eqs. (26)-(30), contact positions Eqs. (31)-(36),
normal forces Eqs. (37)-(39), suspension Eqs. (40)-(45) and flange contact Eq. (46). The
printed equations' typos are corrected as listed in ``docs/model.md``; the condensed
Eqs. (47)-(52) are re-derived there and checked against this code in
``tests/test_dynamics.py``.

Two inputs extend the paper's model without changing it when zero:

- ``inputs`` (N, 4): generalised forces on frame lateral (N), frame yaw (N m) and the yaw
  of wheelsets 1 and 2 (N m). Actuators act on the physics only through this term; an
  actuator between a wheelset and the frame puts its reaction into the frame yaw entry.
- ``track`` (N, N_TRACK): the track samples named by :data:`bogie_env.track.TRACK_SAMPLES`.
  The lateral alignment under each wheelset (m): the rolling radii, gravitational terms and
  flange contact use the wheelset displacement relative to the track; creepages use
  absolute velocities, which is exact for a rail at rest (the slip velocity does not depend
  on where the rail is). The curvature (1/m) and cant angle (rad) under each wheelset and
  the frame: the states are then measured in the track-following axes of each body (lateral
  from the local centreline, yaw from the local tangent), and the curving terms of
  ``docs/model.md`` Section 11 (Eqs. C1-C9) enter. With zero curvature and cant every
  curving term is an exact zero, so straight-track results are bitwise unchanged.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .contact import CreepCoefficients, _flange, _saturation, creep_coefficients
from .params import BogieParams
from .track import (
    ALIGNMENT_WHEELSET1, CANT_FRAME, CANT_WHEELSET1, CURVATURE_FRAME, CURVATURE_WHEELSET1, N_TRACK_SAMPLES,
)  # fmt: skip

N_STATES = 20
N_INPUTS = 4
N_TRACK = N_TRACK_SAMPLES
#: Gravity (m/s^2) for the cant's share of the lateral balance and the car-body mass (Eq. C3).
GRAVITY = 9.81

STATE_NAMES: tuple[str, ...] = (
    "y1", "dy1", "z1", "dz1", "psi1", "dpsi1", "phi1", "dphi1",
    "y2", "dy2", "z2", "dz2", "psi2", "dpsi2", "phi2", "dphi2",
    "yb", "dyb", "psib", "dpsib",
)  # fmt: skip
STATE_UNITS: tuple[str, ...] = (
    "m", "m/s", "m", "m/s", "rad", "rad/s", "rad", "rad/s",
    "m", "m/s", "m", "m/s", "rad", "rad/s", "rad", "rad/s",
    "m", "m/s", "rad", "rad/s",
)  # fmt: skip
INPUT_NAMES: tuple[str, ...] = ("frame_lateral_force", "frame_yaw_torque", "wheelset1_yaw_torque", "wheelset2_yaw_torque")
#: Indices of the states that change sign under the mirror y -> -y (all but z, dz).
ANTISYMMETRIC_STATES = tuple(i for i, name in enumerate(STATE_NAMES) if not name.lstrip("d").startswith("z"))
#: States of the vertical DOFs; they do not feed back into the others (docs/model.md).
VERTICAL_STATES = (2, 3, 10, 11)
LATERAL_STATES = tuple(i for i in range(N_STATES) if i not in VERTICAL_STATES)

#: Speeds the model accepts, m/s. Creepages divide by V; above 250 m/s (900 km/h) the
#: model is far outside anything it was built for.
MIN_SPEED = 1.0
MAX_SPEED = 250.0


def state_index(name: str) -> int:
    """Index of a state by name (``"y1"``, ``"dpsib"``, ...)."""
    try:
        return STATE_NAMES.index(name)
    except ValueError:
        raise KeyError(f"unknown state {name!r}; states: {', '.join(STATE_NAMES)}") from None


# ---- coefficient vector: the compiled kernels read parameters from one float64 array ----
COEFFICIENT_NAMES: tuple[str, ...] = (
    "mb", "Ibz", "mw", "Iwx", "Iwy", "Iwz", "L1", "L2", "b1", "b2", "b3", "h1", "h2",
    "e", "r0", "lam", "Wpa", "Kpx", "Kpy", "Kpz", "Cpx", "Cpy", "Cpz",
    "Ksx", "Ksy", "Csx", "Csy", "Kr", "delta", "mu", "f11", "f12", "f22", "f33",
    "h_Ksy", "h_Csy",
)  # fmt: skip
(
    P_MB, P_IBZ, P_MW, P_IWX, P_IWY, P_IWZ, P_L1, P_L2, P_B1, P_B2, P_B3, P_H1, P_H2,
    P_E, P_R0, P_LAM, P_WPA, P_KPX, P_KPY, P_KPZ, P_CPX, P_CPY, P_CPZ,
    P_KSX, P_KSY, P_CSX, P_CSY, P_KR, P_DELTA, P_MU, P_F11, P_F12, P_F22, P_F33,
    P_H_KSY, P_H_CSY,
) = range(len(COEFFICIENT_NAMES))  # fmt: skip
N_COEFFICIENTS = len(COEFFICIENT_NAMES)


def coefficient_vector(params: BogieParams, creep: CreepCoefficients | None = None) -> np.ndarray:
    """The float64 vector the kernels read: the parameters, the creep coefficients and the
    heights at which Ksy and Csy act in Eq. (43) (``params.secondary_heights``)."""
    creep = creep if creep is not None else creep_coefficients(params)
    values = params.to_dict()
    values.update(f11=creep.f11, f12=creep.f12, f22=creep.f22, f33=creep.f33)
    if params.secondary_heights == "printed":  # Eqs. (43), (50) as printed
        values.update(h_Ksy=params.h1, h_Csy=params.h2)
    else:  # Table 1: h2 is the spring height, h1 the damper height
        values.update(h_Ksy=params.h2, h_Csy=params.h1)
    return np.array([values[name] for name in COEFFICIENT_NAMES], dtype=np.float64)


# ---------------------------------------------------------------------------------
# The right-hand side of one bogie. Generic in the scalar type (float or complex) so the
# complex-step Jacobian runs the very same code; branches compare real parts.
# ---------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _creep(y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p):
    """Creepages and saturated creep forces of both wheels of one wheelset, in contact axes.

    Returns (xi_x_left, xi_y_left, xi_sp_left, xi_x_right, xi_y_right, xi_sp_right,
    fx_left, fy_left, mz_left, fx_right, fy_right, mz_right): creepages after Eq. (30) with the
    curvature ``kappa`` of the track under the wheelset (Eq. C5: the wheelset's absolute yaw rate
    is dpsi + V kappa), Kalker's linear creep and the saturation of Eqs. (26)-(30).
    """
    e = p[P_E]
    r0 = p[P_R0]
    lam = p[P_LAM]
    f11 = p[P_F11]
    f12 = p[P_F12]
    f22 = p[P_F22]
    f33 = p[P_F33]
    half_w = 0.5 * p[P_WPA]
    inv_mu_n = 1.0 / (p[P_MU] * half_w)  # Eq. (28), N = Wpa/2 per wheel (Eq. 37)
    # Eq. (15): conical wheels, contact angle lam, rolling radii.
    r_left = r0 + lam * y_rel
    r_right = r0 - lam * y_rel
    # Creepages (after Eq. 30), with the curving terms of Eq. (C5).
    xi_x_left = -lam * y_rel / r0 - e * dpsi * inv_v - e * kappa
    xi_x_right = lam * y_rel / r0 + e * dpsi * inv_v + e * kappa
    xi_y_left = (dy + r_left * dphi) * inv_v - psi
    xi_y_right = (dy + r_right * dphi) * inv_v - psi
    xi_sp_left = dpsi * inv_v - lam / r0 + kappa
    xi_sp_right = dpsi * inv_v + lam / r0 + kappa
    # Kalker linear creep in the contact frame (Eqs. 29-30 and the spin moment).
    fx_left = -f33 * xi_x_left
    fy_left = -f11 * xi_y_left - f12 * xi_sp_left
    mz_left = f12 * xi_y_left - f22 * xi_sp_left
    fx_right = -f33 * xi_x_right
    fy_right = -f11 * xi_y_right - f12 * xi_sp_right
    mz_right = f12 * xi_y_right - f22 * xi_sp_right
    # Saturation, one factor per wheelset (Eqs. 26-28).
    beta_left = np.sqrt(fx_left * fx_left + fy_left * fy_left) * inv_mu_n
    beta_right = np.sqrt(fx_right * fx_right + fy_right * fy_right) * inv_mu_n
    alpha = _saturation(0.5 * (beta_left + beta_right))
    fx_left = alpha * fx_left
    fy_left = alpha * fy_left
    mz_left = alpha * mz_left
    fx_right = alpha * fx_right
    fy_right = alpha * fy_right
    mz_right = alpha * mz_right
    return (xi_x_left, xi_y_left, xi_sp_left, xi_x_right, xi_y_right, xi_sp_right,
            fx_left, fy_left, mz_left, fx_right, fy_right, mz_right)  # fmt: skip


@njit(cache=True, inline="always")
def _wheel_forces(y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p):
    """Forces of the rails on each wheel of one wheelset, in track axes.

    Returns (Fx_l, Fy_l, Fz_l, Mx_l, mz_l, Fx_r, Fy_r, Fz_r, Mx_r, mz_r, Ny_l, Ny_r, flange):
    creep forces and spin moments (Eqs. 16-25), the normal forces' lateral components
    (Eqs. 37-39) and the flange force (Eq. 46, acting on the left wheel when positive).
    """
    lam = p[P_LAM]
    half_w = 0.5 * p[P_WPA]
    (_, _, _, _, _, _, fx_left, fy_left, mz_left, fx_right, fy_right, mz_right) = _creep(
        y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p
    )
    # Creep forces and moments in track axes (Eqs. 16-25).
    incl_left = lam + phi  # contact-plane inclination, left
    incl_right = lam - phi
    Fx_l = fx_left - fy_left * psi
    Fy_l = fx_left * psi + fy_left
    Fz_l = fy_left * incl_left
    Mx_l = mz_left * incl_left * psi
    Fx_r = fx_right - fy_right * psi
    Fy_r = fx_right * psi + fy_right
    Fz_r = -fy_right * incl_right
    Mx_r = -mz_right * incl_right * psi
    # Normal forces (Eqs. 37-39); their vertical components cancel the axle load in Eq. (4).
    Ny_l = -half_w * incl_left
    Ny_r = half_w * incl_right
    flange = _flange(y_rel, p[P_DELTA], p[P_KR])  # Eq. (46)
    return Fx_l, Fy_l, Fz_l, Mx_l, mz_left, Fx_r, Fy_r, Fz_r, Mx_r, mz_right, Ny_l, Ny_r, flange


@njit(cache=True, inline="always")
def _wheel_rail_forces(y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p):
    """Wheel-rail forces on one wheelset, summed over both wheels, in track axes.

    Returns (lateral force, vertical force, yaw moment, roll moment): creep forces and spin
    moments (Eqs. 16-30), normal forces (Eqs. 37-39) with the contact positions (Eqs. 31-36),
    and the flange force (Eq. 46). The lateral force is EN 14363's sum of guiding forces.
    ``y_rel`` is the displacement relative to the track, ``kappa`` the track's curvature.
    """
    e = p[P_E]
    r0 = p[P_R0]
    lam = p[P_LAM]
    half_w = 0.5 * p[P_WPA]
    r_left = r0 + lam * y_rel
    r_right = r0 - lam * y_rel
    (Fx_l, Fy_l, Fz_l, Mx_l, mz_left, Fx_r, Fy_r, Fz_r, Mx_r, mz_right, Ny_l, Ny_r, flange) = _wheel_forces(
        y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p
    )
    # Contact-point positions (Eqs. 31-36).
    Rx_l = -e * psi
    Ry_l = e + r_left * phi
    Rz_l = e * phi - r_left
    Rx_r = e * psi
    Ry_r = -e + r_right * phi
    Rz_r = -e * phi - r_right
    lateral = Fy_l + Fy_r + Ny_l + Ny_r - flange
    vertical = Fz_l + Fz_r
    yaw = (Rx_r * Fy_r - Ry_r * Fx_r) + (Rx_l * Fy_l - Ry_l * Fx_l) + (Rx_r * Ny_r + Rx_l * Ny_l) + mz_left + mz_right
    roll = (
        (Ry_r * Fz_r - Rz_r * Fy_r)
        + (Ry_l * Fz_l - Rz_l * Fy_l)
        + (Ry_l * half_w - Rz_l * Ny_l)
        + (Ry_r * half_w - Rz_r * Ny_r)
        + Mx_l
        + Mx_r
    )
    return lateral, vertical, yaw, roll


@njit(cache=True, inline="always")
def _sample(yt, k):
    """Track sample k; 0 when the caller passed fewer samples (the alignment alone: straight track)."""
    if k < yt.shape[0]:
        return yt[k]
    return 0.0


@njit(cache=True, inline="always")
def _cant_trig_frame(yt):
    """(cos, sin) of the cant angle under the frame, as :func:`_cant_trig`."""
    cant_b = _sample(yt, CANT_FRAME)
    return (1.0, cant_b) if cant_b == 0.0 else (np.cos(cant_b), np.sin(cant_b))


@njit(cache=True, inline="always")
def _cant_trig(yt):
    """(cos, sin) of the cant angle under the frame, wheelset 1 and wheelset 2, flattened: the only
    transcendental calls of the right-hand side, apart so that SIMD lanes can make them one lane
    at a time (:func:`_rhs_lanes`). Without cant (straight track, uncanted
    curves) they are (1, cant) without the calls: cos(+-0) = 1 and sin(+-0) = +-0 exactly."""
    cos_b, sin_b = _cant_trig_frame(yt)
    cant1 = _sample(yt, CANT_WHEELSET1)
    cant2 = _sample(yt, CANT_WHEELSET1 + 1)
    cos1, sin1 = (1.0, cant1) if cant1 == 0.0 else (np.cos(cant1), np.sin(cant1))
    cos2, sin2 = (1.0, cant2) if cant2 == 0.0 else (np.cos(cant2), np.sin(cant2))
    return cos_b, sin_b, cos1, sin1, cos2, sin2


@njit(cache=True, inline="always")
def _unbalanced_acceleration(V, kappa, cos_cant, sin_cant):
    """Eq. (C1), ``V^2 kappa cos(cant) - g sin(cant)``."""
    return V * V * kappa * cos_cant - GRAVITY * sin_cant


@njit(cache=True, inline="always")
def _primary_lateral(i, x, V, yt, p):
    """Wheelset i's track curvature, the heading of its track axes seen from the frame's and
    that heading's rate (Eqs. C6-C7, trapezoidal in curvature), and its primary lateral spring
    and damper forces (Eqs. 40-41, corrected; Eq. C8 in curves): the part of
    :func:`_wheelset_rhs` that the frame's lateral equation needs, without the contact."""
    L1 = p[P_L1]
    L2 = p[P_L2]
    kappa_b = _sample(yt, CURVATURE_FRAME)
    o = 8 * i
    side = 1.0 - 2.0 * i  # +1 front (x = +L1), -1 rear
    kappa = _sample(yt, CURVATURE_WHEELSET1 + i)
    d = side * L1
    heading = 0.5 * d * (kappa_b + kappa)
    offset = d * d * (2.0 * kappa_b + kappa) / 6.0
    heading_rate = V * (kappa - kappa_b)
    offset_rate = V * (heading - d * kappa_b)
    spring_y = 2.0 * p[P_KPY] * (x[o] + offset - x[16] - side * L1 * x[18])
    damper_y = 2.0 * p[P_CPY] * (x[o + 1] + offset_rate - x[17] - side * L2 * x[19])
    return kappa, heading, heading_rate, spring_y, damper_y


@njit(cache=True, inline="always")
def _wheelset_rhs(i, x, V, Q, yt, trig, p, out):
    """Eqs. (3)-(6) of wheelset i (0 front, 1 rear) into out[8 i : 8 i + 8], with the cants' cos
    and sin ``trig`` (:func:`_cant_trig`); returns its reactions on the frame, (lateral force,
    yaw moment) (Eqs. 44-45). Straight-line code without calls (branches are selects)."""
    mw = p[P_MW]
    L1 = p[P_L1]
    L2 = p[P_L2]
    b1sq = p[P_B1] * p[P_B1]
    yaw_k = 2.0 * p[P_KPX] * b1sq
    yaw_c = 2.0 * p[P_CPX] * b1sq
    roll_k = 2.0 * p[P_KPZ] * b1sq
    roll_c = 2.0 * p[P_CPZ] * b1sq
    inv_v = 1.0 / V
    gyro = p[P_IWY] * V / p[P_R0]  # wheelset spin V/r0 times its pitch inertia
    yb = x[16]
    dyb = x[17]
    psib = x[18]
    dpsib = x[19]
    o = 8 * i
    dy = x[o + 1]
    dpsi = x[o + 5]
    dphi = x[o + 7]
    side = 1.0 - 2.0 * i  # +1 front (x = +L1), -1 rear
    kappa, heading, heading_rate, spring_y, damper_y = _primary_lateral(i, x, V, yt, p)
    accel = _unbalanced_acceleration(V, kappa, trig[2 + 2 * i], trig[3 + 2 * i])  # Eq. (C1)
    lateral, vertical, yaw, roll = _wheel_rail_forces(
        x[o] - yt[ALIGNMENT_WHEELSET1 + i], dy, x[o + 4], dpsi, x[o + 6], dphi, inv_v, kappa, p
    )
    yaw_moment = yaw_k * (x[o + 4] + heading - psib) + yaw_c * (dpsi + heading_rate - dpsib)
    # Eq. (3) lateral, with the unbalanced acceleration (Eq. C2)
    out[o] = dy
    out[o + 1] = (lateral - spring_y - damper_y) / mw - accel
    # Eq. (4) vertical
    out[o + 2] = x[o + 3]
    out[o + 3] = (vertical - 2.0 * p[P_KPZ] * x[o + 2] - 2.0 * p[P_CPZ] * x[o + 3]) / mw
    # Eq. (5) yaw: gyroscopic coupling, wheel-rail moments, primary suspension, input
    out[o + 4] = dpsi
    out[o + 5] = (-gyro * dphi + yaw - yaw_moment + Q[2 + i]) / p[P_IWZ]
    # Eq. (6) roll, with the secondary-suspension moment of Eq. (43)
    m_roll = (
        gyro * dpsi
        + gyro * V * kappa  # Eq. (C5): the absolute yaw rate includes V kappa
        + roll
        - 2.0 * p[P_KSY] * p[P_H_KSY] * yb
        - 2.0 * p[P_CSY] * p[P_H_CSY] * dyb
        - roll_k * x[o + 6]
        - roll_c * dphi
    )
    out[o + 6] = dphi
    out[o + 7] = m_roll / p[P_IWX]
    # Reactions on the frame (Eqs. 44-45).
    return spring_y + damper_y, side * (L1 * spring_y + L2 * damper_y) + yaw_moment


@njit(cache=True, inline="always")
def _frame_lateral(x, V, Q, yt, cos_b, sin_b, p, frame_force):
    """Eq. (1): the frame's lateral acceleration, with the wheelsets' reactions ``frame_force``
    and the unbalanced acceleration of the frame and the car body's share (Eqs. C1-C3)."""
    accel_b = _unbalanced_acceleration(V, _sample(yt, CURVATURE_FRAME), cos_b, sin_b)
    carried = 2.0 * p[P_WPA] / GRAVITY - 2.0 * p[P_MW] - p[P_MB]
    if carried < 0.0:
        carried = 0.0
    return (frame_force - 2.0 * p[P_KSY] * x[16] - 2.0 * p[P_CSY] * x[17] + Q[0] - (p[P_MB] + carried) * accel_b) / p[P_MB]


@njit(cache=True, inline="always")
def frame_lateral_accel(x, V, Q, yt, p):
    """The frame's lateral acceleration, out[17] of :func:`_rhs_row`, without the wheel-rail
    contact (the frame feels the wheelsets through the primary suspension only): the same
    functions in the same order, so the same bits at a fraction of the cost."""
    frame_force = 0.0 * x[16]
    for i in range(2):
        _, _, _, spring_y, damper_y = _primary_lateral(i, x, V, yt, p)
        frame_force += spring_y + damper_y
    cos_b, sin_b = _cant_trig_frame(yt)
    return _frame_lateral(x, V, Q, yt, cos_b, sin_b, p, frame_force)


@njit(cache=True, inline="always")
def _frame_rhs(x, V, Q, yt, trig, p, frame_force, frame_moment, out):
    """Eqs. (1)-(2) with (44)-(45) into out[16:20]: the frame on the secondary suspension to a car
    body that follows the track, with the wheelsets' reactions ``frame_force``, ``frame_moment``;
    in curves the frame and the car body's share carry the unbalanced acceleration (Eqs. C1-C3;
    exact zeros on straight track without cant, docs/model.md Section 11)."""
    yb = x[16]
    dyb = x[17]
    psib = x[18]
    dpsib = x[19]
    out[16] = dyb
    out[17] = _frame_lateral(x, V, Q, yt, trig[0], trig[1], p, frame_force)
    out[18] = dpsib
    out[19] = (
        frame_moment
        - 2.0 * p[P_KSX] * p[P_B2] * p[P_B2] * psib
        - 2.0 * p[P_CSX] * p[P_B3] * p[P_B3] * dpsib
        + Q[1]
    ) / p[P_IBZ]


@njit(cache=True, inline="always")
def _rhs_row(x, V, Q, yt, p, out):
    """The right-hand side of one bogie into out (20,): state x (20,), speed V, inputs Q (4,),
    track samples yt (N_TRACK,), coefficients p. Generic in the scalar type of x (float or complex)."""
    trig = _cant_trig(yt)
    frame_force = 0.0 * x[16]
    frame_moment = 0.0 * x[16]
    for i in range(2):
        force, moment = _wheelset_rhs(i, x, V, Q, yt, trig, p, out)
        frame_force += force
        frame_moment += moment
    _frame_rhs(x, V, Q, yt, trig, p, frame_force, frame_moment, out)


# error_model="numpy" as the stepping kernels (a division by zero gives inf, not an exception);
# _nrt=False (numba's private option): no reference counts on its array arguments, as in the
# row loops that call it (atomic counts across threads cost time, docs/performance.md)
@njit(cache=True, error_model="numpy", _nrt=False)
def rhs_row_call(x, V, Q, yt, p, out):
    """:func:`_rhs_row` as a compiled function of its own, for compiled callers outside the stepping
    interval (studies, benchmarks): each kernel that calls it links it instead
    of re-running numba's inlining of the whole right-hand side, which is most of their
    compilation time. Same arithmetic, same bits."""
    _rhs_row(x, V, Q, yt, p, out)


@njit(cache=True, inline="always")
def _rhs_lanes(x, V, Q, yt, trig, p, out, frame):
    """:func:`_rhs_row` of a lane block (:mod:`bogie_env.lanes`): each argument with a last axis
    of lanes, the cants' cos and sin given (``trig`` (6, lanes), :func:`_cant_trig`), ``frame``
    (2, lanes) scratch for the frame reactions. The same functions in the same order per lane;
    the lane loops are innermost and call straight-line code, so they compile to SIMD
    instructions across the lanes."""
    lanes = x.shape[1]
    for lane in range(lanes):
        frame[0, lane] = 0.0 * x[16, lane]
        frame[1, lane] = 0.0 * x[16, lane]
    for i in range(2):
        for lane in range(lanes):
            force, moment = _wheelset_rhs(i, x[:, lane], V[lane], Q[:, lane], yt[:, lane], trig[:, lane], p[:, lane],
                                          out[:, lane])  # fmt: skip
            frame[0, lane] += force
            frame[1, lane] += moment
    for lane in range(lanes):
        _frame_rhs(x[:, lane], V[lane], Q[:, lane], yt[:, lane], trig[:, lane], p[:, lane], frame[0, lane], frame[1, lane],
                   out[:, lane])  # fmt: skip


@njit(cache=True, inline="always")
def _guiding_forces_row(x, V, yt, p, out):
    """EN 14363's sum of guiding forces, the lateral wheel-rail force on each wheelset (N)."""
    inv_v = 1.0 / V
    for i in range(2):
        o = 8 * i
        out[i] = _wheel_rail_forces(x[o] - yt[ALIGNMENT_WHEELSET1 + i], x[o + 1], x[o + 4], x[o + 5], x[o + 6], x[o + 7],
                                    inv_v, _sample(yt, CURVATURE_WHEELSET1 + i), p)[0]  # fmt: skip


@njit(cache=True)
def guiding_forces_kernel(x, V, yt, p, out):
    """Sum of guiding forces for N bogies: x (N, 20), V (N,), yt (N, 2), out (N, 2)."""
    for n in range(x.shape[0]):
        _guiding_forces_row(x[n], V[n], yt[n], p, out[n])


@njit(cache=True, error_model="numpy")
def solve_dense(a, b):
    """x with a x = b, for a small dense square a, by Gaussian elimination with partial pivoting
    (row swaps by the largest magnitude); NaNs where a is singular.

    Why not LAPACK: its kernels are chosen at run time by the processor (OpenBLAS picks Haswell,
    Zen, SkylakeX, ... code), and they round differently, so the equilibrium that every episode
    starts from moved in its last bits from one machine to the next, and with it every seeded
    trajectory. These IEEE operations in a fixed order give the same bits on any x86-64 host
    (numba compiles without fused multiply-adds unless fastmath asks for them)."""
    n = a.shape[0]
    m = a.copy()
    x = b.copy()
    for k in range(n):
        pivot = k
        for i in range(k + 1, n):
            if abs(m[i, k]) > abs(m[pivot, k]):
                pivot = i
        if m[pivot, k] == 0.0:
            x[:] = np.nan
            return x
        if pivot != k:
            for j in range(n):
                m[k, j], m[pivot, j] = m[pivot, j], m[k, j]
            x[k], x[pivot] = x[pivot], x[k]
        for i in range(k + 1, n):
            factor = m[i, k] / m[k, k]
            for j in range(k + 1, n):
                m[i, j] -= factor * m[k, j]
            x[i] -= factor * x[k]
    for k in range(n - 1, -1, -1):
        total = x[k]
        for j in range(k + 1, n):
            total -= m[k, j] * x[j]
        x[k] = total / m[k, k]
    return x


@njit(cache=True)
def rhs_single_kernel(x, V, Q, yt, p, out):
    """One bogie: x (20,), V float, Q (4,), yt (2,), p coefficients, out (20,). Unchecked."""
    _rhs_row(x, V, Q, yt, p, out)


@njit(cache=True, parallel=True)
def rhs_batch_kernel(x, V, Q, yt, p, out):
    """N bogies in parallel: x (N, 20), V (N,), Q (N, 4), yt (N, 2), out (N, 20). Unchecked."""
    for n in prange(x.shape[0]):
        _rhs_row(x[n], V[n], Q[n], yt[n], p, out[n])


@njit(cache=True)
def jacobian_kernel(x, V, Q, yt, p, jac):
    """Complex-step Jacobian d(rhs)/dx of one bogie, exact to rounding (step 1e-30)."""
    h = 1e-30
    xc = np.empty(N_STATES, dtype=np.complex128)
    out = np.empty(N_STATES, dtype=np.complex128)
    for j in range(N_STATES):
        for k in range(N_STATES):
            xc[k] = x[k]
        xc[j] += 1j * h
        _rhs_row(xc, V, Q, yt, p, out)
        for k in range(N_STATES):
            jac[k, j] = out[k].imag / h


@njit(cache=True)
def _newton_equilibrium(v, q, yt, p, tol):
    """Newton from rest on ``rhs = 0`` (:meth:`BogieModel.equilibrium`): the state and -1 when
    converged, else the last state and its residual's max norm."""
    x = np.zeros(N_STATES)
    f = np.empty(N_STATES)
    jac = np.empty((N_STATES, N_STATES))
    for _ in range(50):
        rhs_single_kernel(x, v, q, yt, p, f)
        if np.max(np.abs(f)) < tol:
            return x, -1.0
        jacobian_kernel(x, v, q, yt, p, jac)
        step = solve_dense(jac, -f)
        x = x + step
        if not np.all(np.isfinite(x)):
            break
        if np.max(np.abs(step)) < 1e-16:
            return x, -1.0
    return x, np.max(np.abs(f))


# ---------------------------------------------------------------------------------
# Checked Python front-end
# ---------------------------------------------------------------------------------


def check_speed(speed: np.ndarray | float, name: str = "speed") -> np.ndarray:
    """Speeds in m/s as a float64 array; raises if any is NaN, inf or outside the model range."""
    if type(speed) in (float, np.float64) and MIN_SPEED <= speed <= MAX_SPEED:  # a scalar in range (resets: twice a row)
        return np.asarray(speed, dtype=np.float64)
    v = np.asarray(speed, dtype=np.float64)
    if v.size and MIN_SPEED <= v.min() and v.max() <= MAX_SPEED:  # all in range (NaN fails the comparisons)
        return v
    bad = ~np.isfinite(v) | (v < MIN_SPEED) | (v > MAX_SPEED)
    if np.any(bad):
        value = float(v.flat[int(np.argmax(bad.ravel()))])
        raise ValueError(
            f"{name} = {value:.6g} m/s ({value * 3.6:.6g} km/h) is not allowed; "
            f"allowed: finite, {MIN_SPEED:g} to {MAX_SPEED:g} m/s ({MIN_SPEED * 3.6:g} to {MAX_SPEED * 3.6:g} km/h)"
        )
    return v


def _as_rows(array, width: int, n_rows: int | None, name: str) -> np.ndarray:
    a = np.asarray(array, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != width or (n_rows is not None and a.shape[0] not in (1, n_rows)):
        expected = f"({width},) or (N, {width})" + (f" with N = {n_rows}" if n_rows is not None else "")
        raise ValueError(f"{name} has shape {np.shape(array)}; expected {expected}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf; all entries must be finite")
    if n_rows is not None and a.shape[0] != n_rows:
        a = np.broadcast_to(a, (n_rows, width))
    return np.ascontiguousarray(a)


def _track_rows(track, n_rows: int) -> np.ndarray:
    """Track samples (N_TRACK,) or (N, N_TRACK) as rows; the two alignment samples alone (width 2)
    mean straight track without cant."""
    if track is None:
        return np.zeros((n_rows, N_TRACK))
    a = np.asarray(track, dtype=np.float64)
    if a.shape[-1:] == (2,) and N_TRACK != 2:
        full = np.zeros(a.shape[:-1] + (N_TRACK,))
        full[..., ALIGNMENT_WHEELSET1 : ALIGNMENT_WHEELSET1 + 2] = a
        a = full
    return _as_rows(a, N_TRACK, n_rows, "track")


class BogieModel:
    """The physics of one bogie design: parameters, contact coefficients and the equations.

    It evaluates the right-hand side and its Jacobian for any batch of states, with named
    accessors for states and inputs. It holds no simulation state; simulators and
    environments own that.
    """

    state_names = STATE_NAMES
    input_names = INPUT_NAMES

    def __init__(self, params: BogieParams | None = None) -> None:
        self.params = params if params is not None else BogieParams.paper()
        self.creep = creep_coefficients(self.params)
        self.coefficients = coefficient_vector(self.params, self.creep)
        self.coefficients.setflags(write=False)

    def __repr__(self) -> str:
        return f"BogieModel(params={self.params.source or 'custom'!r})"

    # ---- right-hand side ---------------------------------------------------------------
    def rhs(
        self,
        state: np.ndarray,
        speed: np.ndarray | float,
        inputs: np.ndarray | None = None,
        track: np.ndarray | None = None,
    ) -> np.ndarray:
        """dx/dt for one state (20,) or a batch (N, 20); speed in m/s, scalar or (N,)."""
        single = np.ndim(state) == 1
        x = _as_rows(state, N_STATES, None, "state")
        n = x.shape[0]
        v = np.broadcast_to(check_speed(speed), (n,)) if np.ndim(speed) == 0 else check_speed(speed)
        if v.shape != (n,):
            raise ValueError(f"speed has shape {np.shape(speed)}; expected a scalar or ({n},)")
        q = _as_rows(np.zeros(N_INPUTS) if inputs is None else inputs, N_INPUTS, n, "inputs")
        yt = _track_rows(track, n)
        out = np.empty((n, N_STATES))
        # a writable contiguous copy whatever the caller passed: one compiled signature (a broadcast
        # speed is read-only, which numba types, and compiles, separately)
        rhs_batch_kernel(x, np.require(v, np.float64, ("C", "W")), q, yt, self.coefficients, out)
        return out[0] if single else out

    def jacobian(
        self,
        state: np.ndarray,
        speed: float,
        inputs: np.ndarray | None = None,
        track: np.ndarray | None = None,
    ) -> np.ndarray:
        """The exact (complex-step) Jacobian d(rhs)/d(state) at one state, shape (20, 20)."""
        x = _as_rows(state, N_STATES, 1, "state")[0]
        v = float(check_speed(speed))
        q = _as_rows(np.zeros(N_INPUTS) if inputs is None else inputs, N_INPUTS, 1, "inputs")[0]
        yt = _track_rows(track, 1)[0]
        jac = np.empty((N_STATES, N_STATES))
        jacobian_kernel(np.ascontiguousarray(x), v, q, yt, self.coefficients, jac)
        return jac

    def input_matrix(self) -> np.ndarray:
        """B = d(rhs)/d(inputs), shape (20, 4); the inputs enter linearly."""
        b = np.zeros((N_STATES, N_INPUTS))
        p = self.coefficients
        b[state_index("dyb"), 0] = 1.0 / p[P_MB]
        b[state_index("dpsib"), 1] = 1.0 / p[P_IBZ]
        b[state_index("dpsi1"), 2] = 1.0 / p[P_IWZ]
        b[state_index("dpsi2"), 3] = 1.0 / p[P_IWZ]
        return b

    # ---- equilibrium -------------------------------------------------------------------
    def equilibrium(self, speed: float, inputs: np.ndarray | None = None, tol: float = 1e-13) -> np.ndarray:
        """The steady state on straight, perfect track, by Newton iteration from rest.

        It is not exactly zero: the constant spin creepage -+lam/r0 of the coned wheels
        pushes both wheels' lateral creep forces into the contact planes, whose vertical
        components lift the wheelset by ``z0 = alpha0 f12 lam^2 / (r0 Kpz)`` (Eq. 48's
        constant term). All lateral, yaw and roll states are zero by mirror symmetry.
        """
        return equilibrium_state(self.coefficients, speed, inputs, tol)


def equilibrium_state(coefficients: np.ndarray, speed: float, inputs: np.ndarray | None = None,
                      tol: float = 1e-13) -> np.ndarray:  # fmt: skip
    """:meth:`BogieModel.equilibrium` of the bogie with this coefficient vector (a reset's
    scenario, without building its model)."""
    v = float(check_speed(speed))
    q = _NO_INPUTS if inputs is None else _as_rows(inputs, N_INPUTS, 1, "inputs")[0]
    x, residual = _newton_equilibrium(v, q, _NO_TRACK, coefficients, tol)
    if residual < 0.0:
        return x
    raise RuntimeError(f"equilibrium: Newton did not converge at {speed} m/s (residual {residual:.3g})")


_NO_INPUTS, _NO_TRACK = np.zeros(N_INPUTS), np.zeros(N_TRACK)  # writable: numba types read-only arrays apart
