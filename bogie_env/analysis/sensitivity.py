"""Sensitivity of the linear critical speed (the paper's Section 5, Figs. 12-16, Table 2).

One-parameter curves and two-parameter grids over scale factors of the nine parameters
(Wpa, Kpx, Kpy, Kpz, Cpz, Ksx, Ksy, Csx, Csy). Every grid point is an independent call of
:func:`bogie_env.stability.critical_speed` on the scaled bogie, so a grid point equals a
direct ``bogie critical-speed --set ...`` call.

What is recomputed when a parameter changes: everything that depends on it. In
particular, a different axle load ``Wpa`` changes the normal load, hence the Hertz contact
ellipse (semi-axes grow as ``Wpa^(1/3)``) and the creep coefficients (``f11, f33`` grow as
``Wpa^(2/3)``, ``f12`` as ``Wpa``, ``f22`` as ``Wpa^(4/3)``), the saturation limit mu N and
the gravitational stiffness terms. The paper recomputes only the varied parameter; with a
fixed contact patch the load study would understate how the creep forces scale with load.
``fixed_contact=True`` reproduces the paper's convention for comparison.

The work is spread over processes (all cores by default) with a progress bar.
"""

from __future__ import annotations

import itertools
import math
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..contact import creep_coefficients
from ..dynamics import BogieModel
from ..params import FIELDS, SENSITIVITY_PARAMS, BogieParams, ConfigError
from ..stability import critical_speed

_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
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


_WORKER_PARAMS: BogieParams | None = None


def _init_worker(params: BogieParams) -> None:
    global _WORKER_PARAMS
    _WORKER_PARAMS = params


def _evaluate_chunk(chunk: list[tuple[dict[str, float], bool]]) -> list[float]:
    return [_evaluate((_WORKER_PARAMS, factors, fixed)) for factors, fixed in chunk]


def run_tasks(tasks: list, workers: int | None = None, progress: bool = True, desc: str = "critical speeds") -> list[float]:
    """Evaluate critical speeds for (params, factors, fixed_contact) tasks, in parallel."""
    workers = os.cpu_count() or 1 if workers is None else max(1, int(workers))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(tasks), desc=desc, unit="pt", leave=False)
    results: list[float] = []
    try:
        if workers == 1 or len(tasks) < 64:
            for task in tasks:
                results.append(_evaluate(task))
                if bar is not None:
                    bar.update(1)
            return results
        params = tasks[0][0]
        if any(task[0] is not params for task in tasks):
            return [_evaluate(task) for task in tasks]  # mixed bases: not the parallel layout
        size = max(16, len(tasks) // (workers * 16))
        light = [(factors, fixed) for _, factors, fixed in tasks]
        chunks = [light[i : i + size] for i in range(0, len(light), size)]
        # One BLAS thread per worker: the workers already use every core.
        previous = {k: os.environ.get(k) for k in _THREAD_VARS}
        os.environ.update({k: "1" for k in _THREAD_VARS})
        try:
            pool = ProcessPoolExecutor(
                max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker, initargs=(params,),
            )  # fmt: skip
        finally:
            for k, v in previous.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        with pool:
            for chunk_result in pool.map(_evaluate_chunk, chunks):
                results.extend(chunk_result)
                if bar is not None:
                    bar.update(len(chunk_result))
        return results
    finally:
        if bar is not None:
            bar.close()


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
) -> Curve:
    name = check_param(name)
    scales = check_scales(name, default_scales(name) if scales is None else scales)
    base = getattr(params, name)
    tasks = [(params, {name: s}, fixed_contact) for s in scales]
    speeds = run_tasks(tasks, workers, progress, desc=name)
    return Curve(name, scales, tuple(base * s for s in scales), tuple(speeds))


def two_parameter(
    params: BogieParams,
    names: tuple[str, str],
    scales=(None, None),
    fixed_contact: bool = False,
    workers: int | None = None,
    progress: bool = False,
) -> Grid:
    a, b = (check_param(n) for n in names)
    if a == b:
        raise ConfigError(f"two-parameter study needs two different parameters; got {a!r} twice")
    sa = check_scales(a, default_scales(a) if scales[0] is None else scales[0])
    sb = check_scales(b, default_scales(b) if scales[1] is None else scales[1])
    tasks = [(params, {a: x, b: y}, fixed_contact) for x in sa for y in sb]
    speeds = np.array(run_tasks(tasks, workers, progress, desc=f"{a} x {b}")).reshape(len(sa), len(sb))
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
) -> Study:
    """All one-parameter curves and all pair grids, as one parallel batch of tasks."""
    names = tuple(check_param(n) for n in names)
    scales = {n: check_scales(n, (scales or {}).get(n, default_scales(n))) for n in names}
    tasks = [(params, {n: s}, fixed_contact) for n in names for s in scales[n]]
    pairs = list(itertools.combinations(names, 2))
    for a, b in pairs:
        tasks.extend((params, {a: x, b: y}, fixed_contact) for x in scales[a] for y in scales[b])
    speeds = run_tasks(tasks, workers, progress, desc="sensitivity")
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
