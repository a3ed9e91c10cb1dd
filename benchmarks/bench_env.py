"""Benchmark of the environments, beside Gymnasium's own Pendulum-v1, in one run.

    python benchmarks/bench_env.py            # table
    python benchmarks/bench_env.py --json     # one JSON object

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

from bogie_agents.vec_env import BogieHuntingSB3VecEnv
import bogie_env  # noqa: F401
from bogie_env.envs.vector import BogieHuntingVectorEnv
from bogie_env.simulator import PARALLEL_MIN_ROWS, default_num_threads

REPEATS = 3


def _burn(n: int) -> list[subprocess.Popen]:
    """n processes that keep a core busy each (a shared host), until terminated."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def rate_single(env, n_steps: int) -> float:
    """Steps per second of a single env with a fixed action, resets included."""
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    best = 0.0
    for _ in range(REPEATS):
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--sizes", default="1,64,1024,4096")
    parser.add_argument("--contention", action="store_true", help="also time the vector env beside CPU-burning processes")
    args = parser.parse_args()
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
