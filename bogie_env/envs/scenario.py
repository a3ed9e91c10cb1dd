"""Per-episode scenarios: the bogie, wheels, rail and actuator health an episode runs with.

The env config's ``randomize`` section maps names to what is drawn at each reset:

- a bogie parameter (``bogie_env.params.FIELDS``) -> ``[low, high]``: a uniform scale factor
  on it (the v0 form, e.g. ``{"Csy": [0.5, 1.0]}``);
- a named entry of :data:`RANGES` -> ``[low, high]``: a uniform draw of that quantity;
- a named entry of :data:`PROBABILITIES` -> a probability.

Draws happen in the order of the section, one uniform per entry (one per channel for
``actuator_gain``; three for a fault: whether, which channel, the held command), whether or
not a reset option then overrides the value: pinning one quantity never shifts the others'
random stream. ``reset(options=...)`` sets any of them directly (:data:`OPTION_NAMES`);
``failed_actuator`` / ``stuck_actuator`` = ``"none"`` (:data:`NO_FAULT`) switch that fault off
for the episode, and :data:`NO_FAULTS` switches both off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..actuators import CHANNEL_NAMES, CH_C_MAX, CH_C_MIN, CH_MAX_FORCE, CH_MODE, H_GAIN, H_HELD_DAMPING, H_HELD_FORCE
from ..actuators import MODE_FORCE, MODE_OFF, MODE_SEMI, N_CHANNELS, healthy
from ..contact import CREEP_NAMES, computed_creep, creep_coefficients, creep_rows
from ..dynamics import COEFFICIENT_NAMES, BogieModel
from ..params import FIELDS, BogieParams, ConfigError, validate_value
from .draws import uniform, uniform_array


@dataclass(frozen=True)
class Range:
    """A named randomised quantity: what it sets and the values it may take."""

    description: str
    low: float
    high: float


#: Named per-episode ranges (uniform draws). Factors multiply the bogie's value.
RANGES: dict[str, Range] = {
    "conicity": Range("equivalent conicity lam (absolute; new wheels ~0.025-0.05, worn 0.1-0.3, EN 15302)", 1e-3, 0.5),
    "primary_longitudinal_stiffness": Range("factor on Kpx (primary longitudinal stiffness)", 0.05, 5.0),
    "primary_lateral_stiffness": Range("factor on Kpy (primary lateral stiffness)", 0.05, 5.0),
    "creep_factor": Range("factor on the Kalker coefficients f11, f12, f22, f33 (contaminated rail < 1)", 0.05, 2.0),
    "damper_factor": Range("factor on the secondary dampers Csx (yaw) and Csy (lateral); degraded < 1", 0.0, 2.0),
    "axle_load": Range("factor on the axle load Wpa (the Hertz contact and creep coefficients follow)", 0.5, 1.5),
    "actuator_gain": Range("factor on each actuator channel's command, drawn per channel (gain error)", 0.0, 3.0),
}
#: Named per-episode probabilities (at most one actuator is faulty per episode).
PROBABILITIES: dict[str, str] = {
    "actuator_failure_probability": "one active channel, drawn uniformly, gives zero force",
    "actuator_stuck_probability": "one active channel, drawn uniformly, holds a random command",
}
#: The equivalent conicities at which controllers are designed and judged: new wheels (0.025,
#: the model's) to worn ones (EN 15302; the v1 range is 0.025-0.3).
CONICITY_GRID: tuple[float, ...] = (0.025, 0.05, 0.1, 0.2, 0.3)
FAULT_OPTIONS = ("failed_actuator", "stuck_actuator", "stuck_command")
#: The value of the reset options ``failed_actuator`` and ``stuck_actuator`` that means "no such
#: fault this episode", whatever the config's probabilities drew (None means "not given": the
#: draw stands).
NO_FAULT = "none"
#: Reset options of a fault-free episode: ``reset(options={**NO_FAULTS, ...})``.
NO_FAULTS: dict[str, str] = {"failed_actuator": NO_FAULT, "stuck_actuator": NO_FAULT}
#: reset(options=...) keys this module reads (besides v0's start_kmh, end_kmh, accel, params).
OPTION_NAMES: tuple[str, ...] = tuple(RANGES) + FAULT_OPTIONS


def validate_randomize(randomize: Any) -> dict[str, Any]:
    """The config's ``randomize`` section, checked entry by entry."""
    if not isinstance(randomize, Mapping):
        raise ConfigError("config 'randomize' must be a mapping like {'conicity': [0.025, 0.3], 'Csy': [0.5, 1.0]}")
    out: dict[str, Any] = {}
    for name, value in randomize.items():
        where = f"randomize.{name}"
        if value is None:  # null: not randomised
            continue
        if name in PROBABILITIES:
            out[name] = _number(where, value, 0.0, 1.0)
        elif name in RANGES or name in FIELDS:
            low, high = (RANGES[name].low, RANGES[name].high) if name in RANGES else (1e-3, 100.0)
            if not isinstance(value, (list, tuple)) or len(value) != 2:
                raise ConfigError(f"config {where!r} = {value!r} must be [low, high]")
            a, b = (_number(where, v, low, high) for v in value)
            if a > b:
                raise ConfigError(f"config {where!r} = {value!r}: low must not exceed high")
            out[name] = (a, b)
        else:
            raise ConfigError(
                f"config {where!r}: unknown parameter or named entry; allowed: the named ranges {', '.join(RANGES)}, "
                f"the probabilities {', '.join(PROBABILITIES)}, or a bogie parameter ({', '.join(FIELDS)})"
            )
    if "conicity" in out and "lam" in out:
        raise ConfigError("config 'randomize' sets both 'conicity' and 'lam'; give one")
    total = out.get("actuator_failure_probability", 0.0) + out.get("actuator_stuck_probability", 0.0)
    if total > 1.0:
        raise ConfigError(f"config 'randomize': actuator_failure_probability + actuator_stuck_probability = {total:g} must be <= 1")
    return out


def _number(where: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not low <= value <= high:
        raise ConfigError(f"{where} = {value!r} is not allowed; allowed: a number in [{low:g}, {high:g}]")
    return float(value)


@dataclass
class Scenario:
    """What one episode runs with (all values as used, after reset options)."""

    factors: dict[str, float] = field(default_factory=dict)  # bogie parameter scale factors (v0 form)
    conicity: float | None = None  # None: the bogie's own
    primary_longitudinal_stiffness: float = 1.0
    primary_lateral_stiffness: float = 1.0
    creep_factor: float = 1.0
    damper_factor: float = 1.0
    axle_load: float = 1.0
    actuator_gain: np.ndarray = field(default_factory=lambda: np.ones(N_CHANNELS))
    failed_actuator: str | None = None
    stuck_actuator: str | None = None
    stuck_command: float = 0.0  # the stuck channel's held action, in [-1, 1]

    def as_dict(self) -> dict[str, Any]:
        """A JSON-friendly summary (``HuntingTask.scenario``; the reset info's ``scenario`` adds
        the other draws, ``HuntingTask.scenario_summary``)."""
        return {
            "params": dict(self.factors),
            "conicity": self.conicity,
            "primary_longitudinal_stiffness": self.primary_longitudinal_stiffness,
            "primary_lateral_stiffness": self.primary_lateral_stiffness,
            "creep_factor": self.creep_factor,
            "damper_factor": self.damper_factor,
            "axle_load": self.axle_load,
            "actuator_gain": dict(zip(CHANNEL_NAMES, map(float, self.actuator_gain))),
            "failed_actuator": self.failed_actuator,
            "stuck_actuator": self.stuck_actuator,
            "stuck_command": self.stuck_command if self.stuck_actuator else None,
        }

    @property
    def is_nominal(self) -> bool:
        """Nothing beyond v0's parameter factors: the v0 code path, bit for bit."""
        return (
            self.conicity is None
            and self.creep_factor == 1.0
            and all(getattr(self, n) == 1.0 for n in ("primary_longitudinal_stiffness", "primary_lateral_stiffness",
                                                      "damper_factor", "axle_load"))  # fmt: skip
            and bool(np.all(self.actuator_gain == 1.0))
            and self.failed_actuator is None
            and self.stuck_actuator is None
        )


def draw_scenario(
    randomize: Mapping[str, Any], options: Mapping[str, Any], rng: np.random.Generator, active: list[str]
) -> Scenario:
    """Draw an episode's scenario from the config's ranges, then apply reset options."""
    s = Scenario()
    fault_draw: tuple[float, int, float] | None = None
    for name, bounds in randomize.items():
        if name in FIELDS:
            s.factors[name] = uniform(rng, *bounds)
        elif name == "conicity":
            s.conicity = uniform(rng, *bounds)
        elif name == "actuator_gain":
            s.actuator_gain = uniform_array(rng, *bounds, N_CHANNELS)
        elif name in RANGES:
            setattr(s, name, uniform(rng, *bounds))
        elif name in PROBABILITIES and fault_draw is None:
            fault_draw = (float(rng.random()), int(rng.integers(max(1, len(active)))), uniform(rng, -1.0, 1.0))
    if fault_draw is not None and active:
        u, which, command = fault_draw
        p_fail = randomize.get("actuator_failure_probability", 0.0)
        p_stuck = randomize.get("actuator_stuck_probability", 0.0)
        if u < p_fail:
            s.failed_actuator = active[which]
        elif u < p_fail + p_stuck:
            s.stuck_actuator, s.stuck_command = active[which], command
    _apply_options(s, options, active)
    return s


def _apply_options(s: Scenario, options: Mapping[str, Any], active: list[str]) -> None:
    if not options:
        return
    for name in RANGES:
        if name not in options:
            continue
        value = options[name]
        where = f"reset option {name!r}"
        r = RANGES[name]
        if name == "actuator_gain":
            gains = np.array(s.actuator_gain, dtype=float)
            if isinstance(value, Mapping):
                for channel, g in value.items():
                    if channel not in CHANNEL_NAMES:
                        raise ConfigError(f"{where}: unknown channel {channel!r}; channels: {', '.join(CHANNEL_NAMES)}")
                    gains[CHANNEL_NAMES.index(channel)] = _number(f"{where}[{channel!r}]", g, r.low, r.high)
            else:
                gains[:] = _number(where, value, r.low, r.high)
            s.actuator_gain = gains
        else:
            setattr(s, name, _number(where, value, r.low, r.high))
    failed, stuck = options.get("failed_actuator"), options.get("stuck_actuator")
    if _is_channel(failed) and _is_channel(stuck):
        raise ConfigError(f"reset options 'failed_actuator' = {failed!r} and 'stuck_actuator' = {stuck!r}: give at most one "
                          f"channel (one faulty actuator per episode); {NO_FAULT!r} switches a fault off")  # fmt: skip
    for key, value in (("failed_actuator", failed), ("stuck_actuator", stuck)):
        if value is None:  # not given: the draw stands
            continue
        if isinstance(value, str) and value == NO_FAULT:  # no such fault this episode
            setattr(s, key, None)
            continue
        if not isinstance(value, str) or value not in active:
            raise ConfigError(f"reset option {key!r} = {value!r} is not an active channel; allowed: {NO_FAULT!r} (no such "
                              f"fault) or an active channel ({', '.join(active) or 'none active'})")  # fmt: skip
        s.failed_actuator = value if key == "failed_actuator" else None
        s.stuck_actuator = value if key == "stuck_actuator" else None
    if "stuck_command" in options:
        s.stuck_command = _number("reset option 'stuck_command'", options["stuck_command"], -1.0, 1.0)


def _is_channel(value: Any) -> bool:
    """A fault option that names a channel (not None, not :data:`NO_FAULT`)."""
    return value is not None and not (isinstance(value, str) and value == NO_FAULT)


#: Parameters the creep coefficients follow (``contact.creep_coefficients``).
CREEP_INPUTS = frozenset(("Wpa", "r0", "Rwheel", "Rrail", "E", "nu", "f11", "f12", "f22", "f33"))
_COEFFICIENT_INDEX = {name: k for k, name in enumerate(COEFFICIENT_NAMES)}


def scenario_params(base: BogieParams, s: Scenario) -> tuple[BogieParams, frozenset[str]]:
    """The bogie parameters of a scenario and the names it changes (``base`` itself and none
    when nothing changes). Factors on one parameter multiply; a conicity replaces ``lam``; a
    creep factor scales the creep coefficients of the otherwise changed bogie."""
    if not s.factors and s.is_nominal:
        return base, frozenset()
    factors = dict(s.factors)
    for name, key in (("primary_longitudinal_stiffness", "Kpx"), ("primary_lateral_stiffness", "Kpy"),
                      ("axle_load", "Wpa")):  # fmt: skip
        value = getattr(s, name)
        if value != 1.0:
            factors[key] = factors.get(key, 1.0) * value
    if s.damper_factor != 1.0:
        for key in ("Csx", "Csy"):
            factors[key] = factors.get(key, 1.0) * s.damper_factor
    changes = base.scaled_values(**factors)
    if s.conicity is not None:
        if "lam" in changes:  # a factor on lam is checked, as the scaled bogie's is, before the conicity replaces it
            validate_value("lam", changes["lam"])
        changes["lam"] = s.conicity
    params = base.replace(**changes) if changes else base
    if s.creep_factor != 1.0:
        creep = creep_coefficients(params)
        params = params.replace(**{k: getattr(creep, k) * s.creep_factor for k in CREEP_NAMES})
        changes.update(dict.fromkeys(CREEP_NAMES))
    return params, frozenset(changes)


def scenario_model(base: BogieParams, s: Scenario, nominal: BogieModel) -> BogieModel:
    """The bogie of a scenario (the nominal model itself when nothing changes)."""
    params, changed = scenario_params(base, s)
    return BogieModel(params) if changed else nominal


def scenario_coefficients(base: BogieParams, s: Scenario, nominal: BogieModel) -> np.ndarray:
    """``scenario_model(base, s, nominal).coefficients`` (read-only), bit for bit, without
    building the model: the nominal vector with the changed entries rewritten, and the creep coefficients
    computed once, only when an input of theirs changed (a reset's cost)."""
    params, changed = scenario_params(base, s)
    if not changed:
        return nominal.coefficients
    if nominal.params is not base or "h1" in changed or "h2" in changed:  # the secondary heights: the general path
        return BogieModel(params).coefficients
    p = nominal.coefficients.copy()
    for name in changed:
        k = _COEFFICIENT_INDEX.get(name)
        if k is not None and name not in CREEP_NAMES:
            p[k] = getattr(params, name)
    if changed & CREEP_INPUTS:
        set_in_params = all(getattr(params, name) is not None for name in CREEP_NAMES)  # they override the computed ones
        creep = params if set_in_params else creep_coefficients(params)
        for name in CREEP_NAMES:
            p[_COEFFICIENT_INDEX[name]] = getattr(creep, name)
    p.setflags(write=False)  # as a model's (and one compiled signature for the equilibrium)
    return p


BATCH_MIN_ROWS = 8  # below, the arrays' fixed cost exceeds the rows' (bench_v1.py --cpu --resets)
_SCALED_BY = (("primary_longitudinal_stiffness", ("Kpx",)), ("primary_lateral_stiffness", ("Kpy",)),
              ("axle_load", ("Wpa",)), ("damper_factor", ("Csx", "Csy")))  # fmt: skip
#: The Scenario fields that scenario_coefficient_rows applies (with "factors", which sends a
#: batch row by row) and those that change only the actuators' health: a new field that changes
#: the bogie must be applied there too (tests/test_scenario_control.py checks the lists).
BATCHED_FIELDS = ("factors", "conicity", "creep_factor", *(quantity for quantity, _ in _SCALED_BY))
HEALTH_FIELDS = ("actuator_gain", "failed_actuator", "stuck_actuator", "stuck_command")


def scenario_coefficient_rows(base: BogieParams, drawn: list[Scenario], nominal: BogieModel) -> np.ndarray:
    """(n, N_COEFFICIENTS): :func:`scenario_coefficients` of each scenario, bit for bit. When no
    scenario has factors on bogie parameters (v1's draws), the bogie computes its own creep
    coefficients and there are at least :data:`BATCH_MIN_ROWS` rows, the chain runs on all rows
    at once with the Hertz ellipse's shape solved once (a vector env's reset); otherwise row by
    row (cheaper for the few rows of an autoreset). A value out of its parameter's range raises the
    same error as there."""
    n = len(drawn)
    if nominal.params is not base or any(getattr(base, k) is not None for k in CREEP_NAMES) or any(s.factors for s in drawn):
        return np.array([scenario_coefficients(base, s, nominal) for s in drawn]).reshape(n, -1)
    if n < BATCH_MIN_ROWS:
        return np.array([_row_coefficients(base, s, nominal) for s in drawn]).reshape(n, -1)
    out = np.repeat(nominal.coefficients[None, :], n, axis=0)
    wpa = np.full(n, base.Wpa)
    for quantity, keys in _SCALED_BY:
        factor = np.array([getattr(s, quantity) for s in drawn], dtype=float)
        if not (0.0 <= factor.min() and factor.max() < math.inf):  # NaN fails the comparisons too
            for value in factor[~(factor >= 0.0) | ~np.isfinite(factor)].tolist():
                base.scaled_values(**{keys[0]: value})  # raises: the factor, its parameter and what is allowed
        wpa = _scale_into(out, base, keys, factor, _checked, wpa)
    conicity = [j for j, s in enumerate(drawn) if s.conicity is not None]
    if conicity:
        out[conicity, _COEFFICIENT_INDEX["lam"]] = _checked("lam", np.array([drawn[j].conicity for j in conicity], dtype=float))
    creep_factor = np.array([s.creep_factor for s in drawn], dtype=float)
    rows = np.nonzero((wpa != base.Wpa) | (creep_factor != 1.0))[0]
    if rows.size:
        creep = creep_rows(0.5 * wpa[rows], base)
        scaled = creep_factor[rows] != 1.0
        creep[scaled] *= creep_factor[rows][scaled, None]
        for k, name in enumerate(CREEP_NAMES):
            _checked(name, creep[scaled, k])
            out[rows, _COEFFICIENT_INDEX[name]] = creep[:, k]
    return out


def _scale_into(out: np.ndarray, base: BogieParams, keys: tuple[str, ...], factor, check, wpa):
    """Write ``base``'s parameters ``keys`` times ``factor`` (checked by ``check(name, values)``)
    into the coefficient vector(s) ``out``; returns the axle load, scaled or ``wpa`` as given."""
    for key in keys:
        values = check(key, getattr(base, key) * factor)
        if key == "Wpa":
            wpa = values
        if key in _COEFFICIENT_INDEX:
            out[..., _COEFFICIENT_INDEX[key]] = values
    return wpa


def _row_coefficients(base: BogieParams, s: Scenario, nominal: BogieModel) -> np.ndarray:
    """One row of the batched chain in floats (the few rows of an autoreset), under the same
    conditions: :func:`scenario_coefficients` bit for bit, without building parameter sets."""
    out = nominal.coefficients.copy()
    wpa = base.Wpa
    for quantity, keys in _SCALED_BY:
        factor = getattr(s, quantity)
        if factor == 1.0:
            continue
        if not 0.0 <= factor < math.inf:  # NaN fails the comparisons too
            base.scaled_values(**{keys[0]: factor})  # raises: the factor, its parameter and what is allowed
        wpa = _scale_into(out, base, keys, factor, validate_value, wpa)
    if s.conicity is not None:
        out[_COEFFICIENT_INDEX["lam"]] = validate_value("lam", s.conicity)
    if wpa != base.Wpa or s.creep_factor != 1.0:
        for name, value in zip(CREEP_NAMES, computed_creep(0.5 * wpa, base)):
            if s.creep_factor != 1.0:
                value = validate_value(name, value * s.creep_factor)
            out[_COEFFICIENT_INDEX[name]] = value
    return out


def _checked(name: str, values: np.ndarray) -> np.ndarray:
    """``values`` if parameter ``name`` may take each, else :func:`validate_value`'s error for the first that may not."""
    spec = FIELDS[name]
    low, high = values.min(initial=math.inf), values.max(initial=-math.inf)
    if high <= spec.high and (low >= spec.low if spec.low_inclusive else low > spec.low) and math.isfinite(high):
        return values  # all in range (NaN fails the comparisons)
    above = values >= spec.low if spec.low_inclusive else values > spec.low
    for value in values[~(above & (values <= spec.high) & np.isfinite(values))].tolist():
        validate_value(name, value)  # raises, or returns an allowed infinity
    return values


def scenario_health(s: Scenario, channels: np.ndarray) -> np.ndarray:
    """(3, N_CHANNELS) the row's actuator health (:func:`bogie_env.actuators.healthy_command`)."""
    h = healthy()
    h[H_GAIN] = s.actuator_gain
    if s.failed_actuator is not None:
        h[H_GAIN, CHANNEL_NAMES.index(s.failed_actuator)] = 0.0
    if s.stuck_actuator is not None:
        k = CHANNEL_NAMES.index(s.stuck_actuator)
        mode = int(channels[k, CH_MODE])
        a = s.stuck_command
        h[H_HELD_FORCE, k] = a * channels[k, CH_MAX_FORCE] if mode == MODE_FORCE else 0.0
        h[H_HELD_DAMPING, k] = (
            channels[k, CH_C_MIN] + 0.5 * (a + 1.0) * (channels[k, CH_C_MAX] - channels[k, CH_C_MIN]) if mode == MODE_SEMI else 0.0
        )
        assert mode != MODE_OFF
    return h
