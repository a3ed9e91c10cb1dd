"""bogie-env: the nonlinear 10-DOF high-speed bogie of Bustos et al. (2022) as a Gymnasium environment.

Importing the package is light (no Gymnasium, numba or SciPy): the model classes load on first
use, and the environment ids register with Gymnasium when it is imported
(:mod:`bogie_env.envs.registration`). It also drops compiled kernels whose source changed
(:mod:`bogie_env._numba_cache`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ._numba_cache import ensure_fresh_cache

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
