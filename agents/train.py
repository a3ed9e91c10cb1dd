"""Stable-Baselines3 training on the native batched VecEnv.

    bogie train --algo ppo --config configs/agents/ppo.yaml --out runs/ppo

A run folder holds: ``config.json`` (the resolved run config), TensorBoard logs (``tb/``),
checkpoints (``checkpoints/``, model plus VecNormalize statistics and, for off-policy
algorithms, the replay buffer), the best model by periodic evaluation (``best_model.zip``
with ``vecnormalize.json``, its observation statistics as plain numbers), ``final_model.zip``
(with ``final_vecnormalize.json``) and ``progress.json``. Re-running the same
command resumes from the latest readable checkpoint, so an interrupted run loses at most one
checkpoint interval. Files the run writes itself are written atomically.
"""

from __future__ import annotations

import copy
import json
import os
import re
import time
from pathlib import Path

import numpy as np

from bogie_env.envs.config import make_config
from bogie_env.fileio import load_yaml, write_text_atomic
from bogie_env.params import CONFIG_DIR, ConfigError

from .policies import NORMALISATION_FILE, save_normalisation

ALGOS = ("ppo", "sac", "td3")
RUN_KEYS = {"algo", "seed", "total_timesteps", "n_envs", "env", "eval_env", "vecnormalize", "policy", "policy_kwargs",
            "hyperparams", "eval", "checkpoint", "torch_threads", "max_wall_time_s"}  # fmt: skip


def write_json_atomic(path: Path, payload: dict) -> None:
    write_text_atomic(path, json.dumps(payload, indent=2, default=float))


def load_run_config(path: str | Path | None, algo: str | None) -> dict:
    """Read ``configs/agents/<algo>.yaml`` (or a given file) and validate its keys."""
    if path is None:
        if algo is None:
            raise ConfigError("give --config FILE or --algo (ppo, sac, td3)")
        path = CONFIG_DIR / "agents" / f"{algo}.yaml"
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"agent config file {str(path)!r} does not exist")
    config = load_yaml(path) or {}
    if not isinstance(config, dict):
        raise ConfigError(f"agent config file {str(path)!r} must hold a mapping of config keys")
    unknown = set(config) - RUN_KEYS
    if unknown:
        raise ConfigError(f"unknown key(s) {sorted(unknown)} in {path}; known keys: {sorted(RUN_KEYS)}")
    if algo is not None:
        if config.get("algo", algo) != algo:
            raise ConfigError(f"--algo {algo!r} but {path} is for {config['algo']!r}")
        config["algo"] = algo
    if config.get("algo") not in ALGOS:
        raise ConfigError(f"config 'algo' = {config.get('algo')!r} is not allowed; allowed: {', '.join(ALGOS)}")
    for key in ("total_timesteps", "n_envs"):
        value = config.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ConfigError(f"config {key!r} = {value!r} must be a positive integer")
    make_config(config.get("env") or {})  # validates the env part now, with its own messages
    config.setdefault("seed", 0)
    config["source"] = str(path)
    return config


def _activation(name: str):
    import torch.nn as nn

    table = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}
    if name not in table:
        raise ConfigError(f"policy_kwargs.activation_fn = {name!r}; allowed: {', '.join(table)}")
    return table[name]


def _policy_kwargs(config: dict) -> dict:
    kwargs = copy.deepcopy(config.get("policy_kwargs") or {})
    if "activation_fn" in kwargs:
        kwargs["activation_fn"] = _activation(kwargs["activation_fn"])
    return kwargs


def _latest_checkpoint(folder: Path) -> list[tuple[Path, int]]:
    """Checkpoints, newest first."""
    found = []
    for zip_path in folder.glob("rl_model_*_steps.zip"):
        match = re.match(r"rl_model_(\d+)_steps\.zip", zip_path.name)
        if match:
            found.append((int(match.group(1)), zip_path))
    return [(p, n) for n, p in sorted(found, reverse=True)]


def make_vec_envs(config: dict, seed: int):
    """Training and evaluation VecEnvs (native batched), normalised and monitored."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from .vec_env import BogieHuntingSB3VecEnv

    env = VecMonitor(BogieHuntingSB3VecEnv(config["n_envs"], config.get("env") or {}, seed=seed))
    vn = {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, **(config.get("vecnormalize") or {})}
    vn.setdefault("gamma", (config.get("hyperparams") or {}).get("gamma", 0.99))
    env = VecNormalize(env, **vn)
    eval_cfg = config.get("eval") or {}
    eval_env = VecMonitor(BogieHuntingSB3VecEnv(int(eval_cfg.get("n_envs", 4)), config.get("eval_env") or {},
                                                 seed=seed + 10_000))  # fmt: skip
    eval_env = VecNormalize(eval_env, training=False, norm_reward=False, clip_obs=vn["clip_obs"])
    return env, eval_env


def train(
    config: dict,
    out_dir: str | Path,
    total_timesteps: int | None = None,
    resume: bool = True,
    progress_bar: bool = True,
    verbose: int = 0,
) -> dict:
    """Train (or resume) one run; returns the summary written to ``progress.json``."""
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    out = Path(out_dir)
    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    algo = config["algo"]
    seed = int(config.get("seed", 0))
    total = int(total_timesteps or config["total_timesteps"])
    torch.set_num_threads(int(config.get("torch_threads", 1)))
    set_random_seed(seed)
    run_config = copy.deepcopy(config)
    run_config["total_timesteps"] = total
    run_config["env"] = make_config(config.get("env") or {})
    write_json_atomic(out / "config.json", run_config)

    env, eval_env = make_vec_envs(config, seed)
    cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[algo]
    hyper = copy.deepcopy(config.get("hyperparams") or {})
    if algo == "td3" and "action_noise_sigma" in hyper:
        from stable_baselines3.common.noise import NormalActionNoise

        sigma = hyper.pop("action_noise_sigma")
        dim = env.action_space.shape[0]
        hyper["action_noise"] = NormalActionNoise(np.zeros(dim), sigma * np.ones(dim))

    model = None
    resumed_from = None
    checkpoints = _latest_checkpoint(out / "checkpoints") if resume else None
    for zip_path, steps in checkpoints or []:
        try:
            norm_path = zip_path.with_name(f"rl_model_vecnormalize_{steps}_steps.pkl")
            if norm_path.is_file():
                env = VecNormalize.load(str(norm_path), env.venv)
            model = cls.load(str(zip_path), env=env, device="cpu", tensorboard_log=str(out / "tb"))
            buffer = zip_path.with_name(f"rl_model_replay_buffer_{steps}_steps.pkl")
            if buffer.is_file() and hasattr(model, "load_replay_buffer"):
                model.load_replay_buffer(str(buffer))
            resumed_from = str(zip_path)
            break
        except Exception as error:  # noqa: BLE001 - a torn checkpoint: fall back to the previous one
            print(f"could not resume from {zip_path.name} ({error}); trying an older checkpoint")
            model = None
    if model is None:
        model = cls(config.get("policy", "MlpPolicy"), env, seed=seed, verbose=verbose, device="cpu",
                    tensorboard_log=str(out / "tb"), policy_kwargs=_policy_kwargs(config), **hyper)  # fmt: skip

    started = time.time()
    done_before = int(model.num_timesteps)
    eval_cfg = config.get("eval") or {}
    ckpt_cfg = config.get("checkpoint") or {}
    n_envs = config["n_envs"]

    class SaveNormalisation(BaseCallback):
        """On a new best evaluation: store the VecNormalize statistics beside best_model.zip."""

        def _on_step(self) -> bool:
            save_normalisation(self.model.get_vec_normalize_env(), out / NORMALISATION_FILE)
            return True

    class WallClock(BaseCallback):
        """Stop cleanly when the run's wall-time budget is spent."""

        def __init__(self, budget_s: float | None) -> None:
            super().__init__()
            self.budget_s = budget_s

        def _on_step(self) -> bool:
            return self.budget_s is None or time.time() - started < self.budget_s

    callbacks = CallbackList([
        CheckpointCallback(save_freq=max(1, int(ckpt_cfg.get("freq_steps", 500_000)) // n_envs),
                           save_path=str(out / "checkpoints"), save_vecnormalize=True,
                           save_replay_buffer=algo != "ppo"),
        EvalCallback(eval_env, n_eval_episodes=int(eval_cfg.get("episodes", 4)),
                     eval_freq=max(1, int(eval_cfg.get("freq_steps", 200_000)) // n_envs),
                     best_model_save_path=str(out), log_path=str(out / "eval"), deterministic=True,
                     callback_on_new_best=SaveNormalisation(), verbose=verbose),
        WallClock(config.get("max_wall_time_s")),
    ])  # fmt: skip
    remaining = max(0, total - done_before)
    if remaining:
        model.learn(total_timesteps=remaining, callback=callbacks, progress_bar=progress_bar,
                    reset_num_timesteps=resumed_from is None and done_before == 0, tb_log_name=algo)  # fmt: skip
    model.save(str(out / "final_model.tmp.zip"))
    os.replace(out / "final_model.tmp.zip", out / "final_model.zip")
    save_normalisation(model.get_vec_normalize_env(), out / f"final_{NORMALISATION_FILE}")
    if not (out / NORMALISATION_FILE).exists():
        save_normalisation(model.get_vec_normalize_env(), out / NORMALISATION_FILE)
    summary = _summary(out, model, started, resumed_from, done_before)
    write_json_atomic(out / "progress.json", summary)
    env.close()
    eval_env.close()
    return summary


def _summary(out: Path, model, started: float, resumed_from: str | None, done_before: int) -> dict:
    previous = {}
    if (out / "progress.json").is_file():
        try:
            previous = json.loads((out / "progress.json").read_text())
        except json.JSONDecodeError:
            previous = {}
    evaluations = out / "eval" / "evaluations.npz"
    best = None
    if evaluations.is_file():
        data = np.load(evaluations)
        means = data["results"].mean(axis=1)
        k = int(np.argmax(means))
        best = {"timesteps": int(data["timesteps"][k]), "mean_return": float(means[k])}
    wall = time.time() - started
    return {
        "algo": type(model).__name__,
        "timesteps": int(model.num_timesteps),
        "wall_time_s": round(wall + float(previous.get("wall_time_s", 0.0)) * (resumed_from is not None), 1),
        "wall_time_this_session_s": round(wall, 1),
        "steps_this_session": int(model.num_timesteps) - done_before,
        "resumed_from": resumed_from,
        "best_eval": best,
    }


def train_from_cli(algo: str | None, config_path: str | None, out: str, timesteps: int | None, seed: int | None,
                   resume: bool, progress: bool) -> dict:  # fmt: skip
    config = load_run_config(config_path, algo)
    if seed is not None:
        config["seed"] = seed
    return train(config, out, timesteps, resume=resume, progress_bar=progress)

