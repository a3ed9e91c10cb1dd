"""Bogie parameters: Table 1 of Bustos et al. (2022) plus named assumptions.

A :class:`BogieParams` is immutable and validated field by field. It loads from
``configs/bogie/*.yaml`` (SI units), rejects unknown keys, and derives variants for
sensitivity studies::

    p = BogieParams.from_yaml()                 # configs/bogie/paper.yaml
    q = p.scaled(Csy=0.5)                       # secondary lateral damping -50 %
    r = p.replace(Kpz=1.0e6, mu=0.4)

Names are the paper's symbols without braces or underscores (``Kpx``, ``Csy``, ``Wpa``,
...). The conicity λ is ``lam`` and the flange clearance δ is ``delta``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

from .errors import ConfigError


def _config_dir() -> Path:
    """The shipped configs: package data ``bogie_env/configs/`` in an installed wheel, else the
    repository's top-level ``configs/`` (a source checkout or an editable install)."""
    packaged = resources.files(__package__) / "configs"
    if packaged.is_dir():
        return Path(str(packaged))
    return Path(__file__).resolve().parent.parent / "configs"


#: Folder of the shipped configs (bogie/*.yaml presets, agents/*.yaml hyperparameters).
CONFIG_DIR = _config_dir()
DEFAULT_BOGIE_CONFIG = CONFIG_DIR / "bogie" / "paper.yaml"


@dataclass(frozen=True)
class FieldSpec:
    """What a parameter means and which values it may take."""

    unit: str
    description: str
    low: float
    high: float
    low_inclusive: bool = True
    allow_inf: bool = False
    optional: bool = False
    source: str = "Table 1"

    def allowed(self) -> str:
        left = "[" if self.low_inclusive else "("
        high = "inf" if math.isinf(self.high) else f"{self.high:g}"
        text = f"{left}{self.low:g}, {high}]"
        if self.allow_inf:
            text += " or .inf"
        if self.optional:
            text += " or null (computed)"
        return f"{text} {self.unit}".rstrip()


_T1 = "Table 1"
_A = "assumption (docs/model.md)"
_O = "optional override (docs/model.md)"

#: Every parameter, in config order. Ranges are deliberately wide (plausible for any
#: standard-gauge passenger or freight bogie) but exclude non-physical values.
FIELDS: dict[str, FieldSpec] = {
    "mb": FieldSpec("kg", "bogie frame mass", 100.0, 2.0e4, False),
    "Ibz": FieldSpec("kg m^2", "bogie frame yaw inertia", 50.0, 5.0e4, False),
    "mw": FieldSpec("kg", "wheelset mass", 100.0, 5.0e3, False),
    "Iwx": FieldSpec("kg m^2", "wheelset roll inertia", 10.0, 5.0e3, False),
    "Iwy": FieldSpec("kg m^2", "wheelset pitch (spin) inertia", 1.0, 2.0e3, False),
    "Iwz": FieldSpec("kg m^2", "wheelset yaw inertia", 10.0, 5.0e3, False),
    "L1": FieldSpec("m", "frame CG to primary lateral springs (semi-wheelbase)", 0.3, 3.0, False),
    "L2": FieldSpec("m", "frame CG to primary lateral dampers", 0.3, 3.0, False),
    "b1": FieldSpec("m", "semi-spacing of primary longitudinal springs/dampers", 0.2, 2.0, False),
    "b2": FieldSpec("m", "semi-spacing of secondary longitudinal springs", 0.2, 2.0, False),
    "b3": FieldSpec("m", "semi-spacing of secondary longitudinal dampers", 0.2, 2.0, False),
    "h1": FieldSpec("m", "height of the secondary lateral damper above the wheelset", 0.0, 2.0),
    "h2": FieldSpec("m", "height of the secondary lateral spring above the wheelset", 0.0, 2.0),
    "e": FieldSpec("m", "half track gauge (contact-point semi-spacing)", 0.3, 1.0, False),
    "r0": FieldSpec("m", "wheel radius", 0.15, 0.8, False),
    "lam": FieldSpec("-", "wheel conicity λ", 1.0e-3, 0.5, False),
    "Wpa": FieldSpec("N", "axle load (a force)", 1.0e4, 4.0e5, False),
    "Kpx": FieldSpec("N/m", "primary longitudinal stiffness", 0.0, 1.0e9),
    "Kpy": FieldSpec("N/m", "primary lateral stiffness", 0.0, 1.0e9),
    "Kpz": FieldSpec("N/m", "primary vertical stiffness", 1.0e3, 1.0e9, False),
    "Cpx": FieldSpec("N s/m", "primary longitudinal damping", 0.0, 1.0e7),
    "Cpy": FieldSpec("N s/m", "primary lateral damping", 0.0, 1.0e7),
    "Cpz": FieldSpec("N s/m", "primary vertical damping", 0.0, 1.0e7),
    "Ksx": FieldSpec("N/m", "secondary longitudinal stiffness", 0.0, 1.0e8),
    "Ksy": FieldSpec("N/m", "secondary lateral stiffness", 0.0, 1.0e8),
    "Csx": FieldSpec("N s/m", "secondary longitudinal damping", 0.0, 1.0e7),
    "Csy": FieldSpec("N s/m", "secondary lateral damping", 0.0, 1.0e7),
    "Kr": FieldSpec("N/m", "rail lateral stiffness at flange contact", 1.0e4, 1.0e10, False),
    "delta": FieldSpec("m", "flange clearance", 1.0e-4, 0.05, False),
    "E": FieldSpec("Pa", "Young's modulus of steel", 1.0e10, 1.0e12, False, source=_A),
    "nu": FieldSpec("-", "Poisson's ratio of steel", 0.0, 0.5, source=_A),
    "mu": FieldSpec("-", "wheel-rail friction coefficient", 0.01, 2.0, False, source=_A),
    "Rrail": FieldSpec("m", "rail-head transverse radius", 0.01, 100.0, False, allow_inf=True, source=_A),
    "Rwheel": FieldSpec("m", "wheel transverse radius (.inf: conical)", 0.01, 100.0, False, allow_inf=True, source=_A),
    "f11": FieldSpec("N", "lateral creep coefficient override", 0.0, 1.0e10, optional=True, source=_O),
    "f12": FieldSpec("N m", "lateral/spin creep coefficient override", 0.0, 1.0e8, optional=True, source=_O),
    "f22": FieldSpec("N m^2", "spin creep coefficient override", 0.0, 1.0e6, optional=True, source=_O),
    "f33": FieldSpec("N", "longitudinal creep coefficient override", 0.0, 1.0e10, optional=True, source=_O),
}

#: Settings that take one of a few named values: name -> (allowed values, default, meaning).
#: ``secondary_heights`` chooses the heights at which the secondary lateral spring and damper
#: act in Eq. (43)'s roll moment: "table1" pairs Ksy with the spring height h2 and Csy with the
#: damper height h1, as Table 1 and the nomenclature define them; "printed" pairs Ksy with h1
#: and Csy with h2, as Eqs. (43) and (50) print them (docs/model.md, Section 3a).
CHOICES: dict[str, tuple[tuple[str, ...], str, str]] = {
    "secondary_heights": (("table1", "printed"), "table1", "heights of Ksy and Csy in Eq. (43)"),
}

#: The nine parameters of the paper's sensitivity study (Section 5).
SENSITIVITY_PARAMS: tuple[str, ...] = ("Wpa", "Kpx", "Kpy", "Kpz", "Cpz", "Ksx", "Ksy", "Csx", "Csy")


def validate_choice(name: str, value: Any) -> str:
    """Return ``value`` if the named setting ``name`` (see :data:`CHOICES`) may take it."""
    allowed = CHOICES[name][0]
    if not isinstance(value, str) or value.strip() not in allowed:
        raise ConfigError(f"setting {name!r} = {value!r} is not allowed; allowed: {', '.join(allowed)}")
    return value.strip()


def _known() -> str:
    return ", ".join([*FIELDS, *CHOICES])


def validate_value(name: str, value: Any) -> float | None:
    """Return ``value`` as a float if parameter ``name`` may take it, else raise ConfigError."""
    spec = FIELDS.get(name)
    if type(value) is float and spec is not None and value <= spec.high and math.isfinite(value):  # the common case
        if value > spec.low or (spec.low_inclusive and value == spec.low):
            return value
    if name not in FIELDS:
        raise ConfigError(f"unknown parameter {name!r}; known parameters: {_known()}")
    spec = FIELDS[name]
    if value is None:
        if spec.optional:
            return None
        raise ConfigError(f"parameter {name!r} is required; allowed: {spec.allowed()}")
    if isinstance(value, bool):
        raise ConfigError(f"parameter {name!r} = {value!r} is a boolean; allowed: {spec.allowed()}")
    if isinstance(value, str):
        text = value.strip().lower()
        if spec.optional and text in ("null", "none", ""):
            return None
        try:
            value = float(text.replace(".inf", "inf"))
        except ValueError:
            raise ConfigError(f"parameter {name!r} = {value!r} is not a number; allowed: {spec.allowed()}") from None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"parameter {name!r} = {value!r} is not a number; allowed: {spec.allowed()}") from None
    if math.isnan(number):
        raise ConfigError(f"parameter {name!r} = nan is not a number; allowed: {spec.allowed()}")
    if math.isinf(number):
        if number > 0 and spec.allow_inf:
            return number
        raise ConfigError(f"parameter {name!r} = {number} is not finite; allowed: {spec.allowed()}")
    too_low = number < spec.low if spec.low_inclusive else number <= spec.low
    if too_low or number > spec.high:
        raise ConfigError(
            f"parameter {name!r} = {number:g} is out of range ({spec.description}); allowed: {spec.allowed()}"
        )
    return number


@dataclass(frozen=True)
class BogieParams:
    """Validated, immutable bogie parameters in SI units (see :data:`FIELDS`)."""

    mb: float
    Ibz: float
    mw: float
    Iwx: float
    Iwy: float
    Iwz: float
    L1: float
    L2: float
    b1: float
    b2: float
    b3: float
    h1: float
    h2: float
    e: float
    r0: float
    lam: float
    Wpa: float
    Kpx: float
    Kpy: float
    Kpz: float
    Cpx: float
    Cpy: float
    Cpz: float
    Ksx: float
    Ksy: float
    Csx: float
    Csy: float
    Kr: float
    delta: float
    E: float
    nu: float
    mu: float
    Rrail: float
    Rwheel: float
    f11: float | None = None
    f12: float | None = None
    f22: float | None = None
    f33: float | None = None
    secondary_heights: str = "table1"
    source: str = field(default="", compare=False, repr=False)

    def __post_init__(self) -> None:
        for name in FIELDS:
            object.__setattr__(self, name, validate_value(name, getattr(self, name)))
        for name in CHOICES:
            object.__setattr__(self, name, validate_choice(name, getattr(self, name)))

    # ---- construction -------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: Mapping[str, Any], source: str = "") -> "BogieParams":
        """Build from a mapping; unknown keys and missing required keys are errors."""
        if not isinstance(values, Mapping):
            raise ConfigError(f"bogie config {source or ''} must be a mapping of parameter names to numbers")
        unknown = [key for key in values if key not in FIELDS and key not in CHOICES]
        if unknown:
            raise ConfigError(
                f"unknown bogie parameter(s) {', '.join(map(repr, unknown))}"
                f"{' in ' + source if source else ''}; known parameters: {_known()}"
            )
        missing = [name for name, spec in FIELDS.items() if not spec.optional and name not in values]
        if missing:
            raise ConfigError(f"missing bogie parameter(s) {', '.join(missing)}{' in ' + source if source else ''}")
        return cls(**{key: values[key] for key in values}, source=source)

    @classmethod
    def from_yaml(cls, path: str | Path | None = None) -> "BogieParams":
        """Load a YAML preset; ``None`` loads ``configs/bogie/paper.yaml``."""
        path = Path(path) if path is not None else DEFAULT_BOGIE_CONFIG
        if not path.is_file():
            raise ConfigError(f"bogie config file {str(path)!r} does not exist")
        from .fileio import load_yaml

        values = load_yaml(path) or {}
        if not isinstance(values, dict):
            raise ConfigError(f"bogie config file {str(path)!r} must hold a mapping of parameter names to values")
        return cls.from_dict(values, source=str(path))

    @classmethod
    def paper(cls) -> "BogieParams":
        """The preset that follows the printed paper (the default everywhere)."""
        return cls.from_yaml(DEFAULT_BOGIE_CONFIG)

    # ---- variants -----------------------------------------------------------------
    def replace(self, **changes: Any) -> "BogieParams":
        """A copy with some parameters set to new values (validated)."""
        validated = {}
        for name, value in changes.items():
            if name in FIELDS:
                validated[name] = validate_value(name, value)
            elif name in CHOICES:
                validated[name] = validate_choice(name, value)
            else:
                raise ConfigError(f"unknown parameter {name!r}; known parameters: {_known()}")
        # the other fields were validated when self was built: only the changes are checked again
        copy = object.__new__(type(self))
        copy.__dict__.update(self.__dict__)
        copy.__dict__.update(validated)
        return copy

    def scaled(self, **factors: float) -> "BogieParams":
        """A copy with parameters multiplied by factors, e.g. ``scaled(Csy=0.5, Kpz=2.5)``."""
        return self.replace(**self.scaled_values(**factors))

    def scaled_values(self, **factors: float) -> dict[str, float]:
        """The values :meth:`scaled` sets, name -> this value times its factor (not yet
        validated against the parameter's range; :meth:`replace` does that)."""
        changes = {}
        for name, factor in factors.items():
            base = getattr(self, name) if name in FIELDS else None
            if name not in FIELDS:
                raise ConfigError(f"unknown parameter {name!r}; known parameters: {', '.join(FIELDS)}")
            if base is None:
                raise ConfigError(f"parameter {name!r} is not set (null), so it cannot be scaled")
            factor = float(factor)
            if not math.isfinite(factor) or factor < 0:
                raise ConfigError(f"scale factor for {name!r} = {factor!r} must be finite and >= 0")
            changes[name] = base * factor
        return changes

    def with_overrides(self, assignments: list[str] | tuple[str, ...] | Mapping[str, Any]) -> "BogieParams":
        """Apply overrides: a mapping of names to values, or the CLI's ``NAME=VALUE`` strings."""
        return self.replace(**(dict(assignments) if isinstance(assignments, Mapping) else parse_assignments(assignments)))

    def to_dict(self) -> dict[str, float | str | None]:
        """Parameter name to value, in config order, then the named settings."""
        return {name: getattr(self, name) for name in (*FIELDS, *CHOICES)}


def parse_assignments(assignments: list[str] | tuple[str, ...]) -> dict[str, float | str | None]:
    """The CLI's ``--set NAME=VALUE`` items, parsed and validated once, as ``{name: value}``."""
    changes: dict[str, float | str | None] = {}
    for item in assignments:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected NAME=VALUE, e.g. Csy=45000")
        name, value = (part.strip() for part in item.split("=", 1))
        changes[name] = validate_choice(name, value) if name in CHOICES else validate_value(name, value)
    return changes


def load_params(
    config: str | Path | None = None, overrides: list[str] | tuple[str, ...] | Mapping[str, Any] = ()
) -> BogieParams:
    """Load a preset (default: the paper's) and apply overrides (a mapping, or ``NAME=VALUE`` strings)."""
    params = BogieParams.from_yaml(config)
    return params.with_overrides(overrides) if overrides else params
