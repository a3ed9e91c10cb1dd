"""Sensitivity of the linear critical speed (the paper's Section 5, Figs. 12-16, Table 2).

One-parameter curves and two-parameter grids over scale factors of the nine parameters
(Wpa, Kpx, Kpy, Kpz, Cpz, Ksx, Ksy, Csx, Csy). Every grid point is an independent call of
:func:`bogie_env.stability.critical_speed` on the scaled bogie, so a grid point equals a
direct ``bogie critical-speed --set ...`` call.

What is recomputed when a parameter changes: everything that depends on it. In
particular, a different axle load ``Wpa`` changes the normal load, hence the Hertz contact
ellipse (semi-axes grow as ``Wpa^(1/3)``) and the creep coefficients (``f11, f33`` grow as
``Wpa^(2/3)``, ``f12`` as ``Wpa``, ``f22`` as ``Wpa^(4/3)``), the saturation limit mu N and
the gravitational stiffness terms. The paper does not say whether its creep coefficients
followed the load. ``fixed_contact=True`` holds them at their nominal values, for comparison:
then the critical speed falls monotonically with the load, while the paper describes a
maximum near the nominal load (docs/model.md, Section 4).

The work is spread in chunks over local processes (all cores by default) or a Ray cluster
(``backend="ray"``, docs/distributed.md), with a progress bar; with a store folder an interrupted
study resumes without recomputing finished chunks. Every backend gives the same numbers, bitwise.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..contact import creep_coefficients
from ..distributed import ChunkStore, chunked, map_chunks, source_digest
from ..dynamics import BogieModel
from ..params import FIELDS, SENSITIVITY_PARAMS, BogieParams, ConfigError
from ..stability import critical_speed

DEFAULT_CHUNK_SIZE = 256  # points per task: about 0.6 s of work on one core, against ~1 ms of Ray overhead
DEFAULT_SCALES = tuple(np.round(np.linspace(0.5, 1.5, 21), 6))
KPZ_SCALES = tuple(np.round(np.linspace(0.5, 2.5, 21), 6))


def check_scales(name: str, scales) -> tuple[float, ...]:
    """Scale factors: a non-empty list of finite numbers > 0."""
    values = tuple(float(s) for s in scales)
    if not values:
        raise ConfigError(f"scales for {name!r} are empty; give at least one factor > 0, e.g. 0.5,1,1.5")
    bad = [s for s in values if not (math.isfinite(s) and s > 0)]
    if bad:
        raise ConfigError(f"scale factor(s) {bad} for {name!r} are not allowed; each must be finite and > 0")
    return values


def check_param(name: str) -> str:
    if name not in FIELDS:
        raise ConfigError(f"unknown parameter {name!r}; known parameters: {', '.join(FIELDS)}")
    return name


def default_scales(name: str) -> tuple[float, ...]:
    """The paper's grid: +-50 % in 21 points; Kpz extends to 2.5x (Section 5)."""
    return KPZ_SCALES if name == "Kpz" else DEFAULT_SCALES


def _scaled(params: BogieParams, factors: dict[str, float], fixed_contact: bool) -> BogieParams:
    variant = params.scaled(**factors)
    if fixed_contact:
        creep = creep_coefficients(params)
        variant = variant.replace(f11=creep.f11, f12=creep.f12, f22=creep.f22, f33=creep.f33)
    return variant


def _evaluate(task: tuple[BogieParams, dict[str, float], bool]) -> float:
    params, factors, fixed_contact = task
    result = critical_speed(BogieModel(_scaled(params, factors, fixed_contact)))
    return float(result.speed_kmh)


def _evaluate_chunk(params: BogieParams, chunk: list) -> list[float]:
    """One scheduling unit: critical speeds of ``[factors, fixed_contact]`` points on ``params``."""
    return [_evaluate((params, factors, fixed)) for factors, fixed in chunk]


def study_definition(params: BogieParams) -> dict:
    """What fixes a study's numbers besides its points: the base bogie and the code computing them."""
    import bogie_env

    return {"params": params.to_dict(), "code": source_digest(bogie_env)}


def run_tasks(
    tasks: list,
    workers: int | None = None,
    progress: bool = True,
    desc: str = "critical speeds",
    backend: str = "local",
    address: str | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
    store_dir: str | Path | None = None,
) -> list[float]:
    """Critical speeds (km/h) of ``(params, factors, fixed_contact)`` tasks, in chunks of
    ``chunk_size`` points on the chosen backend (:mod:`bogie_env.distributed`); with
    ``store_dir``, finished chunks are kept there and a rerun computes only the rest."""
    if not tasks:
        return []
    params = tasks[0][0]
    if any(task[0] != params for task in tasks):
        raise ValueError("run_tasks: every task must share one base bogie (BogieParams)")
    if backend == "local" and (workers == 1 or len(tasks) < 64):
        workers = 1  # a short list: not worth starting processes
    light = [[dict(factors), bool(fixed)] for _, factors, fixed in tasks]
    chunks = chunked(light, chunk_size)
    store = ChunkStore(Path(store_dir), study_definition(params)) if store_dir is not None else None
    results = map_chunks(_evaluate_chunk, chunks, shared=params, backend=backend, address=address, workers=workers,
                         store=store, progress=progress, desc=desc)  # fmt: skip
    return [float(v) for chunk in results for v in chunk]


@dataclass(frozen=True)
class Curve:
    """Critical speed against one parameter's scale factor."""

    param: str
    scales: tuple[float, ...]
    values: tuple[float, ...]
    critical_speed_kmh: tuple[float, ...]

    def to_dict(self) -> dict:
        return {
            "param": self.param,
            "points": [
                {"scale": s, "value": v, "critical_speed_kmh": _json_speed(c)}
                for s, v, c in zip(self.scales, self.values, self.critical_speed_kmh)
            ],
        }


@dataclass(frozen=True)
class Grid:
    """Critical speed over a two-parameter grid; ``critical_speed_kmh[i, j]`` at scales (i, j)."""

    params: tuple[str, str]
    scales: tuple[tuple[float, ...], tuple[float, ...]]
    values: tuple[tuple[float, ...], tuple[float, ...]]
    critical_speed_kmh: np.ndarray

    def maximum(self) -> dict:
        """The grid's maximum (the paper's Table 2 row for this pair)."""
        table = np.where(np.isnan(self.critical_speed_kmh), -np.inf, self.critical_speed_kmh)
        i, j = np.unravel_index(int(np.argmax(table)), table.shape)
        return {
            "params": list(self.params),
            "scales": [self.scales[0][i], self.scales[1][j]],
            "values": [self.values[0][i], self.values[1][j]],
            "critical_speed_kmh": _json_speed(self.critical_speed_kmh[i, j]),
        }

    def to_dict(self) -> dict:
        points = []
        for i, j in itertools.product(range(len(self.scales[0])), range(len(self.scales[1]))):
            points.append(
                {
                    "scales": [self.scales[0][i], self.scales[1][j]],
                    "values": [self.values[0][i], self.values[1][j]],
                    "critical_speed_kmh": _json_speed(self.critical_speed_kmh[i, j]),
                }
            )
        return {"params": list(self.params), "points": points, "maximum": self.maximum()}


def _json_speed(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), 3)


def one_parameter(
    params: BogieParams,
    name: str,
    scales=None,
    fixed_contact: bool = False,
    workers: int | None = None,
    progress: bool = False,
    **distribute,
) -> Curve:
    """Critical speed against one parameter's scale factors. ``distribute``: the keyword
    arguments of :func:`run_tasks` (backend, address, chunk_size, store_dir)."""
    name = check_param(name)
    scales = check_scales(name, default_scales(name) if scales is None else scales)
    base = getattr(params, name)
    tasks = [(params, {name: s}, fixed_contact) for s in scales]
    speeds = run_tasks(tasks, workers, progress, desc=name, **distribute)
    return Curve(name, scales, tuple(base * s for s in scales), tuple(speeds))


def two_parameter(
    params: BogieParams,
    names: tuple[str, str],
    scales=(None, None),
    fixed_contact: bool = False,
    workers: int | None = None,
    progress: bool = False,
    **distribute,
) -> Grid:
    """Critical speed over a two-parameter grid of scale factors (``distribute`` as above)."""
    a, b = (check_param(n) for n in names)
    if a == b:
        raise ConfigError(f"two-parameter study needs two different parameters; got {a!r} twice")
    sa = check_scales(a, default_scales(a) if scales[0] is None else scales[0])
    sb = check_scales(b, default_scales(b) if scales[1] is None else scales[1])
    tasks = [(params, {a: x, b: y}, fixed_contact) for x in sa for y in sb]
    speeds = np.array(run_tasks(tasks, workers, progress, desc=f"{a} x {b}", **distribute)).reshape(len(sa), len(sb))
    return Grid((a, b), (sa, sb), (tuple(getattr(params, a) * s for s in sa), tuple(getattr(params, b) * s for s in sb)), speeds)


@dataclass(frozen=True)
class Study:
    """The full Section-5 study: nine curves and all 36 pair grids."""

    curves: tuple[Curve, ...]
    grids: tuple[Grid, ...]
    nominal_kmh: float
    fixed_contact: bool

    @property
    def n_points(self) -> int:
        return sum(len(c.scales) for c in self.curves) + sum(g.critical_speed_kmh.size for g in self.grids)

    def table2(self) -> list[dict]:
        return [grid.maximum() for grid in self.grids]

    def to_dict(self) -> dict:
        return {
            "nominal_critical_speed_kmh": self.nominal_kmh,
            "fixed_contact": self.fixed_contact,
            "n_critical_speeds": self.n_points,
            "one_parameter": [c.to_dict() for c in self.curves],
            "two_parameter": [g.to_dict() for g in self.grids],
            "table2": self.table2(),
        }


def full_study(
    params: BogieParams,
    names: tuple[str, ...] = SENSITIVITY_PARAMS,
    scales: dict[str, tuple[float, ...]] | None = None,
    fixed_contact: bool = False,
    workers: int | None = None,
    progress: bool = True,
    **distribute,
) -> Study:
    """All one-parameter curves and all pair grids, as one batch of chunked tasks
    (``distribute``: the keyword arguments of :func:`run_tasks`)."""
    names = tuple(check_param(n) for n in names)
    scales = {n: check_scales(n, (scales or {}).get(n, default_scales(n))) for n in names}
    tasks = [(params, {n: s}, fixed_contact) for n in names for s in scales[n]]
    pairs = list(itertools.combinations(names, 2))
    for a, b in pairs:
        tasks.extend((params, {a: x, b: y}, fixed_contact) for x in scales[a] for y in scales[b])
    speeds = run_tasks(tasks, workers, progress, desc="sensitivity", **distribute)
    curves, grids, k = [], [], 0
    for n in names:
        m = len(scales[n])
        curves.append(Curve(n, scales[n], tuple(getattr(params, n) * s for s in scales[n]), tuple(speeds[k : k + m])))
        k += m
    for a, b in pairs:
        m = len(scales[a]) * len(scales[b])
        grid = np.array(speeds[k : k + m]).reshape(len(scales[a]), len(scales[b]))
        values = (tuple(getattr(params, a) * s for s in scales[a]), tuple(getattr(params, b) * s for s in scales[b]))
        grids.append(Grid((a, b), (scales[a], scales[b]), values, grid))
        k += m
    nominal = critical_speed(BogieModel(params)).speed_kmh
    return Study(tuple(curves), tuple(grids), float(nominal), fixed_contact)
