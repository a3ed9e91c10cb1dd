"""Wheel-rail quantities at a state: creepages, creep forces, Y per wheel, the sum of guiding
forces ΣY and the wear number Tγ per wheelset, flange contact.

The same compiled contact functions as the right-hand side (``dynamics._creep``,
``dynamics._wheel_forces``). The env's route variant reads its curving quantities through
:func:`wheelset_details` (inside its step kernel); :func:`wheel_rail_quantities` gives them for
states in bulk (the curving analysis, :mod:`bogie_env.analysis.curving`).

Sign conventions (model axes: x forward, y left): lateral displacement from the local track
centreline, + left; angle of attack = the wheelset's yaw from the local track tangent, + nose
left; creep forces of the rail on the wheel in contact axes, longitudinal + forward, lateral +
left; Y of each wheel = the lateral force the wheel puts on its rail, + towards the outside of
the track for that rail (the derailment sign), Q = the model's wheel load Wpa/2; ΣY = the
lateral force of the wheelset on the track, + left; Tγ = -(Fx ξx + Fy ξy) per wheel, the creep
work per metre rolled (N), summed per wheelset.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .dynamics import N_TRACK, P_DELTA, P_WPA, BogieModel, _creep, _wheel_forces
from .track import ALIGNMENT_WHEELSET1, CURVATURE_WHEELSET1

# Columns of the per-wheelset details (wheel_rail_details_kernel).
DETAIL_NAMES = (
    "xi_x_left", "xi_y_left", "xi_sp_left", "xi_x_right", "xi_y_right", "xi_sp_right",
    "fx_left", "fy_left", "fx_right", "fy_right", "y_left", "y_right", "flange", "guiding",
)  # fmt: skip
(XI_X_L, XI_Y_L, XI_SP_L, XI_X_R, XI_Y_R, XI_SP_R, FX_L, FY_L, FX_R, FY_R, Y_L, Y_R, FLANGE, GUIDING) = range(
    len(DETAIL_NAMES)
)


@njit(cache=True, inline="always")
def wheelset_details(x, inv_v, yt, p, i, row):
    """The DETAIL_NAMES columns of wheelset i (0 front, 1 rear) of one bogie into row
    (len(DETAIL_NAMES),): state x (20,), 1/speed, track samples yt (N_TRACK,), coefficients p.

    The same compiled contact functions as the right-hand side (``dynamics._creep``,
    ``dynamics._wheel_forces``); Y per wheel is the force on its rail, + outwards. The env's
    route variant reads its curving quantities through this function too (in its step kernel).
    """
    o = 8 * i
    y_rel = x[o] - yt[ALIGNMENT_WHEELSET1 + i]
    kappa = yt[CURVATURE_WHEELSET1 + i]
    dy, psi, dpsi, phi, dphi = x[o + 1], x[o + 4], x[o + 5], x[o + 6], x[o + 7]
    (xxl, xyl, xsl, xxr, xyr, xsr, fxl, fyl, _, fxr, fyr, _) = _creep(y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p)
    (_, Fy_l, _, _, _, _, Fy_r, _, _, _, Ny_l, Ny_r, flange) = _wheel_forces(y_rel, dy, psi, dpsi, phi, dphi, inv_v, kappa, p)
    row[XI_X_L] = xxl
    row[XI_Y_L] = xyl
    row[XI_SP_L] = xsl
    row[XI_X_R] = xxr
    row[XI_Y_R] = xyr
    row[XI_SP_R] = xsr
    row[FX_L] = fxl
    row[FY_L] = fyl
    row[FX_R] = fxr
    row[FY_R] = fyr
    # The flange force acts on the left wheel when positive (y_rel >= delta), else on the right.
    row[Y_L] = -(Fy_l + Ny_l - max(flange, 0.0))
    row[Y_R] = Fy_r + Ny_r - min(flange, 0.0)
    row[FLANGE] = flange
    row[GUIDING] = -(Fy_l + Fy_r + Ny_l + Ny_r - flange)


@njit(cache=True, inline="always")
def wheelset_wear_number(row):
    """The wear number Tγ of one wheelset from its details row: -(Fx ξx + Fy ξy) summed over
    both wheels (N; the creep work per metre rolled)."""
    return -(row[FX_L] * row[XI_X_L] + row[FY_L] * row[XI_Y_L] + row[FX_R] * row[XI_X_R] + row[FY_R] * row[XI_Y_R])


@njit(cache=True)
def wheel_rail_details_kernel(x, V, yt, p, out):
    """Per record n and wheelset i, the DETAIL_NAMES columns into out (N, 2, len(DETAIL_NAMES))
    (:func:`wheelset_details`)."""
    for n in range(x.shape[0]):
        inv_v = 1.0 / V[n]
        for i in range(2):
            wheelset_details(x[n], inv_v, yt[n], p, i, out[n, i])



def wheel_rail_quantities(model: BogieModel, states: np.ndarray, speeds: np.ndarray, samples: np.ndarray) -> dict:
    """The curving quantities at states (N, 20), speeds (N,) m/s and track samples (N, N_TRACK)."""
    x = np.ascontiguousarray(np.atleast_2d(states), dtype=np.float64)
    n = x.shape[0]
    v = np.ascontiguousarray(np.broadcast_to(np.asarray(speeds, dtype=np.float64), (n,)))
    yt = np.ascontiguousarray(np.broadcast_to(samples, (n, N_TRACK)), dtype=np.float64)
    out = np.empty((n, 2, len(DETAIL_NAMES)))
    wheel_rail_details_kernel(x, v, yt, model.coefficients, out)
    q = 0.5 * model.coefficients[P_WPA]
    wheel = lambda left, right: np.stack([out[..., left], out[..., right]], axis=-1)  # noqa: E731  (N, 2, 2)
    fx, fy = wheel(FX_L, FX_R), wheel(FY_L, FY_R)
    wear = -(fx * wheel(XI_X_L, XI_X_R) + fy * wheel(XI_Y_L, XI_Y_R))
    return {
        "lateral_displacement_m": x[:, [0, 8]] - yt[:, [ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET1 + 1]],
        "angle_of_attack_rad": x[:, [4, 12]],
        "creep_force_longitudinal_n": fx,
        "creep_force_lateral_n": fy,
        "wheel_lateral_force_n": wheel(Y_L, Y_R),
        "y_over_q": wheel(Y_L, Y_R) / q,
        "guiding_force_n": out[..., GUIDING],
        "wear_number_wheel_n": wear,
        "wear_number_n": wear.sum(axis=-1),
        "flange_force_n": out[..., FLANGE],
        "flange_contact": np.abs(x[:, [0, 8]] - yt[:, [ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET1 + 1]])
        >= model.coefficients[P_DELTA],
    }
