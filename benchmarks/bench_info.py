"""The cost of the per-step criterion info fields: front-end steps per second with config
``info.criterion`` on (default) and off, for the Gymnasium vector env and the single env, in
one run.

The fields (``bogie_env.envs.task.CRITERION_FIELDS``) are computed when the front-end builds
the info, not in ``HuntingTask.step`` (``benchmarks/bench_v1.py`` does not see them). On a
shared host only the ratios within one run mean something.

    PYTHONPATH=. python benchmarks/bench_info.py [--seconds 3] [--sizes 1 4096] [--variants v0 v1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_env.envs.hunting_env import BogieHuntingEnv
from bogie_env.envs.vector import BogieHuntingVectorEnv


def seconds_per_step(step, seconds: float) -> float:
    for _ in range(20):  # warm-up: kernels loaded, the loop chooser settled
        step()
    start, calls = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        step()
        calls += 1
    return (time.perf_counter() - start) / calls


def vector_rate(variant: str | None, n: int, criterion: bool, seconds: float) -> float:
    env = BogieHuntingVectorEnv(n, {"info": {"criterion": criterion}}, variant=variant)
    env.reset(seed=0)
    actions = np.zeros((n, env.single_action_space.shape[0]), dtype=np.float32)
    return n / seconds_per_step(lambda: env.step(actions), seconds)


def single_rate(variant: str | None, criterion: bool, seconds: float) -> float:
    env = BogieHuntingEnv({"info": {"criterion": criterion}}, variant=variant)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=np.float32)

    def step():
        if any(env.step(action)[2:4]):
            env.reset()

    return 1.0 / seconds_per_step(step, seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4096])
    parser.add_argument("--variants", nargs="+", default=["v0", "v1"])
    args = parser.parse_args()
    print(f"{'variant':>7} {'front-end':>12} {'off steps/s':>12} {'on steps/s':>12} {'off/on':>7}")
    for name in args.variants:
        variant = None if name == "v0" else name
        off, on = single_rate(variant, False, args.seconds), single_rate(variant, True, args.seconds)
        print(f"{name:>7} {'single':>12} {off:>12.0f} {on:>12.0f} {off / on:>7.2f}", flush=True)
        for n in args.sizes:
            off, on = vector_rate(variant, n, False, args.seconds), vector_rate(variant, n, True, args.seconds)
            print(f"{name:>7} {f'vector {n}':>12} {off:>12.0f} {on:>12.0f} {off / on:>7.2f}", flush=True)


if __name__ == "__main__":
    main()
