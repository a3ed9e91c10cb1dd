"""bogie-env: the nonlinear 10-DOF high-speed bogie of Bustos et al. (2022) as a Gymnasium environment."""

from .params import BogieParams, ConfigError, load_params
from .dynamics import BogieModel, STATE_NAMES

from .envs.registration import register_envs

register_envs()

__all__ = ["BogieParams", "BogieModel", "ConfigError", "STATE_NAMES", "load_params"]
__version__ = "0.1.0"
