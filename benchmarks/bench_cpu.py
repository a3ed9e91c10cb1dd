"""CPU-time figures of the hot paths on the calling thread, for comparing two trees on a busy host.

    PYTHONPATH=TREE python benchmarks/bench_cpu.py LABEL

Prints one JSON line: RK4 interval rows/s (4096 rows, 2 substeps, straight perfect track), the
native vector env's env-steps/s at N = 4096 on the calling thread, and the critical speed's
milliseconds; and, per row of that vector env, the microseconds of the task's compiled step
and of the simulator's interval alone. Each is the best of 5 repeats of ``time.process_time`` (CPU time, which a busy
host inflates far less than wall time). Run two trees one after the other, twice, and compare
the ratios; the absolute numbers belong to the host's load of the moment.
"""

from __future__ import annotations

import json
import sys
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


def main() -> None:
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
    print(sys.argv[1] if len(sys.argv) > 1 else "", json.dumps({k: round(v, 4) for k, v in figures.items()}))


if __name__ == "__main__":
    main()
