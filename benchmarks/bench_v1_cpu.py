"""v0 and v1 env steps per CPU second on the calling thread, for comparing trees on a busy host.

    PYTHONPATH=. python benchmarks/bench_v1_cpu.py                          # this tree
    python benchmarks/bench_v1_cpu.py --trees /tmp/before . --rounds 3      # trees interleaved

Per tree and round, a fresh process (``PYTHONPATH=tree``, ``BOGIE_NUM_THREADS=1``) steps the task
(``HuntingTask`` with zero actions, as ``bench_v1.py``) of v0 and of v1 at N = 1 and 4096 and
reports, per case, env steps per CPU second (``time.process_time``, the best of ``--chunks``
chunks): on a host shared with other jobs, CPU time is inflated far less than wall time. The
trees alternate within each round; the ratios between trees and between v0 and v1 in one run
are the figures, the absolute ones belong to the host's load of the moment.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

CASES = (("v0", 1, 2000), ("v1", 1, 1000), ("v0", 4096, 20), ("v1", 4096, 6))  # variant, N, steps per chunk


def measure(chunks: int) -> dict:
    import numpy as np

    from bench_route import make_task

    out = {}
    for variant, n, steps in CASES:
        task = make_task(None if variant == "v0" else variant, n)
        actions = np.zeros((n, task.action_dim))
        best = float("inf")
        for _ in range(chunks):
            t0 = time.process_time()
            for _ in range(steps):
                task.step(actions)
                done = np.nonzero(task.done)[0]
                if done.size:
                    task.reset_rows(done)
            best = min(best, time.process_time() - t0)
        out[f"{variant}_N{n}"] = steps * n / best
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", nargs="*", default=None)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--chunks", type=int, default=7)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child or not args.trees:
        print(json.dumps(measure(args.chunks)))
        return
    here = os.path.dirname(os.path.abspath(__file__))
    runs: dict[str, list[dict]] = {t: [] for t in args.trees}
    for r in range(args.rounds):
        for tree in args.trees:
            tree_abs = os.path.abspath(tree)
            env = {**os.environ, "BOGIE_NUM_THREADS": "1", "PYTHONPATH": f"{here}:{tree_abs}"}
            res = subprocess.run([sys.executable, __file__, "--child", "--chunks", str(args.chunks)], env=env,
                                 capture_output=True, text=True, check=True)  # fmt: skip
            fig = json.loads(res.stdout.strip().splitlines()[-1])
            runs[tree].append(fig)
            print(f"round {r} load {os.getloadavg()[0]:.1f} {tree}: " + ", ".join(f"{k} {v / 1e3:.0f} k" for k, v in fig.items()),
                  flush=True)  # fmt: skip
    print("medians (k env-steps per CPU second) and v0/v1:")
    base = args.trees[0]
    for tree in args.trees:
        med = {k: statistics.median(f[k] for f in runs[tree]) for k in runs[tree][0]}
        line = ", ".join(f"{k} {v / 1e3:.0f}" for k, v in med.items())
        ratios = ", ".join(f"v0/v1 N{n} {med[f'v0_N{n}'] / med[f'v1_N{n}']:.2f}" for n in (1, 4096))
        vs = ""
        if tree != base:
            bmed = {k: statistics.median(f[k] for f in runs[base]) for k in runs[base][0]}
            vs = "; against the first tree: " + ", ".join(f"{k} {med[k] / bmed[k]:.3f}" for k in med)
        print(f"{tree}: {line}; {ratios}{vs}")


if __name__ == "__main__":
    main()
