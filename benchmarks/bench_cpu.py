"""CPU-time figures of the hot paths on the calling thread, for comparing two trees on a busy host.

    PYTHONPATH=TREE python benchmarks/bench_cpu.py LABEL

Prints one JSON line: RK4 interval rows/s (4096 rows, 2 substeps, straight perfect track), the
native vector env's env-steps/s at N = 4096 on the calling thread, and the critical speed's
milliseconds; and, per row of that vector env, the microseconds of the task's compiled step
and of the simulator's interval alone. Each is the best of 5 repeats of ``time.process_time`` (CPU time, which a busy
host inflates far less than wall time). Run two trees one after the other, twice, and compare
the ratios; the absolute numbers belong to the host's load of the moment.

``--interval-loop`` runs, instead, the simulator's interval of the default env (Bogie/Hunting-v0:
alignment profile, force channels) on the calling thread in a loop for ``--seconds``: the load to
profile the stepping kernels with::

    python benchmarks/bench_cpu.py --interval-loop [--rows 4096] [--seconds 10]
    perf record -o perf.data python benchmarks/bench_cpu.py --interval-loop --seconds 10 && perf report -i perf.data --sort sym

It prints the CPU nanoseconds per row of one interval (best of the loop's one-second batches).
numba's machine code has no symbols for perf: perf shows addresses, and the NRT_incref /
NRT_decref helpers are the short 'lock inc/dec' functions (disassemble the page that holds them).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

import bogie_env  # noqa: F401
from bogie_env.dynamics import BogieModel
from bogie_env.envs.vector import BogieHuntingVectorEnv
from bogie_env.simulator import BatchSimulator
from bogie_env.stability import critical_speed

from bench_dynamics import best_time  # one timing loop; CPU time here


def best(func, number: int, repeats: int = 5) -> float:
    """Best CPU seconds per call."""
    return best_time(func, number, repeats, clock=time.process_time)


def interval_loop(rows: int, seconds: float) -> None:
    """The default env's interval on the calling thread, in a loop; prints the best CPU-ns per row."""
    from bogie_env.envs.task import HuntingTask
    from bogie_env.simulator import _advance_serial

    task = HuntingTask(rows, num_threads=1)
    task.reset_rows(np.arange(rows))
    sim = task.sim
    call = (sim.rows, sim.channels, sim._track, sim.dt, sim.n_sub, sim.divisors)
    _advance_serial(*call)
    best_s = float("inf")
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        start, calls = time.process_time(), 0
        while time.process_time() - start < 1.0:
            _advance_serial(*call)
            calls += 1
        best_s = min(best_s, (time.process_time() - start) / calls)
    print(f"interval on the calling thread, {rows} rows, {sim.n_sub} substeps: {best_s / rows * 1e9:.0f} CPU-ns per row")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("label", nargs="?", default="", help="printed before the JSON line (e.g. the tree)")
    parser.add_argument("--interval-loop", action="store_true",
                        help="loop the default env's interval instead (the load for perf)")
    parser.add_argument("--rows", type=int, default=4096, help="rows of --interval-loop")
    parser.add_argument("--seconds", type=float, default=10.0, help="seconds of --interval-loop")
    args = parser.parse_args(argv)
    if args.interval_loop:
        interval_loop(args.rows, args.seconds)
        return
    n = 4096
    figures = {}
    model = BogieModel()
    x = model.equilibrium(100.0)
    x[0] += 1e-3
    sim = BatchSimulator(model, n, 0.01, (100.0, 100.0), n_sub=2, num_threads=1)
    sim.set_rows(slice(None), np.repeat(x[None], n, 0), 100.0)
    sim.advance()
    figures["rk4_serial_Mrows_s"] = n / best(sim.advance, 20) / 1e6
    venv = BogieHuntingVectorEnv(n, num_threads=1)
    venv.reset(seed=0)
    actions = np.zeros((n,) + venv.single_action_space.shape, dtype=np.float32)
    venv.step(actions)
    figures["vec4096_serial_Msteps_s"] = n / best(lambda: venv.step(actions), 10) / 1e6
    # where a vector-env step goes: the task's compiled step, and the simulator's interval alone
    task = venv.task
    figures["vec4096_task_step_us_per_row"] = best(lambda: task.step(actions), 10) / n * 1e6
    figures["vec4096_sim_advance_us_per_row"] = best(task.sim.advance, 10) / n * 1e6
    critical_speed(model)
    figures["critical_speed_ms"] = best(lambda: critical_speed(model), 50) * 1e3
    print(args.label, json.dumps({k: round(v, 4) for k, v in figures.items()}))


if __name__ == "__main__":
    main()
