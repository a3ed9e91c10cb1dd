"""The track input: lateral alignment irregularity and the route geometry (curvature, cant).

The alignment irregularity is a stationary random profile with a documented PSD; the route
geometry (tangents, clothoid transitions, circular curves, cant) is :mod:`bogie_env.route`.

Shape: the German high-speed alignment spectrum (low-disturbance class), widely used for
high-speed vehicle simulation (see e.g. X. Lei, *High Speed Railway Track Dynamics*,
Springer 2017, Ch. 5 "Track Irregularity Power Spectrum and Numerical Simulation")::

    S(Omega) = A_a Omega_c^2 / ((Omega^2 + Omega_r^2) (Omega^2 + Omega_c^2))     [m^2 / (rad/m)]

with ``Omega_c = 0.8246 rad/m``, ``Omega_r = 0.0206 rad/m`` and ``A_a = 2.119e-7 m rad``
(the values usually quoted). Only the shape matters here: the profile keeps the
wavelengths between ``wavelength_min`` and ``wavelength_max`` (default 3-80 m, covering
EN 13848-1's bands D1, 3-25 m, and D2, 25-70 m) and is scaled to the requested rms
(default 1 mm). It is synthesised by random phases on an FFT grid, so it is
exactly periodic: the simulator wraps around it without a seam.

The irregularity enters the dynamics only through the wheelset displacement relative to the
rail (rolling radii, gravitational terms, flange contact; see :mod:`bogie_env.dynamics`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from .route import CANT_BASE_M, Route

GERMAN_LOW = {"A_a": 2.119e-7, "Omega_c": 0.8246, "Omega_r": 0.0206}


def german_alignment_psd(omega: np.ndarray, A_a: float = GERMAN_LOW["A_a"]) -> np.ndarray:
    """One-sided alignment PSD (m^2 per rad/m) at spatial frequencies omega (rad/m)."""
    oc, orr = GERMAN_LOW["Omega_c"], GERMAN_LOW["Omega_r"]
    omega = np.asarray(omega, dtype=float)
    return A_a * oc**2 / ((omega**2 + orr**2) * (omega**2 + oc**2))


@dataclass(frozen=True)
class TrackProfile:
    """A periodic lateral alignment profile sampled every ``dx`` metres."""

    values: np.ndarray  # m
    dx: float  # m

    @property
    def length(self) -> float:
        return self.values.size * self.dx

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.values**2))) if self.values.size else 0.0

    def at(self, s: np.ndarray | float) -> np.ndarray:
        """Linear interpolation at distance(s) s (m), periodic."""
        if self.values.size == 0:
            return np.zeros_like(np.asarray(s, dtype=float))
        u = np.asarray(s, dtype=float) / self.dx
        k = np.floor(u)
        w = u - k
        i0 = k.astype(np.int64) % self.values.size
        return (1 - w) * self.values[i0] + w * self.values[(i0 + 1) % self.values.size]


def perfect_track() -> TrackProfile:
    return TrackProfile(np.zeros(0), 1.0)


# ---- the track input of the dynamics ------------------------------------------------------
#: What the dynamics reads from the track, per bogie (its ``yt`` argument): the lateral
#: alignment under the front and the rear wheelset (m), the route's curvature (1/m, + left)
#: and cant angle (rad, + banked towards +y) under each wheelset and the frame centre.
TRACK_SAMPLES: tuple[str, ...] = (
    "alignment_wheelset1", "alignment_wheelset2",
    "curvature_wheelset1", "curvature_wheelset2", "curvature_frame",
    "cant_angle_wheelset1", "cant_angle_wheelset2", "cant_angle_frame",
)  # fmt: skip
(
    ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2,
    CURVATURE_WHEELSET1, CURVATURE_WHEELSET2, CURVATURE_FRAME,
    CANT_WHEELSET1, CANT_WHEELSET2, CANT_FRAME,
) = range(len(TRACK_SAMPLES))  # fmt: skip
N_TRACK_SAMPLES = len(TRACK_SAMPLES)
ALIGNMENT_SAMPLES = (ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2)
# Fields of the compiled track tuple (TrackInput.compiled()).
TRACK_ALIGNMENT, TRACK_ALIGNMENT_INV_DX = range(2)
ROUTE_START, ROUTE_LENGTH, ROUTE_CURVATURE0, ROUTE_CURVATURE1, ROUTE_CANT0, ROUTE_CANT1 = range(2, 8)
_NO_ROUTE = tuple(np.zeros(0) for _ in range(6))


@dataclass(frozen=True)
class TrackInput:
    """The track a bogie runs on, by named field: lateral alignment and the route geometry.

    ``route`` None is straight track without cant (the samples of curvature and cant are
    exact zeros). The compiled code reads the track as the tuple :meth:`compiled` through
    :func:`sample_track`.
    """

    alignment: TrackProfile = field(default_factory=perfect_track)
    route: Route | None = None

    def compiled(self) -> tuple:
        route = _NO_ROUTE if self.route is None else self.route.compiled()
        return (self.alignment.values, 1.0 / self.alignment.dx) + route

    def under_wheelsets(self, distance: np.ndarray | float, L1: float) -> np.ndarray:
        """The samples (..., N_TRACK_SAMPLES) of bogies whose centre is at ``distance``: alignment,
        curvature and cant angle under each wheelset (and the frame), computed in numpy."""
        distance = np.asarray(distance, dtype=float)
        out = np.zeros(distance.shape + (N_TRACK_SAMPLES,))
        out[..., ALIGNMENT_WHEELSET1] = self.alignment.at(distance + L1)
        out[..., ALIGNMENT_WHEELSET2] = self.alignment.at(distance - L1)
        if self.route is not None:
            for column, offset in ((CURVATURE_WHEELSET1, L1), (CURVATURE_WHEELSET2, -L1), (CURVATURE_FRAME, 0.0)):
                out[..., column] = self.route.curvature(distance + offset)
            for column, offset in ((CANT_WHEELSET1, L1), (CANT_WHEELSET2, -L1), (CANT_FRAME, 0.0)):
                out[..., column] = np.arcsin(self.route.cant(distance + offset) / CANT_BASE_M)
        return out


@njit(cache=True, inline="always")
def _wrap(i, m):
    """``i % m`` for m > 0, with the integer division (tens of cycles) only where the index
    leaves the profile: the same index."""
    if i < 0 or i >= m:
        return i % m
    return i


@njit(cache=True, inline="always")
def _interpolate(profile, inv_dx, s):
    """Linear interpolation on a periodic profile sampled every 1/inv_dx metres (empty: 0)."""
    m = profile.shape[0]
    if m == 0:
        return 0.0
    u = s * inv_dx
    k = math.floor(u)
    w = u - k
    i0 = _wrap(int(k), m)
    i1 = i0 + 1  # (i0 + 1) % m without a second integer division
    if i1 == m:
        i1 = 0
    return (1.0 - w) * profile[i0] + w * profile[i1]


@intrinsic
def _prefetch(typingctx, array, index):
    """A hint to the CPU to fetch ``array[index]`` into its cache (LLVM's prefetch: no load, no
    fault, no effect on any value)."""
    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, signature.args[0], ary, [args[1]])
        i32 = llvm_ir.IntType(32)
        fnty = llvm_ir.FunctionType(llvm_ir.VoidType(), [ptr.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])  # read, keep in all cache levels, data
        return context.get_dummy_value()

    return types.void(array, index), codegen


@njit(cache=True, inline="always")
def _prefetch_alignment(profile, inv_dx, s):
    """Prefetch the alignment sample :func:`_interpolate` reads first at distance s."""
    m = profile.shape[0]
    if m > 0:
        _prefetch(profile, _wrap(int(math.floor(s * inv_dx)), m))


@njit(cache=True, inline="always")
def prefetch_track(track, s, L1):
    """Start fetching the alignment samples under the wheelsets of a bogie at distance s: the
    profile is megabytes long and each bogie reads it somewhere else, so without this each row's
    first samples wait for memory."""
    _prefetch_alignment(track[TRACK_ALIGNMENT], track[TRACK_ALIGNMENT_INV_DX], s + L1)
    _prefetch_alignment(track[TRACK_ALIGNMENT], track[TRACK_ALIGNMENT_INV_DX], s - L1)


@njit(cache=True, inline="always")
def _segment(start, s):
    """Index of the last segment starting at or before s (the first one before the route)."""
    lo = 0
    hi = start.shape[0] - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if start[mid] <= s:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def _route_sample(track, s, out, curvature_column, cant_column):
    """Curvature and cant angle at distance s into out: both vary linearly along each segment
    (held beyond the route's ends); one segment search serves both."""
    lo = _segment(track[ROUTE_START], s)
    w = (s - track[ROUTE_START][lo]) / track[ROUTE_LENGTH][lo]
    if w < 0.0:
        w = 0.0
    elif w > 1.0:
        w = 1.0
    k0 = track[ROUTE_CURVATURE0][lo]
    c0 = track[ROUTE_CANT0][lo]
    out[curvature_column] = k0 + (track[ROUTE_CURVATURE1][lo] - k0) * w
    out[cant_column] = math.asin((c0 + (track[ROUTE_CANT1][lo] - c0) * w) / CANT_BASE_M)


@njit(cache=True, inline="always")
def sample_track(track, s, L1, out):
    """The track samples (TRACK_SAMPLES) of a bogie whose centre is at distance s, into out.

    Without a route (straight track) the curvature and cant samples are exact zeros."""
    out[ALIGNMENT_WHEELSET1] = _interpolate(track[TRACK_ALIGNMENT], track[TRACK_ALIGNMENT_INV_DX], s + L1)
    out[ALIGNMENT_WHEELSET2] = _interpolate(track[TRACK_ALIGNMENT], track[TRACK_ALIGNMENT_INV_DX], s - L1)
    if track[ROUTE_START].shape[0] == 0:
        for k in range(CURVATURE_WHEELSET1, N_TRACK_SAMPLES):
            out[k] = 0.0
        return
    _route_sample(track, s + L1, out, CURVATURE_WHEELSET1, CANT_WHEELSET1)
    _route_sample(track, s - L1, out, CURVATURE_WHEELSET2, CANT_WHEELSET2)
    _route_sample(track, s, out, CURVATURE_FRAME, CANT_FRAME)


def alignment_profile(
    rms: float = 1e-3,
    wavelength_min: float = 3.0,
    wavelength_max: float = 80.0,
    dx: float = 0.25,
    n_samples: int = 2**20,
    seed: int = 0,
) -> TrackProfile:
    """A random alignment profile with the German spectrum's shape, band-limited and scaled.

    ``rms`` (m) is the target standard deviation; 0 gives a perfect track. The default
    length, 2^20 samples of 0.25 m, is 262 km: longer than any episode, and periodic.
    """
    for name, value in (("rms", rms), ("dx", dx)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"alignment_profile: {name} = {value!r} must be finite and >= 0")
    if rms == 0:
        return perfect_track()
    if not (0 < 2 * dx < wavelength_min < wavelength_max):
        raise ValueError(
            f"alignment_profile: need 0 < 2*dx < wavelength_min < wavelength_max; got dx={dx}, "
            f"wavelength_min={wavelength_min}, wavelength_max={wavelength_max}"
        )
    n_samples = int(n_samples)
    if n_samples < 64:
        raise ValueError(f"alignment_profile: n_samples = {n_samples} must be at least 64")
    rng = np.random.default_rng(seed)
    omega = 2 * np.pi * np.fft.rfftfreq(n_samples, d=dx)  # rad/m
    band = (omega >= 2 * np.pi / wavelength_max) & (omega <= 2 * np.pi / wavelength_min)
    amplitude = np.zeros_like(omega)
    d_omega = omega[1] - omega[0]
    amplitude[band] = np.sqrt(german_alignment_psd(omega[band]) * d_omega)
    spectrum = amplitude * np.exp(2j * np.pi * rng.random(omega.size))
    values = np.fft.irfft(spectrum, n=n_samples)
    values *= rms / np.sqrt(np.mean(values**2))
    return TrackProfile(values, dx)


# ---- track quality levels (EN 13848-5) ------------------------------------------------------
#: Alignment (lateral) isolated-defect limits, mean-to-peak, wavelength band D1 (3-25 m), for
#: the speed band 230 < V <= 300 km/h (the highest band of the standard's table), m. From
#: EN 13848-5:2008+A1:2010 (alignment, D1): alert limit 4-7 mm, intervention limit 6-8 mm,
#: immediate action limit 10 mm; the lower ends of the infrastructure manager's ranges are
#: taken for "alert" and "intervention". Check against the edition in force (2017).
ALIGNMENT_LEVELS: dict[str, float] = {"alert": 4e-3, "intervention": 6e-3, "immediate_action": 10e-3}
D1_BAND_M = (3.0, 25.0)
#: A level is met by a 200 m section (the length over which EN 13848 assesses a track section's
#: standard deviation) whose largest |alignment| is the level's mean-to-peak limit.
LEVEL_SECTION_M = 200.0


def section_crest_factor(profile: TrackProfile, section_m: float = LEVEL_SECTION_M) -> float:
    """Median over the profile's ``section_m`` sections of (largest |value|) / profile rms."""
    n = max(1, int(round(section_m / profile.dx)))
    m = profile.values.size // n
    if m == 0 or profile.rms == 0:
        raise ValueError(f"section_crest_factor: profile shorter than one {section_m} m section, or flat")
    peaks = np.max(np.abs(profile.values[: m * n].reshape(m, n)), axis=1)
    return float(np.median(peaks) / profile.rms)


def alignment_profile_at_level(
    level: str,
    wavelength_min: float = D1_BAND_M[0],
    wavelength_max: float = D1_BAND_M[1],
    dx: float = 0.25,
    n_samples: int = 2**20,
    seed: int = 0,
) -> TrackProfile:
    """An alignment profile at an EN 13848-5 level (:data:`ALIGNMENT_LEVELS`).

    Conversion: the profile (German spectrum shape, band-limited as in
    :func:`alignment_profile`) is scaled so that the median 200 m section's largest |alignment|
    equals the level's mean-to-peak limit: ``rms = limit / crest``, with ``crest`` measured on
    the profile itself (:func:`section_crest_factor`; about 3.3 for the D1 band).
    """
    if level not in ALIGNMENT_LEVELS:
        raise ValueError(f"track level {level!r} is not known; known levels: {', '.join(ALIGNMENT_LEVELS)}")
    unit = alignment_profile(1.0, wavelength_min, wavelength_max, dx, n_samples, seed)
    rms = ALIGNMENT_LEVELS[level] / section_crest_factor(unit)
    return TrackProfile(unit.values * rms, dx)
