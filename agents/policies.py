"""Policies by name or path: the classical controllers and trained SB3 agents, one interface.

``load_policy(spec, env_config)`` returns an object with ``observation_type``, ``reset(n, rows)``
and ``act(obs) -> actions``:

- ``passive``, ``skyhook``, ``lqr``, ``lqg``: :mod:`bogie_agents.controllers`;
- ``pretrained``: the policy shipped in ``agents/pretrained/`` (see docs/results.md);
- a path to a training run folder (``runs/NAME``) or to an SB3 ``.zip``: the saved model and,
  if present beside it, its ``vecnormalize.pkl`` observation statistics.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np

from bogie_env.params import ConfigError

from .controllers import LQGController, LQRController, PassiveController, SkyhookController

CLASSICAL = {"passive": PassiveController, "skyhook": SkyhookController, "lqr": LQRController, "lqg": LQGController}
PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"
ALGORITHMS = ("ppo", "sac", "td3")


class SB3Policy:
    """A trained SB3 model acting deterministically on normalised observations."""

    observation_type = "sensors"

    def __init__(self, model, obs_mean: np.ndarray | None, obs_var: np.ndarray | None, clip_obs: float, epsilon: float,
                 name: str, env_config: dict | None = None) -> None:  # fmt: skip
        self.model = model
        self.obs_mean, self.obs_var = obs_mean, obs_var
        self.clip_obs, self.epsilon = clip_obs, epsilon
        self.name = name
        self.env_config = env_config or {}
        self.observation_type = self.env_config.get("observation", {}).get("type", "sensors")

    def reset(self, n_envs: int, rows=None) -> None:
        pass

    def normalise(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_mean is None:
            return obs
        scaled = (obs - self.obs_mean) / np.sqrt(self.obs_var + self.epsilon)
        return np.clip(scaled, -self.clip_obs, self.clip_obs).astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        actions, _ = self.model.predict(self.normalise(np.asarray(obs, dtype=np.float32)), deterministic=True)
        return np.asarray(actions, dtype=np.float32)


def _find_model(path: Path) -> tuple[Path, Path | None, Path | None]:
    """(model .zip, vecnormalize.pkl or None, run config.json or None) from a folder or a zip."""
    if path.is_dir():
        candidates = [path / "best_model.zip", path / "final_model.zip", path / "model.zip"]
        candidates += sorted(path.glob("*.zip"))
        for candidate in candidates:
            if candidate.is_file():
                zip_path = candidate
                break
        else:
            raise ConfigError(f"policy folder {str(path)!r} holds no SB3 model (.zip)")
        folder = path
    elif path.is_file() and path.suffix == ".zip":
        zip_path, folder = path, path.parent
    else:
        raise ConfigError(
            f"policy {str(path)!r} is neither a known name ({', '.join(list(CLASSICAL) + ['pretrained'])}), "
            "a training run folder, nor an SB3 .zip file"
        )
    norm = folder / "vecnormalize.pkl"
    config = folder / "config.json"
    return zip_path, norm if norm.is_file() else None, config if config.is_file() else None


def load_sb3_policy(path: str | Path) -> SB3Policy:
    from stable_baselines3 import PPO, SAC, TD3

    zip_path, norm_path, config_path = _find_model(Path(path))
    run_config = json.loads(config_path.read_text()) if config_path else {}
    algo = str(run_config.get("algo", "")).lower()
    classes = {"ppo": PPO, "sac": SAC, "td3": TD3}
    order = [classes[algo]] if algo in classes else [PPO, SAC, TD3]
    model = None
    for cls in order:
        try:
            model = cls.load(str(zip_path), device="cpu")
            break
        except Exception:  # noqa: BLE001 - try the next algorithm class
            continue
    if model is None:
        raise ConfigError(f"could not load {str(zip_path)!r} as a PPO, SAC or TD3 model")
    mean = var = None
    clip_obs, epsilon = 10.0, 1e-8
    if norm_path is not None:
        with norm_path.open("rb") as handle:
            stats = pickle.load(handle)
        mean, var = stats.obs_rms.mean, stats.obs_rms.var
        clip_obs, epsilon = stats.clip_obs, stats.epsilon
    return SB3Policy(model, mean, var, clip_obs, epsilon, name=str(path), env_config=run_config.get("env", {}))


def load_policy(spec: str, env_config: dict):
    """A policy by name (passive, skyhook, lqr, lqg, pretrained) or path."""
    if spec in CLASSICAL:
        return CLASSICAL[spec](env_config)
    if spec == "pretrained":
        if not PRETRAINED_DIR.is_dir() or not list(PRETRAINED_DIR.glob("*.zip")):
            raise ConfigError(f"no pretrained policy in {PRETRAINED_DIR}; train one (docs/results.md)")
        return load_sb3_policy(PRETRAINED_DIR)
    path = Path(spec)
    if not path.exists():
        raise ConfigError(
            f"policy {spec!r} not found: give one of {', '.join(list(CLASSICAL) + ['pretrained'])} "
            "or the path of a training run folder or SB3 .zip"
        )
    return load_sb3_policy(path)
