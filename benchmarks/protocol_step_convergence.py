"""Protocol v2's closed-loop critical speeds with v1's integration step and half of it.

    PYTHONPATH=. python benchmarks/protocol_step_convergence.py [--policy passive --policy pretrained]

Columns nominal (conicity 0.025) and conicity 0.1, 10 seeds, 10 and 20 RK4 substeps per 10 ms
env step (``integration.n_sub``); prints JSON (with the nominal column per seed). The issue-10
tolerance is 2 km/h.
"""

from __future__ import annotations

import argparse
import json

from bogie_env.envs.config import make_config
from bogie_agents.stability_protocol import Settings, evaluate_policy_v2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None)
    args = parser.parse_args()
    out: dict[str, dict] = {}
    for policy in args.policy or ["passive", "pretrained"]:
        for n_sub in (10, 20):
            config = make_config({"integration": {"n_sub": n_sub}}, variant="v1")
            r = evaluate_policy_v2(policy, config, Settings(columns=("nominal", "conicity:0.1"), progress=False), ("critical",))
            out[f"{policy}, {n_sub} substeps"] = {"nominal_kmh": r["nominal"]["kmh"], "conicity_0.1_kmh": r["by_conicity"]["0.1"]["kmh"],
                                                  "nominal_per_seed_kmh": r["nominal"]["per_seed_kmh"]}  # fmt: skip
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
