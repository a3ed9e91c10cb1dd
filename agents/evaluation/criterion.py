"""The protocol's pass criterion for fixed-speed runs and ramp-down windows (protocols v2 and v3):
EN 14363's band-passed ΣY and frame-acceleration rms against their limits, the flange-contact
time (v3: counted only when sustained), and blow-ups. ``settings`` is the protocol's
:class:`bogie_agents.evaluation.stability_protocol.Settings` (its criterion fields); the definitions,
limits and sources are in docs/results.md, "Protocol v3"."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import signal

#: Where the instability frequency f0 is looked for (Hz): above the track's longest
#: wavelengths at low speed, below the wheelset modes (60-85 Hz) and the 50 Hz Nyquist limit.
F0_RANGE_HZ = (0.5, 20.0)


def sum_y_limit_n(axle_load_n: float) -> float:
    """EN 14363's ΣY rms limit for running stability: half of Prud'homme's limit
    ``10 kN + 2 Q0 / 3`` with ``Q0 = P0 / 2`` the static wheel load, i.e. ``(10 kN + P0 / 3) / 2``."""
    return 0.5 * (10e3 + axle_load_n / 3.0)


def frame_accel_limit(frame_mass_kg: float) -> float:
    """EN 14363's limit on the bogie frame's lateral acceleration (simplified method, sliding rms):
    ``(12 - m+ / 5) / 2`` m/s² with ``m+`` the bogie mass in tonnes."""
    return 0.5 * (12.0 - frame_mass_kg / 1e3 / 5.0)


def sliding_rms(x: np.ndarray, window: int, step: int) -> np.ndarray:
    """rms of ``x`` (along the last axis) over windows of ``window`` samples starting every
    ``step`` samples (only whole windows); shape ``x.shape[:-1] + (n_windows,)``."""
    x = np.asarray(x, dtype=float)
    if window < 1 or step < 1 or window > x.shape[-1]:
        raise ValueError(f"sliding_rms: window {window} and step {step} must be >= 1 and window <= {x.shape[-1]} samples")
    cs = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x * x, axis=-1)], axis=-1)
    starts = np.arange(0, x.shape[-1] - window + 1, step)
    return np.sqrt(np.maximum(cs[..., starts + window] - cs[..., starts], 0.0) / window)


def dominant_frequency(x: np.ndarray, fs: float, band: tuple[float, float] = F0_RANGE_HZ) -> float:
    """The peak of the Hann-windowed periodogram of ``x`` (summed over the leading axes) in ``band``."""
    f, p = signal.periodogram(np.asarray(x, dtype=float), fs=fs, window="hann", axis=-1)
    p = p.reshape(-1, f.size).sum(axis=0)
    inside = (f >= band[0]) & (f <= band[1])
    return float(f[inside][np.argmax(p[inside])])


def band_pass(x: np.ndarray, f0: float, half_width: float, fs: float) -> np.ndarray:
    """``x`` band-passed to ``f0 ± half_width`` (4th-order Butterworth, forward and backward:
    zero phase), along the last axis; the lower edge is kept above 0.2 Hz."""
    low = max(f0 - half_width, 0.2)
    high = min(f0 + half_width, 0.45 * fs)
    sos = signal.butter(4, [low, high], btype="band", fs=fs, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=-1)


def flange_occupancy(contact: np.ndarray, dt: float, window_s: float) -> np.ndarray:
    """The share of the consecutive windows of ``window_s`` (whole windows only) in which a run's
    wheelsets touch the flange at least once. ``contact`` (N, T): the flange-contact flag per
    sample, every ``dt``; returns (N,)."""
    contact = np.asarray(contact, dtype=bool)
    per = max(1, int(round(window_s / dt)))
    whole = contact.shape[-1] // per
    if whole < 1:
        raise ValueError(f"flange_occupancy: {contact.shape[-1]} samples hold no window of {window_s:g} s")
    return contact[..., : whole * per].reshape(contact.shape[:-1] + (whole, per)).any(axis=-1).mean(axis=-1)


def sustained_flange_contact(flange_time: np.ndarray, occupancy: np.ndarray | None, settings: Any) -> np.ndarray:
    """Which runs fail on flange contact. A run fails when its wheelsets touch the flange for more
    than ``flange_time_limit`` of the assessed time and (v3) the contact is sustained: it occurs
    in at least ``settings.sustained_fraction`` of the assessed time's ``flange_window_s`` windows.

    Why: a hunting cycle that reaches the flange touches it on every cycle (2-10 Hz here, so in
    nearly every second), while a rough track forces contacts at its isolated defects, seconds
    apart (on the EN 13848-5 intervention track at 40-110 km/h the passive bogie touches in at
    most a third of the seconds; hunting at 152 km/h, in 67-100 %:
    docs/studies/hunting_or_forced_contact.md). EN 14363 likewise judges running stability on a
    sustained oscillation. v2 (fraction 0) counts any contact; ``occupancy`` None: every window
    holds one."""
    over = np.asarray(flange_time, dtype=float) > settings.flange_time_limit
    if occupancy is None or not settings.sustained_fraction:
        return over
    return over & (np.asarray(occupancy, dtype=float) >= settings.sustained_fraction)


@dataclass
class Assessment:
    """The criterion's quantities for N runs (arrays over the runs)."""

    passed: np.ndarray
    sum_y_rms_n: np.ndarray  # largest 100 m sliding rms of band-passed ΣY (either wheelset)
    frame_accel_rms: np.ndarray  # same for the frame's lateral acceleration, m/s^2
    flange_time: np.ndarray  # fraction of the evaluated time with |y - track| >= delta
    f0_hz: np.ndarray
    blowup: np.ndarray
    sum_y_limit_n: np.ndarray
    frame_accel_limit: float
    flange_failed: np.ndarray  # flange contact that fails the run (sustained_flange_contact)
    mean_offset: np.ndarray | None = None  # largest |mean wheelset displacement relative to the rail| / delta
    flange_occupancy: np.ndarray | None = None  # share of the flange_window_s windows with a contact

    def failed_by(self, i: int) -> list[str]:
        """Which criteria run i fails."""
        out = []
        if self.blowup[i]:
            return ["blowup"]
        if self.sum_y_rms_n[i] > self.sum_y_limit_n[i]:
            out.append("sum_y")
        if self.frame_accel_rms[i] > self.frame_accel_limit:
            out.append("frame_accel")
        if self.flange_failed[i]:
            out.append("flange_contact")
        return out


def assess(history: np.ndarray, flange_time: np.ndarray, blowup: np.ndarray, speeds_ms: np.ndarray, dt: float,
           axle_load_n: np.ndarray, frame_mass_kg: float, settings: Any,
           mean_offset: np.ndarray | None = None, flange_occupancy: np.ndarray | None = None) -> Assessment:  # fmt: skip
    """The pass criterion for N runs. ``history`` (N, 3, T): ΣY of wheelset 1 and 2 (N) and the
    frame lateral acceleration (m/s²) over the evaluated time, sampled every ``dt``;
    ``flange_time`` (N,), ``blowup`` (N,) and ``flange_occupancy`` (N,; :func:`flange_occupancy`,
    None: contact counts as sustained) as measured during it."""
    n = history.shape[0]
    fs = 1.0 / dt
    sum_y = np.full(n, np.inf)
    accel = np.full(n, np.inf)
    f0 = np.full(n, np.nan)
    blown = np.asarray(blowup, dtype=bool) | ~np.all(np.isfinite(history), axis=(1, 2))
    y_limit = sum_y_limit_n(np.asarray(axle_load_n, dtype=float)) * np.ones(n)
    a_limit = frame_accel_limit(frame_mass_kg)
    for i in np.nonzero(~blown)[0]:
        # f0: where the three signals, each relative to its limit, have most power
        f0[i] = dominant_frequency(history[i] / np.array([y_limit[i], y_limit[i], a_limit])[:, None], fs)
        filtered = band_pass(history[i], f0[i], settings.band_half_width_hz, fs)
        per_sample = speeds_ms[i] * dt
        window = min(history.shape[2], max(1, int(round(settings.window_m / per_sample))))
        step = max(1, int(round(settings.window_step_m / per_sample)))
        rms = sliding_rms(filtered, window, step).max(axis=-1)
        sum_y[i], accel[i] = rms[:2].max(), rms[2]
    flange_failed = sustained_flange_contact(flange_time, flange_occupancy, settings)
    passed = ~blown & (sum_y <= y_limit) & (accel <= a_limit) & ~flange_failed
    return Assessment(passed, sum_y, accel, np.asarray(flange_time, dtype=float), f0, blown, y_limit, a_limit,
                      flange_failed, None if mean_offset is None else np.asarray(mean_offset, dtype=float),
                      None if flange_occupancy is None else np.asarray(flange_occupancy, dtype=float))


def criterion_text(settings: Any, axle_load_n: float, frame_mass_kg: float) -> dict[str, Any]:
    """The criterion as stated beside every result."""
    return {
        "evaluated_s": [settings.transient_s, settings.duration_s],
        "sum_y_rms_limit_n": round(sum_y_limit_n(axle_load_n), 1),
        "frame_accel_rms_limit_m_per_s2": round(frame_accel_limit(frame_mass_kg), 3),
        "sliding_rms": f"over {settings.window_m:g} m, step {settings.window_step_m:g} m",
        "band_pass": f"f0 +- {settings.band_half_width_hz:g} Hz (4th-order Butterworth, zero phase); "
                     f"f0 = peak of the summed spectra of SumY 1, SumY 2 and the frame acceleration, each "
                     f"relative to its limit, in {F0_RANGE_HZ[0]:g}-{F0_RANGE_HZ[1]:g} Hz",
        "flange_time_limit": settings.flange_time_limit,
        "flange_contact": "|wheelset lateral displacement relative to the rail| >= flange clearance, either wheelset",
        "flange_sustained": (f"the contact time counts only if a contact occurs in at least {settings.sustained_fraction:g} "
                             f"of the assessed time's {settings.flange_window_s:g} s windows (a hunting cycle touches on "
                             "every cycle; a rough track at its isolated defects)") if settings.sustained_fraction
                            else "every contact counts (protocol v2)",
        "blowup": "the env's blowup flag (|y - track| > 0.1 m or integrator failure) or a non-finite state or action",
        "sources": "EN 14363:2016 running stability (SumY: (10 kN + 2 Q0 / 3) / 2; frame: (12 - m+ / 5) / 2)",
    }  # fmt: skip
