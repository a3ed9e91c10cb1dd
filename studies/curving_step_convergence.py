"""The curving columns at v1's integration step and at half of it.

    python studies/curving_step_convergence.py [--policy pretrained] [--seeds 8]

Every shipped route at its design speed, at the RK4 substeps per 10 ms env step that v1's
accuracy criterion chooses for the curving runs (``integration.n_sub`` null) and at twice as many
(passive is rerun at each step); prints JSON: the chosen substeps, then per route and step, the
wear number, flange-contact time, peak Y/Q, max ΣY rms, the excess over passive and whether the
controller is no worse than passive.
"""

from __future__ import annotations

import argparse
import json

from bogie_agents.evaluation.curving_evaluation import CurvingSettings, curving_columns, route_config
from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.route import available_routes

FIELDS = ("wear_number_n", "flange_contact_s", "peak_y_over_q", "max_sum_y_rms_n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None)
    parser.add_argument("--seeds", type=int, default=8)
    args = parser.parse_args()
    default = make_config(None, variant="v1")
    chosen = HuntingTask(1, route_config(default, list(available_routes()), "sensors", CurvingSettings().nominal)).n_sub
    out: dict[str, dict] = {"chosen_substeps": chosen}
    for policy in args.policy or ["pretrained"]:
        for n_sub in (chosen, 2 * chosen):
            config = default if n_sub == chosen else make_config({"integration": {"n_sub": n_sub}}, variant="v1")
            result = curving_columns(policy, config, seeds=args.seeds, progress=False)
            for route, columns in result["routes"].items():
                row = {k: round(float(columns[k]), 4) for k in FIELDS}
                row["excess_over_passive"] = {k: {"mean": round(v["mean"], 4), "tolerance": round(v["tolerance"], 4)}
                                              for k, v in columns["excess_over_passive"].items() if k in FIELDS}  # fmt: skip
                row["no_worse_than_passive"] = columns["no_worse_than_passive"]
                out[f"{policy}, {route}, {n_sub} substeps"] = row
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
