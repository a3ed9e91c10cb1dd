"""Routes for the route variant of the env (``Bogie/HuntingRoute-v1``): the layout of one track.

The simulator holds one track per task (one compiled :class:`bogie_env.track.TrackInput`), so
the route variant lays its routes end to end on one line: ``copies`` rounds of the configured
routes, each route after the other. An episode runs one *slot* (one copy of one route): the
frame starts at the slot's first metre and the episode is truncated when the frame reaches the
slot's last. Each copy lies on a different stretch of the alignment irregularity, so a route
is met with ``copies`` different irregularity samples (the alignment profile is 262 km long;
the default layout uses about 50 km of it).

Every shipped route starts and ends on a tangent without cant, so the layout joins them
without a jump of curvature or cant; a user route that ends in a curve is joined as it stands
(its successor is met only by the front wheelset in the last ``L1`` of the episode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from ..params import ConfigError
from ..route import Route, RouteError, available_routes, load_route

#: The shipped routes with the speed range an episode draws from, km/h. Each lies around the
#: route's design (line) speed within the cant-deficiency limits its file cites (EN 13803,
#: TSI INF): high-speed 300-350 (deficiency -13 to +42 mm at 165 mm cant), conventional 160-190
#: (46-134 mm, limit about 150), S-curve 230-260 (48-106 mm, limit about 100-120).
ROUTE_SPEEDS_KMH: dict[str, list[float]] = {
    "high-speed-7000": [300.0, 350.0],
    "conventional-1500": [160.0, 190.0],
    "s-curve": [230.0, 260.0],
}
MAX_COPIES = 64


@dataclass(frozen=True)
class Slot:
    """One copy of one route on the layout: the frame runs from ``start_m`` to ``end_m``."""

    route_index: int
    copy: int
    start_m: float
    end_m: float


@dataclass(frozen=True)
class RouteLayout:
    """The routes of a route-variant task laid end to end (see the module docstring)."""

    routes: tuple[Route, ...]
    speed_ranges_kmh: tuple[tuple[float, float], ...]
    line_speeds_kmh: tuple[float, ...]
    slots: tuple[Slot, ...]
    track: Route

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.routes)

    def index(self, name: str) -> int:
        """The position of a route in the layout, by name; unknown names raise."""
        if name not in self.names:
            raise ConfigError(f"reset option 'route' = {name!r} is not a route of this env; allowed: {', '.join(self.names)}")
        return self.names.index(name)

    def slot(self, route_index: int, copy: int) -> Slot:
        return self.slots[copy * len(self.routes) + route_index]

    def speed_limits_kmh(self) -> tuple[float, float]:
        return min(lo for lo, _ in self.speed_ranges_kmh), max(hi for _, hi in self.speed_ranges_kmh)

    def max_route_length(self) -> float:
        return max(r.length for r in self.routes)


def route_names(value: Any) -> list[str] | None:
    """The configured ``route.names``: None (straight track), one name or path, or a list."""
    if value is None:
        return None
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, (list, tuple)) or not names or not all(isinstance(n, str) and n for n in names):
        raise ConfigError(f"config 'route.names' = {value!r} must be null, a route name or path, or a non-empty list of them; "
                          f"shipped routes: {', '.join(available_routes())}")  # fmt: skip
    return list(names)


def validate_route_config(rc: Mapping[str, Any], min_kmh: float, max_kmh: float) -> dict[str, Any]:
    """Check the ``route`` block; loads every named route (so a bad file fails when the env is made)."""
    out = dict(rc)
    names = route_names(rc["names"])
    out["names"] = names
    copies = rc["copies"]
    if isinstance(copies, bool) or not isinstance(copies, int) or not 1 <= copies <= MAX_COPIES:
        raise ConfigError(f"config 'route.copies' = {copies!r} must be an integer in [1, {MAX_COPIES}]")
    speeds = rc["speed_kmh"]
    if speeds is not None and not isinstance(speeds, Mapping):
        raise ConfigError(f"config 'route.speed_kmh' = {speeds!r} must be null or a mapping of route name to a speed "
                          "or [low, high] (km/h)")  # fmt: skip
    if names is not None:
        for name in names:
            try:
                load_route(name)
            except RouteError as error:
                raise ConfigError(f"config 'route.names': {error}") from None
        out["speed_kmh"] = {name: list(_speed_range(name, (speeds or {}).get(name), min_kmh, max_kmh)) for name in names}
        unknown = set(speeds or {}) - set(names)
        if unknown:
            raise ConfigError(f"config 'route.speed_kmh' names route(s) {sorted(unknown)} that are not in 'route.names' {names}")
    return out


def _speed_range(name: str, value: Any, min_kmh: float, max_kmh: float) -> tuple[float, float]:
    """A route's speed range: the configured number or [low, high], else the shipped table, else
    the route file's design speed."""
    where = f"route.speed_kmh.{name}"
    if value is None:
        if Path(name).stem in ROUTE_SPEEDS_KMH and not Path(name).is_file():
            value = ROUTE_SPEEDS_KMH[name]
        else:
            design = load_route(name).design_speed_kmh
            if design is None:
                raise ConfigError(f"config '{where}' is needed: route {name!r} has no design_speed_kmh")
            value = design
    pair = [value, value] if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    if not isinstance(pair, (list, tuple)) or len(pair) != 2:
        raise ConfigError(f"config '{where}' = {value!r} must be a speed or [low, high] in km/h")
    for v in pair:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not min_kmh <= v <= max_kmh:
            raise ConfigError(f"config '{where}' = {value!r} is not allowed; allowed: speeds in [{min_kmh:g}, {max_kmh:g}] km/h")
    if pair[0] > pair[1]:
        raise ConfigError(f"config '{where}' = {value!r}: low must not exceed high")
    return float(pair[0]), float(pair[1])


def build_layout(rc: Mapping[str, Any]) -> RouteLayout:
    """The layout of a validated ``route`` block (``names`` not None)."""
    routes = tuple(load_route(name) for name in rc["names"])
    segments = []
    slots = []
    position = 0.0
    for copy in range(rc["copies"]):
        for k, route in enumerate(routes):
            slots.append(Slot(k, copy, position, position + route.length))
            segments.extend(route.segments)
            position += route.length
    ranges = tuple(tuple(rc["speed_kmh"][name]) for name in rc["names"])
    line = tuple(r.design_speed_kmh if r.design_speed_kmh is not None else 0.5 * (lo + hi) for r, (lo, hi) in zip(routes, ranges))
    track = Route(name="layout:" + "+".join(r.name for r in routes), segments=tuple(segments))
    return RouteLayout(routes, ranges, line, tuple(slots), track)
