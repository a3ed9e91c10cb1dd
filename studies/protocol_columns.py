"""Protocol v2's closed-loop critical speed for a few columns, on any block of seeds.

    python studies/protocol_columns.py --seed 10 [--policy passive --policy robust_damping
        --policy pretrained] [--columns nominal,conicity:0.05,conicity:0.1] [--n-sub 20] [--flange-time-limit 0.03]

``--seed S`` runs the seeds S, S+1, ..., S+9 (``Settings.seed``; a seed sets the start on the
track's alignment profile and the sensor noise); ``--seeds N`` (a multiple of 10) runs S..S+N-1
in one batch and reports each block of ten seeds as the protocol would (its lowest seed, and the
floor passive + 100 km/h of that block). ``bogie evaluate`` and ``bogie results`` use
``--seed 0``, i.e. seeds 0-9; ``--seed 10`` gives a block that shares no seed with them (held out
from the seeds on which the shipped table and policy were chosen). Prints JSON: per policy and
column the value (lowest seed), the seeds and the per-seed values, and the floor
passive + 100 km/h on the same seeds when passive is among the policies. ``--n-sub``: RK4 substeps
per 10 ms env step (v1: 10); ``--flange-time-limit``: the criterion's flange-contact time limit
(the protocol's 0.01; 1 leaves EN 14363's ΣY and frame-acceleration limits only), a sensitivity
check, not the protocol. ``--trust-policy``: a ``--policy`` may be a path (a run folder, e.g. a
training checkpoint copied as ``best_model.zip`` beside the run's ``vecnormalize.json`` and
``config.json``), loaded as ``bogie evaluate --trust-policy`` does.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from bogie_env.envs.config import make_config
from bogie_agents.evaluation.stability_protocol import Settings, block_values, columns_by_conicity, evaluate_policy_v2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None)
    parser.add_argument("--trust-policy", action="store_true", help="load a --policy path (an SB3 file is code: only your own runs)")
    parser.add_argument("--seed", type=int, default=10, help="first seed of the block of 10 (default 10: seeds 10-19)")
    parser.add_argument("--seeds", type=int, default=10, help="seeds S..S+N-1, reported per block of ten (default 10)")
    parser.add_argument("--columns", default="nominal,conicity:0.05,conicity:0.1")
    parser.add_argument("--n-sub", type=int, default=None, help="RK4 substeps per env step (default: v1's 10; 20 halves the step)")
    parser.add_argument("--flange-time-limit", type=float, default=None, help="fraction of the time (protocol: 0.01)")
    args = parser.parse_args()
    config = make_config({"integration": {"n_sub": args.n_sub}} if args.n_sub else {}, variant="v1")
    if args.seeds < 10 or args.seeds % 10:
        parser.error(f"--seeds = {args.seeds}: allowed: a multiple of 10 (blocks of ten seeds)")
    settings = Settings(seed=args.seed, seeds=args.seeds, columns=tuple(args.columns.split(",")), progress=False)
    if args.flange_time_limit is not None:
        settings.flange_time_limit = args.flange_time_limit
    out: dict[str, dict] = {}
    for policy in args.policy or ["passive", "robust_damping", "pretrained"]:
        t0 = time.monotonic()
        result = evaluate_policy_v2(policy, config, settings, ("critical",), trusted=args.trust_policy)
        out[policy] = {lam: {"kmh": col["kmh"], "seeds": col["seeds"], "per_seed_kmh": col["per_seed_kmh"],
                             "per_block_kmh": block_values(col["per_seed_kmh"])}
                       for lam, col in columns_by_conicity(result).items()}  # fmt: skip
        print(f"[{policy}: {time.monotonic() - t0:.0f} s, busy host]", file=sys.stderr, flush=True)
    if "passive" in out:
        out["floor_passive_plus_100"] = {lam: round(col["kmh"] + 100.0, 1) for lam, col in out["passive"].items()}
        floors = {lam: [v + 100.0 for v in col["per_block_kmh"]] for lam, col in out["passive"].items()}
        out["floor_per_block"] = {lam: [round(v, 1) for v in f] for lam, f in floors.items()}
        out["blocks_meeting_floor"] = {name: {lam: sum(v >= f for v, f in zip(col["per_block_kmh"], floors[lam]))
                                              for lam, col in cols.items() if lam in floors}
                                       for name, cols in out.items() if name not in ("passive", "floor_passive_plus_100", "floor_per_block")}  # fmt: skip
    print(json.dumps({"seed": args.seed, "n_sub": config["integration"]["n_sub"], "flange_time_limit": settings.flange_time_limit,
                      "columns": list(settings.columns), "policies": out}))  # fmt: skip


if __name__ == "__main__":
    main()
