"""How long `mpc` takes per 10 ms step: one row in the v1 loop at a fixed speed, from the
protocol's large initial offset, each step's `act` (filter update, one OSQP solve) timed.

    python studies/mpc_solve_time.py                       # conicity 0.1 at 250 km/h, 10 s
    python studies/mpc_solve_time.py --conicity 0.3 --speed-kmh 140
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_agents.controllers.mpc import SensorMPC
from bogie_agents.evaluation.stability_protocol import policy_config
from bogie_env.envs.config import make_config, merge_config
from bogie_env.envs.task import HuntingTask


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--conicity", type=float, default=0.1)
    parser.add_argument("--speed-kmh", type=float, default=250.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    v = args.speed_kmh
    cfg = make_config(merge_config(make_config(variant="v1"), {
        "randomize": {}, "large_perturbation_probability": 1.0,
        "speed": {"start_kmh": v, "end_kmh": v, "accel": 0.0, "start_kmh_range": None, "end_kmh_range": None, "accel_range": None}}))  # fmt: skip
    task = HuntingTask(1, cfg)
    task.seed_rows(np.arange(1), [0])
    task.reset_rows(np.arange(1), {"conicity": args.conicity})
    controller = SensorMPC(policy_config(cfg, "sensors", args.conicity), v_range_kmh=(v - 10.0, v + 10.0))
    controller.reset(1)
    times = []
    for _ in range(int(round(args.seconds / cfg["dt"]))):
        start = time.perf_counter()
        actions = controller.act(task.obs)
        times.append(time.perf_counter() - start)
        task.step(actions)
    ms = np.array(times[1:]) * 1e3  # the first builds the QP
    print(f"mpc, conicity {args.conicity:g}, {v:g} km/h, {len(ms)} steps: median {np.median(ms):.2f} ms, "
          f"99th percentile {np.percentile(ms, 99):.2f} ms, max {ms.max():.2f} ms per step "
          f"(the step is {cfg['dt'] * 1e3:g} ms); OSQP fallbacks {controller.fallbacks}")


if __name__ == "__main__":
    main()
