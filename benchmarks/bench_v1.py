"""The cost of v1: env steps per second of Bogie/Hunting-v1 against -v0, at N=1 and N=4096, in one run.

Each case steps the task (``HuntingTask``, the compiled batch step both front-ends use) with
zero actions for at least ``--seconds`` after a warm-up, episodes reset in place when done.
v1 integrates with more substeps (accuracy criterion), adds the sensor model and the
scenario's actuator health; the ratio is the cost of those.

    PYTHONPATH=. python benchmarks/bench_v1.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask


def steps_per_second(variant: str | None, n: int, seconds: float) -> tuple[float, int]:
    task = HuntingTask(n, make_config(variant=variant))
    rows = np.arange(n)
    task.seed_rows(rows, list(range(n)))
    task.reset_rows(rows)
    actions = np.zeros((n, task.action_dim))
    for _ in range(3):
        task.step(actions)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        task.step(actions)
        steps += 1
        done = np.nonzero(task.done)[0]
        if done.size:
            task.reset_rows(done)
    return steps * n / (time.perf_counter() - t0), task.n_sub


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4096])
    args = parser.parse_args()
    print(f"{'N':>6} {'v0 steps/s':>12} {'v1 steps/s':>12} {'v0/v1':>6}  substeps v0, v1")
    for n in args.sizes:
        v0, sub0 = steps_per_second(None, n, args.seconds)
        v1, sub1 = steps_per_second("v1", n, args.seconds)
        print(f"{n:>6} {v0:>12.0f} {v1:>12.0f} {v0 / v1:>6.2f}  {sub0}, {sub1}", flush=True)


if __name__ == "__main__":
    main()
