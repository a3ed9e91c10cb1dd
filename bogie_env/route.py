"""Track geometry: routes of tangents, transition curves and circular curves, with cant.

A route is a list of segments, read from YAML (``configs/routes/*.yaml``)::

    name: example
    design_speed_kmh: 200
    segments:
      - {type: tangent, length: 300}
      - {type: transition, length: 200}        # clothoid: curvature and cant linear in distance
      - {type: curve, length: 800, radius: 2000, cant: 0.12, direction: left}
      - {type: transition, length: 200}
      - {type: tangent, length: 300}

- ``tangent``: zero curvature, zero cant.
- ``curve``: constant curvature ``1/radius`` towards ``direction`` (``left`` or ``right``)
  and constant cant (m, the height of the outer rail above the inner one).
- ``transition``: a clothoid, whose curvature and cant vary linearly with distance from the
  end of the segment before it to the start of the segment after it (the cant ramp lies
  along the transition). A transition between a left and a right curve passes through zero.

Curvature is signed in the model's axes (y to the left): ``+1/R`` for a curve to the left.
Cant enters the dynamics as the cant angle ``theta`` with ``sin(theta) = cant / CANT_BASE_M``,
signed like the curvature (positive: the track plane banked towards +y, i.e. the right rail
raised, as in a left curve). ``CANT_BASE_M`` is EN 13803's reference distance for cant, the
distance between the rail-head centres, 1500 mm for standard gauge; the model's contact
points are 2e = 1.435 m apart. The equilibrium cant at speed V (km/h) and radius R (m) is
then ``1500 V^2 / (3.6^2 g R)`` mm = ``11.8 V^2 / R`` mm, EN 13803's formula.

Cant may not jump between segments (put a transition between them); curvature may (a curve
joined directly to a tangent, as on older lines). Outside the route the geometry holds its
end values. The route compiles to per-segment arrays that :mod:`bogie_env.track` samples
under each wheelset and the frame (:func:`bogie_env.track.sample_track`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .params import CONFIG_DIR, ConfigError

#: EN 13803: cant is the height difference of the rail heads over their centres' distance,
#: 1500 mm for the 1435 mm gauge.
CANT_BASE_M = 1.5
GRAVITY = 9.81  # m/s^2
ROUTE_DIR = CONFIG_DIR / "routes"

SEGMENT_TYPES = ("tangent", "transition", "curve")
#: Allowed values. Radii below 150 m need gauge widening and a flange-climbing model that
#: this bogie model does not have; 200 mm is above every limit of EN 13803 for cant.
MIN_RADIUS_M = 150.0
MAX_CANT_M = 0.2
MAX_SEGMENT_LENGTH_M = 1.0e6
_SEGMENT_KEYS = {
    "tangent": {"type", "length"},
    "transition": {"type", "length"},
    "curve": {"type", "length", "radius", "cant", "direction"},
}
_ROUTE_KEYS = {"name", "description", "design_speed_kmh", "sources", "segments"}


class RouteError(ConfigError):
    """A route file or segment is not allowed; the message names the field, value and rule."""


def cant_angle(cant_m: float) -> float:
    """Cant angle (rad) of a cant (m, signed) over EN 13803's base of 1.5 m."""
    return math.asin(cant_m / CANT_BASE_M)


def equilibrium_cant_m(speed_kmh: float, radius_m: float) -> float:
    """The cant (m) at which the speed has no unbalanced lateral acceleration in the track plane."""
    v = speed_kmh / 3.6
    return CANT_BASE_M * math.sin(math.atan(v * v / (GRAVITY * radius_m)))


def unbalanced_acceleration(speed_kmh: float, curvature: float, cant_m: float) -> float:
    """Lateral acceleration in the track plane not balanced by cant, m/s^2 (Eq. C1 of docs/model.md)."""
    v = speed_kmh / 3.6
    theta = cant_angle(cant_m)
    return v * v * curvature * math.cos(theta) - GRAVITY * math.sin(theta)


@dataclass(frozen=True)
class Segment:
    """One piece of the route: curvature (1/m) and cant (m) vary linearly from start to end."""

    kind: str
    length: float  # m
    curvature_start: float  # 1/m, + left
    curvature_end: float
    cant_start: float  # m, signed like the curvature
    cant_end: float


@dataclass(frozen=True)
class Route:
    """A route: segments end to end, starting at distance 0."""

    name: str
    segments: tuple[Segment, ...]
    description: str = ""
    design_speed_kmh: float | None = None
    sources: tuple[str, ...] = ()

    @property
    def length(self) -> float:
        return float(sum(seg.length for seg in self.segments))

    @property
    def starts(self) -> np.ndarray:
        """Distance (m) at which each segment starts."""
        return np.concatenate([[0.0], np.cumsum([seg.length for seg in self.segments])[:-1]])

    def compiled(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per-segment arrays for the compiled sampler: start, length, curvature at both ends,
        cant (m) at both ends."""
        segs = self.segments
        return (
            np.ascontiguousarray(self.starts, dtype=np.float64),
            np.array([s.length for s in segs], dtype=np.float64),
            np.array([s.curvature_start for s in segs], dtype=np.float64),
            np.array([s.curvature_end for s in segs], dtype=np.float64),
            np.array([s.cant_start for s in segs], dtype=np.float64),
            np.array([s.cant_end for s in segs], dtype=np.float64),
        )

    def _locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        starts = self.starts
        i = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(self.segments) - 1)
        lengths = np.array([seg.length for seg in self.segments])
        w = np.clip((s - starts[i]) / lengths[i], 0.0, 1.0)
        return i, w

    def curvature(self, s: np.ndarray | float) -> np.ndarray:
        """Curvature (1/m, + left) at distance(s) s."""
        i, w = self._locate(np.asarray(s, dtype=float))
        k0 = np.array([seg.curvature_start for seg in self.segments])[i]
        k1 = np.array([seg.curvature_end for seg in self.segments])[i]
        return k0 + (k1 - k0) * w

    def cant(self, s: np.ndarray | float) -> np.ndarray:
        """Cant (m, signed like the curvature) at distance(s) s."""
        i, w = self._locate(np.asarray(s, dtype=float))
        c0 = np.array([seg.cant_start for seg in self.segments])[i]
        c1 = np.array([seg.cant_end for seg in self.segments])[i]
        return c0 + (c1 - c0) * w

    def summary(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "length_m": self.length,
            "design_speed_kmh": self.design_speed_kmh,
            "segments": [
                {"type": s.kind, "length_m": s.length, "curvature_start_1pm": s.curvature_start,
                 "curvature_end_1pm": s.curvature_end, "cant_start_m": s.cant_start, "cant_end_m": s.cant_end}
                for s in self.segments
            ],
        }  # fmt: skip


# ---- validation -------------------------------------------------------------------------------
def _number(where: str, key: str, value: Any, low: float, high: float, low_inclusive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RouteError(f"{where}.{key} = {value!r} is not a number; allowed: {'[' if low_inclusive else '('}{low:g}, {high:g}]")
    number = float(value)
    ok = math.isfinite(number) and (number >= low if low_inclusive else number > low) and number <= high
    if not ok:
        raise RouteError(f"{where}.{key} = {value!r} is not allowed; allowed: {'[' if low_inclusive else '('}{low:g}, {high:g}]")
    return number


def _segment_end_values(where: str, item: Mapping[str, Any]) -> tuple[str, float, float | None, float | None]:
    """(kind, length, curvature, cant) of one YAML entry; curvature/cant None for a transition."""
    if not isinstance(item, Mapping):
        raise RouteError(f"{where} = {item!r} must be a mapping with a 'type' ({', '.join(SEGMENT_TYPES)})")
    kind = item.get("type")
    if kind not in SEGMENT_TYPES:
        raise RouteError(f"{where}.type = {kind!r} is not allowed; allowed: {', '.join(SEGMENT_TYPES)}")
    unknown = set(item) - _SEGMENT_KEYS[kind]
    if unknown:
        raise RouteError(f"{where}: unknown key(s) {', '.join(sorted(map(str, unknown)))} for a {kind}; "
                         f"allowed: {', '.join(sorted(_SEGMENT_KEYS[kind]))}")  # fmt: skip
    if "length" not in item:
        raise RouteError(f"{where}.length is required (m, > 0)")
    length = _number(where, "length", item["length"], 0.0, MAX_SEGMENT_LENGTH_M, low_inclusive=False)
    if kind == "tangent":
        return kind, length, 0.0, 0.0
    if kind == "transition":
        return kind, length, None, None
    for key in ("radius", "direction"):
        if key not in item:
            raise RouteError(f"{where}.{key} is required for a curve")
    radius = _number(where, "radius", item["radius"], MIN_RADIUS_M, math.inf)
    direction = item["direction"]
    if direction not in ("left", "right"):
        raise RouteError(f"{where}.direction = {direction!r} is not allowed; allowed: left, right")
    cant = _number(where, "cant", item.get("cant", 0.0), 0.0, MAX_CANT_M)
    sign = 1.0 if direction == "left" else -1.0
    return kind, length, sign / radius, sign * cant


def route_from_dict(data: Mapping[str, Any], source: str = "") -> Route:
    """Validate a route mapping (as read from YAML) into a :class:`Route`."""
    where_file = f" in {source}" if source else ""
    if not isinstance(data, Mapping):
        raise RouteError(f"route{where_file} must be a mapping with 'segments'")
    unknown = set(data) - _ROUTE_KEYS
    if unknown:
        raise RouteError(f"route{where_file}: unknown key(s) {', '.join(sorted(map(str, unknown)))}; "
                         f"allowed: {', '.join(sorted(_ROUTE_KEYS))}")  # fmt: skip
    items = data.get("segments")
    if not isinstance(items, list) or not items:
        raise RouteError(f"route{where_file}: 'segments' = {items!r} must be a non-empty list")
    speed = data.get("design_speed_kmh")
    if speed is not None:
        speed = _number("route", "design_speed_kmh", speed, 3.6, 900.0)
    parsed = [_segment_end_values(f"segments[{k}]", item) for k, item in enumerate(items)]
    segments: list[Segment] = []
    for k, (kind, length, curvature, cant) in enumerate(parsed):
        if kind == "transition":
            if k == 0 or k == len(parsed) - 1 or parsed[k - 1][0] == "transition" or parsed[k + 1][0] == "transition":
                raise RouteError(f"segments[{k}]: a transition must lie between two tangents or curves "
                                 f"(it links the end of the one before to the start of the one after)")  # fmt: skip
            k0, c0 = parsed[k - 1][2], parsed[k - 1][3]
            k1, c1 = parsed[k + 1][2], parsed[k + 1][3]
            segments.append(Segment(kind, length, k0, k1, c0, c1))
        else:
            if segments and segments[-1].cant_end != cant:
                raise RouteError(f"segments[{k}]: cant jumps from {segments[-1].cant_end:g} m to {cant:g} m; "
                                 f"cant must ramp: put a transition before segments[{k}]")  # fmt: skip
            segments.append(Segment(kind, length, curvature, curvature, cant, cant))
    sources = data.get("sources") or ()
    if isinstance(sources, str):
        sources = (sources,)
    return Route(
        name=str(data.get("name", Path(source).stem if source else "route")),
        segments=tuple(segments),
        description=str(data.get("description", "")),
        design_speed_kmh=speed,
        sources=tuple(str(s) for s in sources),
    )


def available_routes() -> list[str]:
    """Names of the shipped routes (``configs/routes/*.yaml``)."""
    return sorted(p.stem for p in ROUTE_DIR.glob("*.yaml"))


def load_route(name_or_path: str | Path) -> Route:
    """A shipped route by name, or a route file by path (YAML, loaded safely: no code runs)."""
    path = Path(name_or_path)
    if not path.is_file():
        shipped = ROUTE_DIR / f"{name_or_path}.yaml"
        if not shipped.is_file():
            raise RouteError(f"route {str(name_or_path)!r} is neither a file nor a shipped route; "
                             f"shipped routes: {', '.join(available_routes())}")  # fmt: skip
        path = shipped
    with open(path, encoding="utf-8") as handle:
        try:
            data = yaml.safe_load(handle)
        except yaml.YAMLError as error:
            raise RouteError(f"route file {str(path)!r} is not valid YAML: {error}") from None
    return route_from_dict(data, str(path))


def constant_curve(radius_m: float, cant_m: float = 0.0, direction: str = "left", length_m: float = 1.0e5) -> Route:
    """A single circular curve (no transitions) from distance 0, for steady-curving runs."""
    return route_from_dict(
        {"name": f"curve-R{radius_m:g}", "segments": [
            {"type": "curve", "length": length_m, "radius": radius_m, "cant": cant_m, "direction": direction}]}
    )  # fmt: skip
