"""One batched simulator for N bogies: the layer the environments and analyses share.

It owns, per bogie: the 20 states, the speed and its ramp rate, the distance travelled
(which places the wheelsets on the track profile), and the four actuator channels' lagged
force and damping. :meth:`BatchSimulator.step` advances all bogies by one control interval
``dt`` with the compiled RK4 kernel of :mod:`bogie_env.integrate`; the number of substeps
comes from the measured spectrum (:func:`bogie_env.integrate.stable_substep`).
"""

from __future__ import annotations

import math

import numpy as np

from .dynamics import N_INPUTS, N_STATES, BogieModel, check_speed
from .integrate import STATUS_OK, advance_batch_kernel, stable_substep
from .track import TrackProfile, perfect_track


class BatchSimulator:
    """N passive or actuated bogies advanced together.

    Args:
        model: the bogie physics.
        n: number of bogies.
        dt: control interval, s.
        speed_range: (min, max) speed in m/s that the runs will visit; sets the substep.
        track: shared periodic alignment profile (default perfect track).
        lag_tau: first-order lag time constant of each actuator channel, s (0: none).
        n_sub: substeps per interval; default from the spectrum over ``speed_range``.
    """

    def __init__(
        self,
        model: BogieModel,
        n: int,
        dt: float = 0.01,
        speed_range: tuple[float, float] = (250 / 3.6, 650 / 3.6),
        track: TrackProfile | None = None,
        lag_tau: np.ndarray | float = 0.0,
        n_sub: int | None = None,
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
        self.step_choice = stable_substep(model, lo, hi, dt) if n_sub is None else None
        self.n_sub = int(n_sub) if n_sub is not None else self.step_choice.n_sub
        self.track = track if track is not None else perfect_track()
        tau = np.broadcast_to(np.asarray(lag_tau, dtype=float), (N_INPUTS,))
        if np.any(~np.isfinite(tau)) or np.any(tau < 0):
            raise ValueError(f"BatchSimulator: lag_tau = {lag_tau!r} must be finite and >= 0")
        self.decay_rate = np.where(tau > 0, 1.0 / np.maximum(tau, 1e-300), 0.0)
        self.u_max = np.full(N_INPUTS, np.inf)
        self._inv_dx = 1.0 / self.track.dx
        self.x = np.zeros((self.n, N_STATES))
        self.speed = np.full(self.n, lo)
        self.accel = np.zeros(self.n)
        self.distance = np.zeros(self.n)
        self.force = np.zeros((self.n, N_INPUTS))
        self.damping = np.zeros((self.n, N_INPUTS))
        self.channel_output = np.zeros((self.n, N_INPUTS))
        self.channel_power = np.zeros((self.n, N_INPUTS))
        self.status = np.zeros(self.n, dtype=np.int64)
        self._zeros = np.zeros((self.n, N_INPUTS))

    # ---- state management ----------------------------------------------------------------
    def set_rows(
        self,
        rows: np.ndarray | slice,
        x0: np.ndarray,
        speed: np.ndarray | float,
        accel: np.ndarray | float = 0.0,
        distance: np.ndarray | float = 0.0,
    ) -> None:
        """(Re)initialise some bogies; actuator channels start at rest."""
        self.x[rows] = x0
        self.speed[rows] = check_speed(speed)
        self.accel[rows] = accel
        self.distance[rows] = distance
        self.force[rows] = 0.0
        self.damping[rows] = 0.0
        self.channel_output[rows] = 0.0
        self.channel_power[rows] = 0.0
        self.status[rows] = STATUS_OK

    def track_displacement(self) -> np.ndarray:
        """Track alignment under each wheelset now, (N, 2) m."""
        L1 = self.model.params.L1
        return np.stack([self.track.at(self.distance + L1), self.track.at(self.distance - L1)], axis=1)

    # ---- stepping -------------------------------------------------------------------------
    def step(self, force_target: np.ndarray | None = None, damping_target: np.ndarray | None = None) -> np.ndarray:
        """Advance every bogie by ``dt``. Targets are (N, 4); returns the status codes."""
        f_target = self._zeros if force_target is None else np.ascontiguousarray(force_target, dtype=np.float64)
        c_target = self._zeros if damping_target is None else np.ascontiguousarray(damping_target, dtype=np.float64)
        advance_batch_kernel(
            self.x, self.speed, self.accel, self.distance, self.dt, self.n_sub,
            self.force, f_target, self.damping, c_target, self.decay_rate, self.u_max,
            self.track.values, self._inv_dx, self.model.coefficients,
            self.channel_output, self.channel_power, self.status,
        )  # fmt: skip
        if force_target is not None or damping_target is not None or np.any(self.decay_rate):
            w = np.exp(-self.decay_rate * self.dt)
            self.force -= f_target
            self.force *= w
            self.force += f_target
            self.damping -= c_target
            self.damping *= w
            self.damping += c_target
        return self.status
