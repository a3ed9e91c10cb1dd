"""Protocol v2's closed-loop critical speeds with v1's integration step and finer ones, beside
the same protocol on bogies that differ by a physically negligible amount.

    python studies/protocol_step_convergence.py [--policy passive --policy pretrained]
        [--n-sub 10,20,40] [--replicas 5] [--relative 1e-4] [--perturb dampers|start]
        [--columns conicity:0.1] [--duration-s 40]

Columns nominal (conicity 0.025) and conicity 0.1, seeds 0-9, at each ``--n-sub`` (RK4
substeps per 10 ms env step; v1 chooses 10, 20 halves the step). Replica ``k`` (0 to
``--replicas`` - 1) runs the protocol with every damper scaled by ``1 + k * relative``
(``--perturb dampers``, the protocol's ``nominal_options``: a change that acts all along the
run, like an integration error; 1e-4 is far below any damper's tolerance) or with the 12 mm
initial perturbation scaled so (``--perturb start``: acts once, at the start). Replica 0 is the
protocol itself. Comparing the two tells an integration error (the value moves with the step,
not with the replicas) from the sensitivity of the statistic (the replicas at one step move it
as much as the step does): near a controller's boundary a single seed's pass at one speed can
flip with any persistent perturbation of its trajectory, and the column value is the lowest
seed's bisected boundary.

``--duration-s`` runs each fixed-speed run longer than the protocol's 20 s (the first 5 s are still
discarded): a measurement of whether a longer assessed window conditions the statistic, not the
protocol. ``--columns``: a subset of nominal, conicity:0.1.

Prints JSON: per policy, step and column the replicas' values (km/h), their median and range,
the median over seeds of each replica, and the per-seed values; progress on stderr.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

from bogie_env.envs.config import make_config
from bogie_agents.evaluation.stability_protocol import Settings, columns_by_conicity, evaluate_policy_v2

COLUMNS = ("nominal", "conicity:0.1")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None)
    parser.add_argument("--n-sub", default="10,20", help="RK4 substeps per env step, comma-separated (v1: 10)")
    parser.add_argument("--replicas", type=int, default=1, help="perturbed replicas per step (1: the protocol only)")
    parser.add_argument("--relative", type=float, default=1e-4, help="relative change per replica")
    parser.add_argument("--perturb", choices=("dampers", "start"), default="dampers")
    parser.add_argument("--columns", default=",".join(COLUMNS), help="comma-separated subset of " + ", ".join(COLUMNS))
    parser.add_argument("--duration-s", type=float, default=None, help="seconds per fixed-speed run (protocol: 20)")
    args = parser.parse_args()
    steps = [int(v) for v in args.n_sub.split(",")]
    columns = tuple(args.columns.split(","))
    if not columns or set(columns) - set(COLUMNS):
        parser.error(f"--columns = {args.columns!r}: allowed: a comma-separated subset of {', '.join(COLUMNS)}")
    if args.replicas < 1 or any(n < 1 for n in steps):
        parser.error(f"--replicas = {args.replicas} and --n-sub = {args.n_sub!r} must be >= 1")
    policies = args.policy or ["passive", "pretrained"]
    total, done, t0 = len(policies) * len(steps) * args.replicas, 0, time.monotonic()
    out: dict[str, dict] = {}
    for policy in policies:
        for n_sub in steps:
            config = make_config({"integration": {"n_sub": n_sub}}, variant="v1")
            runs: list[dict[str, dict]] = []
            for k in range(args.replicas):
                settings = Settings(columns=columns, progress=False)
                if args.duration_s is not None:
                    settings.duration_s = args.duration_s
                    settings.check()
                if args.perturb == "start":
                    settings.perturbation_m *= 1.0 + k * args.relative
                else:
                    settings.nominal_options["damper_factor"] = 1.0 + k * args.relative
                runs.append(columns_by_conicity(evaluate_policy_v2(policy, config, settings, ("critical",))))
                done += 1
                elapsed = time.monotonic() - t0
                print(f"[{done}/{total}: {policy}, {n_sub} substeps, replica {k}; {elapsed:.0f} s, "
                      f"about {elapsed / done * (total - done):.0f} s left]", file=sys.stderr, flush=True)  # fmt: skip
            out[f"{policy}, {n_sub} substeps"] = {
                lam: {"kmh": [r[lam]["kmh"] for r in runs], "median_kmh": statistics.median(r[lam]["kmh"] for r in runs),
                      "range_kmh": [min(r[lam]["kmh"] for r in runs), max(r[lam]["kmh"] for r in runs)],
                      "seed_median_kmh": [statistics.median(r[lam]["per_seed_kmh"]) for r in runs],
                      "per_seed_kmh": [r[lam]["per_seed_kmh"] for r in runs]}
                for lam in runs[0]
            }  # fmt: skip
    print(json.dumps({"perturb": args.perturb, "relative": args.relative, "replicas": args.replicas,
                      "duration_s": args.duration_s or Settings().duration_s, "results": out}, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
