"""Linear stability: equilibrium, Jacobian against speed, eigenvalues, linear critical speed.

At the equilibrium of the straight, perfect track the Jacobian depends on speed only as

    J(V) = J0 + J1 / V + J2 * V                                              (exact)

because speed enters the right-hand side through the creepages (terms in 1/V: dy/V,
dpsi/V, r dphi/V) and the gyroscopic coupling (Iwy V / r0), while the equilibrium itself
(the lift z0 from the constant spin creepage) does not depend on speed. :func:`linearize`
extracts the three matrices from exact complex-step Jacobians at three speeds;
``tests/test_stability.py`` checks the decomposition at other speeds.

The vertical states (z, dz) do not feed back into the others (docs/model.md), so the
spectrum is that of the 16 lateral states plus the two fixed vertical pairs; the search
works on the 16 x 16 lateral block.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

try:  # numpy's eigenvalue kernel itself: np.linalg.eigvals' argument checks cost a third of a 16 x 16 call
    from numpy.linalg import _umath_linalg
except ImportError:  # pragma: no cover - a numpy without the private module
    _umath_linalg = None

from .dynamics import LATERAL_STATES, MAX_SPEED, MIN_SPEED, N_INPUTS, N_STATES, N_TRACK, BogieModel, check_speed, jacobian_kernel
from .params import BogieParams

KMH = 3.6  # (km/h) per (m/s)

#: Default speed window and scan step of the critical-speed search, km/h.
DEFAULT_SEARCH_KMH = (50.0, 900.0)
DEFAULT_SCAN_STEP_KMH = 100.0
#: Root-finding tolerance on speed, km/h (the issue asks for 0.1 km/h).
DEFAULT_TOL_KMH = 0.02


@dataclass(frozen=True)
class SpeedLinearization:
    """The Jacobian at the equilibrium as an exact function of speed, J0 + J1/V + J2 V."""

    J0: np.ndarray
    J1: np.ndarray
    J2: np.ndarray
    equilibrium: np.ndarray
    lateral: tuple[int, ...] = field(default=LATERAL_STATES)

    def __post_init__(self) -> None:
        idx = np.ix_(self.lateral, self.lateral)
        object.__setattr__(self, "_lateral_blocks", (self.J0[idx].copy(), self.J1[idx].copy(), self.J2[idx].copy()))

    def jacobian(self, speed: float) -> np.ndarray:
        """Full 20 x 20 Jacobian at ``speed`` (m/s)."""
        return self.J0 + self.J1 / speed + self.J2 * speed

    def lateral_jacobian(self, speed: float | np.ndarray) -> np.ndarray:
        """The 16 x 16 lateral block at one speed, or stacked (n, 16, 16) for an array."""
        j0, j1, j2 = self._lateral_blocks
        v = np.asarray(speed, dtype=float)
        if v.ndim == 0:
            return j0 + j1 / float(v) + j2 * float(v)
        return j0[None] + j1[None] / v[:, None, None] + j2[None] * v[:, None, None]

    def eigenvalues(self, speed: float | np.ndarray, lateral_only: bool = False) -> np.ndarray:
        """Eigenvalues at one speed (shape (20,)) or at an array of speeds (n, 20)."""
        v = np.asarray(speed, dtype=float)
        if lateral_only:
            return np.linalg.eigvals(self.lateral_jacobian(v))
        speeds = np.atleast_1d(v)
        stack = self.J0[None] + self.J1[None] / speeds[:, None, None] + self.J2[None] * speeds[:, None, None]
        values = np.linalg.eigvals(stack)
        return values[0] if v.ndim == 0 else values

    def growth_rate(self, speed: float | np.ndarray) -> np.ndarray | float:
        """Largest real part of the lateral eigenvalues (1/s) at each speed."""
        return _eigvals(self.lateral_jacobian(speed)).real.max(axis=-1)


def _eigvals(matrices: np.ndarray) -> np.ndarray:
    """Complex eigenvalues of real square matrices (..., n, n), as ``np.linalg.eigvals`` computes
    them (the same LAPACK call, the same values) without its per-call checks: the matrices of
    this module are finite by construction, and a LAPACK failure (NaN) still raises."""
    if _umath_linalg is None:
        return np.linalg.eigvals(matrices).astype(complex)
    values = _umath_linalg.eigvals(matrices, signature="d->D")
    if np.isnan(values.real).any():
        raise np.linalg.LinAlgError(f"eigenvalues did not converge (or the matrix is not finite): {values}")
    return values


def linearize(model: BogieModel, speeds: tuple[float, float, float] = (40.0, 80.0, 160.0)) -> SpeedLinearization:
    """Extract J0, J1, J2 from exact Jacobians at three speeds (m/s)."""
    v = np.asarray(speeds, dtype=float)
    x_eq = model.equilibrium(v[0])
    q, yt = np.zeros(N_INPUTS), np.zeros(N_TRACK)
    jacobians = np.empty((3, N_STATES, N_STATES))
    for k, s in enumerate(v):
        jacobian_kernel(x_eq, float(s), q, yt, model.coefficients, jacobians[k])
    basis = np.stack([np.ones_like(v), 1.0 / v, v], axis=1)  # J(v) = [1, 1/v, v] . [J0, J1, J2]
    coeffs = np.linalg.solve(basis, jacobians.reshape(3, -1)).reshape(3, N_STATES, N_STATES)
    return SpeedLinearization(coeffs[0], coeffs[1], coeffs[2], x_eq)


@dataclass(frozen=True)
class CriticalSpeed:
    """Result of a linear critical-speed search (SI inside, km/h at the edge)."""

    speed: float  # m/s; nan when no crossing in the window
    frequency_hz: float  # hunting-mode frequency at the crossing
    eigenvalue: complex  # the crossing eigenvalue (real part ~ 0)
    equilibrium: np.ndarray
    window: tuple[float, float]  # searched speeds, m/s
    status: str  # "crossing", "stable" (no crossing up to the window top) or "unstable" (at its bottom)

    @property
    def speed_kmh(self) -> float:
        return self.speed * KMH

    def to_dict(self) -> dict:
        from .dynamics import STATE_NAMES

        return {
            "critical_speed_kmh": None if np.isnan(self.speed) else round(self.speed_kmh, 3),
            "critical_speed_m_per_s": None if np.isnan(self.speed) else self.speed,
            "hunting_frequency_hz": None if np.isnan(self.frequency_hz) else self.frequency_hz,
            "eigenvalue": None if np.isnan(self.eigenvalue) else [self.eigenvalue.real, self.eigenvalue.imag],
            "status": self.status,
            # no crossing: the answer is "stable over the whole window" (or unstable at its bottom)
            "stable_over_window": self.status == "stable",
            "search_window_kmh": [self.window[0] * KMH, self.window[1] * KMH],
            "equilibrium": dict(zip(STATE_NAMES, map(float, self.equilibrium))),
        }


def _leading_eigenvalue(lin: SpeedLinearization, speed: float) -> complex:
    values = _eigvals(lin.lateral_jacobian(speed))
    k = int(np.argmax(values.real + 1e-9 * np.abs(values.imag)))  # prefer the oscillatory one on ties
    return complex(values[k])


def critical_speed(
    model: BogieModel | BogieParams | None = None,
    v_min_kmh: float = DEFAULT_SEARCH_KMH[0],
    v_max_kmh: float = DEFAULT_SEARCH_KMH[1],
    scan_step_kmh: float = DEFAULT_SCAN_STEP_KMH,
    tol_kmh: float = DEFAULT_TOL_KMH,
    linearization: SpeedLinearization | None = None,
) -> CriticalSpeed:
    """Linear critical speed: the lowest speed where the largest real part crosses zero.

    The window is scanned in ``scan_step_kmh`` steps for the first sign change of the
    growth rate, which is then bracketed and refined by Brent's method to ``tol_kmh``.
    An unstable band narrower than the scan step, lying wholly below the first crossing
    found, would be missed; ``tests/test_stability.py`` checks the default 100 km/h step
    against a 5 km/h scan over the whole sensitivity study's parameter range.
    """
    if linearization is None:
        model = model if isinstance(model, BogieModel) else BogieModel(model)
        linearization = linearize(model)
    for name, value in (("v_min_kmh", v_min_kmh), ("v_max_kmh", v_max_kmh)):
        check_speed(value / KMH, name=name.replace("_kmh", ""))
    if not v_min_kmh < v_max_kmh:
        raise ValueError(f"critical_speed: v_min_kmh = {v_min_kmh} must be below v_max_kmh = {v_max_kmh}")
    for name, value in (("scan_step_kmh", scan_step_kmh), ("tol_kmh", tol_kmh)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"critical_speed: {name} = {value!r} must be finite and > 0")
    lo, hi = v_min_kmh / KMH, v_max_kmh / KMH
    n_cells = max(1, int(np.ceil((hi - lo) / (scan_step_kmh / KMH))))
    grid = np.linspace(lo, hi, n_cells + 1)
    window = (lo, hi)
    if linearization.growth_rate(float(grid[0])) >= 0.0:
        ev = _leading_eigenvalue(linearization, lo)
        return CriticalSpeed(lo, abs(ev.imag) / (2 * np.pi), ev, linearization.equilibrium, window, "unstable")
    # the grid upwards until the first speed that is not stable (a scan that stops there: the
    # speeds above are not needed, and each costs one eigenvalue problem)
    for k in range(1, grid.size):
        if linearization.growth_rate(float(grid[k])) >= 0.0:
            break
    else:
        return CriticalSpeed(float("nan"), float("nan"), complex("nan"), linearization.equilibrium, window, "stable")
    from scipy.optimize import brentq  # here, not at import: scipy.optimize takes about 0.3 s to import

    speed = brentq(
        lambda s: float(linearization.growth_rate(s)), grid[k - 1], grid[k], xtol=tol_kmh / KMH, rtol=1e-12
    )
    ev = _leading_eigenvalue(linearization, speed)
    return CriticalSpeed(speed, abs(ev.imag) / (2 * np.pi), ev, linearization.equilibrium, window, "crossing")


__all__ = [
    "CriticalSpeed",
    "SpeedLinearization",
    "critical_speed",
    "linearize",
    "KMH",
    "MIN_SPEED",
    "MAX_SPEED",
]
