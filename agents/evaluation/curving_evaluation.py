"""Curving columns of the evaluation: every controller judged on the shipped routes as well.

:func:`curving_columns` runs a controller along each route (``configs/routes``) at the route's
line speed (its ``design_speed_kmh``), in the route variant of the v1 task
(``Bogie/HuntingRoute-v1``'s world: sensors, 10 ms loop delay, force-rate limits, EN 13848-5
alert-level track), with the nominal bogie (no per-episode randomisation: the curving columns
compare controllers on one vehicle; worn wheels, where the passive bogie hunts below these
speeds, are the stability protocol's business). ``seeds`` rows per route, seeded
``seed, seed + 1, ...``: a seed sets the irregularity (the route copy ``seed mod copies`` of
the layout), the sensor noise and bias and the initial perturbation. Every row runs its whole
route (the env's hunting and Y/Q flags are counted, not obeyed).

Per route (mean over seeds, and per seed):

- ``wear_number_n``: the mean over the route of the bogie's wear number, Tγ summed over both
  wheelsets (N = J/m: the creep energy dissipated per metre run); ``wear_energy_kj``: that
  energy over the whole route;
- ``flange_contact_s``: time with either wheelset in flange contact (|y - track| >= δ);
- ``peak_y_over_q``: the largest wheel Y/Q, sliding mean over 2 m (EN 14363's processing of
  Y/Q), limit 0.8; ``peak_y_over_q_instant`` without the mean;
- ``max_sum_y_rms_n``: the largest sliding rms over 100 m (step 10 m) of ΣY of either wheelset,
  against EN 14363's running-stability limit (10 kN + P0/3)/2 = 30 kN; not band-passed, so the
  quasi-static ΣY of the curve counts in it (conservative);
  ``max_sum_y_2m_n``: the largest |ΣY| sliding mean over 2 m against Prud'homme's track-shift
  limit 10 kN + P0/3 = 60 kN;
- ``peak_force`` and ``rms_force`` per active actuator channel (N, N m).

Against passive (same seeds, so the differences are paired): ``excess`` per column (policy
minus passive, mean over seeds), its standard error over seeds and ``no_worse_than_passive``:
the mean excess is at most the tolerance, ``2 x`` the standard error of the paired difference
plus 1 % of passive's value (the seed spread: a controller whose excess is within twice its
standard error is not distinguishable from passive with these seeds).

``python -m bogie_agents.evaluation.curving_evaluation --policy passive --policy lqr --json``, or
``bogie curving-evaluate ...``; with protocol v2 present, the part ``curving`` of
``bogie evaluate --parts ...,curving``.
"""

from __future__ import annotations

import copy
import math
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.dynamics import P_WPA
from bogie_env.envs.config import make_config, merge_config
from bogie_env.envs.task import HuntingTask
from bogie_env.params import ConfigError
from bogie_env.route import available_routes, load_route

Y_OVER_Q_LIMIT = 0.8  # EN 14363, curves of R >= 250 m
SLIDING_MEAN_M = 2.0  # EN 14363's sliding mean of Y/Q and ΣY
SUM_Y_WINDOW_M = 100.0  # EN 14363's sliding rms of ΣY (running stability)
SUM_Y_STEP_M = 10.0
#: The columns compared with passive, and whether larger is worse (all are).
COMPARED = ("wear_number_n", "wear_energy_kj", "flange_contact_s", "peak_y_over_q", "max_sum_y_rms_n")
#: The tolerance of "no worse than passive": TOLERANCE_SE standard errors of the paired
#: difference over seeds plus TOLERANCE_RELATIVE of passive's value.
TOLERANCE_SE = 2.0
TOLERANCE_RELATIVE = 0.01


@dataclass
class CurvingSettings:
    """The curving evaluation's settings (the defaults are the evaluation; tests shrink them)."""

    seeds: int = 8
    seed: int = 0
    routes: tuple[str, ...] | None = None  # None: every shipped route
    nominal: bool = True  # no per-episode randomisation of the bogie
    max_distance_m: float | None = None  # stop a route early (tests)


def sum_y_limits_n(axle_load_n: float) -> tuple[float, float]:
    """EN 14363's ΣY limits: running stability (sliding rms) ``(10 kN + P0/3)/2`` and track
    shift (2 m sliding mean, Prud'homme) ``10 kN + P0/3``, for the axle load P0 (N)."""
    prudhomme = 10e3 + axle_load_n / 3.0
    return 0.5 * prudhomme, prudhomme


def route_config(env_config: Mapping[str, Any], routes: Sequence[str], observation_type: str, nominal: bool = True) -> dict:
    """The task config of the curving runs: ``env_config`` (a v1 config) on ``routes`` at their
    line speeds, the route variant's detector, the controller's observation type."""
    speeds = {}
    for name in routes:
        design = load_route(name).design_speed_kmh
        if design is None:
            raise ConfigError(f"route {name!r} has no design_speed_kmh: the curving evaluation runs a route at its line speed")
        speeds[name] = float(design)
    update: dict[str, Any] = {
        "route": {"names": list(routes), "speed_kmh": speeds},
        "hunting": {"detrend_m": 10.0},
        "observation": {"type": observation_type},
    }
    if nominal:
        update["randomize"] = {}
    if observation_type != "sensors":
        update["sensors"] = {"enabled": False}  # a full-state observation has no sensor model
    return make_config(merge_config(dict(env_config), update))


class _Progress:
    """Progress with the time left, on stderr."""

    def __init__(self, enabled: bool | Callable[[str], None]) -> None:
        self.emit = enabled if callable(enabled) else (lambda text: print(text, file=sys.stderr, flush=True)) if enabled else None
        self.start = time.monotonic()
        self.last = -math.inf

    def report(self, label: str, done: float, total: float) -> None:
        if self.emit is None:
            return
        now = time.monotonic()
        if now - self.last < 5.0 and done < total:
            return
        self.last = now
        elapsed = now - self.start
        left = elapsed / done * (total - done) if done > 0 else float("nan")
        self.emit(f"[curving] {label}: {100 * done / total:.0f} %; {elapsed:.0f} s elapsed, ~{left:.0f} s left")


def _sliding(values: np.ndarray, window: int, step: int, kind: str) -> np.ndarray:
    """Sliding mean or rms over ``window`` samples every ``step`` of values (T, ...); one window
    if the record is shorter."""
    window = max(1, min(window, values.shape[0]))
    c = np.concatenate([np.zeros((1,) + values.shape[1:]), np.cumsum(values**2 if kind == "rms" else values, axis=0)])
    starts = np.arange(0, values.shape[0] - window + 1, max(1, step))
    mean = (c[starts + window] - c[starts]) / window
    return np.sqrt(np.maximum(mean, 0.0)) if kind == "rms" else mean


def run_routes(policy, env_config: Mapping[str, Any], settings: CurvingSettings, progress: _Progress | None = None) -> dict:
    """Every route x seed row in one task, each row to its route's end; per-route results."""
    routes = list(settings.routes or available_routes())
    config = route_config(env_config, routes, getattr(policy, "observation_type", "sensors"), settings.nominal)
    n_seeds = settings.seeds
    n = len(routes) * n_seeds
    task = HuntingTask(n, config)
    rows = np.arange(n)
    task.seed_rows(rows, [settings.seed + (i % n_seeds) for i in rows])
    copies = config["route"]["copies"]
    for i in rows:
        name = routes[i // n_seeds]
        seed = settings.seed + i % n_seeds
        task.reset_rows(np.array([i]), {"route": name, "start_kmh": config["route"]["speed_kmh"][name][0], "route_copy": seed % copies})
    policy.reset(n)
    dt = config["dt"]
    layout = task.route_layout
    ends = np.array([layout.slots[s].end_m for s in task.route_slot])
    if settings.max_distance_m is not None:
        starts = np.array([layout.slots[s].start_m for s in task.route_slot])
        ends = np.minimum(ends, starts + settings.max_distance_m)
    total_steps = int(np.max(np.ceil((ends - task.distance_m) / (task.speed_kmh / 3.6) / dt))) + 1
    active = np.array([CHANNEL_NAMES.index(c) for c in task.channel_names], dtype=int)
    records: dict[str, list] = {k: [] for k in ("wear", "flange", "yq", "sum_y", "force", "live")}
    running = np.ones(n, dtype=bool)
    blown = np.zeros(n, dtype=bool)
    hunted = np.zeros(n, dtype=bool)
    y_over_q_flag = np.zeros(n, dtype=bool)
    steps = 0
    while running.any():
        actions = np.asarray(policy.act(task.obs), dtype=float)
        if not np.all(np.isfinite(actions)):
            bad = ~np.all(np.isfinite(actions.reshape(n, -1)), axis=1)
            blown |= bad & running
            actions = np.nan_to_num(actions)
        task.step(actions)
        steps += 1
        blown |= task.blowup & running
        hunted |= task.hunting & running
        y_over_q_flag |= task.flags[:, 4].astype(bool) & running
        live = running & ~blown
        records["wear"].append(task.wear_number_n.sum(axis=1).copy())
        records["flange"].append(task.flange_contact.any(axis=1))
        records["yq"].append(task.y_over_q.copy())
        records["sum_y"].append(task.guiding_force_n.copy())
        records["force"].append(task.actuator_force[:, active].copy())
        records["live"].append(live)
        running &= (task.distance_m < ends) & ~blown
        if progress is not None:
            progress.report(f"{getattr(policy, 'name', type(policy).__name__)} on {len(routes)} route(s)", steps, total_steps)
    rec = {k: np.array(v) for k, v in records.items()}  # (T, n, ...)
    out = {}
    for k, name in enumerate(routes):
        idx = np.arange(k * n_seeds, (k + 1) * n_seeds)
        out[name] = _route_result(task, rec, idx, name, dt, blown, hunted, y_over_q_flag, settings)
    return out


def _route_result(task: HuntingTask, rec: dict, idx: np.ndarray, name: str, dt: float, blown: np.ndarray,
                  hunted: np.ndarray, y_over_q_flag: np.ndarray, settings: CurvingSettings) -> dict:  # fmt: skip
    speed = float(task.speed_kmh[idx[0]]) / 3.6
    per_seed: dict[str, list] = {k: [] for k in ("wear_number_n", "wear_energy_kj", "flange_contact_s", "peak_y_over_q",
                                                  "peak_y_over_q_instant", "max_sum_y_rms_n", "max_sum_y_2m_n")}  # fmt: skip
    peak_force = np.zeros(rec["force"].shape[-1])
    force_sq, force_n = np.zeros(rec["force"].shape[-1]), 0
    mean_window = max(1, int(round(SLIDING_MEAN_M / (speed * dt))))
    rms_window = int(round(SUM_Y_WINDOW_M / (speed * dt)))
    rms_step = int(round(SUM_Y_STEP_M / (speed * dt)))
    for i in idx:
        live = rec["live"][:, i]
        if blown[i] or not live.any():
            for values in per_seed.values():
                values.append(math.nan)
            continue
        t = np.nonzero(live)[0]
        wear = rec["wear"][t, i]
        per_seed["wear_number_n"].append(float(wear.mean()))
        per_seed["wear_energy_kj"].append(float(wear.sum() * speed * dt / 1e3))
        per_seed["flange_contact_s"].append(float(rec["flange"][t, i].sum() * dt))
        yq = rec["yq"][t, i]
        per_seed["peak_y_over_q"].append(float(_sliding(yq, mean_window, 1, "mean").max()))
        per_seed["peak_y_over_q_instant"].append(float(yq.max()))
        sum_y = rec["sum_y"][t, i]
        per_seed["max_sum_y_rms_n"].append(float(_sliding(sum_y, rms_window, rms_step, "rms").max()))
        per_seed["max_sum_y_2m_n"].append(float(np.abs(_sliding(sum_y, mean_window, 1, "mean")).max()))
        force = rec["force"][t, i]
        peak_force = np.maximum(peak_force, np.abs(force).max(axis=0))
        force_sq += (force**2).sum(axis=0)
        force_n += force.shape[0]
    channels = list(task.channel_names)
    rms_limit, shift_limit = sum_y_limits_n(float(task.P[idx[0], P_WPA]))
    result: dict[str, Any] = {
        "route": name,
        "speed_kmh": round(speed * 3.6, 3),
        "seeds": [settings.seed + int(j) for j in range(len(idx))],
        "route_length_m": load_route(name).length if settings.max_distance_m is None else settings.max_distance_m,
        **{key: _mean(values) for key, values in per_seed.items()},
        "per_seed": per_seed,
        "y_over_q_limit": Y_OVER_Q_LIMIT,
        "sum_y_rms_limit_n": rms_limit,
        "sum_y_2m_limit_n": shift_limit,
        "within_en14363": bool(_mean(per_seed["max_sum_y_rms_n"]) <= rms_limit and _mean(per_seed["peak_y_over_q"]) <= Y_OVER_Q_LIMIT),
        "peak_force": {c: float(peak_force[k]) for k, c in enumerate(channels)},
        "rms_force": {c: float(math.sqrt(force_sq[k] / max(force_n, 1))) for k, c in enumerate(channels)},
        "blown_up": int(blown[idx].sum()),
        "hunting_flagged": int(hunted[idx].sum()),
        "y_over_q_flagged": int(y_over_q_flag[idx].sum()),
    }
    return result


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


def compare_with_passive(result: dict, passive: dict) -> dict:
    """Excess over passive per compared column, paired over seeds, with the tolerance."""
    out = {}
    for name, route in result.items():
        base = passive[name]
        excess, verdict = {}, {}
        for column in COMPARED:
            a = np.array(route["per_seed"][column], dtype=float)
            b = np.array(base["per_seed"][column], dtype=float)
            d = a - b
            d = d[np.isfinite(d)]
            if d.size == 0:
                excess[column] = {"mean": math.nan, "standard_error": math.nan, "tolerance": math.nan}
                verdict[column] = False
                continue
            se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
            tolerance = TOLERANCE_SE * se + TOLERANCE_RELATIVE * abs(base[column])
            excess[column] = {"mean": float(d.mean()), "standard_error": se, "tolerance": tolerance,
                              "passive": base[column]}  # fmt: skip
            verdict[column] = bool(d.mean() <= tolerance and len(d) == len(a))
        out[name] = {**route, "excess_over_passive": excess, "no_worse_than_passive": verdict}
    return out


_PASSIVE_CACHE: dict[str, dict] = {}


def curving_columns(policy, env_config: Mapping[str, Any] | None = None, routes: Sequence[str] | None = None,
                    seeds: int = 8, progress: bool | Callable[[str], None] = True, seed: int = 0, trusted: bool = False,
                    passive: dict | None = None, settings: CurvingSettings | None = None) -> dict:  # fmt: skip
    """The curving columns of one controller (see the module docstring).

    ``policy``: a name or path (``passive``, ``skyhook``, ``lqr``, ``lqg``, ``pretrained``, a
    run folder with ``trusted``) or a policy object built for ``env_config``; ``env_config``:
    the v1 config the controller is judged in (default ``Bogie/Hunting-v1``'s); ``routes``:
    route names (default every shipped route); ``progress``: report on stderr (or a callable
    taking a line). ``passive``: the passive result of the same settings (computed if None).
    Returns ``{"routes": {name: columns}, "settings": ..., "tolerance": ...}``.
    """
    from ..controllers.policies import CLASSICAL, load_policy

    env_config = make_config(env_config, variant="v1") if env_config is None else make_config(env_config)
    settings = settings or CurvingSettings(seeds=seeds, seed=seed, routes=tuple(routes) if routes else None)
    reporter = _Progress(progress)

    def build(spec):
        if not isinstance(spec, str):
            return spec
        obs_type = getattr(CLASSICAL.get(spec), "observation_type", "sensors")
        config = route_config(env_config, list(settings.routes or available_routes()), obs_type, settings.nominal)
        return load_policy(spec, config, trusted)

    key = repr((sorted(env_config.items(), key=str), asdict(settings)))
    if passive is None and key in _PASSIVE_CACHE:
        passive = _PASSIVE_CACHE[key]
    if passive is None:  # passive runs once: it is the result when the policy is passive
        _PASSIVE_CACHE[key] = passive = run_routes(build("passive"), env_config, settings, reporter)
    result = passive if policy == "passive" else run_routes(build(policy), env_config, settings, reporter)
    return {
        "policy": policy if isinstance(policy, str) else getattr(policy, "name", type(policy).__name__),
        "routes": compare_with_passive(result, passive),
        "settings": asdict(settings),
        "conditions": ("v1 world (sensors, loop delay, rate limits, alert-level track), nominal bogie"
                       if settings.nominal else "v1 world with its per-episode randomisation")
                      + "; each route at its design speed; every row runs the whole route",  # fmt: skip
        "tolerance": f"no worse than passive: mean paired excess over seeds <= {TOLERANCE_SE:g} x its standard error "
                     f"+ {100 * TOLERANCE_RELATIVE:g} % of passive's value",
    }


def constant_curve_run(radius_m: float, cant_m: float, speed_kmh: float, curve_m: float, direction: str = "left",
                       transition_m: float = 150.0, variant: str = "v1_route", update: Mapping[str, Any] | None = None,
                       policy_factory: Callable[[dict], Any] | None = None,
                       on_step: Callable[[HuntingTask], None] | None = None) -> tuple[HuntingTask, Any, dict]:  # fmt: skip
    """One row on a perfect track (no irregularity, no perturbation, no randomisation): 50 m of
    tangent, a ``transition_m`` transition, then ``curve_m`` of a constant curve, run until the
    frame is 5 m from the route's end (the front wheelset still in the curve).

    ``update``: top-level config sections that replace the defaults (e.g. ``sensors``);
    ``policy_factory(config)`` makes the controller (None: zero action); ``on_step(task)`` is
    called after each step. Returns the task, the policy (or None) and the config."""
    import yaml

    route = {"name": "constant-curve", "design_speed_kmh": speed_kmh, "segments": [
        {"type": "tangent", "length": 50}, {"type": "transition", "length": transition_m},
        {"type": "curve", "length": curve_m, "radius": radius_m, "cant": cant_m, "direction": direction}]}  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        path = str(Path(folder) / "constant-curve.yaml")
        Path(path).write_text(yaml.safe_dump(route))
        user = {"route": {"names": [path], "speed_kmh": {path: speed_kmh}, "copies": 1}, "track": {"rms": 0.0, "level": None},
                "initial_perturbation": 0.0, "randomize": {}, **(update or {})}  # fmt: skip
        config = make_config(user, variant=variant)
        task = HuntingTask(1, config)
        task.seed_rows(np.array([0]), [0])
        task.reset_rows(np.array([0]))
        policy = None if policy_factory is None else policy_factory(config)
        if policy is not None:
            policy.reset(1)
        end = task.route_layout.slots[0].end_m - 5.0
        while task.distance_m[0] < end:
            task.step(np.zeros((1, task.action_dim)) if policy is None else policy.act(task.obs))
            if on_step is not None:
                on_step(task)
    return task, policy, config


def steady_state_check(radius_m: float = 1500.0, cant_m: float = 0.15, speed_kmh: float = 180.0, direction: str = "right",
                       curve_m: float = 1500.0) -> dict:  # fmt: skip
    """Independent check of the route runs: the passive bogie in the route env on a long constant
    curve (perfect track, no perturbation), at the end of the curve, against the steady-state
    solver (``bogie curving``, :func:`bogie_env.analysis.curving.steady_curving`). Returns both
    and the largest relative difference of each quantity."""
    from bogie_env.analysis.curving import steady_curving

    task, _, _ = constant_curve_run(radius_m, cant_m, speed_kmh, curve_m, direction, variant="v1_passive")
    steady = steady_curving(task.model, radius_m, cant_m, speed_kmh, direction)
    q = steady.quantities
    route_values = {
        "wear_number_n": task.wear_number_n[0].tolist(),
        "y_over_q_max": float(task.y_over_q[0]),
        "guiding_force_n": task.guiding_force_n[0].tolist(),
        "lateral_displacement_m": task.relative_lateral_m[0].tolist(),
        "cant_deficiency_m": float(task.cant_deficiency_m[0]),
    }
    steady_values = {
        "wear_number_n": q["wear_number_n"][0].tolist(),
        "y_over_q_max": float(q["y_over_q"][0].max()),
        "guiding_force_n": q["guiding_force_n"][0].tolist(),
        "lateral_displacement_m": q["lateral_displacement_m"][0].tolist(),
        "cant_deficiency_m": float(steady.cant_deficiency_m),
    }
    difference = {k: float(np.max(np.abs(np.subtract(route_values[k], steady_values[k])) / np.maximum(np.abs(steady_values[k]), 1e-12)))
                  for k in route_values}  # fmt: skip
    return {"radius_m": radius_m, "cant_m": cant_m, "speed_kmh": speed_kmh, "direction": direction,
            "route_run": route_values, "steady_state": steady_values, "relative_difference": difference}  # fmt: skip


def format_table(results: Sequence[dict]) -> str:
    """A markdown table: one row per (route, controller)."""
    head = ("| route (speed) | controller | wear Tγ (N) | excess | flange contact (s) | excess | peak Y/Q (2 m) | "
            "max ΣY rms (kN) / limit | peak ΣY 2 m (kN) | peak / rms force (kN, kN m) | no worse than passive |")  # fmt: skip
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    routes = list(results[0]["routes"]) if results else []
    for name in routes:
        for r in results:
            c = r["routes"][name]
            ex = c["excess_over_passive"]
            forces = ", ".join(f"{c['peak_force'][k] / 1e3:.1f}/{c['rms_force'][k] / 1e3:.1f}" for k in c["peak_force"]) or "-"
            worse = [k for k, ok in c["no_worse_than_passive"].items() if not ok]
            lines.append(
                f"| {name} ({c['speed_kmh']:g}) | {r['policy']} | {c['wear_number_n']:.2f} | {ex['wear_number_n']['mean']:+.2f} "
                f"| {c['flange_contact_s']:.2f} | {ex['flange_contact_s']['mean']:+.2f} | {c['peak_y_over_q']:.3f} "
                f"| {c['max_sum_y_rms_n'] / 1e3:.1f} / {c['sum_y_rms_limit_n'] / 1e3:.0f} | {c['max_sum_y_2m_n'] / 1e3:.1f} "
                f"| {forces} | {'yes' if not worse else 'no: ' + ', '.join(worse)} |"
            )  # fmt: skip
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    import argparse
    import json

    from bogie_env.envs.registration import IDS

    from ..controllers import POLICY_HELP

    parser = argparse.ArgumentParser(description="curving columns of controllers on the shipped routes")
    parser.add_argument("--policy", action="append", required=True, help=POLICY_HELP)
    parser.add_argument("--trust-policy", action="store_true", help="allow loading a policy PATH (an SB3 file is code)")
    parser.add_argument("--env", default="Bogie/Hunting-v1", help="the v1 env whose world the routes run in")
    parser.add_argument("--routes", default=None, help="comma-separated route names (default: every shipped route)")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--steady-check", action="store_true", help="also run the steady-state check")
    args = parser.parse_args(argv)
    if args.env not in IDS:
        raise ConfigError(f"--env {args.env!r} is not a bogie-env id; known ids: {', '.join(IDS)}")
    if args.seeds < 2:
        raise ConfigError(f"--seeds {args.seeds} must be at least 2 (the tolerance needs a seed spread)")
    routes = [r.strip() for r in args.routes.split(",")] if args.routes else None
    env_config = make_config(variant=IDS[args.env])
    results = [curving_columns(spec, env_config, routes, args.seeds, progress=True, seed=args.seed, trusted=args.trust_policy)
               for spec in args.policy]  # fmt: skip
    payload: dict[str, Any] = {"env_id": args.env, "policies": results}
    if args.steady_check:
        payload["steady_state_check"] = steady_state_check()
    if args.json:
        print(json.dumps(payload, indent=2, default=float))
    else:
        print(format_table(results))
    return 0


def _register_protocol_part() -> None:
    """Register ``curving`` as a part of protocol v2 (:mod:`bogie_agents.evaluation.stability_protocol`)."""
    from .stability_protocol import register_part

    @register_part("curving")
    def curving_part(ctx) -> dict[str, Any]:
        """The curving columns on the shipped routes, against passive (this module's docstring)."""
        routes = available_routes()
        policy = ctx.factory(route_config(ctx.env_config, routes, ctx.observation_type))
        settings = CurvingSettings(seed=ctx.settings.seed)

        def progress(line: str) -> None:
            ctx.progress.report(line, 1.0, 0.0)

        columns = curving_columns(policy, ctx.env_config, settings=settings, progress=progress if ctx.settings.progress else False)
        columns["policy"] = ctx.progress.label  # the controller's name in the protocol, not its object's path
        return {"curving": columns}


_register_protocol_part()


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
