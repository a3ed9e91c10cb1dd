"""Hunting or forced contact: each seed's highest passing speed on a fine grid, under protocol v2's
flange rule (any contact over 1 % of the time) and under v3's (the contact also sustained: in at
least a given share of the assessed time's 1 s windows), for one controller, conicity and track
level. It shows where a rough track's forced contacts set v2's value and which shares of the
windows separate them from hunting (docs/studies/hunting_or_forced_contact.md).

    python studies/forced_contact_scan.py --level intervention --conicity 0.1 --speeds 40,200,4
    python studies/forced_contact_scan.py --level alert --conicity 0.025 --speeds 330,400,2 --shares 0.5,0.67,0.8
    python studies/forced_contact_scan.py --level intervention --conicity 0.1 --speeds 40,160,14 --per-speed

Every speed of the grid runs as one fixed-speed protocol row (the protocol's task, seeds, 12 mm
start and 5 s transient); a seed's value is the upper end of its highest passing range, as the
protocol's search defines it, without the bisection.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from bogie_agents.evaluation import stability_protocol as sp
from bogie_env.envs.config import make_config


def scan(policy: str, level: str, conicity: float, speeds_kmh: np.ndarray, shares: list[float], seeds: int = 10) -> dict:
    """Per flange rule, each seed's highest passing speed (None: no speed passes) and the number of
    grid speeds below it that fail."""
    env = make_config({"track": {"level": level}}, variant="v1")
    settings = sp.Settings(seeds=seeds, progress=False)
    ctx = sp.PartContext(sp.factory_for(policy), env, settings, "sensors", sp.Progress(policy, False))
    key = "nominal" if np.isclose(conicity, 0.025) else f"conicity:{conicity:g}"
    cases = sp.columns(env, settings)[key]
    rows = [c for _ in speeds_kmh for c in cases]
    task, controller = sp.Runner(ctx)._task(rows, np.repeat(speeds_kmh, len(cases)), "default")
    dt = task.config["dt"]
    steps, first = int(round(settings.duration_s / dt)), int(round(settings.transient_s / dt))
    contact = np.zeros((len(rows), steps - first), dtype=bool)
    for k in range(steps):
        sp.step_guarded(task, controller.act(task.obs))
        if k >= first:
            contact[:, k - first] = sp.flange_touching(task)
    flange_time = contact.mean(axis=1)
    occupancy = sp.flange_occupancy(contact, dt, settings.flange_window_s)
    per_speed = {}
    for j, v in enumerate(speeds_kmh):
        rows_j = slice(j * len(cases), (j + 1) * len(cases))
        per_speed[f"{v:g}"] = {"flange_time": np.round(flange_time[rows_j], 3).tolist(),
                               "occupancy": np.round(occupancy[rows_j], 2).tolist()}  # fmt: skip
    out: dict = {"policy": policy, "level": level, "conicity": conicity, "seeds": [c.seed for c in cases],
                 "rules": {}, "per_speed": per_speed}  # fmt: skip
    for share in [0.0] + shares:
        rule = sp.Settings(version=2) if share == 0.0 else sp.Settings(flange_sustained_fraction=share)
        fails = sp.sustained_flange_contact(flange_time, occupancy, rule).reshape(len(speeds_kmh), len(cases)).T
        tops, below = [], []
        for row in fails:
            passing = np.nonzero(~row)[0]
            top = int(passing[-1]) if passing.size else -1
            tops.append(None if top < 0 else float(speeds_kmh[top]))
            below.append(int(row[: max(top, 0)].sum()))
        name = "v2 (any contact)" if share == 0.0 else f"v3 rule, share {share:g}"
        out["rules"][name] = {"lowest_seed_kmh": min((t for t in tops if t is not None), default=None),
                              "seeds_without_a_pass": tops.count(None), "per_seed_kmh": tops, "fails_below": below}  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="passive")
    parser.add_argument("--level", default="intervention", help="EN 13848-5 level: alert, intervention, immediate_action")
    parser.add_argument("--conicity", type=float, default=0.1)
    parser.add_argument("--speeds", default="40,200,4", help="start,stop,step in km/h (numpy.arange)")
    parser.add_argument("--shares", default="0.5,0.67,0.8", help="v3 shares of the 1 s windows to compare")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--per-speed", action="store_true",
                        help="also print, per speed and seed, the contact time and the share of 1 s windows with a contact")
    args = parser.parse_args()
    speeds = np.arange(*[float(v) for v in args.speeds.split(",")])
    shares = [float(v) for v in args.shares.split(",") if v]
    result = scan(args.policy, args.level, args.conicity, speeds, shares, args.seeds)
    print(json.dumps({k: v for k, v in result.items() if k not in ("rules", "per_speed")}))
    if args.per_speed:
        for speed, row in result["per_speed"].items():
            print(json.dumps({"speed_kmh": float(speed), **row}))
    for name, rule in result["rules"].items():
        print(json.dumps({"rule": name, **rule}))


if __name__ == "__main__":
    main()
