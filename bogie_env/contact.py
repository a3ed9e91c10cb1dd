"""Wheel-rail contact mechanics: Hertz ellipse, Kalker coefficients, saturation, flange.

- :func:`hertz_ellipse` solves Hertz's problem exactly with complete elliptic integrals
  (Johnson, *Contact Mechanics*, 1985, Sec. 4.2); the paper cites Hertz [27, 28].
- :func:`kalker_coefficients` implements the paper's fits, Eqs. (11)-(14), with the two
  corrections recorded in ``docs/model.md`` (Eq. 12 lost a ``ν g`` term; Eq. 14 is a fit in
  ``b/a``, not ``a/b``).
- :func:`creep_coefficients` gives Eqs. (7)-(10).
- :func:`saturation_factor` is Eq. (26), with the saturated branch corrected to ``1/β``.
- :func:`flange_force` is Eq. (46).

The compiled kernels in :mod:`bogie_env.dynamics` call the scalar ``_saturation`` and
``_flange`` functions defined here, so there is one implementation of each law.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.special import ellipe, ellipk

from .params import BogieParams
from .rootfind import brentq  # scipy.optimize.brentq, bit for bit, without its 0.3-s import

# ---------------------------------------------------------------------------------
# Hertz
# ---------------------------------------------------------------------------------


def _hertz_ratio(m: float) -> float:
    """B/A as a function of m = e^2 = 1 - (b/a)^2 for a >= b (Johnson Eq. 4.39)."""
    k_m, e_m = ellipk(m), ellipe(m)
    return (e_m / (1.0 - m) - k_m) / (k_m - e_m)


@lru_cache(maxsize=256)
def _k_minus_e_over_m(m: float) -> float:
    """(K(m) - E(m)) / m, with its series near m = 0 where the difference cancels."""
    if m < 1e-6:
        return math.pi / 4.0 * (1.0 + 3.0 * m / 8.0)
    return (ellipk(m) - ellipe(m)) / m


@lru_cache(maxsize=256)
def _eccentricity_squared(ratio: float) -> float:
    """Solve B/A = ratio (>= 1) for m = e^2; cached, since load variants share the shape."""
    if ratio - 1.0 < 1e-12:
        return 0.0
    # _hertz_ratio rises monotonically from 1 (m = 0) to infinity (m -> 1).
    return brentq(lambda mm: _hertz_ratio(mm) - ratio, 1e-9, 1.0 - 1e-15, xtol=1e-15, rtol=1e-14)


@dataclass(frozen=True)
class HertzContact:
    """Hertz contact ellipse: ``a`` along the rolling direction x, ``b`` lateral, in m."""

    a: float
    b: float
    A: float
    B: float
    normal_load: float

    @property
    def ratio(self) -> float:
        """g = a/b, the argument of the Kalker fits (Eqs. 11-14)."""
        return self.a / self.b


def hertz_ellipse(normal_load: float, A: float, B: float, E: float, nu: float) -> HertzContact:
    """Semi-axes of the Hertz contact ellipse between two identical elastic bodies.

    ``A`` and ``B`` are the relative curvature sums (1/m) in the rolling (x) and lateral (y)
    planes: ``A = (1/R1x + 1/R2x)/2`` and ``B = (1/R1y + 1/R2y)/2``. The longer semi-axis
    lies along the direction of the smaller curvature. With ``1/E* = 2(1-nu^2)/E`` and the
    eccentricity ``e^2 = 1 - (short/long)^2`` solving ``B/A`` (Johnson Eq. 4.39),
    ``long^3 = 3 N (K - E) / (2 pi E* e^2 A_long)``. For ``A = B`` this reduces to the
    sphere-on-flat radius ``(3 N R / (4 E*))^(1/3)`` with ``R = 1/(2A)``.
    """
    for name, value in (("normal_load", normal_load), ("A", A), ("B", B), ("E", E)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"hertz_ellipse: {name} = {value!r} must be finite and > 0")
    if not 0.0 <= nu < 0.5 + 1e-12:
        raise ValueError(f"hertz_ellipse: nu = {nu!r} must be in [0, 0.5]")
    a, b = _semi_axes(normal_load, A, B, E / (2.0 * (1.0 - nu * nu)), _eccentricity_squared(max(A, B) / min(A, B)))
    return HertzContact(a=a, b=b, A=A, B=B, normal_load=normal_load)


def _semi_axes(normal_load: float, A: float, B: float, e_star: float, m: float) -> tuple[float, float]:
    """(a, b) of :func:`hertz_ellipse`, given ``E*`` and the eccentricity ``m`` of ``A/B``."""
    small = A if A <= B else B
    semi_long = (3.0 * normal_load * _k_minus_e_over_m(m) / (2.0 * math.pi * e_star * small)) ** (1.0 / 3.0)
    semi_short = semi_long * math.sqrt(1.0 - m)
    return (semi_long, semi_short) if A <= B else (semi_short, semi_long)


def wheel_rail_curvatures(params: BogieParams) -> tuple[float, float]:
    """Relative curvature sums (A, B) of the tread contact.

    Rolling plane: wheel radius r0 against a straight rail. Lateral plane: the wheel's
    transverse radius (infinite for the paper's cone) against the rail-head crown radius.
    """
    A = 0.5 * (1.0 / params.r0)
    B = 0.5 * (1.0 / params.Rwheel + 1.0 / params.Rrail)
    return A, B


# ---------------------------------------------------------------------------------
# Kalker
# ---------------------------------------------------------------------------------


def kalker_coefficients(g: float, nu: float) -> tuple[float, float, float, float]:
    """Kalker's coefficients (c11, c22, c23, c33) from the paper's fits, Eqs. (11)-(14).

    ``g = a/b`` (longitudinal over lateral semi-axis). Corrections, with the evidence in
    ``docs/model.md`` and ``tests/test_contact.py`` (Kalker's table as oracle):

    - Eq. (12) prints a bare ``1.163``; the term is ``1.163 ν g``, which reproduces the
      table (``c22 = 3.67`` at ``g = 1, ν = 0.25``) where a constant or ``ν²`` cannot.
    - Eq. (14) decreases with ``b/a`` as Kalker's ``C33`` does; it is a fit in ``b/a``,
      so it is evaluated at ``1/g``.
    """
    if not (math.isfinite(g) and g > 0):
        raise ValueError(f"kalker_coefficients: g = a/b = {g!r} must be finite and > 0")
    v = nu
    c11 = 2.39 + 2.338 * v + 1.014 * g + 2.736 * v * v - 0.0728 * v * g - 0.0139 * g * g  # Eq. (11)
    c22 = 2.353 - 0.0212 * v + 1.074 * g + 1.163 * v * g - 0.0319 * g * g  # Eq. (12), corrected
    c23 = (
        0.2866 + 0.4467 * v + 1.049 * g + 0.038 * v * g - 0.0177 * g * g + 0.005 * g**3 + 0.1479 * g * g * v
    )  # Eq. (13)
    q = 1.0 / g
    c33 = 0.7375 - 1.177 * v + 0.4506 * q + 1.076 * v * q - 0.023 * q * q  # Eq. (14), in b/a
    return c11, c22, c23, c33


@dataclass(frozen=True)
class CreepCoefficients:
    """Kalker linear creep coefficients, Eqs. (7)-(10), paper naming.

    ``f11`` lateral (N), ``f12`` lateral/spin (N m), ``f22`` spin (N m^2),
    ``f33`` longitudinal (N). ``contact`` is the Hertz ellipse they came from.
    """

    f11: float
    f12: float
    f22: float
    f33: float
    contact: HertzContact | None


def creep_coefficients(params: BogieParams) -> CreepCoefficients:
    """Eqs. (7)-(10) on the Hertz ellipse of one wheel under the static load ``Wpa/2`` (Eq. 37).

    Any of ``f11, f12, f22, f33`` set in ``params`` overrides the computed value.
    """
    A, B = wheel_rail_curvatures(params)
    contact = hertz_ellipse(0.5 * params.Wpa, A, B, params.E, params.nu)
    computed = dict(zip(CREEP_NAMES, _creep_from_axes(contact.a, contact.b, params.E, params.nu)))
    values = {name: (getattr(params, name) if getattr(params, name) is not None else computed[name]) for name in computed}
    return CreepCoefficients(contact=contact, **values)


CREEP_NAMES = ("f11", "f12", "f22", "f33")


def _creep_from_axes(a: float, b: float, E: float, nu: float) -> tuple[float, float, float, float]:
    """(f11, f12, f22, f33), Eqs. (7)-(10), on the contact ellipse with semi-axes a, b."""
    shear_modulus = E / (2.0 * (1.0 + nu))
    c11, c22, c23, c33 = kalker_coefficients(a / b, nu)
    area = a * b
    return (area * shear_modulus * c22,  # Eq. (7)
            area**1.5 * shear_modulus * c23,  # Eq. (8)
            area**2 * shear_modulus * c33,  # Eq. (9)
            area * shear_modulus * c11)  # Eq. (10)  # fmt: skip


def computed_creep(normal_load: float, params: BogieParams) -> tuple[float, float, float, float]:
    """The computed (f11, f12, f22, f33) of ``params``' bogie under one wheel load (N), without
    the overrides set in ``params``: Eqs. (7)-(10) on the Hertz ellipse of that load (N, N m,
    N m^2, N), :func:`creep_rows` of one load."""
    A, B = wheel_rail_curvatures(params)
    contact = hertz_ellipse(normal_load, A, B, params.E, params.nu)
    return _creep_from_axes(contact.a, contact.b, params.E, params.nu)


def creep_rows(normal_loads: np.ndarray, params: BogieParams) -> np.ndarray:
    """(n, 4): the computed (f11, f12, f22, f33) of ``params``' bogie under each of the wheel
    loads ``normal_loads`` (N), bit for bit :func:`creep_coefficients` of each (without the
    overrides set in ``params``): the ellipse's shape is solved once for all."""
    A, B = wheel_rail_curvatures(params)
    loads = np.asarray(normal_loads, dtype=float)
    if loads.size:
        hertz_ellipse(float(loads.min()), A, B, params.E, params.nu)  # the checks: positive, finite loads; A, B, E, nu
        hertz_ellipse(float(loads.max()), A, B, params.E, params.nu)
    e_star, m = params.E / (2.0 * (1.0 - params.nu * params.nu)), _eccentricity_squared(max(A, B) / min(A, B))
    return np.array([_creep_from_axes(*_semi_axes(load, A, B, e_star, m), params.E, params.nu) for load in loads.tolist()]).reshape(-1, 4)


# ---------------------------------------------------------------------------------
# Saturation and flange: scalar laws shared by the compiled kernels
# ---------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _saturation(beta):
    """Eq. (26): alpha(beta) = 1 - beta/3 + beta^2/27 for beta <= 3, else 1/beta.

    The printed saturated branch reads ``beta``; ``1/beta`` makes ``alpha*beta = 1``
    (force = mu N) and continuous at beta = 3. Written for real or complex ``beta`` (the
    complex-step Jacobian), so the branch compares the real part.
    """
    if beta.real <= 3.0:
        return 1.0 - beta / 3.0 + beta * beta / 27.0
    return 1.0 / beta


@njit(cache=True, inline="always")
def _flange(y, delta, stiffness):
    """Eq. (46): piecewise-linear flange force for lateral displacement y (N)."""
    if y.real >= delta:
        return stiffness * (y - delta)
    if y.real <= -delta:
        return stiffness * (y + delta)
    return 0.0 * y


@njit(cache=True)
def _saturation_scalar(beta: float) -> float:
    return _saturation(beta)


@njit(cache=True)
def _flange_scalar(y: float, delta: float, stiffness: float) -> float:
    return _flange(y, delta, stiffness)


def saturation_factor(beta: np.ndarray | float) -> np.ndarray:
    """Eq. (26) for an array of ``beta = |F_lin| / (mu N)`` (must be >= 0 and finite)."""
    beta = np.asarray(beta, dtype=float)
    if not np.all(np.isfinite(beta)) or np.any(beta < 0):
        raise ValueError("saturation_factor: beta must be finite and >= 0")
    return np.vectorize(_saturation_scalar, otypes=[float])(beta)


def saturated_force_ratio(u: np.ndarray | float) -> np.ndarray:
    """F/(mu N) as a function of u = F_lin/(mu N): ``u * alpha(u)`` (Johnson-Vermeulen cubic)."""
    u = np.asarray(u, dtype=float)
    return u * saturation_factor(u)


def flange_force(y: np.ndarray | float, delta: float, stiffness: float) -> np.ndarray:
    """Eq. (46) for an array of lateral displacements (m); returns N."""
    y = np.asarray(y, dtype=float)
    return np.vectorize(lambda yy: _flange_scalar(yy, delta, stiffness), otypes=[float])(y)
