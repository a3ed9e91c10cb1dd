"""Root loci (the paper's Figs. 7, 8 and 10): eigenvalues against speed, modes tracked.

Modes are followed from speed to speed by continuity, not by sorting: at each step the
eigenvalues are matched to the previous step's by a minimum-cost assignment (Hungarian
algorithm) on a cost that combines eigenvalue distance and eigenvector dissimilarity
(1 - MAC, the modal assurance criterion). Sorting by real part would swap modes where
their real parts cross; continuity keeps each branch on its mode.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..dynamics import LATERAL_STATES, N_STATES, STATE_NAMES, BogieModel
from ..stability import KMH, CriticalSpeed, SpeedLinearization, critical_speed, linearize


@dataclass(frozen=True)
class RootLocus:
    """Tracked eigenvalues: ``eigenvalues[k, j]`` is mode j at ``speeds[k]`` (m/s)."""

    speeds: np.ndarray
    eigenvalues: np.ndarray  # (n_speeds, n_modes) complex, columns are continuous branches
    hunting_mode: int  # the column that crosses into the right half-plane (or comes closest)
    critical: CriticalSpeed
    states: tuple[str, ...]

    @property
    def speeds_kmh(self) -> np.ndarray:
        return self.speeds * KMH

    @property
    def hunting(self) -> np.ndarray:
        return self.eigenvalues[:, self.hunting_mode]

    def to_dict(self) -> dict:
        return {
            "speeds_kmh": self.speeds_kmh.tolist(),
            "hunting_mode_real": self.hunting.real.tolist(),
            "hunting_mode_imag": self.hunting.imag.tolist(),
            "critical_speed_kmh": None if np.isnan(self.critical.speed) else self.critical.speed_kmh,
            "hunting_frequency_hz": None if np.isnan(self.critical.frequency_hz) else self.critical.frequency_hz,
        }


def _mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Modal assurance criterion between the columns of a and b (0..1)."""
    num = np.abs(a.conj().T @ b) ** 2
    den = np.outer(np.sum(np.abs(a) ** 2, axis=0), np.sum(np.abs(b) ** 2, axis=0))
    return num / np.maximum(den, 1e-300)


def track_modes(jacobians: np.ndarray, mac_weight: float = 1.0) -> np.ndarray:
    """Eigenvalues of a sequence of matrices, columns ordered as continuous branches."""
    n_steps, n, _ = jacobians.shape
    tracked = np.empty((n_steps, n), dtype=complex)
    values, vectors = np.linalg.eig(jacobians[0])
    tracked[0] = values
    for k in range(1, n_steps):
        new_values, new_vectors = np.linalg.eig(jacobians[k])
        scale = np.maximum(np.abs(values)[:, None], 1.0)
        cost = np.abs(values[:, None] - new_values[None, :]) / scale
        cost = cost + mac_weight * (1.0 - _mac(vectors, new_vectors))
        rows, cols = linear_sum_assignment(cost)
        order = cols[np.argsort(rows)]
        values, vectors = new_values[order], new_vectors[:, order]
        tracked[k] = values
    return tracked


def root_locus(
    model: BogieModel,
    v_min_kmh: float = 300.0,
    v_max_kmh: float = 600.0,
    n_speeds: int = 301,
    lateral_only: bool = True,
    linearization: SpeedLinearization | None = None,
) -> RootLocus:
    """Root locus over a speed range (default the paper's 300-600 km/h)."""
    if not (np.isfinite(v_min_kmh) and np.isfinite(v_max_kmh) and 0 < v_min_kmh < v_max_kmh):
        raise ValueError(
            f"root_locus: speed range {v_min_kmh}-{v_max_kmh} km/h is not allowed; need 0 < v_min_kmh < v_max_kmh"
        )
    if int(n_speeds) < 2:
        raise ValueError(f"root_locus: n_speeds = {n_speeds} must be at least 2")
    lin = linearization if linearization is not None else linearize(model)
    speeds = np.linspace(v_min_kmh, v_max_kmh, int(n_speeds)) / KMH
    idx = list(LATERAL_STATES) if lateral_only else list(range(N_STATES))
    stack = np.stack([lin.jacobian(v)[np.ix_(idx, idx)] for v in speeds])
    tracked = track_modes(stack)
    # the hunting mode: the branch with the largest real part at the top speed
    hunting = int(np.argmax(tracked[-1].real))
    critical = critical_speed(linearization=lin)
    return RootLocus(speeds, tracked, hunting, critical, tuple(STATE_NAMES[i] for i in idx))
