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
from ..params import CONFIG_DIR, FIELDS, BogieParams, ConfigError, load_params
from ..track import ALIGNMENT_LEVELS
from .routes import validate_route_config
from .scenario import validate_randomize
from .sensors import NOISE_DRAWS, SENSOR_NAMES, SENSOR_SETTINGS, default_sensor_config

ACTUATOR_MODES = MODES
OBSERVATION_TYPES = ("sensors", "state")
#: How the RK4 substep is chosen (``integration.step_criterion``): "stability" (every
#: eigenvalue inside RK4's stability region; v0) or "accuracy" (also the damping and frequency
#: of every lightly damped mode within ``integration.tolerance``; v1). ``integration.n_sub``
#: fixes the substeps per env step instead (convergence studies).
STEP_CRITERIA = ("stability", "accuracy")
#: The integration method (``integration.method``): "rk4", classic RK4 (v0, v1); "taylor10",
#: a 10-stage explicit method whose stability polynomial is exp's degree-10 Taylor polynomial
#: (v2); or "poly14", a 14-stage explicit method of second order whose stability polynomial was
#: designed for the bogie's spectrum (v3; ``bogie_env.integrate.METHOD_DIVISORS``,
#: docs/studies/integrator.md); or "poly12", 12 stages by the same design (v4). The step
#: criterion applies to the method chosen.
INTEGRATION_METHODS = ("rk4", "taylor10", "poly14", "poly12")
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
            # null, or [low, high] km/h added to the supported speed range: the range the
            # integration step is chosen for and reset options may use is the union of this and
            # the ramp's (start_kmh .. end_kmh and their ranges); e.g. [40, 600] for low-speed
            # studies on v1 (v1's step is then chosen for 40-600 km/h: other substeps, so other
            # trajectories than the registered id's)
            "supported_kmh": None,
        },
        "initial_perturbation": 1e-3,  # m, std of the random initial lateral offsets
        # with this probability an episode starts with large offsets instead (uniform in
        # [0.5, 1] x large_perturbation, random signs): flange contact, as on a hunting cycle
        "large_perturbation_probability": 0.0,
        "large_perturbation": 0.012,  # m
        # level: an EN 13848-5 alignment level (track.ALIGNMENT_LEVELS) instead of an rms
        "track": {"rms": 5e-4, "wavelength_min": 3.0, "wavelength_max": 80.0, "seed": 0, "level": None},
        # per-episode draws (envs/scenario.py): parameter scale ranges, e.g. {"Csy": [0.5, 1.0]},
        # and named ranges/probabilities, e.g. {"conicity": [0.025, 0.3]}
        "randomize": {},
        "actuators": copy.deepcopy(_ACTUATOR_DEFAULTS),
        # noise: white Gaussian noise of this standard deviation in observation units (the scaled
        # values, ~1 at full scale) added to every entry, actuator forces included, after the
        # sensor model; a generic robustness knob, not the sensor model (that is `sensors`)
        "observation": {"type": "sensors", "noise": 0.0, "include_actuators": True},
        # the sensor model of the "sensors" observation (envs/sensors.py); off in v0. noise_scale and
        # bias_scale multiply every channel's noise_density and bias (0: no noise / no bias)
        "sensors": default_sensor_config(),
        "integration": {"step_criterion": "stability", "tolerance": 0.1, "n_sub": None, "method": "rk4"},
        # wear_weight, flange_weight: the curving penalties of the route variant (0: off); the wear
        # penalty is min(mean wheelset wear number / wear_reference, 1), wear_reference in N
        "reward": {"lateral_weight": 0.5, "yaw_weight": 0.2, "effort_weight": 0.2, "time_weight": 0.0,
                   "yaw_reference": 5e-3, "wear_weight": 0.0, "flange_weight": 0.0, "wear_reference": 65.0},  # fmt: skip
        # detrend_m: the detector (and the lateral penalty) use each wheelset's displacement minus
        # its exponentially weighted mean over detrend_m of track, so the quasi-static offset in a
        # curve is not taken for hunting (route variant: 10 m); null (v0, v1): the displacement
        "hunting": {"window_m": 100.0, "rms_fraction": 0.6, "blowup_m": 0.1, "detrend_m": None},
        # route variant (envs/routes.py): names null is straight track (v0, v1); else a shipped
        # route name or path, or a list drawn per episode; speed_kmh per route (a speed or
        # [low, high], default routes.ROUTE_SPEEDS_KMH or the file's design speed); copies: rounds
        # of the routes on the layout (different irregularity under each copy)
        "route": {"names": None, "speed_kmh": None, "copies": 8},
        # route variant's termination: the wheel's Y/Q, averaged over y_over_q_window_m of track
        # (EN 14363's 2 m sliding mean), above y_over_q_limit ends the episode (null: never)
        "curving": {"y_over_q_limit": None, "y_over_q_window_m": 2.0},
        # criterion: true adds the per-step criterion fields to every info (task.CRITERION_FIELDS:
        # displacement relative to the rail, flange contact, ΣY, Y/Q); off by default, as they cost
        # a front-end step measurably (benchmarks/bench_env.py --criterion-info)
        "info": {"criterion": False},
        # reuse_options: the vector envs reset a finished row with the options of its last reset
        # (Gymnasium vector env: reset(options=...); SB3 VecEnv: set_options); false: no options
        "autoreset": {"reuse_options": False},
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
    sp["supported_kmh"] = _range("speed.supported_kmh", sp["supported_kmh"], MIN_SPEED_KMH, MAX_SPEED_KMH)
    if sp["end_kmh"] < sp["start_kmh"]:
        raise ConfigError(f"config 'speed.end_kmh' = {sp['end_kmh']:g} must not be below 'speed.start_kmh' = {sp['start_kmh']:g}")
    c["initial_perturbation"] = _number("initial_perturbation", c["initial_perturbation"], 0.0, 0.02)
    c["large_perturbation_probability"] = _number("large_perturbation_probability", c["large_perturbation_probability"], 0.0, 1.0)
    c["large_perturbation"] = _number("large_perturbation", c["large_perturbation"], 0.0, 0.03)
    tr = c["track"]
    if tr["level"] is not None:
        if not isinstance(tr["level"], str) or tr["level"] not in ALIGNMENT_LEVELS:
            raise ConfigError(f"config 'track.level' = {tr['level']!r} is not allowed; allowed: null, {', '.join(ALIGNMENT_LEVELS)}")
        if tr["rms"] is not None:
            raise ConfigError("config 'track.level' and 'track.rms' are both set; set 'track.rms' to null to use a level")
    elif tr["rms"] is None:
        raise ConfigError("config 'track.rms' is null and 'track.level' is null; give one")
    else:
        tr["rms"] = _number("track.rms", tr["rms"], 0.0, 0.01)
    tr["wavelength_min"] = _number("track.wavelength_min", tr["wavelength_min"], 1.0, 200.0)
    tr["wavelength_max"] = _number("track.wavelength_max", tr["wavelength_max"], 1.0, 500.0)
    if not tr["wavelength_min"] < tr["wavelength_max"]:
        raise ConfigError("config 'track.wavelength_min' must be below 'track.wavelength_max'")
    if isinstance(tr["seed"], bool) or not isinstance(tr["seed"], int) or tr["seed"] < 0:
        raise ConfigError(f"config 'track.seed' = {tr['seed']!r} must be an integer >= 0")
    if not isinstance(c["bogie_overrides"], Mapping):
        raise ConfigError("config 'bogie_overrides' must be a mapping of parameter names to numbers")
    c["randomize"] = validate_randomize(c["randomize"])
    factors = {k: v for k, v in c["randomize"].items() if k in FIELDS}
    if factors:  # every scale in a range must give a valid bogie, checked now rather than at a reset
        base = load_params(c["bogie"], c["bogie_overrides"])
        for name, (low, high) in factors.items():
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
        if spec.get("rate_limit") is not None:
            spec["rate_limit"] = _number(f"{where}.rate_limit", spec["rate_limit"], 0.0, 1e9, low_open=True)
        d = spec["delay_steps"]
        if isinstance(d, bool) or not isinstance(d, int) or not 0 <= d <= MAX_DELAY_STEPS:
            raise ConfigError(f"config '{where}.delay_steps' = {d!r} must be an integer in [0, {MAX_DELAY_STEPS}]")
    se = c["sensors"]
    if not isinstance(se["enabled"], bool):
        raise ConfigError(f"config 'sensors.enabled' = {se['enabled']!r} must be true or false")
    if se["noise_draws"] not in NOISE_DRAWS:
        raise ConfigError(f"config 'sensors.noise_draws' = {se['noise_draws']!r} is not allowed; allowed: {', '.join(NOISE_DRAWS)}")
    se["noise_scale"] = _number("sensors.noise_scale", se["noise_scale"], 0.0, 100.0)
    se["bias_scale"] = _number("sensors.bias_scale", se["bias_scale"], 0.0, 100.0)
    for name in SENSOR_NAMES:
        if not isinstance(se[name], Mapping):
            raise ConfigError(f"config 'sensors.{name}' must be a mapping with keys {', '.join(SENSOR_SETTINGS)}")
        unknown = set(se[name]) - set(SENSOR_SETTINGS)
        if unknown:
            raise ConfigError(f"unknown config key(s) 'sensors.{name}.{sorted(unknown)[0]}'; known: {', '.join(SENSOR_SETTINGS)}")
        se[name]["noise_density"] = _number(f"sensors.{name}.noise_density", se[name]["noise_density"], 0.0, 1e3)
        se[name]["bias"] = _number(f"sensors.{name}.bias", se[name]["bias"], 0.0, 1e3)
        se[name]["bandwidth_hz"] = _number(f"sensors.{name}.bandwidth_hz", se[name]["bandwidth_hz"], 0.0, 1e4, low_open=True)
    if se["enabled"] and c["observation"]["type"] != "sensors":
        raise ConfigError("config 'sensors.enabled' = true needs 'observation.type' = 'sensors' (the model measures those channels)")
    ig = c["integration"]
    if ig["step_criterion"] not in STEP_CRITERIA:
        raise ConfigError(f"config 'integration.step_criterion' = {ig['step_criterion']!r} is not allowed; allowed: {', '.join(STEP_CRITERIA)}")
    ig["tolerance"] = _number("integration.tolerance", ig["tolerance"], 0.0, 1.0, low_open=True)
    if ig["method"] not in INTEGRATION_METHODS:
        raise ConfigError(f"config 'integration.method' = {ig['method']!r} is not allowed; allowed: {', '.join(INTEGRATION_METHODS)}")
    n_sub = ig["n_sub"]
    if n_sub is not None and (isinstance(n_sub, bool) or not isinstance(n_sub, int) or not 1 <= n_sub <= 1000):
        raise ConfigError(f"config 'integration.n_sub' = {n_sub!r} must be null or an integer in [1, 1000]")
    ob = c["observation"]
    if ob["type"] not in OBSERVATION_TYPES:
        raise ConfigError(f"config 'observation.type' = {ob['type']!r} is not allowed; allowed: {', '.join(OBSERVATION_TYPES)}")
    ob["noise"] = _number("observation.noise", ob["noise"], 0.0, 10.0)
    if not isinstance(ob["include_actuators"], bool):
        raise ConfigError("config 'observation.include_actuators' must be true or false")
    rw = c["reward"]
    weights = ("lateral_weight", "yaw_weight", "effort_weight", "wear_weight", "flange_weight")
    for key in weights:
        rw[key] = _number(f"reward.{key}", rw[key], 0.0, 1.0)
    if sum(rw[key] for key in weights) >= 1.0:
        raise ConfigError(f"config reward weights ({', '.join(weights)}) must sum to less than 1, so a step alive always pays (docs)")
    rw["wear_reference"] = _number("reward.wear_reference", rw["wear_reference"], 0.0, 1e6, low_open=True)
    rw["time_weight"] = _number("reward.time_weight", rw["time_weight"], 0.0, 1e3)
    rw["yaw_reference"] = _number("reward.yaw_reference", rw["yaw_reference"], 0.0, 1.0, low_open=True)
    hu = c["hunting"]
    hu["window_m"] = _number("hunting.window_m", hu["window_m"], 1.0, 1e4)
    hu["rms_fraction"] = _number("hunting.rms_fraction", hu["rms_fraction"], 0.0, 10.0, low_open=True)
    hu["blowup_m"] = _number("hunting.blowup_m", hu["blowup_m"], 0.0, 10.0, low_open=True)
    if hu["detrend_m"] is not None:
        hu["detrend_m"] = _number("hunting.detrend_m", hu["detrend_m"], 0.1, 1e4)
    c["route"] = validate_route_config(c["route"], MIN_SPEED_KMH, MAX_SPEED_KMH)
    cu = c["curving"]
    if cu["y_over_q_limit"] is not None:
        cu["y_over_q_limit"] = _number("curving.y_over_q_limit", cu["y_over_q_limit"], 0.0, 10.0, low_open=True)
    cu["y_over_q_window_m"] = _number("curving.y_over_q_window_m", cu["y_over_q_window_m"], 0.1, 1e4)
    if (rw["wear_weight"] > 0 or rw["flange_weight"] > 0 or cu["y_over_q_limit"] is not None) and c["route"]["names"] is None:
        raise ConfigError("config 'reward.wear_weight', 'reward.flange_weight' and 'curving.y_over_q_limit' act on routes: "
                          "set 'route.names' (e.g. Bogie/HuntingRoute-v1) or leave them at 0 / null")  # fmt: skip
    for where, value in (("info.criterion", c["info"]["criterion"]), ("autoreset.reuse_options", c["autoreset"]["reuse_options"])):
        if not isinstance(value, bool):
            raise ConfigError(f"config {where!r} = {value!r} must be true or false")
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

# ---- v1: the realistic task (sources in docs/environment.md, "Bogie/Hunting-v1") ---------------
#: One control step of loop delay: the computational delay of a digital loop sampled at
#: 100 Hz (measure, compute, output within one sample; Franklin, Powell & Workman, "Digital
#: Control of Dynamic Systems", 3rd ed., Sec. 4.3.5), inside the 5-20 ms of active suspensions.
V1_DELAY_STEPS = 1
#: Force-rate limits: series stiffness x the actuator's stroke-velocity limit,
#: 2 MN/m x 0.1 m/s = 200 kN/s per actuator (yaw-damper series stiffness of a few MN/m; stroke
#: velocities of 0.1-0.2 m/s for servo-hydraulic and electromechanical suspension actuators),
#: and for the yaw channels, a pair of such actuators on a lever of about 1 m: 400 kN m/s.
V1_RATE_LIMITS = {"frame_lateral": 2.0e5, "frame_yaw": 4.0e5, "wheelset1_yaw": 4.0e5, "wheelset2_yaw": 4.0e5}
V1_RANDOMIZE: dict[str, Any] = {
    "conicity": [0.025, 0.3],  # new to worn wheels (EN 15302 equivalent conicity)
    "primary_longitudinal_stiffness": [0.5, 1.5],
    "primary_lateral_stiffness": [0.5, 1.5],
    "creep_factor": [0.5, 1.0],  # dry to contaminated rail
    "damper_factor": [0.5, 1.0],  # new to degraded secondary dampers
    "axle_load": [0.8, 1.2],
    "actuator_gain": [0.8, 1.25],
    "actuator_failure_probability": 0.05,
    "actuator_stuck_probability": 0.05,
}


def _v1(actuators: dict[str, Any], **extra: Any) -> dict[str, Any]:
    acts = {name: {**spec, "delay_steps": V1_DELAY_STEPS, "rate_limit": V1_RATE_LIMITS[name]} for name, spec in actuators.items()}
    base = {
        "speed": {"start_kmh": 100.0, "end_kmh": 600.0, "accel": 1.5},
        "track": {"level": "alert", "rms": None, "wavelength_min": 3.0, "wavelength_max": 25.0},
        "randomize": copy.deepcopy(V1_RANDOMIZE),
        "sensors": {"enabled": True},
        "actuators": acts,
        "integration": {"step_criterion": "accuracy"},
    }
    return _merge(base, extra, "") if extra else base


VARIANTS.update({
    "v1": _v1(copy.deepcopy(_ACTUATOR_DEFAULTS)),
    "v1_passive": _v1(passive_actuators()),
    "v1_semi_active": _v1(semi_active_actuators()),
    "v1_slow_ramp": _v1(copy.deepcopy(_ACTUATOR_DEFAULTS), speed={"accel": 0.1}),
})
#: v2 (Bogie/Hunting-v2): v1's task integrated with the 10-stage Taylor method, the substeps chosen
#: by the same accuracy criterion (2 per 10-ms step: 20 right-hand sides, RK4 needs 40).
def _v2(actuators: dict[str, Any]) -> dict[str, Any]:
    return {**_v1(actuators), "integration": {"step_criterion": "accuracy", "method": "taylor10"}}


VARIANTS.update({
    "v2": _v2(copy.deepcopy(_ACTUATOR_DEFAULTS)),
    "v2_passive": _v2(passive_actuators()),
})



#: v3 (Bogie/Hunting-v3): v1's task integrated with the 14-stage designed method, the substeps chosen
#: by the same accuracy criterion (1 per 10-ms step: 14 right-hand sides; v2 needs 20, RK4 40), and
#: the sensor noise drawn in pairs (sensors.NOISE_DRAWS).
def _v3(actuators: dict[str, Any]) -> dict[str, Any]:
    return {**_v1(actuators), "integration": {"step_criterion": "accuracy", "method": "poly14"},
            "sensors": {"enabled": True, "noise_draws": "paired"}}


VARIANTS.update({
    "v3": _v3(copy.deepcopy(_ACTUATOR_DEFAULTS)),
    "v3_passive": _v3(passive_actuators()),
})


#: v4 (Bogie/Hunting-v4): v3 with the 12-stage designed method (poly12): one substep per 10-ms
#: step by the same accuracy criterion, 12 right-hand sides.
def _v4(actuators: dict[str, Any]) -> dict[str, Any]:
    return {**_v3(actuators), "integration": {"step_criterion": "accuracy", "method": "poly12"}}


VARIANTS.update({
    "v4": _v4(copy.deepcopy(_ACTUATOR_DEFAULTS)),
    "v4_passive": _v4(passive_actuators()),
})


#: The route variant (Bogie/HuntingRoute-v1): v1's world on the shipped routes at their line
#: speeds (constant speed per episode, drawn from each route's range), with the curving terms
#: of the reward and termination (docs/environment.md, "Bogie/HuntingRoute-v1").
#: time_weight 5.4 (km/h per s): a step alive pays what a step of v1's 1.5 m/s^2 ramp pays.
#: The lateral penalty and the detector read the displacement about its mean over 10 m of track
#: (hunting.detrend_m): a first-order high-pass that lags a transition's ramp of the curving
#: offset (10 mm over 180 m) by 0.6 mm and keeps 81-94 % of the amplitude of this model's 2-4 Hz
#: hunting at 330 km/h (docs/environment.md).
ROUTE_NAMES = ["high-speed-7000", "conventional-1500", "s-curve"]
_ROUTE_EXTRA: dict[str, Any] = {
    "route": {"names": ROUTE_NAMES, "copies": 8},
    "reward": {"lateral_weight": 0.3, "yaw_weight": 0.1, "effort_weight": 0.1, "wear_weight": 0.2, "flange_weight": 0.2,
               "time_weight": 5.4},
    "hunting": {"detrend_m": 10.0},
    "curving": {"y_over_q_limit": 0.8},
}  # fmt: skip
VARIANTS.update({
    "v1_route": {**_v1(copy.deepcopy(_ACTUATOR_DEFAULTS)), **copy.deepcopy(_ROUTE_EXTRA)},
    "v1_route_passive": {**_v1(passive_actuators()), **copy.deepcopy(_ROUTE_EXTRA)},
})


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
    if c["route"]["names"] is not None:  # constant speed along the longest route at its lowest speed
        from .routes import build_layout

        layout = build_layout(c["route"])
        slowest = min(lo for lo, _ in layout.speed_ranges_kmh) / 3.6
        return int(math.ceil(layout.max_route_length() / slowest / c["dt"] * 1.1)) + 10
    sp = c["speed"]
    accel = min([sp["accel"]] + ([sp["accel_range"][0]] if sp["accel_range"] else []))
    lo = min([sp["start_kmh"]] + ([sp["start_kmh_range"][0]] if sp["start_kmh_range"] else []))
    hi = max([sp["end_kmh"]] + ([sp["end_kmh_range"][1]] if sp["end_kmh_range"] else []))
    if accel <= 0:
        return 100_000
    return int(math.ceil((hi - lo) / 3.6 / accel / c["dt"] * 1.1)) + 10
