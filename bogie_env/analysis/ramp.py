"""Time-domain runs: the paper's speed ramp (Figs. 9 and 11) with frozen eigenvalues.

A passive bogie is run with the compiled RK4 kernel, speed ramping at a constant rate.
Along the trajectory the Jacobian is evaluated at the current state (the paper's "frozen
eigenvalues", Section 4), and the lateral amplitude is tracked as a peak envelope.

Two speeds summarise the onset of hunting, and both are reported with their assumptions:

- ``growth_start_kmh`` (perfect track only): where the envelope stops decaying and starts
  to grow. The envelope obeys d(ln A)/dt = Re(lambda), so it turns at the linear critical
  speed;
- ``onset_kmh``: where the envelope first exceeds ``onset_threshold`` (default half the
  flange clearance). It depends on how small the motion became below the critical speed:
  a ramp delays the visible onset by the time needed to grow back from the lowest amplitude
  (the slow passage through a Hopf bifurcation). A perturbation that decayed to the
  round-off floor (~1e-17 m here) cannot regrow at all: the creep forces at that size are
  below the resolution of the force sums. :func:`onset_sensitivity` shows how the onset
  moves with the initial perturbation and with the track-irregularity level, which sets a
  physical noise floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..dynamics import LATERAL_STATES, N_STATES, BogieModel, check_speed, state_index
from ..integrate import STATUS_OK, stable_substep
from ..simulator import BatchSimulator
from ..stability import KMH, critical_speed
from ..track import TrackProfile, alignment_profile, perfect_track


@dataclass(frozen=True)
class Trajectory:
    """Recorded run: ``states[k]`` at ``time[k]`` (s), speed ``speed[k]`` (m/s)."""

    time: np.ndarray
    speed: np.ndarray
    states: np.ndarray
    status: str = "ok"
    track_at_wheelsets: np.ndarray | None = None  # (n, 2) alignment under each wheelset, m

    @property
    def speed_kmh(self) -> np.ndarray:
        return self.speed * KMH

    def signal(self, name: str) -> np.ndarray:
        return self.states[:, state_index(name)]

    def relative_lateral(self, wheelset: int = 1) -> np.ndarray:
        """Lateral displacement of a wheelset relative to the rail under it (m): what meets the flange."""
        y = self.signal(f"y{wheelset}")
        if self.track_at_wheelsets is None:
            return y
        return y - self.track_at_wheelsets[:, wheelset - 1]

    def envelope(self, name: str = "y1", window: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Peak |signal| over consecutive windows of ``window`` seconds: (speed at window end, peak).

        ``"y1"``/``"y2"`` are taken relative to the track; other names are raw states.
        """
        values = np.abs(self.relative_lateral(int(name[1])) if name in ("y1", "y2") else self.signal(name))
        if self.time.size < 2:
            return self.speed[:1].copy(), values[:1].copy()
        step = float(self.time[1] - self.time[0])
        per = max(1, int(round(window / step)))
        n = values.size // per
        peaks = values[: n * per].reshape(n, per).max(axis=1)
        speeds = self.speed[per - 1 : n * per : per]
        return speeds, peaks


def simulate(
    model: BogieModel,
    x0: np.ndarray,
    speed: float,
    accel: float = 0.0,
    duration: float = 10.0,
    dt: float = 0.01,
    record_every: int = 1,
    track: TrackProfile | None = None,
    n_sub: int | None = None,
) -> Trajectory:
    """Run one passive bogie; the speed goes from ``speed`` at ``accel`` (m/s^2) for ``duration``."""
    x = np.array(x0, dtype=float)
    if x.shape != (N_STATES,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x0 must be a finite array of shape ({N_STATES},); got shape {x.shape}")
    if not (np.isfinite(duration) and duration > 0):
        raise ValueError(f"duration = {duration!r} s must be finite and > 0")
    final = speed + accel * duration
    check_speed(speed, "start speed")
    check_speed(final, "final speed")
    track = track if track is not None else perfect_track()
    lo, hi = min(speed, final), max(speed, final)
    if n_sub is None:
        n_sub = stable_substep(model, lo, hi, dt).n_sub
    n_steps = int(round(duration / dt))
    record_every = max(1, int(record_every))
    sim = BatchSimulator(model, 1, dt, (lo, hi), track, n_sub=int(n_sub))
    # the ramp stops just past its final speed (rounding of V + a dt must not stop it early)
    sim.set_rows(0, x, float(speed), float(accel), end_speed=final + (1e-9 if accel >= 0 else -1e-9))
    states, speeds = sim.run(n_steps, record_every)
    count = states.shape[0]
    code = int(sim.status[0])
    time = np.arange(count) * dt * record_every
    if code == STATUS_OK:
        time[-1] = n_steps * dt
    distance = speed * time + 0.5 * accel * time**2
    L1 = model.params.L1
    under = np.stack([track.at(distance + L1), track.at(distance - L1)], axis=1)
    return Trajectory(time, speeds[:, 0].copy(), states[:, 0].copy(), "ok" if code == STATUS_OK else "nonfinite", under)


def frozen_eigenvalues(model: BogieModel, trajectory: Trajectory, every_kmh: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of the Jacobian at the trajectory's states, sampled every ``every_kmh``.

    Returns (speeds in m/s, eigenvalues (n, 16) of the lateral block).
    """
    speed_kmh = trajectory.speed_kmh
    targets = np.arange(speed_kmh.min(), speed_kmh.max() + 1e-9, every_kmh)
    if speed_kmh[-1] < speed_kmh[0]:
        targets = targets[::-1]
    idx = np.searchsorted(speed_kmh, targets) if speed_kmh[-1] >= speed_kmh[0] else \
        np.searchsorted(-speed_kmh, -targets)  # fmt: skip
    idx = np.clip(idx, 0, speed_kmh.size - 1)
    lateral = np.ix_(LATERAL_STATES, LATERAL_STATES)
    stack = []
    for k in idx:
        track = None if trajectory.track_at_wheelsets is None else trajectory.track_at_wheelsets[k]
        stack.append(model.jacobian(trajectory.states[k], float(trajectory.speed[k]), track=track)[lateral])
    return trajectory.speed[idx], np.linalg.eigvals(np.array(stack))


@dataclass(frozen=True)
class RampResult:
    """A speed-ramp run with its summary speeds (km/h at the edge)."""

    trajectory: Trajectory
    eigen_speeds: np.ndarray
    eigenvalues: np.ndarray
    accel: float
    initial_offset: float
    track_rms: float
    onset_threshold: float
    onset_kmh: float | None
    growth_start_kmh: float | None
    linear_critical_speed_kmh: float
    frozen_crossing_kmh: float | None
    extras: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "accel_m_per_s2": self.accel,
            "initial_offset_m": self.initial_offset,
            "track_rms_m": self.track_rms,
            "onset_threshold_m": self.onset_threshold,
            "onset_kmh": self.onset_kmh,
            "growth_start_kmh": self.growth_start_kmh,
            "linear_critical_speed_kmh": self.linear_critical_speed_kmh,
            "frozen_eigenvalue_crossing_kmh": self.frozen_crossing_kmh,
            "simulated_time_s": float(self.trajectory.time[-1]),
            "status": self.trajectory.status,
            **self.extras,
        }


def _onset(trajectory: Trajectory, threshold: float) -> tuple[float | None, float | None]:
    """(onset, growth start) in km/h; the initial transient (before the envelope first falls
    below the threshold) does not count."""
    speeds, peaks = trajectory.envelope("y1", 1.0)
    below = np.nonzero(peaks <= threshold)[0]
    if below.size == 0:
        return None, None
    first_below = int(below[0])
    above = np.nonzero(peaks[first_below:] > threshold)[0]
    if above.size == 0:
        return None, None
    k = first_below + int(above[0])
    start = first_below + int(np.argmin(peaks[first_below : k + 1]))
    return float(speeds[k] * KMH), float(speeds[start] * KMH)


def speed_ramp(
    model: BogieModel,
    v_start_kmh: float = 300.0,
    v_end_kmh: float = 600.0,
    accel: float = 0.1,
    initial_offset: float = 1e-3,
    track_rms: float = 1e-6,
    track_seed: int = 0,
    dt: float = 0.01,
    record_every: int = 1,
    frozen_every_kmh: float = 1.0,
    onset_threshold: float | None = None,
) -> RampResult:
    """The paper's ramp: ``v_start_kmh`` to ``v_end_kmh`` at ``accel`` m/s^2 (0.1: 833 s).

    The default noise floor is a 1 micrometre rms track alignment: physically negligible,
    but it keeps the motion from decaying into the round-off dead zone, where a perfect
    track would never show hunting at all (see the module docstring and
    :func:`onset_sensitivity`). ``growth_start_kmh`` (envelope minimum) is only reported
    on a perfect track, where it marks the linear critical speed.
    """
    if not (np.isfinite(v_start_kmh) and np.isfinite(v_end_kmh) and v_start_kmh < v_end_kmh):
        raise ValueError(f"speed_ramp: need v_start_kmh < v_end_kmh; got {v_start_kmh} and {v_end_kmh}")
    if not (np.isfinite(accel) and accel > 0):
        raise ValueError(f"speed_ramp: accel = {accel!r} m/s^2 must be finite and > 0")
    threshold = 0.5 * model.params.delta if onset_threshold is None else float(onset_threshold)
    x0 = model.equilibrium(v_start_kmh / KMH)
    x0[state_index("y1")] += initial_offset
    track = alignment_profile(track_rms, seed=track_seed) if track_rms > 0 else perfect_track()
    duration = (v_end_kmh - v_start_kmh) / KMH / accel
    trajectory = simulate(model, x0, v_start_kmh / KMH, accel, duration, dt, record_every, track)
    eig_speeds, eigenvalues = frozen_eigenvalues(model, trajectory, frozen_every_kmh)
    growth = eigenvalues.real.max(axis=1)
    crossing = np.nonzero(growth >= 0)[0]
    onset, start = _onset(trajectory, threshold)
    start = start if track_rms == 0 else None
    return RampResult(
        trajectory, eig_speeds, eigenvalues, accel, initial_offset, track_rms, threshold, onset, start,
        critical_speed(model).speed_kmh, float(eig_speeds[crossing[0]] * KMH) if crossing.size else None,
    )  # fmt: skip


def onset_sensitivity(
    model: BogieModel,
    offsets: tuple[float, ...] = (1e-3, 1e-5, 1e-7),
    offset_start_kmh: float = 350.0,
    track_levels: tuple[float, ...] = (1e-7, 1e-6, 1e-5, 1e-4),
    v_start_kmh: float = 300.0,
    v_end_kmh: float = 600.0,
    accel: float = 0.1,
) -> list[dict]:
    """How the ramp's visible onset moves with the noise floor.

    Two families: an initial offset on a perfect track, starting at ``offset_start_kmh``
    (just below the critical speed: from 300 km/h the motion would decay into the round-off
    dead zone and never return), and a track-alignment noise floor from ``v_start_kmh``.
    """
    rows = []
    for offset in offsets:
        result = speed_ramp(model, offset_start_kmh, v_end_kmh, accel, initial_offset=offset, track_rms=0.0,
                            frozen_every_kmh=50.0)  # fmt: skip
        rows.append({"start_kmh": offset_start_kmh, "initial_offset_m": offset, "track_rms_m": 0.0,
                     "onset_kmh": result.onset_kmh, "growth_start_kmh": result.growth_start_kmh})  # fmt: skip
    for level in track_levels:
        result = speed_ramp(model, v_start_kmh, v_end_kmh, accel, initial_offset=0.0, track_rms=level,
                            frozen_every_kmh=50.0)  # fmt: skip
        rows.append({"start_kmh": v_start_kmh, "initial_offset_m": 0.0, "track_rms_m": level,
                     "onset_kmh": result.onset_kmh, "growth_start_kmh": None})  # fmt: skip
    return rows
