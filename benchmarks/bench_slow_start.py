"""Slow start: a fresh vector env's first env steps against its steady rate, beside a busy process.

    PYTHONPATH=. python benchmarks/bench_slow_start.py                       # this tree, 3 rounds
    python benchmarks/bench_slow_start.py --trees /tmp/before . --rounds 4   # two trees, interleaved

Per round and tree, a fresh process (``PYTHONPATH=tree``) makes
``gym.make_vec("Bogie/Hunting-v0", num_envs=4096, vectorization_mode="vector_entry_point")``,
resets it, steps it once (the warm-up a user does), then times ``--steps`` (30) steps, then
``--steady`` (300) more: the ratio of the first rate to the steady one is the slow start (1.0:
none). A second process keeps the host busy throughout (``--busy``: ``spin``, a Python loop
on one core; ``env``, another 4096-env vector env stepping with its own thread pool). The trees
run one after the other within each round (a shared host drifts); compare ratios, not
absolute figures. The kernels must be in the numba cache (the benchmark runs one untimed
process per tree first).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

CHILD = r"""
import json, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
import gymnasium as gym
import bogie_env  # noqa: F401
variant, n, steps, steady = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
t0 = time.perf_counter()
env = gym.make_vec(f"Bogie/Hunting-{variant}", num_envs=n, vectorization_mode="vector_entry_point")
env.reset(seed=0)
a = np.zeros(env.action_space.shape, np.float32)
env.step(a)
t1 = time.perf_counter()
per_step = []
for _ in range(steps):
    s = time.perf_counter()
    env.step(a)
    per_step.append(time.perf_counter() - s)
s = time.perf_counter()
for _ in range(steady):
    env.step(a)
steady_s = time.perf_counter() - s
loops = env.unwrapped.task.loops
print(json.dumps({"make_reset_warm_s": t1 - t0, "first_rate": n * steps / sum(per_step),
                  "steady_rate": n * steady / steady_s, "worst_step_ms": 1e3 * max(per_step),
                  "loop_calls": loops.loop_calls, "seconds": loops.seconds}))
"""

BUSY = {
    "spin": "while True:\n    pass\n",
    "env": (
        "import warnings, numpy as np, gymnasium as gym, bogie_env\nwarnings.simplefilter('ignore')\n"
        "env = gym.make_vec('Bogie/Hunting-v0', num_envs=4096, vectorization_mode='vector_entry_point')\n"
        "env.reset(seed=1)\na = np.zeros(env.action_space.shape, np.float32)\n"
        "while True:\n    env.step(a)\n"
    ),
}


def child(tree: str, args) -> dict:
    env = {**os.environ, "PYTHONPATH": os.path.abspath(tree)}
    out = subprocess.run([sys.executable, "-c", CHILD, args.variant, str(args.n), str(args.steps), str(args.steady)],
                         env=env, capture_output=True, text=True, check=True)  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", nargs="+", default=["."])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--variant", default="v0")
    parser.add_argument("--n", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--steady", type=int, default=300)
    parser.add_argument("--busy", choices=sorted(BUSY), default="spin")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    for tree in args.trees:  # fill the numba caches, untimed
        child(tree, argparse.Namespace(**{**vars(args), "steps": 1, "steady": 1}))
    busy_tree = os.path.abspath(args.trees[-1])
    busy = subprocess.Popen([sys.executable, "-c", BUSY[args.busy]], env={**os.environ, "PYTHONPATH": busy_tree},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    runs: dict[str, list[dict]] = {tree: [] for tree in args.trees}
    try:
        time.sleep(2.0)  # the busy process is up (and, for "env", compiled from the cache)
        for r in range(args.rounds):
            for tree in args.trees:
                fig = child(tree, args)
                fig["ratio"] = fig["first_rate"] / fig["steady_rate"]
                runs[tree].append(fig)
                if not args.json:
                    print(f"round {r} {tree}: first {args.steps} steps {fig['first_rate']:.0f}/s, steady "
                          f"{fig['steady_rate']:.0f}/s, ratio {fig['ratio']:.2f}, worst step {fig['worst_step_ms']:.1f} ms, "
                          f"calls per loop {fig['loop_calls']}", flush=True)  # fmt: skip
    finally:
        busy.kill()
        busy.wait()
    summary = {tree: {"median_ratio": statistics.median(f["ratio"] for f in runs[tree]),
                      "min_ratio": min(f["ratio"] for f in runs[tree]),
                      "median_first_rate": statistics.median(f["first_rate"] for f in runs[tree])} for tree in args.trees}  # fmt: skip
    if args.json:
        print(json.dumps({"args": vars(args), "load_average": os.getloadavg(), "runs": runs, "summary": summary}))
        return
    print(f"load average at the end: {os.getloadavg()}")
    for tree, s in summary.items():
        print(f"{tree}: first/steady median {s['median_ratio']:.2f} (worst {s['min_ratio']:.2f}), "
              f"first {args.steps} steps median {s['median_first_rate']:.0f} env-steps/s")  # fmt: skip


if __name__ == "__main__":
    main()
