"""The sensor model of the ``"sensors"`` observation: noise, bias and bandwidth per channel.

:data:`SENSOR_MODELS` is the named table, one entry per observed channel (the six
:data:`bogie_env.envs.task.SENSORS` and the speed), with datasheet-level figures and their
sources. Each channel, sampled at the control rate (``dt``), is

    measured[n] = F(true)[n] + bias + noise[n]

- ``F``: a first-order anti-alias filter of corner ``bandwidth_hz``, discretised exactly for
  a signal held over the sample (``y += (1 - exp(-2 pi f_c dt)) (x - y)``); it starts settled
  on the first sample of an episode. It sees the signal only at the samples, so it models
  the filter's phase lag, not its removal of content above the Nyquist frequency.
- ``bias``: drawn once per episode, normal with standard deviation ``bias * bias_scale``.
- ``noise``: white, normal, per sample, with standard deviation
  ``noise_density * noise_scale * sqrt(pi/2 * bandwidth_hz)``: the datasheet's noise density over the
  equivalent noise bandwidth of the first-order filter (pi/2 times its corner). Sampling keeps
  the variance, so this is the rms of the sampled, filtered sensor noise.

``noise_scale`` and ``bias_scale`` (config ``sensors``, default 1) scale every channel at once:
0 switches the noise (or the bias) off, 2 doubles it. They are not ``observation.noise``, which
adds noise in observation units to every entry after this model.

Values are in SI units (m/s^2, rad/s, m, rad, m/s); the observation divides them by the
channel's scale (``task.py``). Noise comes from a small per-row generator (SplitMix64 and
Box-Muller) seeded from the row's episode RNG at reset, so a row's noise depends on its seed
only, not on the batch or the thread count.

Adding a sensor: an entry here with the same name as its entry in ``task.SENSORS``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from .draws import centred_normal

G0 = 9.80665  # m/s^2
DEG = math.pi / 180.0


@dataclass(frozen=True)
class SensorModel:
    """One measured channel: its unit and error figures, with where they come from."""

    name: str
    unit: str
    noise_density: float  # unit / sqrt(Hz)
    bias: float  # unit, standard deviation of the per-episode bias
    bandwidth_hz: float  # first-order anti-alias corner
    source: str

    def defaults(self) -> dict[str, float]:
        return {"noise_density": self.noise_density, "bias": self.bias, "bandwidth_hz": self.bandwidth_hz}


#: Anti-alias corner of every channel: 0.4 x the 100 Hz sample rate (below Nyquist, 50 Hz,
#: well above hunting, 2-10 Hz: 7 degrees of phase lag at 5 Hz).
ANTI_ALIAS_HZ = 40.0
#: Displacement transducers: LVDT noise density (electronics-limited) and 0.25 % FS linearity.
LVDT_NOISE_DENSITY = 1.0e-6  # m/sqrt(Hz)
#: Semi-spacing of the two longitudinal transducers that give a wheelset's yaw: the axle boxes
#: (the paper's b1 = 1.02 m); yaw = (x_left - x_right) / (2 b1).
YAW_TRANSDUCER_SEMI_SPACING = 1.02  # m

SENSOR_MODELS: tuple[SensorModel, ...] = (
    SensorModel(
        "frame_lateral_accel", "m/s^2", 80e-6 * G0, 7.5e-3 * G0, ANTI_ALIAS_HZ,
        "MEMS accelerometer, Analog Devices ADXL356/ADXL357 data sheet (Rev. 0, 2017): noise "
        "density 80 ug/sqrt(Hz) (+-10 g range); bias: 0 g offset drift 0.75 mg/degC max over "
        "10 degC from the calibration temperature (7.5 mg)",
    ),
    SensorModel(
        "frame_yaw_rate", "rad/s", 0.008 * DEG, 0.2 * DEG, ANTI_ALIAS_HZ,
        "MEMS IMU gyroscope, Analog Devices ADIS16470 data sheet: rate noise density "
        "0.008 deg/s/sqrt(Hz); bias: initial bias error 0.2 deg/s (1 sigma)",
    ),
    SensorModel(
        "wheelset1_lateral_rel", "m", LVDT_NOISE_DENSITY, 0.0025 * 25e-3, ANTI_ALIAS_HZ,
        "LVDT +-25 mm between axle box and frame (e.g. TE Connectivity MHR series: "
        "non-linearity 0.25 % FS, taken as the bias; electronics noise 1 um/sqrt(Hz))",
    ),
    SensorModel(
        "wheelset2_lateral_rel", "m", LVDT_NOISE_DENSITY, 0.0025 * 25e-3, ANTI_ALIAS_HZ,
        "as wheelset1_lateral_rel",
    ),
    SensorModel(
        "wheelset1_yaw_rel", "rad", math.sqrt(2) * LVDT_NOISE_DENSITY / (2 * YAW_TRANSDUCER_SEMI_SPACING),
        math.sqrt(2) * 0.0025 * 10e-3 / (2 * YAW_TRANSDUCER_SEMI_SPACING), ANTI_ALIAS_HZ,
        "two +-10 mm longitudinal LVDTs at the axle boxes, 2 x 1.02 m apart (figures as "
        "wheelset1_lateral_rel, independent errors: sqrt(2) / (2 b1) per transducer)",
    ),
    SensorModel(
        "wheelset2_yaw_rel", "rad", math.sqrt(2) * LVDT_NOISE_DENSITY / (2 * YAW_TRANSDUCER_SEMI_SPACING),
        math.sqrt(2) * 0.0025 * 10e-3 / (2 * YAW_TRANSDUCER_SEMI_SPACING), ANTI_ALIAS_HZ,
        "as wheelset1_yaw_rel",
    ),
    SensorModel(
        "speed", "m/s", 0.1 / 3.6, 2.0 / 3.6, ANTI_ALIAS_HZ,
        "train odometry: ERA ETCS SUBSET-041 (performance requirements) bounds the speed error "
        "at +-2 km/h below 30 km/h, rising to +-12 km/h at 500 km/h; taken as a 2 km/h bias "
        "(1 sigma) and 0.1 (km/h)/sqrt(Hz) noise (0.8 km/h rms)",
    ),
)  # fmt: skip
SENSOR_NAMES: tuple[str, ...] = tuple(s.name for s in SENSOR_MODELS)
N_SENSED = len(SENSOR_MODELS)
SENSOR_SETTINGS = ("noise_density", "bias", "bandwidth_hz")

# Columns of the compiled sensor table (N_SENSED, 2): filter weight per sample, noise rms per sample.
S_FILTER_WEIGHT, S_NOISE_RMS = range(2)
#: How the sensor noise is drawn (``sensors.noise_draws``): "per_channel", one Box-Muller draw of
#: two uniforms per channel and sample, its cosine branch (v1, v2); or "paired", both branches of
#: one draw for two channels, half the logarithms and uniforms (v3). Both give independent
#: standard normals; the sequences differ, so the choice is part of an env version.
NOISE_DRAWS = ("per_channel", "paired")


def default_sensor_config() -> dict[str, Any]:
    """The env config's ``sensors`` section: off (v0), and each channel's figures."""
    out: dict[str, Any] = {"enabled": False, "noise_scale": 1.0, "bias_scale": 1.0, "noise_draws": "per_channel"}
    for s in SENSOR_MODELS:
        out[s.name] = s.defaults()
    return out


def noise_rms(noise_density: float, bandwidth_hz: float) -> float:
    """Per-sample noise rms: the density over the first-order filter's noise bandwidth."""
    return noise_density * math.sqrt(math.pi / 2 * bandwidth_hz)


def filter_weight(bandwidth_hz: float, dt: float) -> float:
    """Weight of the new sample in the discretised first-order filter (1: no filtering)."""
    return 1.0 - math.exp(-2 * math.pi * bandwidth_hz * dt)


def channel_noise_rms(sensors: dict[str, Any], name: str) -> float:
    """Per-sample noise rms of channel ``name`` under the config's ``sensors`` section (SI): its
    noise density times ``noise_scale``, over its filter's noise bandwidth."""
    spec = sensors[name]
    return noise_rms(spec["noise_density"] * sensors.get("noise_scale", 1.0), spec["bandwidth_hz"])


def channel_bias(sensors: dict[str, Any], name: str) -> float:
    """Standard deviation of channel ``name``'s per-episode bias (SI): its ``bias`` times
    ``bias_scale``."""
    return sensors[name]["bias"] * sensors.get("bias_scale", 1.0)


def sensor_table(sensors: dict[str, Any], dt: float) -> np.ndarray:
    """(N_SENSED, 2) compiled settings from the config's ``sensors`` section."""
    table = np.zeros((N_SENSED, 2))
    for j, name in enumerate(SENSOR_NAMES):
        table[j, S_FILTER_WEIGHT] = filter_weight(sensors[name]["bandwidth_hz"], dt)
        table[j, S_NOISE_RMS] = channel_noise_rms(sensors, name)
    return table


def bias_deviations(sensors: dict[str, Any]) -> np.ndarray:
    """(N_SENSED,) the standard deviations of the per-episode biases (:func:`channel_bias`)."""
    return np.array([channel_bias(sensors, name) for name in SENSOR_NAMES])


def draw_biases(sensors: dict[str, Any], rng: np.random.Generator, deviations: np.ndarray | None = None) -> np.ndarray:
    """(N_SENSED,) one episode's biases, SI units: one normal draw per channel, in channel
    order (``deviations``: :func:`bias_deviations`, when the caller has them)."""
    return centred_normal(rng, bias_deviations(sensors) if deviations is None else deviations)


# ---- compiled: per-row generator, filter, noise ----------------------------------------------
@njit(cache=True, inline="always")
def _splitmix64(state, n):
    """Next 64-bit output of row n's SplitMix64 generator (state: uint64 array)."""
    state[n] = state[n] + np.uint64(0x9E3779B97F4A7C15)
    z = state[n]
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, inline="always")
def _uniform(state, n):
    """Uniform in (0, 1): the top 53 bits, offset by half a unit."""
    return (float(_splitmix64(state, n) >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def standard_normal(state, n):
    """One standard normal draw from row n's generator (Box-Muller)."""
    u1 = _uniform(state, n)
    u2 = _uniform(state, n)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True, inline="always")
def sense_row(n, obs, filtered, bias, scale, rng_state, table, start, bound, paired=False):
    """Measure the clean observation ``obs[n, :N_SENSED]`` of row ``n`` in place (:func:`sense_rows`).
    A row's measurement depends on that row's arrays only, so rows may be measured in any
    order or on any thread with the same bits. ``paired``: channels 2i and 2i + 1 take the
    cosine and sine branches of one Box-Muller draw (:data:`NOISE_DRAWS`)."""
    second = 0.0
    for j in range(table.shape[0]):
        clean = obs[n, j]
        if start:
            filtered[n, j] = clean
        else:
            filtered[n, j] += table[j, S_FILTER_WEIGHT] * (clean - filtered[n, j])
        if not paired:
            normal = standard_normal(rng_state, n)
        elif j % 2 == 0:
            u1 = _uniform(rng_state, n)
            u2 = _uniform(rng_state, n)
            radius = math.sqrt(-2.0 * math.log(u1))
            normal = radius * math.cos(2.0 * math.pi * u2)
            second = radius * math.sin(2.0 * math.pi * u2)
        else:
            normal = second
        error = bias[n, j] + table[j, S_NOISE_RMS] * normal
        obs[n, j] = min(max(filtered[n, j] + error / scale[n, j], -bound), bound)


@njit(cache=True)
def sense_rows(rows, obs, filtered, bias, scale, rng_state, table, start, bound, paired=False):
    """Measure the clean observations ``obs[n, :N_SENSED]`` of ``rows`` in place.

    ``filtered`` (N, N_SENSED) holds the filter states in observation units, ``bias`` (N,
    N_SENSED) the episode biases in SI units, ``scale`` (N, N_SENSED) each channel's SI value
    of one observation unit; ``start``: the rows' first sample (the filter starts settled).
    """
    for n in rows:
        sense_row(n, obs, filtered, bias, scale, rng_state, table, start, bound, paired)
