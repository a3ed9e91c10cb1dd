"""The robust controller's command line: ``python -m bogie_agents.design.robust_cli WHAT``.

- ``design [--out FILE] [--washout-order 2]``: the stage-1 gain table for the v1 env
  (:func:`bogie_agents.controllers.robust.tune`);
- ``retune --base STAGE1 [--out FILE] [--w-track W] [--w-yaw W]``: stage 2
  (:func:`bogie_agents.controllers.robust_track.retune_track`);
- ``report``: the design's linear onsets by conicity and its margins (:func:`bogie_agents.controllers.robust.report`);
- ``ramp [--policy NAME ...]``: onsets on the v1 ramp by conicity (:func:`ramp_onsets`);
- ``route``: closed-loop curving on the v1 route variant (:func:`route_run`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask

from ..controllers.policies import load_policy
from ..controllers.robust import GAINS_FILE, WASHOUT_ORDERS, DesignSettings, load_gains, report, save_gains, tune
from ..controllers.robust_track import TrackSettings, retune_track


def ramp_onsets(spec: str, env_config: dict, conicity: float, seeds: int = 10) -> dict:
    """The v1 ramp (the env config's speed ramp and world; pass one without randomisation) with
    the conicity pinned by ``reset(options={"conicity": c})``, seeds 0..seeds-1: each seed's onset
    of the env's hunting criterion (None: reached the end speed) and the peak channel forces."""
    policy = load_policy(spec, env_config)
    task = HuntingTask(seeds, env_config)
    rows = np.arange(seeds)
    task.seed_rows(rows, list(range(seeds)))
    task.reset_rows(rows, {"conicity": conicity})
    policy.reset(seeds)
    done = np.zeros(seeds, dtype=bool)
    onset = np.full(seeds, np.nan)
    peak = np.zeros(len(CHANNEL_NAMES))
    while not done.all():
        task.step(policy.act(task.obs))
        live = ~done
        peak = np.maximum(peak, np.abs(task.actuator_force[live]).max(axis=0))
        finished = live & task.done
        onset[finished] = task.onset_speed_kmh[finished]
        done |= finished
    return {"policy": spec, "conicity": conicity, "onset_kmh": [None if np.isnan(v) else round(float(v), 1) for v in onset],
            "peak_force": [round(float(v)) for v in peak]}  # fmt: skip


def route_run(spec: str, env_config: dict, steps: int = 6000, seeds: int = 6) -> dict:
    """Closed-loop curving on a route env config (e.g. the ``v1_route`` variant without
    randomisation), seeds 0..seeds-1, rows counted until their episode ends: mean wear number
    (all, and where the frame is in a curve), flange-contact fraction, largest Y/Q, and each
    channel's mean force signed by the curve's direction and mean |force| in curves."""
    policy = load_policy(spec, env_config)
    task = HuntingTask(seeds, env_config)
    rows = np.arange(seeds)
    task.seed_rows(rows, list(range(seeds)))
    task.reset_rows(rows)
    policy.reset(seeds)
    alive = np.ones(seeds, dtype=bool)
    wear = flange = count = wear_curve = count_curve = 0.0
    y_over_q = 0.0
    signed, absolute, n_curve = np.zeros(len(CHANNEL_NAMES)), np.zeros(len(CHANNEL_NAMES)), 0
    for _ in range(steps):
        task.step(policy.act(task.obs))
        live = alive.copy()
        curve = live & (np.abs(task.curvature_1pm) > 1e-5)
        wear += task.wear_number_n[live].sum()
        flange += task.flange_contact[live].sum()
        count += 2 * live.sum()
        wear_curve += task.wear_number_n[curve].sum()
        count_curve += 2 * curve.sum()
        if live.any():
            y_over_q = max(y_over_q, float(task.y_over_q[live].max()))
        signed += (task.actuator_force[curve] * np.sign(task.curvature_1pm[curve])[:, None]).sum(axis=0)
        absolute += np.abs(task.actuator_force[curve]).sum(axis=0)
        n_curve += int(curve.sum())
        alive &= ~task.done
        if not alive.any():
            break
    return {"policy": spec, "mean_wear_number_n": wear / max(count, 1), "mean_wear_number_in_curves_n": wear_curve / max(count_curve, 1),
            "flange_contact_fraction": flange / max(count, 1), "max_y_over_q": y_over_q,
            "mean_signed_force_in_curves": (signed / max(n_curve, 1)).round(0).tolist(),
            "mean_abs_force_in_curves": (absolute / max(n_curve, 1)).round(0).tolist()}  # fmt: skip


def _progress_printer(total: int):
    """A callback that prints ``[k/total] message`` with the elapsed and the estimated remaining time."""
    start, done = time.time(), [0]

    def progress(message: str) -> None:
        done[0] += 1
        elapsed = time.time() - start
        print(f"[{done[0]}/{total}] {message}; {elapsed:.0f} s, about {elapsed / done[0] * (total - done[0]):.0f} s left",
              file=sys.stderr, flush=True)  # fmt: skip

    return progress


def main(argv: list[str] | None = None) -> None:
    """``python -m bogie_agents.design.robust_cli design [--out FILE]``: design the gain table for the v1 env (stage 1);
    ``python -m bogie_agents.design.robust_cli retune --base STAGE1 [--out FILE]``: stage 2 (:mod:`bogie_agents.controllers.robust_track`);
    ``python -m bogie_agents.design.robust_cli report``: its linear onsets by conicity and its margins;
    ``python -m bogie_agents.design.robust_cli ramp --policy NAME``: onsets on the v1 ramp by conicity;
    ``python -m bogie_agents.design.robust_cli route``: closed-loop curving on the v1 route variant."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("what", choices=("design", "retune", "report", "ramp", "route"))
    parser.add_argument("--base", default=None, help="retune: stage 1's gain table (python -m bogie_agents.design.robust_cli design --out FILE)")
    parser.add_argument("--steps", type=int, default=6000, help="route: env steps per episode at most")
    parser.add_argument("--policy", action="append", help="ramp: policy names (default: passive and robust_damping)")
    parser.add_argument("--conicities", default="0.025,0.05,0.1,0.2,0.3", help="ramp: comma-separated conicities")
    parser.add_argument("--seeds", type=int, default=10, help="ramp, route: seeds 0..N-1")
    parser.add_argument("--out", default=str(GAINS_FILE))
    parser.add_argument("--variant", default="v1")
    parser.add_argument("--w-track", default=None,
                        help="retune: the track weight, one number or one per stage-2 row, comma-separated (default: the shipped table's)")
    parser.add_argument("--w-yaw", type=float, default=None,
                        help="retune: the weight of the wheelset-yaw command per mm of alignment (default: the shipped table's, 0.05)")
    parser.add_argument("--washout-order", type=int, default=1, choices=WASHOUT_ORDERS,
                        help="design: the filter bank's washout order (filter_bank; the shipped table: 1)")
    args = parser.parse_args(argv)
    config = make_config({"randomize": {}}, variant=args.variant)
    if args.what == "report":
        print(report(config))
        return
    if args.what == "route":
        route_config = make_config({"randomize": {}}, variant="v1_route")
        for spec in args.policy or ["passive", "robust_damping"]:
            r = route_run(spec, route_config, args.steps, args.seeds)
            print(" ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()), flush=True)
        return
    if args.what == "ramp":
        for spec in args.policy or ["passive", "robust_damping"]:
            for c in (float(v) for v in args.conicities.split(",")):
                r = ramp_onsets(spec, config, c, args.seeds)
                hunted = [v for v in r["onset_kmh"] if v is not None]
                span = f"{min(hunted):g} / {float(np.median(hunted)):g} / {max(hunted):g}" if hunted else "none"
                print(f"{spec} conicity {c:g}: hunted {len(hunted)}/{args.seeds}, onset min / median / max {span} km/h; "
                      f"onsets {r['onset_kmh']}; peak forces {r['peak_force']}", flush=True)  # fmt: skip
        return
    if args.what == "retune":
        if args.base is None:
            parser.error("retune needs --base (stage 1's table)")
        track = TrackSettings()
        if args.w_track is not None:
            try:
                weights = tuple(float(v) for v in args.w_track.split(","))
            except ValueError:
                parser.error(f"--w-track = {args.w_track!r}: allowed: one number or {len(track.speeds_kmh)} comma-separated numbers")
            track.w_track = weights[0] if len(weights) == 1 else weights
            try:
                track.track_weight(track.speeds_kmh[0])  # checks the count
            except ValueError as error:
                parser.error(str(error))
        if args.w_yaw is not None:
            if not (math.isfinite(args.w_yaw) and args.w_yaw >= 0.0):
                parser.error(f"--w-yaw = {args.w_yaw!r}: allowed: a finite number >= 0")
            track.w_yaw = args.w_yaw
        report_row = _progress_printer(len(track.speeds_kmh))
        base = load_gains(args.base)
        table = retune_track(config, base, track, progress=lambda row: report_row(json.dumps(row)))
        table["command"] = (f"{base.get('command', '?')} --out STAGE1; python -m bogie_agents.design.robust_cli retune --variant {args.variant} --base STAGE1"
                            + (f" --w-track {args.w_track}" if args.w_track is not None else "")
                            + (f" --w-yaw {args.w_yaw:g}" if args.w_yaw is not None else ""))  # fmt: skip
        save_gains(table, args.out)
        print(f"wrote {args.out}")
        return
    settings = DesignSettings(washout_order=args.washout_order)
    table = tune(config, settings, _progress_printer(len(settings.speeds_kmh)))
    table["command"] = f"python -m bogie_agents.design.robust_cli design --variant {args.variant}" + (
        f" --washout-order {args.washout_order}" if args.washout_order != 1 else "")
    save_gains(table, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
