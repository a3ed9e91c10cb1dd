"""Where the first (cold) compilation goes: numba compile time per kernel and signature.

    python benchmarks/compile_profile.py [env|vec|curving]

Compiles into a fresh temporary numba cache (``NUMBA_CACHE_DIR``; the tree's own cache is not
touched), runs the first steps of a single env (``env``), of a 512-row vector env on two threads
(``vec``) or one steady-curving solve (``curving``), and prints each compilation's seconds,
inclusive and exclusive of the kernels it compiled on the way, then the process's CPU and wall
seconds. Two signatures of one kernel mean two compilations (array layout, read-only flag, dtype).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

os.environ.setdefault("NUMBA_CACHE_DIR", tempfile.mkdtemp(prefix="bogie_numba_cache_"))

from numba.core import event  # noqa: E402


def run(what: str) -> None:
    import numpy as np

    if what == "env":
        from bogie_env.envs.hunting_env import BogieHuntingEnv

        env = BogieHuntingEnv()
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    elif what == "vec":
        from bogie_env.envs.vector import BogieHuntingVectorEnv

        venv = BogieHuntingVectorEnv(512, num_threads=2)
        venv.reset(seed=0)
        for _ in range(4):
            venv.step(np.zeros((512,) + venv.single_action_space.shape, dtype=np.float32))
    elif what == "curving":
        from bogie_env.analysis import curving
        from bogie_env.dynamics import BogieModel

        curving.steady_curving(BogieModel(), 7000, 0.15, 350)
    else:
        raise SystemExit(f"unknown case {what!r}; allowed: env, vec, curving")


def main() -> None:
    what = sys.argv[1] if len(sys.argv) > 1 else "env"
    recorder = event.RecordingListener()
    event.register("numba:compile", recorder)
    cpu, wall = time.process_time(), time.perf_counter()
    run(what)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    stack, rows = [], []
    for stamp, ev in recorder.buffer:
        if ev.is_start:
            stack.append([stamp, ev.data["dispatcher"].py_func.__qualname__, str(ev.data["args"])[:70], 0.0])
        else:
            start, name, args, children = stack.pop()
            seconds = stamp - start
            if stack:
                stack[-1][3] += seconds
            rows.append((seconds, seconds - children, name, args))
    for seconds, own, name, args in sorted(rows, reverse=True)[:15]:
        print(f"{seconds:8.2f} s incl {own:8.2f} s excl  {name}  {args}")
    print(f"case {what}: {cpu:.1f} CPU-s, {wall:.1f} s wall")


if __name__ == "__main__":
    main()
