"""The simulator's interval of the default env (Bogie/Hunting-v0: alignment profile, force channels),
on the calling thread, in a loop: the load to profile the stepping kernels with.

    python benchmarks/interval_loop.py [--rows 4096] [--seconds 10]
    perf record -o perf.data python benchmarks/interval_loop.py --seconds 10 && perf report -i perf.data --sort sym

Prints the CPU nanoseconds per row of one interval (best of the loop's one-second batches).
numba's machine code has no symbols for perf: perf shows addresses, and the NRT_incref /
NRT_decref helpers are the short 'lock inc/dec' functions (disassemble the page that holds them).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_env.envs.task import HuntingTask
from bogie_env.simulator import _advance_serial


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=4096)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    task = HuntingTask(args.rows, num_threads=1)
    task.reset_rows(np.arange(args.rows))
    sim = task.sim
    call = (sim.rows, sim.channels, sim._track, sim.dt, sim.n_sub)
    _advance_serial(*call)
    best = float("inf")
    end = time.perf_counter() + args.seconds
    while time.perf_counter() < end:
        start, calls = time.process_time(), 0
        while time.process_time() - start < 1.0:
            _advance_serial(*call)
            calls += 1
        best = min(best, (time.process_time() - start) / calls)
    print(f"interval on the calling thread, {args.rows} rows, {sim.n_sub} substeps: {best / args.rows * 1e9:.0f} CPU-ns per row")


if __name__ == "__main__":
    main()
