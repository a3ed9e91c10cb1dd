"""Environment configuration: ``default_config()`` merged with the user's (highway-env style).

Every key is checked: unknown keys are errors that list the known ones, and every value
is validated with a message naming the key, the value and what is allowed.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Mapping

from ..actuators import CHANNEL_NAMES as CHANNELS
from ..actuators import CHANNELS as ACTUATOR_CHANNELS
from ..actuators import MAX_DELAY_STEPS, MODES
from ..fileio import load_yaml
from ..params import CONFIG_DIR, BogieParams, ConfigError, load_params

ACTUATOR_MODES = MODES
OBSERVATION_TYPES = ("sensors", "state")
_ACTUATOR_DEFAULTS = {c.name: dict(c.defaults) for c in ACTUATOR_CHANNELS}


MIN_SPEED_KMH = 30.0  # the env's speed range; above 850 km/h the model is not meant to be used
MAX_SPEED_KMH = 850.0
MAX_ACCEL = 10.0  # m/s^2; the speed only ramps up (or stays constant)
MAX_NUM_ENVS = 65_536  # one task's rows; 10^6 rows take minutes to reset and gigabytes of state
# Semi-active damping coefficients above this make the damper so stiff that the integrator's stable
# substep shrinks in proportion: at 1e7 the frame-lateral channel needs ~24 substeps per 10 ms step
# (2 at the default 1e5), at 1e8 about 235, i.e. ~100x slower. 1e7 (N s/m or N m s/rad) is already
# far above what reaches the force limits at hunting velocities.
MAX_DAMPING = 1.0e7


def default_config() -> dict[str, Any]:
    """The full default configuration; every key is documented in ``BogieHuntingEnv``."""
    return {
        "bogie": None,  # bogie preset YAML path (None: configs/bogie/paper.yaml)
        "bogie_overrides": {},  # {"Csy": 45000.0, ...}
        "dt": 0.01,  # s, one env step (control interval)
        "speed": {
            "start_kmh": 300.0,
            "end_kmh": 600.0,
            "accel": 1.0,  # m/s^2 (the paper's ramp is 0.1: 833 s)
            # optional per-episode randomisation, each [low, high] or None
            "start_kmh_range": None,
            "end_kmh_range": None,
            "accel_range": None,
        },
        "initial_perturbation": 1e-3,  # m, std of the random initial lateral offsets
        # with this probability an episode starts with large offsets instead (uniform in
        # [0.5, 1] x large_perturbation, random signs): flange contact, as on a hunting cycle
        "large_perturbation_probability": 0.0,
        "large_perturbation": 0.012,  # m
        "track": {"rms": 5e-4, "wavelength_min": 3.0, "wavelength_max": 80.0, "seed": 0},
        "randomize": {},  # per-episode parameter scale ranges, e.g. {"Csy": [0.5, 1.0]}
        "actuators": copy.deepcopy(_ACTUATOR_DEFAULTS),
        "observation": {"type": "sensors", "noise": 0.0, "include_actuators": True},
        "reward": {"lateral_weight": 0.5, "yaw_weight": 0.2, "effort_weight": 0.2, "time_weight": 0.0,
                   "yaw_reference": 5e-3},  # fmt: skip
        "hunting": {"window_m": 100.0, "rms_fraction": 0.6, "blowup_m": 0.1},
        # threads for batches of >= simulator.PARALLEL_MIN_ROWS rows (None: BOGIE_NUM_THREADS or
        # the usable cores); results do not depend on it
        "num_threads": None,
    }


def passive_actuators() -> dict[str, Any]:
    return {name: {**spec, "mode": "off"} for name, spec in _ACTUATOR_DEFAULTS.items()}


def semi_active_actuators() -> dict[str, Any]:
    """Every channel that is on by default becomes a semi-active damper."""
    return {name: {**spec, "mode": "semi_active" if spec["mode"] != "off" else "off"} for name, spec in _ACTUATOR_DEFAULTS.items()}


def merge_config(base: dict, update: Mapping) -> dict:
    """``base`` (a full config) with ``update`` merged in; unknown keys are errors, nothing is
    re-validated (call :func:`make_config` for that)."""
    return _merge(base, update, "")


def _merge(base: dict, update: Mapping, path: str) -> dict:
    out = copy.deepcopy(base)
    for key, value in update.items():
        where = f"{path}.{key}" if path else str(key)
        if key not in base:
            raise ConfigError(f"unknown config key {where!r}; known keys at this level: {', '.join(map(str, base))}")
        if isinstance(base[key], dict) and key not in ("bogie_overrides", "randomize"):
            if not isinstance(value, Mapping):
                raise ConfigError(f"config key {where!r} must be a mapping; got {value!r}")
            out[key] = _merge(base[key], value, where)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _number(where: str, value: Any, low: float, high: float, low_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"config {where!r} = {value!r} must be a number in {'(' if low_open else '['}{low:g}, {high:g}]")
    v = float(value)
    bad_low = v <= low if low_open else v < low
    if not math.isfinite(v) or bad_low or v > high:
        raise ConfigError(f"config {where!r} = {value!r} is not allowed; allowed: {'(' if low_open else '['}{low:g}, {high:g}]")
    return v


def _range(where: str, value: Any, low: float, high: float) -> tuple[float, float] | None:
    if value is None:
        return None
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(f"config {where!r} = {value!r} must be null or [low, high]")
    a, b = (_number(where, v, low, high) for v in value)
    if a > b:
        raise ConfigError(f"config {where!r} = {value!r}: low must not exceed high")
    return a, b


def validate(config: dict) -> dict:
    """Check every value; returns the config with numbers as floats."""
    c = copy.deepcopy(config)
    c["dt"] = _number("dt", c["dt"], 0.01, 0.1)
    sp = c["speed"]
    sp["start_kmh"] = _number("speed.start_kmh", sp["start_kmh"], MIN_SPEED_KMH, MAX_SPEED_KMH)
    sp["end_kmh"] = _number("speed.end_kmh", sp["end_kmh"], MIN_SPEED_KMH, MAX_SPEED_KMH)
    sp["accel"] = _number("speed.accel", sp["accel"], 0.0, MAX_ACCEL)
    for key in ("start_kmh_range", "end_kmh_range"):
        sp[key] = _range(f"speed.{key}", sp[key], MIN_SPEED_KMH, MAX_SPEED_KMH)
    sp["accel_range"] = _range("speed.accel_range", sp["accel_range"], 0.0, MAX_ACCEL)
    if sp["end_kmh"] < sp["start_kmh"]:
        raise ConfigError(f"config 'speed.end_kmh' = {sp['end_kmh']:g} must not be below 'speed.start_kmh' = {sp['start_kmh']:g}")
    c["initial_perturbation"] = _number("initial_perturbation", c["initial_perturbation"], 0.0, 0.02)
    c["large_perturbation_probability"] = _number("large_perturbation_probability", c["large_perturbation_probability"], 0.0, 1.0)
    c["large_perturbation"] = _number("large_perturbation", c["large_perturbation"], 0.0, 0.03)
    tr = c["track"]
    tr["rms"] = _number("track.rms", tr["rms"], 0.0, 0.01)
    tr["wavelength_min"] = _number("track.wavelength_min", tr["wavelength_min"], 1.0, 200.0)
    tr["wavelength_max"] = _number("track.wavelength_max", tr["wavelength_max"], 1.0, 500.0)
    if not tr["wavelength_min"] < tr["wavelength_max"]:
        raise ConfigError("config 'track.wavelength_min' must be below 'track.wavelength_max'")
    if isinstance(tr["seed"], bool) or not isinstance(tr["seed"], int) or tr["seed"] < 0:
        raise ConfigError(f"config 'track.seed' = {tr['seed']!r} must be an integer >= 0")
    if not isinstance(c["bogie_overrides"], Mapping):
        raise ConfigError("config 'bogie_overrides' must be a mapping of parameter names to numbers")
    if not isinstance(c["randomize"], Mapping):
        raise ConfigError("config 'randomize' must be a mapping like {'Csy': [0.5, 1.0]}")
    from ..params import FIELDS

    for name, value in c["randomize"].items():
        if name not in FIELDS:
            raise ConfigError(f"config 'randomize.{name}': unknown parameter; known parameters: {', '.join(FIELDS)}")
        c["randomize"][name] = _range(f"randomize.{name}", value, 1e-3, 100.0)
    c["randomize"] = {name: bounds for name, bounds in c["randomize"].items() if bounds is not None}  # null: not randomised
    if c["randomize"]:  # every scale in a range must give a valid bogie, checked now rather than at a reset
        base = load_params(c["bogie"], c["bogie_overrides"])
        for name, (low, high) in c["randomize"].items():
            for scale in (low, high):
                try:
                    base.scaled(**{name: scale})
                except ConfigError as error:
                    raise ConfigError(f"config 'randomize.{name}' = [{low:g}, {high:g}]: the scale {scale:g} gives an "
                                      f"invalid bogie ({error})") from None  # fmt: skip
    for name in CHANNELS:
        spec = c["actuators"][name]
        where = f"actuators.{name}"
        if spec["mode"] not in ACTUATOR_MODES:
            raise ConfigError(f"config '{where}.mode' = {spec['mode']!r} is not allowed; allowed: {', '.join(ACTUATOR_MODES)}")
        spec["max_force"] = _number(f"{where}.max_force", spec["max_force"], 0.0, 1e6, low_open=True)
        for key in ("c_min", "c_max"):
            try:
                spec[key] = _number(f"{where}.{key}", spec[key], 0.0, MAX_DAMPING)
            except ConfigError as error:
                raise ConfigError(f"{error} (a stiffer damper forces the integrator into ever smaller substeps: "
                                  "1e8 would make the env ~100x slower)") from None  # fmt: skip
        if spec["c_min"] > spec["c_max"]:
            raise ConfigError(f"config '{where}.c_min' must not exceed '{where}.c_max'")
        spec["bandwidth_hz"] = _number(f"{where}.bandwidth_hz", spec["bandwidth_hz"], 0.0, 1e4, low_open=True)
        d = spec["delay_steps"]
        if isinstance(d, bool) or not isinstance(d, int) or not 0 <= d <= MAX_DELAY_STEPS:
            raise ConfigError(f"config '{where}.delay_steps' = {d!r} must be an integer in [0, {MAX_DELAY_STEPS}]")
    ob = c["observation"]
    if ob["type"] not in OBSERVATION_TYPES:
        raise ConfigError(f"config 'observation.type' = {ob['type']!r} is not allowed; allowed: {', '.join(OBSERVATION_TYPES)}")
    ob["noise"] = _number("observation.noise", ob["noise"], 0.0, 10.0)
    if not isinstance(ob["include_actuators"], bool):
        raise ConfigError("config 'observation.include_actuators' must be true or false")
    rw = c["reward"]
    for key in ("lateral_weight", "yaw_weight", "effort_weight"):
        rw[key] = _number(f"reward.{key}", rw[key], 0.0, 1.0)
    if rw["lateral_weight"] + rw["yaw_weight"] + rw["effort_weight"] >= 1.0:
        raise ConfigError("config reward weights must sum to less than 1, so a step alive always pays (docs)")
    rw["time_weight"] = _number("reward.time_weight", rw["time_weight"], 0.0, 1e3)
    rw["yaw_reference"] = _number("reward.yaw_reference", rw["yaw_reference"], 0.0, 1.0, low_open=True)
    hu = c["hunting"]
    hu["window_m"] = _number("hunting.window_m", hu["window_m"], 1.0, 1e4)
    hu["rms_fraction"] = _number("hunting.rms_fraction", hu["rms_fraction"], 0.0, 10.0, low_open=True)
    hu["blowup_m"] = _number("hunting.blowup_m", hu["blowup_m"], 0.0, 10.0, low_open=True)
    t = c["num_threads"]
    if t is not None and (isinstance(t, bool) or not isinstance(t, int) or t < 1):
        raise ConfigError(f"config 'num_threads' = {t!r} must be null or an integer >= 1")
    return c


def bogie_params(config: Mapping[str, Any]) -> BogieParams:
    """The bogie of a (validated) env config: its preset with ``bogie_overrides`` applied."""
    return load_params(config["bogie"], config["bogie_overrides"])


#: Named presets behind the registered ids; a user's config merges into its variant's.
VARIANTS: dict[str, dict[str, Any]] = {
    "active": {},  # force actuators on all four channels (the default)
    "passive": {"actuators": passive_actuators()},  # no actuators; the action is ignored
    "semi_active": {"actuators": semi_active_actuators()},  # semi-active dampers on all four channels
    "slow_ramp": {"speed": {"accel": 0.1}},  # the paper's ramp, 300 -> 600 km/h in 833 s
}


def make_config(
    config: Mapping[str, Any] | str | Path | None = None, *, variant: str | None = None, **overrides: Any
) -> dict:
    """Merge a variant (a name in :data:`VARIANTS`), then a user config (mapping or YAML path),
    then keyword overrides into the defaults."""
    if variant is not None and variant not in VARIANTS:
        raise ConfigError(f"variant {variant!r} is not known; known variants: {', '.join(VARIANTS)}")
    user: dict = {}
    if isinstance(config, (str, Path)):
        path = Path(config)
        if not path.is_file():
            candidate = CONFIG_DIR / "env" / f"{config}.yaml"
            if candidate.is_file():
                path = candidate
            else:
                raise ConfigError(f"env config file {str(config)!r} does not exist")
        user = load_yaml(path) or {}
        if not isinstance(user, Mapping):
            raise ConfigError(f"env config file {str(path)!r} must hold a mapping of config keys")
    elif config is not None:
        if not isinstance(config, Mapping):
            raise ConfigError(f"env config must be a mapping or a YAML path; got {type(config).__name__}")
        user = dict(config)
    merged = _merge(default_config(), VARIANTS[variant] if variant else {}, "")
    merged = _merge(merged, user, "")
    merged = _merge(merged, overrides, "")
    return validate(merged)


def max_steps_for(config: Mapping[str, Any] | None) -> int:
    """Steps to ramp from the lowest start to the highest end at the slowest rate, +10 %
    (100,000 when a fixed-speed run has no natural end)."""
    c = make_config(config)
    sp = c["speed"]
    accel = min([sp["accel"]] + ([sp["accel_range"][0]] if sp["accel_range"] else []))
    lo = min([sp["start_kmh"]] + ([sp["start_kmh_range"][0]] if sp["start_kmh_range"] else []))
    hi = max([sp["end_kmh"]] + ([sp["end_kmh_range"][1]] if sp["end_kmh_range"] else []))
    if accel <= 0:
        return 100_000
    return int(math.ceil((hi - lo) / 3.6 / accel / c["dt"] * 1.1)) + 10
