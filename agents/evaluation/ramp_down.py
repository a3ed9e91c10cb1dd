"""The ramp-down parts of the protocol (``ramp_down``, ``ramp_down_ideal``): the closed loop's
nonlinear critical speed by the ramp-down method (True 2013), per conicity of the grid. The
protocol imports this module by name (:data:`bogie_agents.evaluation.stability_protocol.PART_MODULES`)
when it reads its registry of parts."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Mapping, NamedTuple

import numpy as np

from bogie_env.analysis.en14363 import running_signals_rows
from bogie_env.envs.config import bogie_params
from bogie_env.envs.sensors import SENSOR_NAMES

from .criterion import assess, flange_occupancy
from .stability_protocol import PartContext, Progress, Runner, Settings, columns, flange_touching, register_part, step_guarded

#: The ideal world of the ``ramp_down_ideal`` part: a perfect track (no alignment) and sensors
#: and observations without noise; each sensor keeps its bias and filter, the actuators their
#: delay, lag, rate and force limits. Nothing random excites the bogie while it runs, so the
#: runs do not depend on the integration step beyond its error. A seed still sets the 12 mm
#: start and the sensor biases (the same sizes as under v1, other draws: a perfect track draws
#: no start position on the alignment).
IDEAL_WORLD_NAME = "perfect track, noise-free sensors (bias, filters and actuators as v1)"
IDEAL_WORLD: dict[str, Any] = {
    "track": {"level": None, "rms": 0.0},
    "sensors": {name: {"noise_density": 0.0} for name in SENSOR_NAMES},
    "observation": {"noise": 0.0},
}


class HuntingEnd(NamedTuple):
    """Per row of a ramp-down: where the hunting it started with stops."""

    kmh: np.ndarray  # the highest speed of the first window that passes after it
    bound: np.ndarray  # "ended", "at_least" (first window passes) or "at_most" (no window passes)
    first_pass: np.ndarray  # that window's index (the number of windows if none passes)


def hunting_end(failing: np.ndarray, top_kmh: np.ndarray, floor_kmh: float, ceiling_kmh: float) -> HuntingEnd:
    """Where the hunting a ramp-down started with stops, per row. ``failing`` (rows, windows):
    the criterion's verdict on each window of the ramp, highest speeds first; ``top_kmh``
    (windows,): each window's highest speed. The failing run that begins with the first window
    is that hunting; the first window that passes after it starts where the hunting has
    stopped. ``at_least`` the ceiling if the first window passes (the controller stopped the
    hunting during the hold), ``at_most`` the floor if no window passes. Windows failing after
    the first pass (e.g. a track-forced flange contact) do not lower the value."""
    w = failing.shape[1]
    first_pass = np.where(~failing, np.arange(w)[None, :], w).min(axis=1)
    stopped = first_pass < w
    value = np.where(stopped, top_kmh[np.minimum(first_pass, w - 1)], floor_kmh)
    value[first_pass == 0] = ceiling_kmh
    bound = np.where(first_pass == 0, "at_least", np.where(stopped, "ended", "at_most"))
    return HuntingEnd(value, bound, first_pass)


def ramp_speeds_kmh(settings: Settings, dt: float, steps: int) -> np.ndarray:
    """The speed after each env step of the ramp-down (km/h): from the ceiling at
    ``ramp_down_decel`` until the floor, where it stays."""
    drop = 3.6 * settings.ramp_down_decel * dt * np.arange(1, steps + 1)
    return np.maximum(settings.ceiling_kmh - drop, settings.floor_kmh)


@register_part("ramp_down")
def ramp_down_part(ctx: PartContext) -> dict[str, Any]:
    """Closed-loop nonlinear critical speed by the ramp-down method, per conicity of the grid,
    under the v1 defaults (the alert track, sensor noise): :func:`ramp_down_runs`."""
    return {"ramp_down": ramp_down_runs(ctx)}


@register_part("ramp_down_ideal")
def ramp_down_ideal_part(ctx: PartContext) -> dict[str, Any]:
    """The ramp-down in :data:`IDEAL_WORLD`: the same controller and loop (bias, filters, delay,
    rate and force limits) on a perfect track with noise-free sensors. Nothing random knocks
    the bogie off its hunting cycle during the ramp, so the value is where the closed loop's
    cycle stops failing the criterion (the ramp-down method of the nonlinear critical speed,
    True 2013, judged by the protocol's criterion instead of by the cycle's existence: a small
    cycle that passes it may live on below), and it is insensitive to the integration step,
    unlike the values judged under noise."""
    return {"ramp_down_ideal": ramp_down_runs(ctx, IDEAL_WORLD, IDEAL_WORLD_NAME)}


def flange_span(start: int, length: int, sustained: bool) -> slice:
    """The recorded samples on which a ramp-down window starting at ``start`` (``length``
    samples) judges flange contact. v2's any-contact rule judges the window itself, whose first
    sample is its top speed. v3's rule (``sustained``) is a majority over the seconds, which would
    put the end of sustained contact at the window's middle; it judges the window's length
    centred on the top speed instead (clipped at the ramp's start), so that the value is where
    the sustained contact stops. The criterion's other quantities always judge the window."""
    if not sustained:
        return slice(start, start + length)
    return slice(max(0, start - length // 2), start + length - length // 2)


def ramp_down_runs(ctx: PartContext, world: Mapping[str, Any] | None = None,
                   world_name: str | None = None) -> dict[str, Any]:  # fmt: skip
    """Closed-loop nonlinear critical speed by the ramp-down method, per conicity of the grid
    (``world``: a config overlay of the task, e.g. :data:`IDEAL_WORLD`, named ``world_name`` in the result).

    Each seed's bogie runs passive at the ceiling for ``ramp_down_onset_s`` from the 12 mm
    start (fully developed hunting on every conicity of the grid at 600 km/h; a seed whose
    wheelsets did not touch the flange in the last second of it is listed in
    ``not_hunting_at_switch_on``), then the controller is switched on (reset, as at a cold
    start), holds the ceiling for ``transient_s`` and ramps down at ``ramp_down_decel`` to the
    floor, where it runs one more window. The protocol's criterion judges windows as long as a
    fixed-speed run's assessed time (15 s: 13.5 km/h of the default ramp), one starting every
    ``ramp_down_stride_kmh`` (v3 judges a window's flange contact on the same length of ramp
    centred on the window's top speed: its majority rule locates the end of sustained contact at
    the middle of what it judges); the seed's value is where the hunting the ramp began with stops
    (:func:`hunting_end`): the lowest speed at which that hunting, e.g. a limit cycle of the
    saturated loop, survives. The fixed-speed search asks whether a 12 mm start grows into
    hunting; this asks whether the controller gets the bogie out of hunting, and the two differ
    where a stable limit cycle coexists with the stable running state (hysteresis).
    """
    s = ctx.settings
    progress = Progress(ctx.progress.label, ctx.progress.enabled)  # this part's own time left
    nominal_lam = bogie_params(ctx.env_config).lam
    names = ("nominal",) + tuple(f"conicity:{lam:g}" for lam in s.conicities if not math.isclose(lam, nominal_lam))
    cols = columns(ctx.env_config, replace(s, columns=names))
    cases = [c for col in cols.values() for c in col]
    n = len(cases)
    task, policy = Runner(ctx)._task(cases, np.full(n, s.ceiling_kmh), "default", world)
    dt = task.config["dt"]
    onset, hold = int(round(s.ramp_down_onset_s / dt)), int(round(s.transient_s / dt))
    length = int(round((s.duration_s - s.transient_s) / dt))  # a window: a fixed-speed run's assessed time
    ramp = int(math.ceil((s.ceiling_kmh - s.floor_kmh) / 3.6 / s.ramp_down_decel / dt))
    recorded = ramp + length  # the ramp, then one window at the floor
    history = np.zeros((n, 3, recorded), dtype=np.float32)
    contact = np.zeros((n, recorded), dtype=bool)
    blown = np.zeros((n, recorded), dtype=bool)
    blown_before = np.zeros(n, dtype=bool)
    onset_contact = np.zeros(n)
    buffer = np.zeros((n, 3))
    zero = np.zeros((n, task.action_dim))
    total = onset + hold + recorded
    last_second = max(1, int(round(1.0 / dt)))
    for k in range(total):
        if k == onset:
            policy.reset(n)
        if k == onset + hold:
            task.ramp_rows(np.arange(n), -s.ramp_down_decel, s.floor_kmh)
        bad = step_guarded(task, zero if k < onset else policy.act(task.obs))
        touching = flange_touching(task)
        j = k - onset - hold
        if j == ramp // 2:
            midway = task.speed_kmh.copy()
        if j >= 0:
            running_signals_rows(task.sim.rows, buffer)
            history[:, :, j] = buffer
            contact[:, j] = touching
            blown[:, j] = bad
        else:
            blown_before |= bad
            if onset - last_second <= k < onset:
                onset_contact += touching
        if k % 500 == 499:
            progress.report(f"ramp down: {k + 1}/{total} steps of {n} rows", k + 1, total - k - 1)
    speed = ramp_speeds_kmh(s, dt, recorded)
    moving = ~(blown.any(axis=1) | blown_before)
    if not np.allclose(midway[moving], speed[ramp // 2]):  # the schedule the windows are judged on
        raise RuntimeError(f"ramp_down: rows at {midway[moving]} km/h midway, the schedule at {speed[ramp // 2]:g}")
    axle = np.array([task.scenarios[i].axle_load * task.base_params.Wpa for i in range(n)])
    stride = max(1, int(round(s.ramp_down_stride_kmh / 3.6 / s.ramp_down_decel / dt)))
    starts = np.arange(0, ramp + 1, stride)
    failing = np.zeros((n, starts.size), dtype=bool)
    judging = Progress(ctx.progress.label, ctx.progress.enabled)
    for w, a in enumerate(starts):
        part = slice(a, a + length)
        flange = flange_span(a, length, bool(s.sustained_fraction))
        occupancy = flange_occupancy(contact[:, flange], dt, s.flange_window_s) if s.sustained_fraction else None
        r = assess(history[:, :, part], contact[:, flange].mean(axis=1), blown_before | blown[:, part].any(axis=1),
                   np.full(n, speed[part].mean() / 3.6), dt, axle, task.base_params.mb, s,
                   flange_occupancy=occupancy)  # fmt: skip
        failing[:, w] = ~r.passed
        judging.report(f"ramp down: judging window {w + 1}/{starts.size}", w + 1, starts.size - w - 1)
    top_kmh = speed[starts]
    end = hunting_end(failing, top_kmh, s.floor_kmh, s.ceiling_kmh)
    hunting = onset_contact / last_second > s.flange_time_limit
    out: dict[str, Any] = {}
    start = 0
    for col in cols.values():
        idx = np.arange(start, start + len(col))
        start += len(col)
        crit = end.kmh[idx]
        worst = int(np.argmin(crit))
        at_least = "at least: the controller stops the hunting at the ceiling" if hunting[idx[worst]] else \
            "at least: no hunting at the switch-on at the ceiling"  # fmt: skip
        out[f"{col[0].conicity:g}"] = {
            "kmh": round(float(crit[worst]), 1),
            "bound": {"at_least": f"{at_least} {s.ceiling_kmh:g} km/h",
                      "at_most": f"at most: the bogie still hunts in the window at the floor {s.floor_kmh:g} km/h",
                      "ended": f"hunting ended: windows every {s.ramp_down_stride_kmh:g} km/h"}[str(end.bound[idx[worst]])],
            "seeds": [c.seed for c in col],
            "per_seed_kmh": [round(float(v), 1) for v in crit],
            "spread_kmh": {"min": round(float(crit.min()), 1), "median": round(float(np.median(crit)), 1),
                           "max": round(float(crit.max()), 1)},
            "not_hunting_at_switch_on": [col[a].seed for a, i in enumerate(idx) if not hunting[i]],
            # windows below the hunting's end that fail again (their highest speeds), by seed
            "fails_below_kmh": {str(col[a].seed): [round(float(top_kmh[w]), 1) for w in np.nonzero(failing[i, end.first_pass[i]:])[0] + end.first_pass[i]]
                                for a, i in enumerate(idx) if failing[i, end.first_pass[i]:].any()},
        }  # fmt: skip
    named = {"world": world_name} if world_name else {}
    return {"decel_m_per_s2": s.ramp_down_decel, "onset_s": s.ramp_down_onset_s, "hold_s": s.transient_s,
            "window_s": s.duration_s - s.transient_s, "window_every_kmh": s.ramp_down_stride_kmh,
            "floor_kmh": s.floor_kmh, "ceiling_kmh": s.ceiling_kmh, **named, "by_conicity": out}  # fmt: skip
