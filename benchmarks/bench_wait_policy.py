"""OpenMP wait policy: what idle pool threads cost the calls that follow a parallel kernel.

    python benchmarks/bench_wait_policy.py                 # table, 3 rounds
    python benchmarks/bench_wait_policy.py --rounds 5 --json

numba's ``omp`` threading layer (GNU libgomp on Linux wheels) keeps its worker threads spinning
for about 3 ms after each parallel region unless ``OMP_WAIT_POLICY=PASSIVE``; ``bogie_env`` sets
PASSIVE unless the user set a value (``docs/environment.md``, Threads). Each figure is timed in
a fresh process per policy, the policies interleaved round by round (a shared host drifts):

- ``unset``: the process removes ``OMP_WAIT_POLICY`` after ``import bogie_env`` and before the
  first parallel kernel, so libgomp sees it unset (its own default: spin, then sleep);
- ``PASSIVE``: the library's default (workers sleep at once).

Figures, per process: ``rhs_*``: single-row ``BogieModel.rhs`` calls (a parallel kernel on one
row), CPU seconds of the whole process (all threads) and wall seconds per call; ``mixed_*``: one
step of a 4096-env vector env on the pool, then 200 steps of a single env on the calling thread,
per round of both; ``vector_*``: the native vector env at N = 64 and 4096 (env-steps/s, wall,
default threads). The ratios within one run are the figures to trust on a shared host.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

POLICIES = ("unset", "PASSIVE")


def _child(policy: str) -> dict:
    """The figures of one fresh process under one wait policy."""
    import numpy as np

    import bogie_env  # sets OMP_WAIT_POLICY unless set

    if policy == "unset":
        os.environ.pop("OMP_WAIT_POLICY", None)
    else:
        os.environ["OMP_WAIT_POLICY"] = policy
    import gymnasium as gym
    import numba

    from bogie_env.dynamics import BogieModel
    from bogie_env.envs.vector import BogieHuntingVectorEnv

    out: dict = {"policy": policy}
    model = BogieModel()
    x = np.zeros(20)
    model.rhs(x, 100.0)  # loads the kernel and starts the pool
    out["threading_layer"] = numba.threading_layer()
    out["seen_OMP_WAIT_POLICY"] = os.environ.get("OMP_WAIT_POLICY")
    calls = 300
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(calls):
        model.rhs(x, 100.0)
    out["rhs_cpu_ms_per_call"] = 1e3 * (time.process_time() - cpu) / calls
    out["rhs_wall_ms_per_call"] = 1e3 * (time.perf_counter() - wall) / calls

    big = BogieHuntingVectorEnv(4096, num_threads=2)
    big.reset(seed=0)
    big_actions = np.zeros((4096,) + big.single_action_space.shape, dtype=np.float32)
    big.task.loops.enabled = True
    big.task.loops.run = lambda serial, parallel, *args: parallel(*args)  # always the pool here
    single = gym.make("Bogie/Hunting-v0").unwrapped
    single.reset(seed=0)
    action = np.zeros(single.action_space.shape, dtype=np.float32)
    big.step(big_actions)
    for _ in range(200):
        single.step(action)
    rounds = 10
    cpu, wall = time.process_time(), time.perf_counter()
    for _ in range(rounds):
        big.step(big_actions)
        for _ in range(200):
            _, _, term, trunc, _ = single.step(action)
            if term or trunc:
                single.reset()
    out["mixed_cpu_ms_per_round"] = 1e3 * (time.process_time() - cpu) / rounds
    out["mixed_wall_ms_per_round"] = 1e3 * (time.perf_counter() - wall) / rounds

    for n in (64, 4096):
        venv = BogieHuntingVectorEnv(n)
        venv.reset(seed=0)
        actions = np.zeros((n,) + venv.single_action_space.shape, dtype=np.float32)
        venv.step(actions)
        steps = max(10, 20000 // n)
        best = 0.0
        for _ in range(3):
            start = time.perf_counter()
            for _ in range(steps):
                venv.step(actions)
            best = max(best, steps * n / (time.perf_counter() - start))
        out[f"vector_N{n}_steps_per_s"] = best
        out[f"vector_N{n}_pool_share"] = venv.task.loops.parallel_share if venv.task.loops.enabled else None
    return out


def _load() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--child", choices=POLICIES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(args.child)))
        return
    runs: dict[str, list[dict]] = {p: [] for p in POLICIES}
    loads = [_load()]
    for k in range(args.rounds):
        for policy in POLICIES if k % 2 == 0 else POLICIES[::-1]:
            env = dict(os.environ)
            env.pop("OMP_WAIT_POLICY", None)
            done = subprocess.run([sys.executable, __file__, "--child", policy], env=env, check=True,
                                  capture_output=True, text=True)  # fmt: skip
            runs[policy].append(json.loads(done.stdout.splitlines()[-1]))
            print(f"round {k + 1}/{args.rounds} {policy} done, load {_load()}", file=sys.stderr)
        loads.append(_load())
    keys = [k for k, v in runs["unset"][0].items() if isinstance(v, float)]
    summary = {"load_average_1_5_15": loads, "runs": runs, "median": {}, "passive_over_unset": {}}
    for key in keys:
        med = {p: statistics.median(r[key] for r in runs[p] if r[key] is not None) for p in POLICIES}
        summary["median"][key] = med
        summary["passive_over_unset"][key] = med["PASSIVE"] / med["unset"]
    if args.json:
        print(json.dumps(summary, indent=2))
        return
    print(f"threading layer {runs['PASSIVE'][0]['threading_layer']}; load average (1, 5, 15 min) per round: {loads}")
    print(f"{'figure (median of ' + str(args.rounds) + ' processes)':40s} {'unset':>12s} {'PASSIVE':>12s} {'ratio':>7s}")
    for key in keys:
        med = summary["median"][key]
        print(f"{key:40s} {med['unset']:12.4g} {med['PASSIVE']:12.4g} {summary['passive_over_unset'][key]:7.3f}")


if __name__ == "__main__":
    main()
