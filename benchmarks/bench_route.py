"""The cost of the route variant: env steps per second of Bogie/HuntingRoute-v1 against
Bogie/Hunting-v1, in one run (alternating, so host load hits both alike).

Each case steps the task (``HuntingTask``, the compiled batch step both front-ends use) with
zero actions for ``--seconds`` after a warm-up, episodes reset in place when done. The route
variant adds, per env step, the route lookups of the track samples (binary search over the
layout's segments, at every RK4 stage) and one evaluation of the wheel-rail quantities
(``bogie_env.wheel_rail.wheelset_details``) for the reward, termination and info. Its substep
count can differ from v1's (the accuracy criterion over its own speed range), so the table
also gives the cost per substep. v1's own ramp (100 -> 600 km/h) is cheaper per step than a
constant 250 km/h (fewer saturated contacts at low speed), so the like-for-like reference is
v1 at a constant 250 km/h (``v1 const``).

    python benchmarks/bench_route.py [--seconds 5] [--sizes 1 1024] [--repeats 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask


def steps_per_second(task: HuntingTask, seconds: float) -> float:
    n = task.num_envs
    actions = np.zeros((n, task.action_dim))
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        task.step(actions)
        steps += 1
        done = np.nonzero(task.done)[0]
        if done.size:
            task.reset_rows(done)
    return steps * n / (time.perf_counter() - t0)


CONSTANT = {"speed": {"start_kmh": 250.0, "end_kmh": 250.0, "accel": 0.0}}


def make_task(variant: str | None, n: int, config: dict | None = None) -> HuntingTask:
    task = HuntingTask(n, make_config(config, variant=variant))
    rows = np.arange(n)
    task.seed_rows(rows, list(range(n)))
    task.reset_rows(rows)
    for _ in range(3):
        task.step(np.zeros((n, task.action_dim)))
    return task


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 1024])
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    print(f"{'N':>6} {'v1 steps/s':>11} {'v1 const':>9} {'route':>9} {'v1 const/route':>15} {'per substep':>12}  "
          "substeps v1, v1 const, route")  # fmt: skip
    for n in args.sizes:
        tasks = {"v1": make_task("v1", n), "const": make_task("v1", n, CONSTANT), "route": make_task("v1_route", n)}
        rate = dict.fromkeys(tasks, 0.0)
        for _ in range(args.repeats):
            for name, task in tasks.items():
                rate[name] += steps_per_second(task, args.seconds) / args.repeats
        ratio = rate["const"] / rate["route"]
        per_sub = ratio * tasks["const"].n_sub / tasks["route"].n_sub
        subs = ", ".join(str(t.n_sub) for t in tasks.values())
        print(f"{n:>6} {rate['v1']:>11.0f} {rate['const']:>9.0f} {rate['route']:>9.0f} {ratio:>15.2f} {per_sub:>12.2f}  {subs}",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
