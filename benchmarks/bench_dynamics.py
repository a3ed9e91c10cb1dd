"""Benchmark of the dynamics core: right-hand side, batched RHS, RK4 stepping, critical speed.

    python benchmarks/bench_dynamics.py            # table
    python benchmarks/bench_dynamics.py --json     # one JSON object

All figures come from one run on one machine; compare ratios, not absolute numbers, across
machines (shared machines are noisy). Each figure is the best of ``--repeats`` timings.
Compilation happens before timing (the numba cache makes it a one-off per install).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from bogie_env.dynamics import BogieModel, rhs_batch_kernel, rhs_single_kernel
from bogie_env.params import BogieParams
from bogie_env.simulator import BatchSimulator
from bogie_env.stability import critical_speed, linearize


def best_time(func, number: int, repeats: int, clock=time.perf_counter) -> float:
    """Best mean seconds per call over ``repeats`` batches of ``number`` calls (``clock``: wall
    time by default; ``time.process_time`` for CPU time)."""
    best = float("inf")
    for _ in range(repeats):
        start = clock()
        for _ in range(number):
            func()
        best = min(best, (clock() - start) / number)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    params = BogieParams.paper()
    model = BogieModel(params)
    p = model.coefficients
    x = model.equilibrium(100.0)
    x[0] += 1e-3
    q, yt, out = np.zeros(4), np.zeros(2), np.empty(20)
    rhs_single_kernel(x, 100.0, q, yt, p, out)
    single = best_time(lambda: rhs_single_kernel(x, 100.0, q, yt, p, out), 20000, args.repeats)

    results: dict = {"rhs_single_us": single * 1e6}
    for n in (1024, 4096):
        xs = np.repeat(x[None], n, axis=0)
        vs, qs, yts, outs = np.full(n, 100.0), np.zeros((n, 4)), np.zeros((n, 2)), np.empty((n, 20))
        rhs_batch_kernel(xs, vs, qs, yts, p, outs)
        t = best_time(lambda: rhs_batch_kernel(xs, vs, qs, yts, p, outs), 200, args.repeats)
        results[f"rhs_batch{n}_states_per_s"] = n / t

    # RK4 stepping through the simulator's driver: one 10-ms interval in 2 substeps (the step
    # chosen for 300-600 km/h); 4096 rows on the thread pool and on the calling thread
    for n, threads in ((1, 1), (4096, None), (4096, 1)):
        sim = BatchSimulator(model, n, 0.01, (100.0, 100.0), n_sub=2, num_threads=threads)
        sim.set_rows(slice(None), np.repeat(x[None], n, axis=0), 100.0)
        sim.advance()
        t = best_time(sim.advance, 2000 if n == 1 else 50, args.repeats)
        results[f"rk4_interval_batch{n}{'_serial' if threads == 1 and n > 1 else ''}_steps_per_s"] = n / t

    lin = linearize(model)
    results["critical_speed_ms"] = best_time(lambda: critical_speed(model), 50, args.repeats) * 1e3
    results["critical_speed_search_only_ms"] = best_time(lambda: critical_speed(linearization=lin), 50, args.repeats) * 1e3
    results["model_build_ms"] = best_time(lambda: BogieModel(params.scaled(Csy=1.1)), 50, args.repeats) * 1e3
    results["linearize_ms"] = best_time(lambda: linearize(model), 50, args.repeats) * 1e3
    results["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(), "processor": platform.machine()}
    targets = {"rhs_single_us": ("<=", 1.0), "rhs_batch4096_states_per_s": (">=", 20e6), "critical_speed_ms": ("<=", 1.0)}
    results["targets"] = {
        key: {"target": f"{op} {value:g}", "met": bool(results[key] <= value if op == "<=" else results[key] >= value)}
        for key, (op, value) in targets.items()
    }
    if args.json:
        print(json.dumps(results, indent=2))
        return
    for key, value in results.items():
        if isinstance(value, float):
            print(f"{key:40s} {value:14.4g}")
    print("targets:", json.dumps(results["targets"]))


if __name__ == "__main__":
    main()
