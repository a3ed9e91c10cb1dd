"""The cost of v1-v4: env steps per second of Bogie/Hunting-v1, -v2, -v3 and -v4 against -v0, at N=1 and N=4096, in one run.

Each case steps the task (``HuntingTask``, the compiled batch step both front-ends use) with
zero actions for at least ``--seconds`` after a warm-up, episodes reset in place when done.
v1 integrates with more substeps (accuracy criterion), adds the sensor model and the
scenario's actuator health; the ratio is the cost of those. v2 is v1 with the 10-stage Taylor
integrator at 2 substeps (20 right-hand sides per env step against v1's 40), v3 with the 14-stage
designed method at 1 substep (14), v4 with the 12-stage one (12).

``--cpu`` instead reports env steps per CPU second on the calling thread, for comparing trees on
a busy host: per tree and round a fresh process (``PYTHONPATH=tree``, ``BOGIE_NUM_THREADS=1``)
steps v0-v4 at N = 1 and 4096 and reports the best of ``--chunks`` chunks of
``time.process_time``. The trees alternate within each round; the ratios between trees and
between v0 and v1 in one run are the figures. A version that a tree does not have is skipped there.

``--parts`` reports, in one process on the calling thread, the CPU time per row of a v2 env step
at N = 4096 beside two pieces of it: the full scalar right-hand side (with both wheel-rail
contacts) and the frame's lateral equation alone (``dynamics.frame_lateral_accel``), which is
what the observation's frame acceleration costs since it stopped evaluating the former.

``--row-parts`` reports the CPU time per row at N = 4096 of each version's (v0-v4) compiled step on
the calling thread (run it with ``BOGIE_NUM_THREADS=1``), beside its pieces: the commands, the
simulator's interval, the task's reward, termination and observation, and the sensor model.

``--resets`` steps v4 and v0 at N = 4096 for ``--seconds`` as the default run does and reports
the share of the wall clock spent in ``reset_rows`` (episodes that end start again in place; each
row draws in Python), its time per row, and the rate without it; then the time per row of
``reset_rows`` alone, with no steps between, in batches of 1, 3 and 4096 rows (best of 5 rounds):
one row is a single env's reset, a few rows a vector env's autoreset, 4096 a vector env's reset.
With ``--cpu`` it reports only the latter, in CPU time, per tree (``--trees`` interleaved, as below).

``--single`` times the single env of each id the way a Gymnasium user steps it
(``bench_env.rate_single``: zero actions, resets included) beside Gymnasium's Pendulum-v1, raw
(``env.unwrapped``) and as ``gym.make`` returns it (with Gymnasium's wrappers), in ``--rounds``
rounds of one process. In a round the eight cases alternate in chunks of 5,000 steps and each
keeps its best chunk, so a burst of load from another process does not decide a ratio; the
ratios to Pendulum-v1 of one round are the figures.

    python benchmarks/bench_v1.py
    python benchmarks/bench_v1.py --single --rounds 2                       # single envs against Pendulum-v1
    python benchmarks/bench_v1.py --parts                                    # pieces of a v2 step, CPU time
    BOGIE_NUM_THREADS=1 python benchmarks/bench_v1.py --row-parts           # pieces of each version's step, per row
    python benchmarks/bench_v1.py --resets                                   # the resets' share at N = 4096
    python benchmarks/bench_v1.py --cpu                                      # this tree, CPU time
    python benchmarks/bench_v1.py --cpu --trees /tmp/before . --rounds 3     # trees interleaved
    python benchmarks/bench_v1.py --cpu --resets --trees /tmp/before . --rounds 3   # reset_rows alone, trees interleaved
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
import warnings

from bench_route import make_task, steps_per_second  # the same warm-up and stepping loop


def rate(variant: str | None, n: int, seconds: float) -> tuple[float, int]:
    """Env steps per second of ``variant`` at ``n`` rows, and its substeps per env step."""
    task = make_task(variant, n)
    return steps_per_second(task, seconds), task.n_sub


VERSIONS = ("v1", "v2", "v3", "v4")  # compared with v0
CASES = (("v0", 1, 2000), ("v1", 1, 1000), ("v2", 1, 1000), ("v3", 1, 1000), ("v4", 1, 1000), ("v0", 4096, 20), ("v1", 4096, 6),
         ("v2", 4096, 10), ("v3", 4096, 12), ("v4", 4096, 14))  # variant, N, steps per chunk


def reset_share(seconds: float, n: int = 4096) -> None:
    """--resets: the wall-clock share of resets while stepping v4 and v0 (module docstring)."""
    import numpy as np

    for variant in ("v4", None):
        task = make_task(variant, n)
        actions = np.zeros((n, task.action_dim))
        steps = resets = 0
        in_reset = 0.0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            task.step(actions)
            steps += 1
            done = np.nonzero(task.done)[0]
            if done.size:
                t1 = time.perf_counter()
                task.reset_rows(done)
                in_reset += time.perf_counter() - t1
                resets += done.size
        wall = time.perf_counter() - t0
        print(f"{variant or 'v0'}: {steps * n / wall / 1e6:.2f} M env-steps/s, {steps} steps, {resets} resets, resets "
              f"{in_reset / wall:.0%} of the wall clock at {in_reset / max(resets, 1) * 1e3:.3f} ms per row; without them "
              f"{steps * n / (wall - in_reset) / 1e6:.2f} M/s (load {os.getloadavg()[0]:.2f})", flush=True)  # fmt: skip
    for variant in ("v4", None):
        print(f"{variant or 'v0'} reset_rows alone, ms per row: " + ", ".join(
            f"{batch} rows {reset_cost(make_task(variant, n), batch) * 1e3:.3f}" for batch in (1, 3, n)), flush=True)  # fmt: skip


def reset_cost(task, batch: int, rounds: int = 5, rows: int = 3000, clock=time.perf_counter) -> float:
    """Seconds per row of ``task.reset_rows`` in batches of ``batch`` rows, best of ``rounds``."""
    import numpy as np

    batches = [np.arange(i, i + batch) % task.num_envs for i in range(0, max(rows, batch), batch)]
    task.reset_rows(batches[0])
    best = math.inf
    for _ in range(rounds):
        t0 = clock()
        for b in batches:
            task.reset_rows(b)
        best = min(best, (clock() - t0) / (len(batches) * batch))
    return best


def measure_resets(chunks: int, n: int = 4096) -> dict:
    """--cpu --resets: CPU microseconds per row of ``reset_rows`` alone, v4 and v0, in batches of 1,
    3 and ``n`` rows (best of ``chunks`` rounds)."""
    out = {}
    for variant in ("v4", None):
        task = make_task(variant, n)
        for batch in (1, 3, n):
            out[f"{variant or 'v0'}_reset{batch}_us"] = reset_cost(task, batch, rounds=chunks, clock=time.process_time) * 1e6
    return out


def measure(chunks: int) -> dict:
    import numpy as np

    from bench_route import make_task
    from bogie_env.envs.config import VARIANTS

    out = {}
    for variant, n, steps in CASES:
        if variant != "v0" and variant not in VARIANTS:  # a tree from before that version (--trees)
            continue
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


def step_parts(chunks: int, n: int = 4096, reps: int = 20) -> dict:
    """CPU microseconds per row (best of ``chunks``) of a v2 env step, of the full scalar
    right-hand side and of the frame's lateral equation alone, at the rows' states after warm-up."""
    import numpy as np
    from numba import njit

    from bench_route import make_task
    from bogie_env.dynamics import N_STATES, frame_lateral_accel, rhs_row_call

    @njit
    def full(x, v, q, yt, p, out, reps):
        total = 0.0
        for _ in range(reps):
            for i in range(x.shape[0]):
                rhs_row_call(x[i], v[i], q, yt[i], p[i], out)
                total += out[17]
        return total

    @njit
    def frame_equation(x, v, q, yt, p, reps):
        total = 0.0
        for _ in range(reps):
            for i in range(x.shape[0]):
                total += frame_lateral_accel(x[i], v[i], q, yt[i], p[i])
        return total

    task = make_task("v2", n)
    sim = task.sim
    x, p, yt = sim.x, sim.coefficients, sim.track_sample
    v, q, out = np.full(n, 80.0), np.zeros(4), np.empty(N_STATES)
    actions = np.zeros((n, task.action_dim))
    full(x, v, q, yt, p, out, 1)
    frame_equation(x, v, q, yt, p, 1)
    figures: dict[str, list[float]] = {"v2_step_us": [], "full_rhs_us": [], "frame_equation_us": []}
    for _ in range(chunks):
        t0 = time.process_time()
        for _ in range(5):
            task.step(actions)
        figures["v2_step_us"].append((time.process_time() - t0) / (5 * n) * 1e6)
        t0 = time.process_time()
        full(x, v, q, yt, p, out, reps)
        figures["full_rhs_us"].append((time.process_time() - t0) / (reps * n) * 1e6)
        t0 = time.process_time()
        frame_equation(x, v, q, yt, p, reps)
        figures["frame_equation_us"].append((time.process_time() - t0) / (reps * n) * 1e6)
    return {"load": os.getloadavg()[0], **{k: min(v) for k, v in figures.items()}}


def row_parts(chunks: int, n: int = 4096) -> dict:
    """CPU microseconds per row (best of ``chunks``) of the compiled step of v0 and :data:`VERSIONS` on the
    calling thread, and of its pieces: commands, the simulator's interval (integrator, lag,
    delay, track), the task (reward, termination, observation) and the sensor model."""
    import numpy as np

    from bench_route import make_task
    from bogie_env.dynamics import N_STATES
    from bogie_env.envs.task import DETAIL_NAMES, _commands, _sense_run, _step_rows, _task_run
    from bogie_env.simulator import advance_rows

    out = {"load": os.getloadavg()[0]}
    for variant in (None, *VERSIONS):
        task = make_task(variant, n)
        sim_rows, channels, track, dt, n_sub, stages, action, task_rows, cfg, scales, health, sensing = args = task._step_args()
        start, stop = np.int64(0), np.int64(n)
        scratch, details = np.empty((2, N_STATES)), np.empty((2, len(DETAIL_NAMES)))
        pieces = {
            "step": lambda: _step_rows(start, stop, *args),
            "commands": lambda: _commands(start, stop, sim_rows, channels, action, health),
            "interval": lambda: advance_rows(start, stop, sim_rows, channels, track, dt, n_sub, stages),
            "task": lambda: _task_run(start, stop, sim_rows, channels, dt, task_rows, cfg, scales, scratch, details),
            "sensors": lambda: _sense_run(start, stop, task_rows[1], sensing),
        }  # fmt: skip
        best = {k: float("inf") for k in pieces}
        for _ in range(chunks):
            for name, call in pieces.items():
                t0 = time.process_time()
                for _ in range(5):
                    call()
                best[name] = min(best[name], (time.process_time() - t0) / (5 * n) * 1e6)
        out[variant or "v0"] = {"stages per step": task.n_sub * (task.stages or 4), **{k: round(v, 3) for k, v in best.items()}}
    return out


def cpu_main(args: argparse.Namespace) -> None:
    """--cpu: env steps per CPU second, this tree or ``--trees`` interleaved in fresh processes."""
    if args.child or not args.trees:
        print(json.dumps(measure_resets(args.chunks) if args.resets else measure(args.chunks)))
        return
    here = os.path.dirname(os.path.abspath(__file__))
    runs: dict[str, list[dict]] = {t: [] for t in args.trees}
    for r in range(args.rounds):
        for tree in args.trees:
            tree_abs = os.path.abspath(tree)
            env = {**os.environ, "BOGIE_NUM_THREADS": "1", "PYTHONPATH": f"{here}:{tree_abs}"}
            res = subprocess.run([sys.executable, __file__, "--cpu", "--child", "--chunks", str(args.chunks)]
                                 + ["--resets"] * args.resets, env=env,
                                 capture_output=True, text=True, check=True)  # fmt: skip
            fig = json.loads(res.stdout.strip().splitlines()[-1])
            runs[tree].append(fig)
            figures = ", ".join(f"{k} {v:.1f}" if args.resets else f"{k} {v / 1e3:.0f} k" for k, v in fig.items())
            print(f"round {r} load {os.getloadavg()[0]:.1f} {tree}: {figures}", flush=True)
    print("medians (µs per row)" if args.resets else "medians (k env-steps per CPU second) and v0/v1:")
    base = args.trees[0]
    for tree in args.trees:
        med = {k: statistics.median(f[k] for f in runs[tree]) for k in runs[tree][0]}
        line = ", ".join(f"{k} {v:.1f}" if args.resets else f"{k} {v / 1e3:.0f}" for k, v in med.items())
        ratios = ", ".join(f"{v}/v0 N{n} {med[f'{v}_N{n}'] / med[f'v0_N{n}']:.2f}" for n in (1, 4096) for v in VERSIONS
                           if f"{v}_N{n}" in med)  # fmt: skip
        vs = ""
        if tree != base:
            bmed = {k: statistics.median(f[k] for f in runs[base]) for k in runs[base][0]}
            vs = "; against the first tree: " + ", ".join(f"{k} {med[k] / bmed[k]:.3f}" for k in med if k in bmed)
        print(f"{tree}: {line}; {ratios}{vs}")


CHUNKS = 8  # --single: interleaved chunks per case and round


def single_main(rounds: int, steps: int = 40000) -> None:
    """The single env of v0-v4 against Pendulum-v1 (module docstring)."""
    import gymnasium as gym

    import bogie_env  # noqa: F401
    from bench_env import rate_single

    warnings.filterwarnings("ignore", category=DeprecationWarning)  # gym.make's note that -v0 and -v1 have a newer version
    ids = ("Pendulum-v1", "Bogie/Hunting-v0", "Bogie/Hunting-v1", "Bogie/Hunting-v2", "Bogie/Hunting-v3", "Bogie/Hunting-v4")
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'round':>5} {'id':>18} {'raw steps/s':>12} {'/ Pendulum':>10} {'made steps/s':>13} {'/ Pendulum':>10}")
    for k in range(rounds):
        envs = {env_id: gym.make(env_id) for env_id in ids}
        cases = [(env_id, kind, env.unwrapped if kind == 0 else env) for env_id, env in envs.items() for kind in (0, 1)]
        best = {(env_id, kind): 0.0 for env_id, kind, _ in cases}
        for _ in range(CHUNKS):  # the cases alternate, each keeps its best chunk: a burst of load hits one chunk
            for env_id, kind, env in cases:
                best[env_id, kind] = max(best[env_id, kind], rate_single(env, steps // CHUNKS, repeats=1))
        rates = {env_id: (best[env_id, 0], best[env_id, 1]) for env_id in ids}
        for env in envs.values():
            env.close()
        raw0, made0 = rates["Pendulum-v1"]
        for env_id, (raw, made) in rates.items():
            print(f"{k:>5} {env_id:>18} {raw:>12.0f} {raw / raw0:>10.2f} {made:>13.0f} {made / made0:>10.2f}", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f}")
    print("pieces of a single Bogie/Hunting-v2 step, µs per call (best of five):", json.dumps(single_parts()))


def single_parts(calls: int = 10000) -> dict:
    """µs per call of the single v2 env's step and of its pieces: the task's step, the compiled
    kernel called as the task calls it, the info dict and the observation copy; and what passing
    the kernel's arguments alone costs, packed (as the task does) and one by one."""
    import gymnasium as gym
    import numpy as np

    from numba import njit

    from bogie_env.envs.task import StepArgs, _step_serial_packed

    env = gym.make("Bogie/Hunting-v2").unwrapped
    env.reset(seed=0)
    task = env.task
    action = np.zeros(env.action_space.shape, dtype=np.float32)
    kernel_args = (action[None, :], StepArgs(*task._step_args()))
    unpacked_args = (action[None, :], *task._step_args())

    @njit
    def nothing_packed(action_in, packed):  # compiled calls that do no work: what passing the arguments costs
        return 0

    @njit
    def nothing(*args):
        return 0

    nothing_packed(*kernel_args)
    nothing(*unpacked_args)

    def env_step():
        if any(env.step(action)[2:4]):
            env.reset()

    pieces = {"env.step": env_step, "task.step": lambda: task.step(action), "kernel": lambda: _step_serial_packed(*kernel_args),
              "info_dict": lambda: task.info_dict(0), "obs copy": lambda: task.obs[0].copy(),
              "dispatch packed": lambda: nothing_packed(*kernel_args), "dispatch unpacked": lambda: nothing(*unpacked_args)}  # fmt: skip
    out = {}
    for name, call in pieces.items():
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(calls):
                call()
            best = min(best, time.perf_counter() - t0)
        out[name] = round(1e6 * best / calls, 2)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4096])
    parser.add_argument("--cpu", action="store_true", help="env steps per CPU second (see the docstring)")
    parser.add_argument("--trees", nargs="*", default=None, help="--cpu: trees to compare, interleaved")
    parser.add_argument("--rounds", type=int, default=3, help="--cpu: rounds")
    parser.add_argument("--chunks", type=int, default=7, help="--cpu: chunks per case, the best kept")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--parts", action="store_true", help="CPU time of a v2 step and two pieces of it (see the docstring)")
    parser.add_argument("--single", action="store_true", help="single envs against Pendulum-v1 (see the docstring)")
    parser.add_argument("--row-parts", action="store_true", help="CPU time per row of the step's pieces (see the docstring)")
    parser.add_argument("--resets", action="store_true", help="the resets' share of the wall clock (see the docstring)")
    args = parser.parse_args()
    if args.resets and not args.cpu:
        reset_share(args.seconds)
        return
    if args.single:
        single_main(args.rounds)
        return
    if args.row_parts:
        print(json.dumps(row_parts(args.chunks)))
        return
    if args.parts:
        print(json.dumps(step_parts(args.chunks)))
        return
    if args.cpu:
        cpu_main(args)
        return
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'N':>6} {'v0 steps/s':>12} " + " ".join(f"{v + ' steps/s':>12}" for v in VERSIONS) + " "
          + " ".join(f"{v + '/v0':>6}" for v in VERSIONS) + "  substeps v0, " + ", ".join(VERSIONS))  # fmt: skip
    for n in args.sizes:
        (v0, sub0), *others = [rate(v, n, args.seconds) for v in (None, *VERSIONS)]
        print(f"{n:>6} {v0:>12.0f} " + " ".join(f"{r:>12.0f}" for r, _ in others) + " "
              + " ".join(f"{r / v0:>6.2f}" for r, _ in others) + f"  {sub0}, " + ", ".join(str(k) for _, k in others),
              flush=True)  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
