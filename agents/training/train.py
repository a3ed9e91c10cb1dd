"""Stable-Baselines3 training on the native batched VecEnv.

    bogie train --algo ppo --config configs/agents/ppo.yaml --out runs/ppo

A run folder holds: ``config.json`` (the resolved run config), TensorBoard logs (``tb/``),
checkpoints (``checkpoints/``, model plus VecNormalize statistics and, for off-policy
algorithms, the replay buffer), the best model by periodic evaluation (``best_model.zip``
with ``vecnormalize.json``, its observation statistics as plain numbers), ``final_model.zip``
(with ``final_vecnormalize.json``) and ``progress.json``. Re-running the same
command resumes from the latest readable checkpoint, so an interrupted run loses at most one
checkpoint interval; the evaluation history (``eval/evaluations.npz``) is restored, so
``best_model.zip`` is only replaced by a better evaluation. ``--no-resume`` moves an earlier run to
``OUT/previous/<UTC time>/``. The folder is locked (``OUT/.train.lock``) while a training runs.
Every key of the agent config is validated (:func:`validate_run_config`). Files the run writes
itself are written atomically. Memory: ``algo: recurrent_ppo`` (sb3-contrib's RecurrentPPO) or
``frame_stack: K`` (:mod:`bogie_agents.controllers.memory`); ``eval.seed``: every evaluation runs the same
episodes, for learning curves across training seeds (:mod:`bogie_agents.training.learning_curves`).
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np

from bogie_env.envs.config import make_config
from bogie_env.fileio import load_yaml, write_text_atomic
from bogie_env.params import CONFIG_DIR, ConfigError

from ..controllers.memory import RECURRENT_POLICY_KWARGS, check_memory_config, stack_env, unstack_env
from ..controllers.policies import NORMALISATION_FILE, save_normalisation

ALGOS = ("ppo", "sac", "td3", "recurrent_ppo")
#: The on-policy algorithms (rollouts of n_envs x n_steps, no replay buffer).
ON_POLICY = ("ppo", "recurrent_ppo")
RUN_KEYS = {"algo", "seed", "total_timesteps", "n_envs", "env_id", "env", "eval_env", "vecnormalize", "policy",
            "policy_kwargs", "hyperparams", "eval", "checkpoint", "torch_threads", "max_wall_time_s", "residual",
            "extra_envs", "frame_stack"}  # fmt: skip
EXTRA_ENV_KEYS = {"env_id", "n_envs", "env"}
#: The env id a config without ``env_id`` trains on (the configs written before v1 existed).
DEFAULT_ENV_ID = "Bogie/Hunting-v0"


def write_json_atomic(path: Path, payload: dict) -> None:
    write_text_atomic(path, json.dumps(payload, indent=2, default=float))


def load_run_config(path: str | Path | None, algo: str | None) -> dict:
    """Read ``configs/agents/<algo>.yaml`` (or a given file) and validate its keys."""
    if path is None:
        if algo is None:
            raise ConfigError(f"give --config FILE or --algo ({', '.join(ALGOS)})")
        path = CONFIG_DIR / "agents" / f"{algo}.yaml"
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"agent config file {str(path)!r} does not exist")
    config = load_yaml(path) or {}
    if not isinstance(config, dict):
        raise ConfigError(f"agent config file {str(path)!r} must hold a mapping of config keys")
    unknown = set(config) - RUN_KEYS
    if unknown:
        raise ConfigError(f"unknown key(s) {sorted(map(str, unknown))} in {path}; known keys: {sorted(RUN_KEYS)}")
    if algo is not None:
        if config.get("algo", algo) != algo:
            raise ConfigError(f"--algo {algo!r} but {path} is for {config['algo']!r}")
        config["algo"] = algo
    config.setdefault("seed", 0)
    validate_run_config(config, where=str(path))
    config["source"] = str(path)
    return config


MAX_N_ENVS = 4096  # the vector env's cap (bogie_env.envs.config.MAX_NUM_ENVS would say the same)
POLICY_KWARGS = {"net_arch", "activation_fn", "log_std_init", "ortho_init", *RECURRENT_POLICY_KWARGS}
VECNORMALIZE_KEYS = {"norm_obs": bool, "norm_reward": bool, "clip_obs": float, "clip_reward": float, "gamma": float,
                     "epsilon": float}  # fmt: skip
# hyperparameter -> (kind, low, high); kinds: "int", "float", "float|auto" (SAC's ent_coef)
HYPERPARAMS = {
    "learning_rate": ("float", 0.0, 1.0), "gamma": ("float", 0.0, 1.0), "batch_size": ("int", 1, 10**7),
    "n_steps": ("int", 1, 10**7), "n_epochs": ("int", 1, 1000), "gae_lambda": ("float", 0.0, 1.0),
    "clip_range": ("float", 0.0, 10.0), "clip_range_vf": ("float", 0.0, 10.0), "ent_coef": ("float|auto", 0.0, 10.0),
    "vf_coef": ("float", 0.0, 10.0), "max_grad_norm": ("float", 0.0, 1e6), "target_kl": ("float", 0.0, 10.0),
    "normalize_advantage": ("bool", 0, 1), "use_sde": ("bool", 0, 1), "sde_sample_freq": ("int", -1, 10**7),
    "buffer_size": ("int", 1, 10**8), "learning_starts": ("int", 0, 10**9), "tau": ("float", 0.0, 1.0),
    "train_freq": ("int", 1, 10**6), "gradient_steps": ("int", -1, 10**4), "target_update_interval": ("int", 1, 10**7),
    "target_entropy": ("float|auto", -100.0, 100.0), "policy_delay": ("int", 1, 1000),
    "target_policy_noise": ("float", 0.0, 10.0), "target_noise_clip": ("float", 0.0, 10.0),
    "action_noise_sigma": ("float", 0.0, 10.0),
}  # fmt: skip
HYPERPARAMS_OF = {
    "ppo": {"learning_rate", "gamma", "batch_size", "n_steps", "n_epochs", "gae_lambda", "clip_range", "clip_range_vf",
            "ent_coef", "vf_coef", "max_grad_norm", "target_kl", "normalize_advantage", "use_sde", "sde_sample_freq"},
    "sac": {"learning_rate", "gamma", "batch_size", "buffer_size", "learning_starts", "tau", "train_freq",
            "gradient_steps", "ent_coef", "target_update_interval", "target_entropy", "use_sde", "sde_sample_freq"},
    "td3": {"learning_rate", "gamma", "batch_size", "buffer_size", "learning_starts", "tau", "train_freq",
            "gradient_steps", "policy_delay", "target_policy_noise", "target_noise_clip", "action_noise_sigma"},
}  # fmt: skip
HYPERPARAMS_OF["recurrent_ppo"] = HYPERPARAMS_OF["ppo"]
SECTION_KEYS = {"eval": {"freq_steps", "n_envs", "episodes", "seed"}, "checkpoint": {"freq_steps"}}


def _bad(where: str, key: str, value, allowed: str) -> ConfigError:
    return ConfigError(f"agent config {where}: {key!r} = {value!r} is not allowed; allowed: {allowed}")


def _int(where: str, key: str, value, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise _bad(where, key, value, f"an integer in [{low}, {high}]")
    return value


def _float(where: str, key: str, value, low: float, high: float, low_open: bool = True) -> float:
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
    if not ok or not ((value > low) if low_open else (value >= low)) or value > high:
        raise _bad(where, key, value, f"a number in {'(' if low_open else '['}{low:g}, {high:g}]")
    return float(value)


def _mapping(where: str, key: str, value, known: set[str] | None = None) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _bad(where, key, value, "a mapping")
    unknown = set(value) - known if known is not None else set()
    if unknown:
        raise ConfigError(f"agent config {where}: unknown key(s) {sorted(map(str, unknown))} in {key!r}; "
                          f"known keys: {sorted(known)}")  # fmt: skip
    return value


def validate_run_config(config: dict, where: str = "") -> None:
    """Check every key of an agent config: name the key, the value and what is allowed."""
    where = where or "(mapping)"
    unknown = set(config) - RUN_KEYS - {"source"}
    if unknown:
        raise ConfigError(f"unknown key(s) {sorted(map(str, unknown))} in {where}; known keys: {sorted(RUN_KEYS)}")
    algo = config.get("algo")
    if algo not in ALGOS:
        raise _bad(where, "algo", algo, ", ".join(ALGOS))
    _int(where, "total_timesteps", config.get("total_timesteps"), 1, 10**10)
    _int(where, "n_envs", config.get("n_envs"), 1, MAX_N_ENVS)
    _int(where, "seed", config.get("seed", 0), 0, 2**32 - 1)
    _int(where, "torch_threads", config.get("torch_threads", 1), 1, 256)
    if config.get("max_wall_time_s") is not None:
        _float(where, "max_wall_time_s", config["max_wall_time_s"], 0.0, 1e8)
    variant = env_variant(config.get("env_id", DEFAULT_ENV_ID), where)
    for key in ("env", "eval_env"):
        try:
            make_config(_mapping(where, key, config.get(key)), variant=variant)
        except ConfigError as error:
            raise ConfigError(f"agent config {where}: in {key!r}: {error}") from None
    extra = config.get("extra_envs") or []
    if not isinstance(extra, list):
        raise _bad(where, "extra_envs", extra, "a list of {env_id, n_envs, env} mappings")
    for k, item in enumerate(extra):
        item = _mapping(where, f"extra_envs[{k}]", item, EXTRA_ENV_KEYS)
        _int(where, f"extra_envs[{k}].n_envs", item.get("n_envs"), 1, MAX_N_ENVS)
        try:
            make_config(_mapping(where, f"extra_envs[{k}].env", item.get("env")),
                        variant=env_variant(item.get("env_id"), f"{where}: extra_envs[{k}]"))  # fmt: skip
        except ConfigError as error:
            raise ConfigError(f"agent config {where}: in 'extra_envs[{k}]': {error}") from None
    if config.get("residual") is not None:
        from ..controllers.residual import check_residual_config

        residual = check_residual_config(config["residual"], where=f"agent config {where}: 'residual'")
        if residual["features"] == "washed_out" and (config.get("vecnormalize") or {}).get("norm_obs", True):
            raise _bad(where, "vecnormalize.norm_obs", (config.get("vecnormalize") or {}).get("norm_obs", True),
                       "false with residual.features 'washed_out' (its features are scaled already, and a "
                       "mean subtracted from them would make the residual nonzero at rest)")  # fmt: skip
        if residual["features"] == "washed_out" and algo not in ON_POLICY:
            raise _bad(where, "algo", algo, f"{' or '.join(ON_POLICY)} with residual.features 'washed_out' (its odd actor)")
    check_memory_config(config, where)
    pk = _mapping(where, "policy_kwargs", config.get("policy_kwargs"), POLICY_KWARGS)
    if "net_arch" in pk:
        arch = pk["net_arch"]
        layers = arch if isinstance(arch, list) else None
        if isinstance(arch, dict) and set(arch) <= {"pi", "vf", "qf"}:
            layers = [n for v in arch.values() for n in (v if isinstance(v, list) else [None])]
        if layers is None or not all(isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 4096 for n in layers):
            raise _bad(where, "policy_kwargs.net_arch", arch, "a list of layer widths in [1, 4096], or {pi: [...], vf: [...]}")
    if "activation_fn" in pk:
        _activation(pk["activation_fn"])
    if "log_std_init" in pk:
        _float(where, "policy_kwargs.log_std_init", pk["log_std_init"], -20.0, 5.0, low_open=False)
    if "ortho_init" in pk and not isinstance(pk["ortho_init"], bool):
        raise _bad(where, "policy_kwargs.ortho_init", pk["ortho_init"], "true or false")
    vn = _mapping(where, "vecnormalize", config.get("vecnormalize"), set(VECNORMALIZE_KEYS))
    for key, value in vn.items():
        if VECNORMALIZE_KEYS[key] is bool:
            if not isinstance(value, bool):
                raise _bad(where, f"vecnormalize.{key}", value, "true or false")
        else:
            _float(where, f"vecnormalize.{key}", value, 0.0, 1.0 if key == "gamma" else 1e6)
    hyper = _mapping(where, "hyperparams", config.get("hyperparams"), HYPERPARAMS_OF[algo])
    for key, value in hyper.items():
        kind, low, high = HYPERPARAMS[key]
        name = f"hyperparams.{key}"
        if kind == "int":
            _int(where, name, value, low, high)
        elif kind == "bool":
            if not isinstance(value, bool):
                raise _bad(where, name, value, "true or false")
        elif kind == "float|auto" and isinstance(value, str):
            if not (value == "auto" or (value.startswith("auto_") and _is_number(value[5:]))):
                raise _bad(where, name, value, f"'auto', 'auto_<initial value>' or a number in ({low:g}, {high:g}]")
        else:
            _float(where, name, value, low, high, low_open=key not in ("ent_coef", "learning_starts", "target_entropy"))
    if algo in ON_POLICY and "batch_size" in hyper:
        rollout = hyper.get("n_steps", 2048) * total_envs(config)
        if hyper["batch_size"] > rollout:
            raise _bad(where, "hyperparams.batch_size", hyper["batch_size"],
                       f"at most n_steps x n_envs = {rollout} (one rollout)")  # fmt: skip
    for section, known in SECTION_KEYS.items():
        values = _mapping(where, section, config.get(section), known)
        for key, value in values.items():
            if key == "seed":  # eval.seed: every evaluation runs the episodes of this seed (agents/training/learning_curves.py)
                _int(where, f"{section}.{key}", value, 0, 2**32 - 1)
                continue
            _int(where, f"{section}.{key}", value, 1, 10**10 if key == "freq_steps" else MAX_N_ENVS)


def total_envs(config: dict) -> int:
    """The training's parallel envs: ``n_envs`` plus those of ``extra_envs``."""
    return int(config["n_envs"]) + sum(int(item["n_envs"]) for item in config.get("extra_envs") or [])


def env_variant(env_id, where: str = "(mapping)") -> str | None:
    """The config variant behind a registered env id (the agent config's ``env_id``)."""
    from bogie_env.envs.registration import IDS

    if not isinstance(env_id, str) or env_id not in IDS:
        raise _bad(where, "env_id", env_id, ", ".join(IDS))
    return IDS[env_id]


def env_config_of(config: dict, key: str = "env") -> dict:
    """The full env config of a run: ``env_id``'s variant with the run's ``env`` (or ``eval_env``) merged in."""
    return make_config(config.get(key) or {}, variant=env_variant(config.get("env_id", DEFAULT_ENV_ID)))


def _residual(venv, config: dict, env_config: dict):
    """Wrap the native VecEnv in :class:`~bogie_agents.controllers.residual.ResidualVecEnv` if the run is a residual one."""
    if config.get("residual") is None:
        return venv
    from ..controllers.policies import load_policy
    from ..controllers.residual import ResidualVecEnv, WashedOutFeatures, check_residual_config

    residual = check_residual_config(config["residual"])
    features = WashedOutFeatures(env_config) if residual["features"] == "washed_out" else None
    return ResidualVecEnv(venv, load_policy(residual["baseline"], env_config), residual["scale"], features)


def _is_number(text: str) -> bool:
    try:
        return math.isfinite(float(text)) and float(text) > 0
    except ValueError:
        return False


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


def vecnormalize_kwargs(config: dict) -> dict:
    """The training VecNormalize's arguments: the config's ``vecnormalize`` over the defaults, the
    discount the learner's."""
    vn = {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, **(config.get("vecnormalize") or {})}
    vn.setdefault("gamma", (config.get("hyperparams") or {}).get("gamma", 0.99))
    return vn


def make_vec_envs(config: dict, seed: int):
    """Training and evaluation VecEnvs (native batched), normalised and monitored."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from .vec_env import BogieHuntingSB3VecEnv

    train_config, eval_config = env_config_of(config, "env"), env_config_of(config, "eval_env")
    env = _residual(BogieHuntingSB3VecEnv(config["n_envs"], train_config, seed=seed), config, train_config)
    if config.get("extra_envs"):  # further tasks (routes, say) beside the main one, rows n_envs, n_envs + 1, ...
        from .vec_env import ConcatVecEnv

        parts, offset = [env], config["n_envs"]
        for item in config["extra_envs"]:
            extra_config = make_config(item.get("env") or {}, variant=env_variant(item["env_id"]))
            parts.append(_residual(BogieHuntingSB3VecEnv(item["n_envs"], extra_config, seed=seed + offset), config,
                                   extra_config))  # fmt: skip
            offset += item["n_envs"]
        env = ConcatVecEnv(parts)
    env = VecMonitor(env)
    vn = vecnormalize_kwargs(config)
    env = VecNormalize(env, **vn)
    eval_cfg = config.get("eval") or {}
    eval_env = VecMonitor(_residual(BogieHuntingSB3VecEnv(int(eval_cfg.get("n_envs", 4)), eval_config, seed=seed + 10_000),
                                    config, eval_config))  # fmt: skip
    eval_env = VecNormalize(eval_env, training=False, norm_obs=vn["norm_obs"], norm_reward=False, clip_obs=vn["clip_obs"])
    return stack_env(env, config), stack_env(eval_env, config)  # frame_stack: the history on top of the normalisation


class RunFolderLock:
    """An exclusive ``flock`` on ``OUT/.train.lock`` for the duration of one training.

    A second training into the same folder fails at once with a :class:`ConfigError`, instead of
    two runs writing a mixed folder. The kernel drops the lock if the process dies."""

    def __init__(self, out: Path) -> None:
        self.path = out / ".train.lock"
        self.handle = None

    def __enter__(self) -> "RunFolderLock":
        import fcntl

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.handle = self.path.open("a+")
        try:
            fcntl.flock(self.handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.handle.seek(0)
            holder = self.handle.read().strip() or "another process"
            self.handle.close()
            raise ConfigError(f"run folder {str(self.path.parent)!r} is in use by another training ({holder}, lock "
                              f"{self.path.name}); wait for it to finish or give another --out") from None  # fmt: skip
        self.handle.seek(0)
        self.handle.truncate()
        self.handle.write(f"pid {os.getpid()}\n")
        self.handle.flush()
        return self

    def __exit__(self, *exc) -> None:
        import fcntl

        fcntl.flock(self.handle.fileno(), fcntl.LOCK_UN)
        self.handle.close()


def move_previous_run(out: Path) -> Path | None:
    """``--no-resume``: move what an earlier run left in ``out`` to ``out/previous/<UTC time>/``, so
    that nothing is lost and no later resume can pick up its checkpoints."""
    leftovers = [p for p in out.iterdir() if p.name not in (".train.lock", "previous")] if out.is_dir() else []
    if not leftovers:
        return None
    target = out / "previous" / time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    while target.exists():
        target = target.with_name(target.name + "_")
    target.mkdir(parents=True)
    for item in leftovers:
        os.replace(item, target / item.name)
    return target


def steps_learned(config: dict, total: int) -> int:
    """The step count SB3 will actually reach: it collects whole rollouts of ``n_envs x n_steps``
    (PPO) or ``n_envs x train_freq`` (SAC, TD3), so a budget is rounded up to a whole number of
    them. Training to this total keeps the progress bar's count and total consistent."""
    hyper = config.get("hyperparams") or {}
    unit = total_envs(config) * int(hyper.get("n_steps", 2048) if config["algo"] in ON_POLICY else hyper.get("train_freq", 1))
    return -(-total // unit) * unit


def check_timesteps(total_timesteps) -> None:
    if total_timesteps is not None and (isinstance(total_timesteps, bool) or not isinstance(total_timesteps, int)
                                        or not 1 <= total_timesteps <= 10**10):  # fmt: skip
        raise ConfigError(f"--timesteps (total_timesteps) = {total_timesteps!r} is not allowed; allowed: an integer "
                          "in [1, 1e10], or leave it out to use the config's total_timesteps")  # fmt: skip


def train(
    config: dict,
    out_dir: str | Path,
    total_timesteps: int | None = None,
    resume: bool = True,
    progress_bar: bool = True,
    verbose: int = 0,
) -> dict:
    """Train (or resume) one run; returns the summary written to ``progress.json``.

    The run folder is locked for the duration. ``resume=False`` moves an earlier run's files to
    ``OUT/previous/<time>/``. Resuming restores the evaluation history, so ``best_model.zip`` is
    only replaced by a better evaluation."""
    validate_run_config(config, where=str(config.get("source", "(mapping)")))
    check_timesteps(total_timesteps)
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is an existing file; give a folder for the run")
    with RunFolderLock(out):
        moved = None if resume else move_previous_run(out)
        if moved is not None:
            print(f"--no-resume: moved the previous run in {out} to {moved}")
        return _train_locked(config, out, total_timesteps, resume, progress_bar, verbose)


def _train_locked(config: dict, out: Path, total_timesteps: int | None, resume: bool, progress_bar: bool,
                  verbose: int) -> dict:  # fmt: skip
    import torch
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    from .learning_curves import eval_callback

    (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    algo = config["algo"]
    seed = int(config.get("seed", 0))
    total = steps_learned(config, int(config["total_timesteps"] if total_timesteps is None else total_timesteps))
    torch.set_num_threads(int(config.get("torch_threads", 1)))
    set_random_seed(seed)
    run_config = copy.deepcopy(config)
    run_config["total_timesteps"] = total
    run_config["env_id"] = config.get("env_id", DEFAULT_ENV_ID)
    run_config["env"] = env_config_of(config, "env")
    write_json_atomic(out / "config.json", run_config)

    env, eval_env = make_vec_envs(config, seed)
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO as cls
    else:
        cls = {"ppo": PPO, "sac": SAC, "td3": TD3}[algo]
    hyper = copy.deepcopy(config.get("hyperparams") or {})
    if algo == "td3" and "action_noise_sigma" in hyper:
        from stable_baselines3.common.noise import NormalActionNoise

        sigma = hyper.pop("action_noise_sigma")
        dim = env.action_space.shape[0]
        hyper["action_noise"] = NormalActionNoise(np.zeros(dim), sigma * np.ones(dim))

    model = None
    resumed_from = None
    # Resuming loads this run folder's own checkpoints (SB3 zips and pickles): the folder is trusted
    # as the user's own output; never point --out at a folder from elsewhere.
    checkpoints = _latest_checkpoint(out / "checkpoints") if resume else None
    for zip_path, steps in checkpoints or []:
        try:
            norm_path = zip_path.with_name(f"rl_model_vecnormalize_{steps}_steps.pkl")
            if norm_path.is_file():
                normalised, restack = unstack_env(env)
                env = restack(VecNormalize.load(str(norm_path), normalised.venv))
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
        model = cls(config.get("policy", "MlpLstmPolicy" if algo == "recurrent_ppo" else "MlpPolicy"), env, seed=seed, verbose=verbose, device="cpu",
                    tensorboard_log=str(out / "tb"), policy_kwargs=_policy_kwargs(config), **hyper)  # fmt: skip

    if (config.get("residual") or {}).get("features") == "washed_out":
        from ..controllers.residual import odd_actor

        from ..controllers.memory import zero_lstm_biases

        odd_actor(model)  # after a resume too: requires_grad is not saved
        zero_lstm_biases(model)
    started = time.time()
    done_before = int(model.num_timesteps)
    eval_cfg = config.get("eval") or {}
    ckpt_cfg = config.get("checkpoint") or {}
    n_envs = total_envs(config)

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

    evaluation = eval_callback(eval_env, seed=eval_cfg.get("seed"), n_eval_episodes=int(eval_cfg.get("episodes", 4)),
                              eval_freq=max(1, int(eval_cfg.get("freq_steps", 200_000)) // n_envs),
                              best_model_save_path=str(out), log_path=str(out / "eval"), deterministic=True,
                              callback_on_new_best=SaveNormalisation(), verbose=verbose)  # fmt: skip
    if resumed_from is not None:
        restore_evaluations(evaluation, out)
    callbacks = CallbackList([
        CheckpointCallback(save_freq=max(1, int(ckpt_cfg.get("freq_steps", 500_000)) // n_envs),
                           save_path=str(out / "checkpoints"), save_vecnormalize=True,
                           save_replay_buffer=algo not in ON_POLICY),
        evaluation,
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


def restore_evaluations(evaluation, out: Path) -> None:
    """Give a resumed run's EvalCallback the earlier evaluations (``eval/evaluations.npz``) and best
    mean reward, so the first evaluation after a resume replaces ``best_model.zip`` only if better."""
    history = out / "eval" / "evaluations.npz"
    best = -np.inf
    if history.is_file():
        try:
            with np.load(history, allow_pickle=False) as data:
                evaluation.evaluations_timesteps = [int(t) for t in data["timesteps"]]
                evaluation.evaluations_results = [list(map(float, r)) for r in data["results"]]
                evaluation.evaluations_length = [list(map(int, r)) for r in data["ep_lengths"]]
            if evaluation.evaluations_results:
                best = max(float(np.mean(r)) for r in evaluation.evaluations_results)
        except (OSError, KeyError, ValueError) as error:
            print(f"could not read the evaluation history {history} ({error}); keeping best_model.zip's record")
    if not np.isfinite(best) and (out / "progress.json").is_file():
        try:
            best = float(json.loads((out / "progress.json").read_text())["best_eval"]["mean_return"])
        except (ValueError, KeyError, TypeError):
            pass
    if not np.isfinite(best) and (out / "best_model.zip").is_file():
        print(f"{out / 'best_model.zip'} has no evaluation record; the next evaluation replaces it")
    evaluation.best_mean_reward = best


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
        if not 0 <= seed <= 2**32 - 1:
            raise ConfigError(f"--seed {seed} is not allowed; allowed: an integer in [0, 2**32 - 1]")
        config["seed"] = seed
    check_timesteps(timesteps)
    return train(config, out, timesteps, resume=resume, progress_bar=progress)

