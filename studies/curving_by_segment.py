"""Where on each shipped route a controller's flange contact and wear occur: per route segment.

    python studies/curving_by_segment.py [--policy passive --policy robust_damping ...]
        [--seeds 8] [--perfect-track] [--commands]

The curving evaluation's conditions (``bogie_agents.evaluation.curving_evaluation.route_config``: the v1
world on the shipped routes at their design speeds, nominal bogie, seeds 0..N-1, route copy =
seed mod copies, every row to its route's end), split by the segment under the bogie frame:
flange-contact time (either wheelset, mean over seeds, s) and the mean wear number (Tγ summed
over both wheelsets, N). ``--perfect-track``: no irregularity (sensor noise and bias stay). The
totals over the segments are the curving columns' ``flange_contact_s`` (the mean wear number is
weighted by steps). ``--commands``: instead, per segment the mean command of each actuator
channel (normalised, -1..1) times the sign of the segment's start plus end curvature (zero on
tangents and on a reversing transition), which shows a steady command held through a curve. Used in
docs/controllers.md ("Curving: where the excess over passive is") and
docs/studies/distillation.md.
"""

from __future__ import annotations

import argparse

import numpy as np

from bogie_agents.evaluation.curving_evaluation import route_config
from bogie_agents.controllers.policies import load_policy
from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.route import available_routes, load_route


def by_segment(spec: str, seeds: int, perfect_track: bool) -> dict[str, tuple[float, float, np.ndarray]]:
    """``{"route[k:kind]": (flange-contact time per seed in s, mean wear number in N, mean command
    per channel signed by the segment's curvature)}``."""
    routes = available_routes()
    base = make_config({"track": {"rms": 0.0, "level": None}} if perfect_track else None, variant="v1")
    config = route_config(base, routes, "sensors")
    n = len(routes) * seeds
    task = HuntingTask(n, config)
    rows = np.arange(n)
    task.seed_rows(rows, [int(i) % seeds for i in rows])
    for i in rows:
        name = routes[i // seeds]
        task.reset_rows(np.array([i]), {"route": name, "start_kmh": config["route"]["speed_kmh"][name][0],
                                        "route_copy": (int(i) % seeds) % config["route"]["copies"]})  # fmt: skip
    policy = load_policy(spec, config)
    policy.reset(n)
    slots = [task.route_layout.slots[s] for s in task.route_slot]
    starts = np.array([s.start_m for s in slots])
    ends = np.array([s.end_m for s in slots])
    segments = {r: load_route(r).segments for r in routes}
    bounds = {r: np.cumsum([0.0] + [s.length for s in segments[r]]) for r in routes}
    route_of_row = [routes[i // seeds] for i in rows]
    totals: dict[tuple[str, int], np.ndarray] = {}
    running = np.ones(n, dtype=bool)
    dt = config["dt"]
    while running.any():
        action = np.asarray(policy.act(task.obs), dtype=float)
        task.step(action)
        position = task.distance_m - starts
        contact = task.flange_contact.any(axis=1)
        wear = task.wear_number_n.sum(axis=1)
        for i in np.nonzero(running)[0]:
            r = route_of_row[i]
            k = int(np.clip(np.searchsorted(bounds[r], position[i], side="right") - 1, 0, len(segments[r]) - 1))
            sign = np.sign(segments[r][k].curvature_start + segments[r][k].curvature_end)
            totals.setdefault((r, k), np.zeros(3 + action.shape[1]))[:] += (contact[i] * dt, wear[i], 1.0, *(sign * action[i]))
        running &= task.distance_m < ends
    return {f"{r}[{k}:{segments[r][k].kind}]": (t[0] / seeds, t[1] / t[2], t[3:] / t[2]) for (r, k), t in sorted(totals.items())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None, help="policy names (default: passive, robust_damping)")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--perfect-track", action="store_true")
    parser.add_argument("--commands", action="store_true", help="the mean signed command per channel instead")
    args = parser.parse_args()
    specs = args.policy or ["passive", "robust_damping"]
    results = {spec: by_segment(spec, args.seeds, args.perfect_track) for spec in specs}
    keys = list(results[specs[0]])
    if args.commands:
        channels = HuntingTask(1, make_config(None, variant="v1")).channel_names
        print("mean command signed by the curvature, per channel: " + ", ".join(channels))
        for key in keys:
            print(key.ljust(34) + "".join(f"{spec:>20}: " + " ".join(f"{c:+.3f}" for c in results[spec][key][2]) for spec in specs))
        return
    print("segment".ljust(34) + "".join(f"{spec:>28}" for spec in specs))
    print("".ljust(34) + "".join(f"{'flange (s)':>14}{'wear (N)':>14}" for _ in specs))
    for key in keys:
        print(key.ljust(34) + "".join(f"{results[s][key][0]:>14.2f}{results[s][key][1]:>14.2f}" for s in specs))


if __name__ == "__main__":
    main()
