"""Limit cycles, the bifurcation diagram and the nonlinear critical speed.

The nonlinear critical speed is the lowest speed at which a hunting limit cycle survives
(True, VSD 51(3), 2013). It is found two ways, which must agree:

- **ramp-down** (the GENSYS recipe): start on the limit cycle above the linear critical
  speed and decrease the speed slowly; the cycle collapses where the periodic attractor
  disappears (the fold). Faster ramps collapse later (lower); the result converges as the
  ramp slows, and :func:`nonlinear_critical_speed` reports that convergence.
- **fixed-speed runs** started on the limit cycle at a grid of speeds: the lowest speed at
  which the amplitude persists after a long settling time.

The bifurcation diagram runs every speed twice, from a small perturbation and from the
limit cycle; between the fold and the linear critical speed the two differ (hysteresis).
All runs of one diagram are advanced together by the batched simulator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dynamics import BogieModel, state_index
from ..simulator import BatchSimulator
from ..stability import KMH, critical_speed
from .ramp import simulate

Y1 = state_index("y1")


def _lc_threshold(model: BogieModel, threshold: float | None) -> float:
    return 0.5 * model.params.delta if threshold is None else float(threshold)


def fixed_speed_amplitudes(
    model: BogieModel,
    speeds: np.ndarray,
    initial_states: np.ndarray,
    duration: float = 60.0,
    window: float = 5.0,
    dt: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Run each (speed, initial state) pair at constant speed; peak |y1| over the last window.

    Returns (amplitudes (n,), final states (n, 20)). Rows that blow up get amplitude nan.
    """
    speeds = np.asarray(speeds, dtype=float)
    sim = BatchSimulator(model, speeds.size, dt, speed_range=(speeds.min(), speeds.max()))
    sim.set_rows(slice(None), initial_states, speeds)
    n_steps = int(round(duration / dt))
    n_window = int(round(window / dt))
    peak = np.zeros(speeds.size)
    for k in range(n_steps):
        status = sim.step()
        if k >= n_steps - n_window:
            np.maximum(peak, np.abs(sim.x[:, Y1]), out=peak)
    peak[status != 0] = np.nan
    return peak, sim.x.copy()


def limit_cycle_state(model: BogieModel, speed_kmh: float, offset: float = 0.015, settle: float = 40.0) -> np.ndarray:
    """A state on the hunting limit cycle at ``speed_kmh``, from a large lateral offset
    (GENSYS: about 15 mm) after ``settle`` seconds. Raises if no cycle is reached."""
    x0 = model.equilibrium(speed_kmh / KMH)
    x0[[state_index("y1"), state_index("y2"), state_index("yb")]] += offset
    amplitude, final = fixed_speed_amplitudes(model, np.array([speed_kmh / KMH]), x0[None], settle, 5.0)
    if not amplitude[0] > 0.5 * model.params.delta:
        raise RuntimeError(f"no hunting limit cycle at {speed_kmh:g} km/h (amplitude {amplitude[0]:.3g} m)")
    return final[0]


@dataclass(frozen=True)
class BifurcationDiagram:
    """Limit-cycle amplitude (peak |y1|, m) against speed from two kinds of start."""

    speeds_kmh: np.ndarray
    from_small: np.ndarray
    from_limit_cycle: np.ndarray
    small_offset: float
    threshold: float
    linear_critical_speed_kmh: float

    @property
    def lowest_limit_cycle_kmh(self) -> float | None:
        """Lowest grid speed at which the limit cycle persisted (grid resolution)."""
        alive = self.speeds_kmh[self.from_limit_cycle > self.threshold]
        return float(alive.min()) if alive.size else None

    def to_dict(self) -> dict:
        return {
            "speeds_kmh": self.speeds_kmh.tolist(),
            "amplitude_from_small_m": self.from_small.tolist(),
            "amplitude_from_limit_cycle_m": self.from_limit_cycle.tolist(),
            "small_offset_m": self.small_offset,
            "limit_cycle_threshold_m": self.threshold,
            "linear_critical_speed_kmh": self.linear_critical_speed_kmh,
            "lowest_limit_cycle_on_grid_kmh": self.lowest_limit_cycle_kmh,
        }


def bifurcation_diagram(
    model: BogieModel,
    v_min_kmh: float = 250.0,
    v_max_kmh: float = 550.0,
    n_speeds: int = 61,
    small_offset: float = 1e-4,
    duration: float = 60.0,
    threshold: float | None = None,
    refine_kmh: float = 5.0,
) -> BifurcationDiagram:
    """Amplitude against speed from a small perturbation and from the top speed's limit cycle.

    Besides the even grid, speeds every 0.5 km/h from ``refine_kmh`` below the linear critical
    speed to 2 km/h above it resolve the narrow hysteresis band of a subcritical Hopf point.
    """
    if not (np.isfinite(v_min_kmh) and np.isfinite(v_max_kmh) and 0 < v_min_kmh < v_max_kmh):
        raise ValueError(f"bifurcation_diagram: need 0 < v_min_kmh < v_max_kmh; got {v_min_kmh}, {v_max_kmh}")
    if int(n_speeds) < 2:
        raise ValueError(f"bifurcation_diagram: n_speeds = {n_speeds} must be >= 2")
    speeds_kmh = np.linspace(v_min_kmh, v_max_kmh, int(n_speeds))
    linear = critical_speed(model).speed_kmh
    if refine_kmh > 0 and np.isfinite(linear):
        fine = np.arange(linear - refine_kmh, linear + 2.0, 0.5)
        speeds_kmh = np.unique(np.round(np.concatenate([speeds_kmh, fine[(fine > v_min_kmh) & (fine < v_max_kmh)]]), 3))
    speeds = speeds_kmh / KMH
    x_eq = model.equilibrium(speeds[0])
    small = np.repeat(x_eq[None], speeds.size, axis=0)
    small[:, Y1] += small_offset
    cycle = limit_cycle_state(model, v_max_kmh)
    starts = np.concatenate([small, np.repeat(cycle[None], speeds.size, axis=0)])
    amplitude, _ = fixed_speed_amplitudes(model, np.concatenate([speeds, speeds]), starts, duration)
    return BifurcationDiagram(
        speeds_kmh, amplitude[: speeds.size], amplitude[speeds.size :], small_offset, _lc_threshold(model, threshold),
        linear,
    )  # fmt: skip


def ramp_down(
    model: BogieModel,
    rate_kmh_per_s: float,
    v_start_kmh: float,
    v_end_kmh: float,
    start_state: np.ndarray | None = None,
    threshold: float | None = None,
) -> tuple[float | None, "object"]:
    """Decrease the speed from a limit cycle at ``rate_kmh_per_s``; the collapse speed (km/h)
    is where the 1-s peak |y1| first drops below ``threshold`` (default half the clearance)."""
    if not (np.isfinite(rate_kmh_per_s) and rate_kmh_per_s > 0):
        raise ValueError(f"ramp_down: rate_kmh_per_s = {rate_kmh_per_s!r} must be finite and > 0")
    if not v_end_kmh < v_start_kmh:
        raise ValueError(f"ramp_down: v_end_kmh = {v_end_kmh} must be below v_start_kmh = {v_start_kmh}")
    x0 = limit_cycle_state(model, v_start_kmh) if start_state is None else np.asarray(start_state, dtype=float)
    accel = -rate_kmh_per_s / KMH
    duration = (v_start_kmh - v_end_kmh) / rate_kmh_per_s
    trajectory = simulate(model, x0, v_start_kmh / KMH, accel, duration, record_every=1)
    speeds, peaks = trajectory.envelope("y1", 1.0)
    below = np.nonzero(peaks < _lc_threshold(model, threshold))[0]
    collapse = float(speeds[below[0]] * KMH) if below.size else None
    return collapse, trajectory


@dataclass(frozen=True)
class NonlinearCriticalSpeed:
    """Ramp-down collapse speeds for several rates, and the fixed-speed fold."""

    rates_kmh_per_s: tuple[float, ...]
    collapse_kmh: tuple[float | None, ...]
    fixed_speed_kmh: float | None  # lowest grid speed where the cycle persisted
    fixed_speed_step_kmh: float
    linear_critical_speed_kmh: float
    threshold: float

    @property
    def extrapolated_kmh(self) -> float | None:
        """Ramp-down collapse speeds extrapolated to a vanishing rate.

        Near a fold the delay of the collapse grows like the square root of the rate (slow
        passage past a saddle-node), so ``collapse = V0 - b sqrt(rate)`` is fitted to the three
        slowest ramps and V0 returned.
        """
        pairs = [(r, c) for r, c in zip(self.rates_kmh_per_s, self.collapse_kmh) if c is not None]
        if len(pairs) < 3:
            return None
        rates, collapse = np.array(pairs[-3:]).T
        slope, intercept = np.polyfit(np.sqrt(rates), collapse, 1)
        return float(intercept)

    @property
    def value_kmh(self) -> float | None:
        """The nonlinear critical speed: the fixed-speed fold (the limit the ramp-downs converge
        to), or the slowest ramp's collapse speed if the fixed-speed check was not run."""
        return self.fixed_speed_kmh if self.fixed_speed_kmh is not None else self.collapse_kmh[-1]

    def to_dict(self) -> dict:
        return {
            "nonlinear_critical_speed_kmh": self.value_kmh,
            "ramp_down_extrapolated_kmh": self.extrapolated_kmh,
            "linear_critical_speed_kmh": self.linear_critical_speed_kmh,
            "ramp_down": [
                {"rate_kmh_per_s": r, "collapse_kmh": c} for r, c in zip(self.rates_kmh_per_s, self.collapse_kmh)
            ],
            "fixed_speed_fold_kmh": self.fixed_speed_kmh,
            "fixed_speed_grid_step_kmh": self.fixed_speed_step_kmh,
            "limit_cycle_threshold_m": self.threshold,
        }


def fixed_speed_fold(
    model: BogieModel,
    v_lo_kmh: float,
    v_hi_kmh: float,
    step_kmh: float = 0.5,
    duration: float = 150.0,
    start_state: np.ndarray | None = None,
    threshold: float | None = None,
) -> float | None:
    """Lowest speed on a grid at which a run started on the limit cycle keeps cycling."""
    speeds_kmh = np.arange(v_lo_kmh, v_hi_kmh + 1e-9, step_kmh)
    cycle = limit_cycle_state(model, v_hi_kmh + 20.0) if start_state is None else start_state
    amplitude, _ = fixed_speed_amplitudes(
        model, speeds_kmh / KMH, np.repeat(cycle[None], speeds_kmh.size, axis=0), duration, 5.0
    )
    alive = speeds_kmh[amplitude > _lc_threshold(model, threshold)]
    return float(alive.min()) if alive.size else None


def nonlinear_critical_speed(
    model: BogieModel,
    rates_kmh_per_s: tuple[float, ...] = (5.0, 2.0, 1.0, 0.5, 0.2, 0.1),
    v_start_kmh: float | None = None,
    v_end_kmh: float | None = None,
    fixed_speed_check: bool = True,
    threshold: float | None = None,
) -> NonlinearCriticalSpeed:
    """Ramp-down at decreasing rates (the last, slowest, is the reported value), plus the
    fixed-speed fold as an independent check."""
    linear = critical_speed(model).speed_kmh
    if not np.isfinite(linear):
        raise ValueError("nonlinear_critical_speed: the bogie has no linear critical speed in 50-900 km/h")
    top = linear + 60.0 if v_start_kmh is None else v_start_kmh
    bottom = max(30.0, linear - 150.0) if v_end_kmh is None else v_end_kmh
    cycle = limit_cycle_state(model, top)
    rates = tuple(sorted(rates_kmh_per_s, reverse=True))
    collapses = tuple(ramp_down(model, r, top, bottom, cycle, threshold)[0] for r in rates)
    fold = None
    if fixed_speed_check and collapses[-1] is not None:
        fold = fixed_speed_fold(model, collapses[-1] - 10.0, min(linear, collapses[-1] + 10.0), 0.5,
                                start_state=cycle, threshold=threshold)  # fmt: skip
    return NonlinearCriticalSpeed(rates, collapses, fold, 0.5, linear, _lc_threshold(model, threshold))
