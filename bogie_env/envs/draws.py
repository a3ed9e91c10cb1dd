"""numpy ``Generator`` draws at a reset's call cost, bit for bit.

A reset draws a dozen scalars per row from the row's own ``Generator``. Its ``uniform`` and
``normal`` spend most of their time parsing and broadcasting their arguments, far more than
``random`` itself takes (``docs/performance.md``, "Cheaper draws"). numpy computes ``uniform(low, high)`` as
``low + (high - low) * random()`` and ``normal(0, scale)`` as ``0 + scale * standard_normal()``;
the functions here do the same arithmetic on the same stream, so the draws and the stream's
state after them are identical (``tests/test_draws.py`` checks both against numpy). Arguments
that numpy rejects go to numpy, which raises its own error.
"""

from __future__ import annotations

import math

import numpy as np


def uniform(rng: np.random.Generator, low: float, high: float) -> float:
    """``float(rng.uniform(low, high))``."""
    width = high - low
    if 0.0 <= width < math.inf:  # NaN and inf fail: numpy's error
        return low + width * rng.random()
    return float(rng.uniform(low, high))


def uniform_array(rng: np.random.Generator, low: float, high: float, size: int) -> np.ndarray:
    """``rng.uniform(low, high, size)``."""
    width = high - low
    if 0.0 <= width < math.inf:
        return low + width * rng.random(size)
    return rng.uniform(low, high, size)


def centred_normal(rng: np.random.Generator, scales: np.ndarray) -> np.ndarray:
    """``rng.normal(0.0, scales)`` for a 1-d array ``scales``: one draw per entry, in order."""
    if scales.size and scales.min() >= 0.0:  # NaN fails: numpy's error
        return scales * rng.standard_normal(scales.size) + 0.0  # + 0.0 as numpy's loc: -0.0 becomes 0.0
    return rng.normal(0.0, scales)
