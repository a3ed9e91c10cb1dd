"""robust_damping at conicity 0.1 with an edited command lead, or with edited actuator limits:
the protocol-v2 column and the smallest command factor the design model tolerates near the lead.

    python studies/lambda_lead.py [--gains agents/controllers/robust_gains.json] \
        [--lead-s 0.01 --lead-lowpass-hz 4 --lead-speeds 240,270] [--env-override JSON] [--columns conicity:0.1]

- ``--lead-s`` / ``--lead-lowpass-hz`` / ``--lead-speeds``: replace the table's lead (0: none) on a
  copy of the table (the shipped file is not touched);
- ``--env-override``: JSON merged into the v1 config of the protocol's tasks and of the
  controller, e.g. ``'{"actuators": {"frame_lateral": {"rate_limit": 400000.0}}}'`` (a test of
  what limits the controller, not a v1 setting).

- ``--seeds N`` (default 10, the protocol's): seeds S..S+N-1 (``--seed S``, default 0); with more
  than 10, also each block of ten seeds' lowest value against its floor (passive + 100 km/h on the
  same block, run here).

Prints the column (worst seed, per seed, median) and, per conicity 0.025-0.1, the largest command
factor (0.1 steps up to 3) for which the design-model closed loop stays stable, worst over
225-285 km/h.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from bogie_env.envs.config import make_config, merge_config
from bogie_agents.controllers.robust import GAINS_FILE, DesignModel, RobustDampingController, closed_loop, filter_bank, load_gains
from bogie_agents.evaluation.stability_protocol import Settings, block_values, columns_by_conicity, evaluate_policy_v2


def largest_factor(controller: RobustDampingController, config: dict, conicity: float, speeds) -> float:
    """The largest command factor of the grid 1.0, 1.1, ... 3.0 up to which the design loop is stable at every speed."""
    model = DesignModel(config, conicity)
    bank = filter_bank(model.n_obs, config["dt"], controller.washout_hz, controller.leak_hz, controller.washout_order)
    worst = 3.0
    for v in speeds:
        g = controller.gain_at(np.array([v]))[0]
        lead = float(controller.lead_at(np.array([v]))[0])
        plant = model.plant(v)
        top = 0.0
        for f in np.arange(1.0, 3.001, 0.1):
            if np.max(np.abs(np.linalg.eigvals(closed_loop(plant, bank, g, f, lead, config["dt"], controller.lead_lowpass_hz)))) >= 1.0:
                break
            top = round(float(f), 1)
        worst = min(worst, top)
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--gains", default=str(GAINS_FILE))
    ap.add_argument("--lead-s", type=float, default=None)
    ap.add_argument("--lead-lowpass-hz", type=float, default=None)
    ap.add_argument("--lead-speeds", default="240,270")
    ap.add_argument("--env-override", default=None)
    ap.add_argument("--columns", default="conicity:0.1")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0, help="the first seed (default 0; 100-139 are the test blocks)")
    args = ap.parse_args()
    table = load_gains(args.gains)
    if args.lead_s is not None:
        rows = [float(v) for v in args.lead_speeds.split(",")]
        table["lead_s"] = np.array([args.lead_s if v in rows else 0.0 for v in table["speeds_kmh"]])
        table["lead_lowpass_hz"] = args.lead_lowpass_hz
    config = make_config(variant="v1")
    if args.env_override:
        config = make_config(merge_config(config, json.loads(args.env_override)))
    t0 = time.monotonic()
    if args.seeds < 1:
        ap.error(f"--seeds = {args.seeds} must be >= 1")
    if args.seeds > 10 and args.seeds % 10:
        ap.error(f"--seeds = {args.seeds}: allowed: 1-10, or a multiple of 10 (blocks of ten seeds)")
    settings = Settings(seeds=args.seeds, seed=args.seed, columns=tuple(args.columns.split(",")), progress=False)

    def columns_of(source, label: str) -> dict:
        return columns_by_conicity(evaluate_policy_v2(source, config, settings, parts=("critical",), label=label))

    columns = columns_of(lambda cfg: RobustDampingController(cfg, gains=table), "robust_damping (edited copy)")
    passive = columns_of("passive", "passive") if args.seeds > 10 else {}
    label = f"lead {table['lead_s'].max():g} s, low-pass {table.get('lead_lowpass_hz')} Hz" + (f", env {args.env_override}" if args.env_override else "")
    for lam, col in columns.items():
        per_seed = col["per_seed_kmh"]
        print(f"{label}: λ {lam}: {col['kmh']} km/h, per seed {per_seed}, median {float(np.median(per_seed)):.1f}, "
              f"worst seed fails by {col['worst_seed_fails_by']}")  # fmt: skip
        if lam in passive:
            lows, floors = block_values(per_seed), block_values(passive[lam]["per_seed_kmh"])
            blocks = [(10 * k, low - floor - 100.0) for k, (low, floor) in enumerate(zip(lows, floors))]
            print(f"{label}: λ {lam}: lowest seed - floor per block of ten seeds: "
                  + ", ".join(f"{args.seed + b}-{args.seed + b + 9}: {m:+.1f}" for b, m in blocks) + f"; met on {sum(m >= 0 for _, m in blocks)} of {len(blocks)}")
    design = make_config({"randomize": {}}, variant="v1")
    controller = RobustDampingController(design, gains=table)
    factors = {c: largest_factor(controller, design, c, np.arange(225.0, 286.0, 15.0)) for c in (0.025, 0.05, 0.1)}
    print(f"{label}: largest stable command factor over 225-285 km/h (design model): {factors}")
    print(f"[{time.monotonic() - t0:.0f} s, busy host]", file=sys.stderr)


if __name__ == "__main__":
    main()
