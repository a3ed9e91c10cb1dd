"""bogie-env: the nonlinear 10-DOF high-speed bogie of Bustos et al. (2022) as a Gymnasium environment.

Importing the package is light (no Gymnasium, numba or SciPy): the model classes load on first
use, and the environment ids register with Gymnasium when it is imported
(:mod:`bogie_env.envs.registration`).
"""

from __future__ import annotations

from typing import Any

from .envs.registration import register_envs_with_gymnasium
from .params import BogieParams, ConfigError, load_params

register_envs_with_gymnasium()

__all__ = ["BogieParams", "BogieModel", "ConfigError", "STATE_NAMES", "load_params"]
__version__ = "0.1.0"

_LAZY = {"BogieModel": "dynamics", "STATE_NAMES": "dynamics"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
