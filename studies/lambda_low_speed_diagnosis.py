"""Why a controller fails protocol v2 at conicity 0.1 on some seeds: speed scans of chosen seeds
on the v1 alert track, on a perfect track (same seed: same start, perturbation, sensor bias and
noise) and on the alert track with the start shifted along it.

    python studies/lambda_low_speed_diagnosis.py --policy pretrained --seeds 3,9,0 \
        --speeds 130:260:10 --modes alert,perfect,shift200 [--conicity 0.1] [--gains FILE] [--json OUT]

Each row is one protocol v2 run (``agents/evaluation/stability_protocol.py``: 20 s at a fixed speed, the first
5 s discarded, 12 mm initial perturbation, the controller told the conicity class) judged by the
protocol's own criterion (:func:`assess`); the script adds what the criterion does not report:
the dominant frequency and the growth of the wheelsets' displacement relative to the rail (the
rms over the last 5 s against the rms over 5-10 s: > 1 grows, a limit cycle stays near 1), the
track alignment's rms under the wheelset and the coherence-free ratio of the displacement to it.

Track modes: ``alert`` (the protocol's), ``perfect`` (the alignment zeroed after the task is built:
the row's random draws are unchanged) and ``shiftN`` (the alert track with the start moved ``N`` m
further along it).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np
from scipy import signal

from bogie_env.analysis.en14363 import running_signals_rows
from bogie_env.envs.config import bogie_params, make_config, merge_config
from bogie_env.envs.task import HuntingTask
from bogie_env.simulator import M_DISTANCE, _sample_rows
from bogie_agents.evaluation.stability_protocol import (NOMINAL_OPTIONS, Settings, assess, factory_for, policy_config,
                                             protocol_config, told_conicity)  # fmt: skip


def parse_speeds(text: str) -> list[float]:
    """``a:b:step`` (inclusive) or a comma list, km/h."""
    if ":" in text:
        a, b, step = (float(v) for v in text.split(":"))
        return [float(v) for v in np.arange(a, b + 1e-9, step)]
    return [float(v) for v in text.split(",")]


def make_policy(name: str, env_config: dict, conicity: float, gains: str | None) -> tuple[object, str]:
    """The controller as protocol v2 builds it (told the conicity class) and its observation
    type; ``gains``: a gain table for robust_damping (e.g. an edited copy of agents/controllers/robust_gains.json)."""
    s = Settings()
    if gains is not None:
        from bogie_agents.controllers.robust import RobustDampingController

        cfg = policy_config(env_config, "sensors", told_conicity(conicity, s.conicities))
        return RobustDampingController(cfg, gains=gains), "sensors"
    probe = factory_for(name)(env_config)
    obs_type = getattr(probe, "observation_type", "sensors")
    return factory_for(name)(policy_config(env_config, obs_type, told_conicity(conicity, s.conicities))), obs_type


def run_mode(policy_name: str, gains: str | None, rows: list[tuple[int, float]], mode: str, conicity: float,
             settings: Settings, task_override: dict | None = None) -> list[dict]:  # fmt: skip
    """One batched task of (seed, speed) rows in one track mode; a dict per row. ``task_override``:
    merged into the task's config only (the controller is built for the unchanged v1 config)."""
    env_config = make_config(variant="v1")
    policy, obs_type = make_policy(policy_name, env_config, conicity, gains)
    cfg = protocol_config(env_config, settings, obs_type)
    if task_override:
        cfg = make_config(merge_config(cfg, task_override))
    n = len(rows)
    task = HuntingTask(n, cfg)
    if mode == "perfect":
        sim = task.sim
        sim._track = (np.zeros_like(sim._track[0]),) + tuple(sim._track[1:])
    task.seed_rows(np.arange(n), [seed for seed, _ in rows])
    for i, (seed, v) in enumerate(rows):
        task.reset_rows(np.array([i]), {**NOMINAL_OPTIONS, "conicity": conicity, "start_kmh": v, "end_kmh": v, "accel": 0.0})
    if mode.startswith("shift"):
        task.sim.motion[:, M_DISTANCE] += float(mode[5:])
        _sample_rows(np.arange(n), task.sim.motion, task.sim.coefficients, task.sim._track, task.sim.track_sample)
        task.observe(np.arange(n))
    policy.reset(n)
    dt = task.config["dt"]
    steps, first = int(round(settings.duration_s / dt)), int(round(settings.transient_s / dt))
    history = np.zeros((n, 3, steps - first))
    rel = np.zeros((n, 2, steps))
    track = np.zeros((n, steps))
    force = np.zeros((n, 4, steps))
    contact = np.zeros(n)
    saturated = np.zeros((n, 4))
    blowup = np.zeros(n, dtype=bool)
    buf = np.zeros((n, 3))
    for k in range(steps):
        action = np.asarray(policy.act(task.obs), dtype=float)
        task.step(action)
        if k >= first:
            saturated[:, : action.shape[1]] += np.abs(action) >= 0.999
        blowup |= task.blowup
        r = task.relative_lateral_m
        rel[:, :, k] = r / task.flange_clearance[:, None]
        track[:, k] = task.sim.track_sample[:, 0]
        force[:, :, k] = task.actuator_force
        if k >= first:
            running_signals_rows(task.sim.rows, buf)
            history[:, :, k - first] = buf
            contact += np.any(np.abs(r) >= task.flange_clearance[:, None], axis=1)
    params = bogie_params(env_config)
    speeds = np.array([v for _, v in rows]) / 3.6
    a = assess(history, contact / (steps - first), blowup, speeds, dt, np.full(n, params.Wpa), params.mb, settings)
    out = []
    fs = 1.0 / dt
    for i, (seed, v) in enumerate(rows):
        y = rel[i, :, first:]
        f, p = signal.periodogram(y - y.mean(axis=1, keepdims=True), fs=fs, window="hann", axis=-1)
        p = p.sum(axis=0)
        band = (f > 0.3) & (f < 20)
        f_y = float(f[band][np.argmax(p[band])])
        w = int(round(5.0 / dt))
        growth = float(np.sqrt(np.mean(rel[i, :, -w:] ** 2)) / max(np.sqrt(np.mean(rel[i, :, first:first + w] ** 2)), 1e-12))
        # which samples touch: flange contacts per second and when the first/last happen
        touch = np.any(np.abs(y) >= 1.0, axis=0)
        t_touch = (np.nonzero(touch)[0] + first) * dt
        out.append({
            "seed": seed, "speed_kmh": v, "mode": mode, "passed": bool(a.passed[i]),
            "failed_by": a.failed_by(i),
            "flange_time": round(float(a.flange_time[i]), 4), "f0_hz": round(float(a.f0_hz[i]), 2),
            "sum_y_rms_kn": round(float(a.sum_y_rms_n[i]) / 1e3, 2), "frame_accel_rms": round(float(a.frame_accel_rms[i]), 3),
            "rel_dominant_hz": round(f_y, 2), "rel_rms_over_delta": round(float(np.sqrt(np.mean(y**2))), 3),
            "rel_peak_over_delta": round(float(np.abs(y).max()), 3), "growth_last5_over_5to10": round(growth, 2),
            "track_rms_mm": round(1e3 * float(np.std(track[i, first:])), 2),
            "contact_times_s": [round(float(t), 2) for t in t_touch[:: max(1, len(t_touch) // 8)]][:8],
            "saturated_fraction": [round(float(x) / (steps - first), 3) for x in saturated[i]],
            "force_rms": [round(float(np.sqrt(np.mean(force[i, c, first:] ** 2))), 0) for c in range(4)],
        })  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", default="pretrained")
    ap.add_argument("--gains", default=None, help="a robust_damping gain table (JSON); implies robust_damping")
    ap.add_argument("--seeds", default="3,9")
    ap.add_argument("--speeds", default="130:260:10")
    ap.add_argument("--modes", default="alert")
    ap.add_argument("--conicity", type=float, default=0.1)
    ap.add_argument("--task-override", default=None, help="JSON merged into the task's config only, e.g. "
                    "'{\"track\": {\"wavelength_min\": 10.0}}'")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    override = json.loads(args.task_override) if args.task_override else None
    seeds = [int(s) for s in args.seeds.split(",")]
    speeds = parse_speeds(args.speeds)
    settings = Settings()
    rows = [(s, v) for s in seeds for v in speeds]
    results = []
    for mode in args.modes.split(","):
        t0 = time.monotonic()
        res = run_mode(args.policy, args.gains, rows, mode, args.conicity, settings, override)
        print(f"[{mode}] {len(rows)} rows in {time.monotonic() - t0:.0f} s (busy host)", file=sys.stderr, flush=True)
        results += res
        for r in res:
            tag = "pass" if r["passed"] else "FAIL " + "+".join(r["failed_by"])
            print(f"{args.policy if args.gains is None else 'gains:' + args.gains} {mode:8s} seed {r['seed']:2d} "
                  f"{r['speed_kmh']:6.1f} km/h {tag:22s} flange {r['flange_time']:.4f} f0 {r['f0_hz']:5.2f} "
                  f"ΣY {r['sum_y_rms_kn']:5.2f} kN acc {r['frame_accel_rms']:.2f} | y/δ rms {r['rel_rms_over_delta']:.2f} "
                  f"peak {r['rel_peak_over_delta']:.2f} at {r['rel_dominant_hz']:.2f} Hz growth {r['growth_last5_over_5to10']:.2f} "
                  f"track {r['track_rms_mm']:.2f} mm sat {r['saturated_fraction']} F {r['force_rms']}", flush=True)  # fmt: skip
    if args.json:
        from pathlib import Path

        from bogie_env.fileio import write_text_atomic

        write_text_atomic(Path(args.json), json.dumps({"argv": sys.argv[1:], "rows": results}, indent=1))


if __name__ == "__main__":
    main()
