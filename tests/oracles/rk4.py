"""Classic RK4 over one control interval, written out in numpy: the independent reference that
the compiled integrator is checked against (tests/test_integrate.py, tests/test_curving.py)."""

from __future__ import annotations

from typing import Callable

import numpy as np


def rk4_interval(f: Callable[[float, np.ndarray], np.ndarray], x0: np.ndarray, dt: float, n_sub: int) -> np.ndarray:
    """x(dt) from x(0) = x0 in ``n_sub`` classic RK4 steps of dx/dt = f(t, x)."""
    x, h = np.array(x0, dtype=float), dt / n_sub
    for j in range(n_sub):
        t = j * h
        k1 = f(t, x)
        k2 = f(t + h / 2, x + h / 2 * k1)
        k3 = f(t + h / 2, x + h / 2 * k2)
        k4 = f(t + h, x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x
