"""bogie-env: the nonlinear 10-DOF high-speed bogie of Bustos et al. (2022) as a Gymnasium environment.

Importing the package is light (no Gymnasium, numba or SciPy): the model classes load on first
use, and the environment ids register with Gymnasium when it is imported
(:mod:`bogie_env.envs.registration`). It also drops compiled kernels whose source changed
(:mod:`bogie_env._numba_cache`), and sets ``OMP_WAIT_POLICY=PASSIVE`` unless it is set, so
numba's OpenMP threads sleep between parallel calls (``docs/environment.md``, Threads).
"""

from __future__ import annotations

import os

# Before numba's threading layer (or torch) loads OpenMP, which reads this once: idle pool threads
# sleep at once instead of spinning (GNU libgomp spins about 3 ms after each parallel region). On
# a busy host the spinning threads took the cores that the next small call needed: a single-row
# ``BogieModel.rhs`` cost 7.8 ms instead of 0.03 (docs/performance.md, Threads). A user's value is
# kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from ._numba_cache import ensure_fresh_cache  # noqa: E402

try:  # numba's cached kernels must not outlive an edit of any source they compile in
    ensure_fresh_cache(Path(__file__).parent)
except (OSError, ImportError):  # a read-only or unusual install: numba's own per-file check still applies
    pass

from .envs.registration import register_envs_with_gymnasium  # noqa: E402
from .params import BogieParams, ConfigError, load_params  # noqa: E402

register_envs_with_gymnasium()

__all__ = ["BogieParams", "BogieModel", "ConfigError", "STATE_NAMES", "load_params"]
__version__ = "0.1.0"

_LAZY = {"BogieModel": "dynamics", "STATE_NAMES": "dynamics"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
