"""``bogie tune``: hyperparameter search for an SB3 agent with Ray Tune and Optuna's sampler.

    bogie tune --algo ppo --trials 4 --out runs/tune_ppo

Each trial trains the algorithm with one sampled set of hyperparameters (the rest of the agent
config, ``configs/agents/<algo>.yaml``, unchanged) for a bounded budget (``--timesteps``, capped
by ``--trial-time-s`` of wall time), then scores the final model by its mean return over
deterministic evaluation episodes on the config's ``eval_env`` with fixed seeds. Ray Tune runs
the trials as tasks (one CPU each, as many at once as the cluster has CPUs, or
``--concurrent``); ``OptunaSearch`` proposes each next trial from the finished ones.

The task is the newest registered version of ``Bogie/Hunting`` (v1 once it exists, else v0); its
registered variant and config are merged under the agent config's ``env`` and ``eval_env``.

Resume: the experiment lives in ``OUT/experiment`` (Tune's state, with the searcher's) and each
trial's SB3 run in ``OUT/trials/<trial id>`` (with checkpoints). Re-running the same command
restores the experiment with ``Tuner.restore``: finished trials are kept, an interrupted trial
resumes from its last SB3 checkpoint. At the end the best trial's hyperparameters are written,
merged into the agent config, as a YAML that ``bogie train --config`` accepts (default:
``configs/agents/<algo>_tuned.yaml``) and ``OUT/best.json`` records the scores of every trial.

A trial stopped by its wall-time cap has trained for fewer steps than another, so results are
reproducible from seeds only when ``--timesteps`` is the binding budget.
"""

from __future__ import annotations

import copy
import json
import math
import time
from pathlib import Path

import yaml

from bogie_env.params import CONFIG_DIR, ConfigError

from ..controllers.policies import NORMALISATION_FILE, apply_normalisation, load_normalisation
from .train import load_run_config, train, validate_run_config, write_json_atomic

TASK_IDS = ("Bogie/Hunting-v1", "Bogie/Hunting-v0")  # newest first
METRIC = "mean_return"

# (kind, arguments): "loguniform"/"uniform" (low, high), "choice" (values)
SEARCH_SPACES: dict[str, dict[str, tuple]] = {
    "ppo": {
        "learning_rate": ("loguniform", 5e-5, 2e-3),
        "gamma": ("choice", [0.98, 0.99, 0.995, 0.999]),
        "gae_lambda": ("uniform", 0.9, 0.99),
        "clip_range": ("choice", [0.1, 0.2, 0.3]),
        "ent_coef": ("loguniform", 1e-7, 1e-2),
        "n_epochs": ("choice", [3, 5, 10]),
    },
    "sac": {
        "learning_rate": ("loguniform", 5e-5, 2e-3),
        "gamma": ("choice", [0.98, 0.99, 0.995]),
        "tau": ("choice", [0.002, 0.005, 0.01, 0.02]),
        "batch_size": ("choice", [128, 256, 512]),
    },
    "td3": {
        "learning_rate": ("loguniform", 5e-5, 2e-3),
        "gamma": ("choice", [0.98, 0.99, 0.995]),
        "batch_size": ("choice", [128, 256, 512]),
        "action_noise_sigma": ("choice", [0.05, 0.1, 0.2]),
    },
}


def task_id() -> str:
    """The newest registered Bogie/Hunting version."""
    import gymnasium as gym

    import bogie_env  # noqa: F401 - registers the ids

    return next(env_id for env_id in TASK_IDS if env_id in gym.registry)


def _deep_update(base: dict, update: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in update.items():
        out[key] = _deep_update(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else copy.deepcopy(value)
    return out


def task_config(base: dict, env_id: str) -> dict:
    """The agent config with the task's registered env config merged under ``env`` and ``eval_env``."""
    import gymnasium as gym

    from bogie_env.envs.config import VARIANTS

    kwargs = gym.registry[env_id].kwargs or {}
    registered = _deep_update(VARIANTS[kwargs["variant"]] if kwargs.get("variant") else {}, kwargs.get("config") or {})
    config = copy.deepcopy(base)
    for key in ("env", "eval_env"):
        config[key] = _deep_update(registered, config.get(key) or {})
    return config


def search_space(algo: str) -> dict:
    """The algorithm's search space as Ray Tune sampling objects."""
    from ray import tune

    space = {}
    for name, (kind, *args) in SEARCH_SPACES[algo].items():
        space[name] = {"loguniform": tune.loguniform, "uniform": tune.uniform, "choice": tune.choice}[kind](*args)
    return space


def trial_config(base: dict, hyperparams: dict, timesteps: int, trial_time_s: float | None) -> dict:
    """One trial's run config: the base with sampled hyperparameters and the trial's budget."""
    config = copy.deepcopy(base)
    config["hyperparams"] = {**(config.get("hyperparams") or {}), **_plain(hyperparams)}
    config["total_timesteps"] = int(timesteps)
    config["max_wall_time_s"] = trial_time_s
    config["checkpoint"] = {"freq_steps": max(config["n_envs"], timesteps // 4)}
    config["eval"] = {**(config.get("eval") or {}), "freq_steps": 10 * timesteps}  # scored once, at the end
    if config["algo"] != "ppo":
        hyper = config["hyperparams"]
        hyper["learning_starts"] = min(int(hyper.get("learning_starts", 0)), timesteps // 4)
    return fit_minibatch(config)


def fit_minibatch(config: dict) -> dict:
    """PPO's minibatch capped at one rollout (n_steps x n_envs), in place: ``bogie tune --n-envs``
    may run fewer envs than the agent config was written for."""
    hyper = config["hyperparams"]
    if config["algo"] == "ppo" and "batch_size" in hyper:
        hyper["batch_size"] = min(int(hyper["batch_size"]), int(hyper.get("n_steps", 2048)) * int(config["n_envs"]))
    return config


def _plain(values: dict) -> dict:
    """numpy scalars to Python numbers (for YAML and JSON)."""
    return {k: (v.item() if hasattr(v, "item") else v) for k, v in values.items()}


def score(run_dir: Path, config: dict, episodes: int, seed: int) -> float:
    """Mean undiscounted return of the final model over ``episodes`` deterministic episodes on
    the config's ``eval_env``, seeded ``seed + 20000, ...``."""
    from stable_baselines3 import PPO, SAC, TD3
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from .vec_env import BogieHuntingSB3VecEnv

    venv = VecMonitor(BogieHuntingSB3VecEnv(episodes, config.get("eval_env") or {}, seed=seed + 20_000))
    final = run_dir / f"final_{NORMALISATION_FILE}"
    venv = VecNormalize(venv, training=False, norm_reward=False)
    apply_normalisation(venv, load_normalisation(final if final.is_file() else run_dir / NORMALISATION_FILE))
    model = {"ppo": PPO, "sac": SAC, "td3": TD3}[config["algo"]].load(str(run_dir / "final_model.zip"), device="cpu")
    rewards, _ = evaluate_policy(model, venv, n_eval_episodes=episodes, deterministic=True, return_episode_rewards=True)
    venv.close()
    return float(sum(rewards) / len(rewards))


def run_trial(hyperparams: dict, base: dict, out: str, timesteps: int, trial_time_s: float | None, episodes: int) -> None:
    """The Tune trainable: train, score, report (or resume the trial's SB3 run after a restore)."""
    from ray import tune

    folder = Path(out) / "trials" / tune.get_context().get_trial_id()
    config = trial_config(base, hyperparams, timesteps, trial_time_s)
    started = time.time()
    summary = _finished(folder, timesteps)  # trained before an interruption: only the score is missing
    if summary is None:
        summary = train(config, folder, resume=True, progress_bar=False)
    value = score(folder, config, episodes, int(config.get("seed", 0)))
    tune.report({METRIC: value, "timesteps": summary["timesteps"], "trial_wall_time_s": round(time.time() - started, 1),
                 "run_dir": str(folder)})  # fmt: skip


def _finished(folder: Path, timesteps: int) -> dict | None:
    """The trial's training summary if its final model reached the budget, else None."""
    try:
        summary = json.loads((folder / "progress.json").read_text())
    except (OSError, ValueError):
        return None
    done = (folder / "final_model.zip").is_file() and int(summary.get("timesteps", 0)) >= timesteps
    return summary if done else None


def check_budget(trials: int, timesteps: int, trial_time_s: float | None, episodes: int) -> None:
    for name, value in (("--trials", trials), ("--timesteps", timesteps), ("--episodes", episodes)):
        if not isinstance(value, int) or value < 1:
            raise ConfigError(f"{name} = {value!r} must be a positive integer")
    if trial_time_s is not None and not (math.isfinite(trial_time_s) and trial_time_s > 0):
        raise ConfigError(f"--trial-time-s = {trial_time_s!r} must be a positive number of seconds")


def tune_agent(
    algo: str,
    out: str | Path,
    trials: int = 4,
    timesteps: int = 100_000,
    trial_time_s: float | None = 300.0,
    episodes: int = 4,
    config_path: str | Path | None = None,
    write_config: str | Path | None = None,
    address: str | None = None,
    concurrent: int | None = None,
    seed: int = 0,
    n_envs: int | None = None,
) -> dict:
    """Run (or resume) the experiment; write the best configuration; return a summary."""
    from bogie_env.distributed import init_ray

    check_budget(trials, timesteps, trial_time_s, episodes)
    base = load_run_config(config_path, algo)
    base.pop("source", None)
    base["seed"] = seed
    if n_envs is not None:
        base["n_envs"] = int(n_envs)
        fit_minibatch(base)
    validate_run_config(trial_config(base, {}, timesteps, trial_time_s), where="bogie tune trial config")
    env_id = task_id()
    base = task_config(base, env_id)
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    ray = init_ray(address)
    from ray import tune
    from ray.tune.search import ConcurrencyLimiter
    from ray.tune.search.optuna import OptunaSearch

    trainable = tune.with_resources(
        tune.with_parameters(run_trial, base=base, out=str(out), timesteps=timesteps, trial_time_s=trial_time_s,
                             episodes=episodes),
        {"cpu": 1},
    )  # fmt: skip
    experiment = out / "experiment"
    if tune.Tuner.can_restore(str(experiment)):
        tuner = tune.Tuner.restore(str(experiment), trainable, resume_unfinished=True, resume_errored=True)
        restored = True
    else:
        limit = concurrent or max(1, int(ray.cluster_resources().get("CPU", 1)))
        searcher = ConcurrencyLimiter(OptunaSearch(seed=seed), max_concurrent=limit)
        tuner = tune.Tuner(
            trainable,
            param_space=search_space(algo),
            tune_config=tune.TuneConfig(metric=METRIC, mode="max", search_alg=searcher, num_samples=trials),
            run_config=tune.RunConfig(name="experiment", storage_path=str(out), verbose=1),
        )  # fmt: skip
        restored = False
    results = tuner.fit()
    rows = []
    for result in results:
        if result.metrics and METRIC in result.metrics:
            rows.append({"hyperparams": _plain(result.config), METRIC: result.metrics[METRIC],
                         "timesteps": result.metrics.get("timesteps"), "run_dir": result.metrics.get("run_dir")})  # fmt: skip
    errors = [str(r.error) for r in results if r.error]
    if not rows:
        if errors:
            raise RuntimeError(f"no trial of {out} finished; errors: {errors[:3]}")
        return {"algo": algo, "env_id": env_id, "experiment": str(experiment), "restored": restored, "trials_finished": 0,
                "interrupted": True, "best": None, "config": None, "trials": []}  # fmt: skip
    best = max(rows, key=lambda row: row[METRIC])
    target = Path(write_config) if write_config else CONFIG_DIR / "agents" / f"{algo}_tuned.yaml"
    written = write_best_config(base, best, target, env_id, len(rows), out)
    summary = {"algo": algo, "env_id": env_id, "experiment": str(experiment), "restored": restored,
               "trials_finished": len(rows), "interrupted": len(rows) + len(errors) < max(len(results), 0 if restored else trials),
               "best": best, "config": str(written), "trials": rows}  # fmt: skip
    write_json_atomic(out / "best.json", summary)
    return summary


def write_best_config(base: dict, best: dict, path: Path, env_id: str, n_trials: int, experiment: Path) -> Path:
    """The agent config with the best hyperparameters, as YAML, checked by ``bogie train``'s loader."""
    config = copy.deepcopy(base)
    config["hyperparams"] = {**(config.get("hyperparams") or {}), **best["hyperparams"]}
    fit_minibatch(config)
    header = (f"# written by bogie tune: best of {n_trials} trials on {env_id}, {METRIC} "
              f"{best[METRIC]:.4g} after {best['timesteps']} steps per trial (experiment: {experiment})\n")  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(header + yaml.safe_dump(config, sort_keys=False))
    load_run_config(tmp, config["algo"])  # what bogie train will accept
    tmp.replace(path)
    return path
