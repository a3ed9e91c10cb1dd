"""Every linearised loop of a distilled student's loop penalty: growth bound, exact growth rate and
the frequency of the fastest-growing mode.

    python studies/distill_loop_rates.py --run runs/NAME/iterations/002

The loops are the penalty's (:class:`bogie_agents.training.loop_penalty.LoopPenalty`) with the
settings of the run's own config (``fit.loop_penalty``, or the defaults for a run without it), for
a mirrored student: a plain one or a correction on a baseline. The exact rate is the largest
log-modulus of the loop's eigenvalues over the step (1/s, below zero stable); the frequency is
that eigenvalue's angle (Hz).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bogie_agents.controllers.distilled import META_FILE, load_student
from bogie_agents.training.distill import env_config, load_config, mirror_signs
from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a distilled student's folder (a run, or one of its iterations)")
    args = parser.parse_args(argv)
    from bogie_env.envs.task import HuntingTask

    meta = json.loads((Path(args.run) / META_FILE).read_text())
    cfg = load_config(None, {k: v for k, v in meta["config"].items() if k != "fit"} | {"fit": {**meta["config"]["fit"], "loop_penalty": None}})
    settings = check_penalty_config(meta["config"]["fit"].get("loop_penalty") or {})
    env_cfg = env_config(cfg)
    student = load_student(args.run)
    if student.network.mirror is None:
        raise SystemExit(f"{args.run}: not a mirrored student; the penalty's loops linearise a mirror-odd one")
    task = HuntingTask(1, env_cfg)
    penalty = LoopPenalty(student.frames, env_cfg, settings, mirror=mirror_signs(task, student.frames.history, student.frames))
    bounds, rates = penalty.growth_bounds_of(student.network), penalty.growth_rates_of(student.network)
    fastest = [z[v, np.argmax(np.abs(z[v]))] for z in penalty.eigenvalues_of(student.network) for v in range(z.shape[0])]
    frequencies = [abs(np.angle(z)) / (2.0 * np.pi * t.dt) for z, t in zip(fastest, (t for t in penalty.terms for _ in t.variants))]
    print(f"{'km/h':>6} {'conicity':>8} {'kind':8} {'variant':28} {'bound 1/s':>9} {'rate 1/s':>9} {'mode Hz':>8}")
    for (speed, lam, kind, variant), b, r, f in zip(penalty.named_rows(), bounds, rates, frequencies):
        print(f"{speed:6.0f} {lam:8.3f} {kind:8} {variant:28} {b:9.2f} {r:9.2f} {f:8.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
