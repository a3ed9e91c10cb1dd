"""The loop penalty's growth bounds of a distilled correction with half the creep and with each actuator failed.

    python studies/distill_fault_loops.py [--policy agents/pretrained/distilled_v1] [--speeds 200,243,280,329,400] [--conicity 0.025]
        [--degraded creep-50%,Kpx-50%,Kpy-50%,dampers-50%]

For each speed, the upper bound on the growth rate (1/s) of the student's linearised loop
(:class:`bogie_agents.training.loop_penalty.LoopPenalty`, ``fault_points``) with each actuator
failed in turn (its command times 0) and with each of the protocol's degraded bogies in
``--degraded`` (default the Kalker coefficients halved, creep -50 %), and the exact growth rate of the same loop (its largest eigenvalue). A bound above
zero does not prove the loop unstable; below zero it is stable.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bogie_agents.controllers.distilled import META_FILE, load_student
from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="agents/pretrained/distilled_v1", help="a distilled student's folder (a correction on a baseline)")
    parser.add_argument("--speeds", default="200,243,280,329,400", help="km/h, comma-separated")
    parser.add_argument("--conicity", type=float, default=0.025)
    parser.add_argument("--degraded", default="creep-50%", help="the protocol's degraded bogies, comma-separated (Kpx-50%%, Kpy-50%%, dampers-50%%, creep-50%%)")
    args = parser.parse_args(argv)
    folder = Path(args.policy)
    policy = load_student(folder)
    if not policy.residual:
        raise SystemExit(f"{folder}: not a correction on a baseline (student.residual); the penalty's loops need one")
    env_cfg = json.loads((folder / META_FILE).read_text())["residual"]["env_config"]
    speeds = [float(v) for v in args.speeds.split(",")]
    settings = check_penalty_config({"points": [[speeds[0], args.conicity]], "stable_points": [],
                                     "fault_points": [[v, args.conicity] for v in speeds],
                                     "fault_degraded": args.degraded.split(",")})  # fmt: skip
    penalty = LoopPenalty(policy.frames, env_cfg, settings)
    bounds, rates = penalty.growth_bounds_of(policy.network), penalty.growth_rates_of(policy.network)
    print(f"{folder}, conicity {args.conicity:g}: growth bound and exact growth rate (1/s)")
    for (speed, _, kind, name), bound, rate in zip(penalty.named_rows(), bounds, rates):
        if kind == "faults":
            print(f"  {speed:5.0f} km/h  {name:22s} {bound:+.3f}  {rate:+.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
