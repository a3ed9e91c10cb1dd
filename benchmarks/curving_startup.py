"""Where a warm ``bogie curving --radius 7000 --cant 0.15 --speed 350`` spends its CPU time.

    python benchmarks/curving_startup.py

CPU seconds (``time.process_time``) of each phase in one fresh process, kernels cached: the
imports of numpy, numba, scipy.linalg (which numba's first cached-kernel load imports in any
program, for its BLAS check; imported here first so that the next phase is what scipy.special
adds), scipy.special (which ``bogie_env.contact`` needs for the elliptic integrals; its root
finder is :mod:`bogie_env.rootfind`, not scipy.optimize) and the package, the
model, the root finder (with the first kernel loads), the stability check, the simulation
fallback for an unstable root (with its kernel loads), then one more full ``steady_curving``.
Run it twice: the first run after an edit compiles.
"""

from __future__ import annotations

import time

marks = [("start", time.process_time())]
import numpy as np  # noqa: E402,F401

marks.append(("numpy", time.process_time()))
import numba  # noqa: E402,F401

marks.append(("numba", time.process_time()))
import scipy.linalg  # noqa: E402,F401  (numba's first kernel load imports it: its BLAS check)

marks.append(("scipy.linalg", time.process_time()))
import scipy.special  # noqa: E402,F401

marks.append(("scipy.special", time.process_time()))
from bogie_env.analysis import curving  # noqa: E402
from bogie_env.dynamics import BogieModel  # noqa: E402

marks.append(("package", time.process_time()))
model = BogieModel()
marks.append(("model", time.process_time()))
speed = 350 / 3.6
samples = curving.curve_samples(1 / 7000, 0.15)
state, _, _ = curving.solve_steady_state(model, speed, samples)
marks.append(("root finder and first kernel loads", time.process_time()))
curving._max_real_eigenvalue(model, state, speed, samples)
marks.append(("eigenvalues", time.process_time()))
curving._steady_state_from_simulation(model, speed, samples, 1e-9)
marks.append(("simulation fallback and its kernel loads", time.process_time()))
curving.steady_curving(model, 7000, 0.15, 350)
marks.append(("steady_curving once more", time.process_time()))
print(", ".join(f"{name} {t - before:.3f}" for (name, t), (_, before) in zip(marks[1:], marks[:-1])), "(CPU s)")
