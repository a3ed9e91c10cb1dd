"""Benchmark of the environments, beside Gymnasium's own Pendulum-v1, in one run.

    python benchmarks/bench_env.py            # table
    python benchmarks/bench_env.py --json     # one JSON object
    python benchmarks/bench_env.py --criterion-info [--seconds 3] [--sizes 1,4096]   # the criterion info fields' cost

Each env step of bogie-env covers 10 ms of simulated time (2 RK4 substeps over 300-600 km/h).
``--contention`` adds the thread figures on a busy host (two CPU-burning processes beside it).
Single envs are timed both raw (``env.unwrapped``) and as ``gym.make`` returns them (with
Gymnasium's wrappers). Vector figures include observations, rewards and infos. Ratios within
one run are the trustworthy numbers on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np

from bogie_agents.training.vec_env import BogieHuntingSB3VecEnv
import bogie_env  # noqa: F401
from bogie_env.envs.hunting_env import BogieHuntingEnv
from bogie_env.envs.vector import BogieHuntingVectorEnv
from bogie_env.simulator import PARALLEL_MIN_ROWS, default_num_threads

REPEATS = 3


def _burn(n: int) -> list[subprocess.Popen]:
    """n processes that keep a core busy each (a shared host), until terminated."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def rate_single(env, n_steps: int, repeats: int = REPEATS) -> float:
    """Steps per second of a single env with a fixed action, resets included (best of ``repeats``)."""
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(n_steps):
            _, _, term, trunc, _ = env.step(action)
            if term or trunc:
                env.reset()
        best = max(best, n_steps / (time.perf_counter() - start))
    return best


def rate_vector(venv, n_calls: int) -> float:
    venv.reset(seed=0)
    actions = np.zeros((venv.num_envs,) + venv.single_action_space.shape, dtype=np.float32)
    venv.step(actions)
    best = 0.0
    for _ in range(REPEATS):
        start = time.perf_counter()
        for _ in range(n_calls):
            venv.step(actions)
        best = max(best, n_calls * venv.num_envs / (time.perf_counter() - start))
    return best


def rate_sb3(venv, n_calls: int) -> float:
    venv.reset()
    actions = np.zeros((venv.num_envs,) + venv.action_space.shape, dtype=np.float32)
    best = 0.0
    for _ in range(REPEATS):
        start = time.perf_counter()
        for _ in range(n_calls):
            venv.step_async(actions)
            venv.step_wait()
        best = max(best, n_calls * venv.num_envs / (time.perf_counter() - start))
    return best


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


def criterion_info_table(seconds: float, sizes: list[int], variants: list[str]) -> None:
    """The cost of the per-step criterion info fields (``info.criterion``, off by default): front-end
    steps per second with them off and on, the single env and the vector env, in one run. They
    are computed when the front-end builds the info, not in ``HuntingTask.step``
    (``benchmarks/bench_v1.py`` does not see them)."""
    print(f"{'variant':>7} {'front-end':>12} {'off steps/s':>12} {'on steps/s':>12} {'off/on':>7}")
    for name in variants:
        variant = None if name == "v0" else name
        off, on = single_rate(variant, False, seconds), single_rate(variant, True, seconds)
        print(f"{name:>7} {'single':>12} {off:>12.0f} {on:>12.0f} {off / on:>7.2f}", flush=True)
        for n in sizes:
            off, on = vector_rate(variant, n, False, seconds), vector_rate(variant, n, True, seconds)
            print(f"{name:>7} {f'vector {n}':>12} {off:>12.0f} {on:>12.0f} {off / on:>7.2f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--sizes", default="1,64,1024,4096")
    parser.add_argument("--contention", action="store_true", help="also time the vector env beside CPU-burning processes")
    parser.add_argument("--criterion-info", action="store_true",
                        help="instead: the cost of the criterion info fields, steps/s with info.criterion off and on "
                             "(--sizes for the vector env, --seconds per rate)")
    parser.add_argument("--seconds", type=float, default=3.0, help="--criterion-info: seconds per rate")
    parser.add_argument("--variants", default="v0,v1", help="--criterion-info: env variants")
    args = parser.parse_args()
    if args.criterion_info:
        sizes = [int(s) for s in args.sizes.split(",")] if args.sizes != "1,64,1024,4096" else [1, 4096]
        criterion_info_table(args.seconds, sizes, args.variants.split(","))
        return
    sizes = [int(s) for s in args.sizes.split(",")]

    results: dict = {}
    bogie = gym.make("Bogie/Hunting-v0")
    pendulum = gym.make("Pendulum-v1")
    results["single_steps_per_s"] = rate_single(bogie.unwrapped, 20000)
    results["pendulum_steps_per_s"] = rate_single(pendulum.unwrapped, 20000)
    results["single_made_steps_per_s"] = rate_single(bogie, 20000)
    results["pendulum_made_steps_per_s"] = rate_single(pendulum, 20000)
    results["single_vs_pendulum"] = results["single_steps_per_s"] / results["pendulum_steps_per_s"]
    results["vector_steps_per_s"] = {}
    for n in sizes:
        venv = BogieHuntingVectorEnv(n)
        calls = max(20, 40000 // n)
        results["vector_steps_per_s"][str(n)] = rate_vector(venv, calls)
    results["sb3_vec_env_steps_per_s"] = {}
    for n in (64, 4096):
        results["sb3_vec_env_steps_per_s"][str(n)] = rate_sb3(BogieHuntingSB3VecEnv(n, seed=0), max(20, 40000 // n))
    # Threads: the vector env on the calling thread (num_threads=1) against the default, on an
    # idle host and with two CPU-burning processes beside it (a busy host).
    results["threads"] = {}
    for busy in (False, True) if args.contention else (False,):
        burners = _burn(os.cpu_count() or 1) if busy else []
        try:
            for n in (64, 4096):
                for threads in (1, None):
                    venv = BogieHuntingVectorEnv(n, num_threads=threads)
                    key = f"{'busy' if busy else 'idle'}_N{n}_{'serial' if threads == 1 else 'default'}"
                    results["threads"][key] = rate_vector(venv, max(10, 20000 // n))
        finally:
            for proc in burners:
                proc.terminate()
    results["default_num_threads"] = default_num_threads()
    results["parallel_min_rows"] = PARALLEL_MIN_ROWS
    results["simulated_seconds_per_step"] = bogie.unwrapped.config["dt"]
    results["rk4_substeps_per_step"] = bogie.unwrapped.task.n_sub
    results["cpus"] = os.cpu_count()
    results["targets"] = {
        "single >= Pendulum-v1": results["single_vs_pendulum"] >= 1.0,
        "vector N=4096 >= 2000000 env-steps/s": results["vector_steps_per_s"].get("4096", 0) >= 2e6,
    }
    if args.json:
        print(json.dumps(results, indent=2))
        return
    for key, value in results.items():
        print(f"{key:32s} {value}")


if __name__ == "__main__":
    main()
