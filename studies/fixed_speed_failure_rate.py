"""The fraction of seeds that fail the protocol's criterion at fixed speeds, at several
integration steps: whether a step changes the physics or only which seeds fail.

    python studies/fixed_speed_failure_rate.py [--policy robust_steering] \
        [--n-sub 10,40] [--conicity 0.025] [--speeds 460:600:20] [--seeds 40] [--degraded Kpx-50%]

Each (seed, speed) row is one protocol run (``agents/evaluation/stability_protocol.py``: 20 s at a fixed
speed, the first 5 s discarded, the 12 mm start, the controller told the conicity class),
seeds 0 to ``--seeds`` - 1, all rows of a step in one batch. Where two attractors coexist (the
bogie settles, or falls into a hunting cycle), the column's lowest seed is a sample minimum
over ten seeds; the failure rate per speed is the quantity a step could bias. Prints JSON: per
step and speed the failing seeds and their fraction with its binomial standard error; progress
on stderr. ``--degraded NAME``: every row with one of the protocol's degraded bogies
(``stability_protocol.DEGRADED``), as in that column; ``--trust-policy``: a ``--policy`` may be a
path, loaded as ``bogie evaluate --trust-policy`` does. The criterion is the protocol's current
version (v3). Unlike the protocol's search, which checks a grid of speeds and bisects above the
highest passing one, this looks at every speed asked for.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from bogie_env.envs.config import make_config
from bogie_agents.evaluation.stability_protocol import (DEGRADED, NOMINAL_OPTIONS, Case, PartContext, Progress, Runner, Settings,
                                             factory_for)  # fmt: skip
from lambda_low_speed_diagnosis import parse_speeds  # this folder: the script's own directory is on sys.path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="robust_steering")
    parser.add_argument("--n-sub", default="10,40", help="RK4 substeps per env step, comma-separated (v1: 10)")
    parser.add_argument("--conicity", type=float, default=0.025)
    parser.add_argument("--speeds", default="460:600:20")
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--degraded", default=None, help=f"one of {', '.join(DEGRADED)} (default: the nominal bogie)")
    parser.add_argument("--trust-policy", action="store_true", help="load a --policy path (an SB3 file is code: only your own runs)")
    args = parser.parse_args()
    if args.degraded is not None and args.degraded not in DEGRADED:
        parser.error(f"--degraded = {args.degraded!r}; allowed: {', '.join(DEGRADED)}")
    degraded = DEGRADED[args.degraded] if args.degraded else {}
    steps = [int(v) for v in args.n_sub.split(",")]
    try:
        speeds = parse_speeds(args.speeds)
    except ValueError:
        parser.error(f"--speeds = {args.speeds!r}: allowed: a:b:step or a comma list of km/h")
    if args.seeds < 1 or any(n < 1 for n in steps) or not 0.0 < args.conicity <= 0.5:
        parser.error(f"--seeds = {args.seeds}, --n-sub = {args.n_sub!r}: >= 1; --conicity = {args.conicity}: in (0, 0.5]")
    out: dict[str, dict] = {}
    t0 = time.monotonic()
    for k, n_sub in enumerate(steps):
        config = make_config({"integration": {"n_sub": n_sub}}, variant="v1")
        settings = Settings(progress=False)
        factory = factory_for(args.policy, trusted=args.trust_policy)
        ctx = PartContext(factory, config, settings, getattr(factory(config), "observation_type", "sensors"),
                          Progress(args.policy, False))  # fmt: skip
        cases = [Case("fixed", seed, {**NOMINAL_OPTIONS, **degraded, "conicity": args.conicity}, args.conicity)
                 for _ in speeds for seed in range(args.seeds)]  # fmt: skip
        rows_kmh = np.repeat(speeds, args.seeds)
        result = Runner(ctx).run(cases, rows_kmh, "fixed speeds", 0)
        failed = ~result.passed.reshape(len(speeds), args.seeds)
        out[f"{n_sub} substeps"] = {
            f"{v:g}": {"failing_seeds": [int(s) for s in np.nonzero(failed[i])[0]],
                       "fraction": round(float(failed[i].mean()), 3),
                       "standard_error": round(math.sqrt(failed[i].mean() * (1 - failed[i].mean()) / args.seeds), 3)}
            for i, v in enumerate(speeds)
        }  # fmt: skip
        elapsed = time.monotonic() - t0
        print(f"[{k + 1}/{len(steps)}: {n_sub} substeps; {elapsed:.0f} s, about {elapsed / (k + 1) * (len(steps) - k - 1):.0f} s left]",
              file=sys.stderr, flush=True)  # fmt: skip
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
