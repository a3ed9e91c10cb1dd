"""The chunked map (bogie_env.distributed): backends agree bitwise, chunks resume, killed tasks retry.

The Ray tests share one local 2-CPU cluster per module and skip when the optional extra
(``pip install -e '.[distributed]'``) is not installed."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from bogie_env import distributed as dist
from bogie_env.analysis import sensitivity as sens
from bogie_env.params import ConfigError

CALLS: list = []


def _square_chunk(offset, chunk):
    CALLS.append(list(chunk))
    return [offset + x * x for x in chunk]


def _die_once(marker_dir, chunk):
    """Kills its worker process on the first attempt at each chunk (a marker file remembers)."""
    marker = Path(marker_dir) / f"attempted_{chunk[0]}"
    if not marker.exists():
        marker.write_text("1")
        os._exit(1)
    return [x + 0.5 for x in chunk]


# ---- without Ray ---------------------------------------------------------------------------
def test_local_map_keeps_chunk_order_and_json_values():
    chunks = dist.chunked(list(range(10)), 3)
    assert [len(c) for c in chunks] == [3, 3, 3, 1]
    out = dist.map_chunks(_square_chunk, chunks, shared=1, workers=1, progress=False)
    assert out == [[1 + x * x for x in c] for c in chunks]


def test_store_resumes_without_recomputing(tmp_path):
    chunks = dist.chunked(list(range(10)), 4)
    CALLS.clear()
    first = dist.map_chunks(_square_chunk, chunks, shared=0, workers=1, progress=False,
                            store=dist.ChunkStore(tmp_path, {"study": "squares"}))  # fmt: skip
    assert len(CALLS) == 3
    folder = next(p for p in tmp_path.iterdir() if p.is_dir())
    assert sorted(p.name for p in folder.iterdir()) == ["chunk_000000.json", "chunk_000001.json", "chunk_000002.json", "study.json"]
    (folder / "chunk_000001.json").unlink()  # as if interrupted before the second chunk finished
    (folder / "chunk_000002.json").write_text('{"index": 2, "res')  # a torn file is recomputed, not trusted
    CALLS.clear()
    again = dist.map_chunks(_square_chunk, chunks, shared=0, workers=1, progress=False,
                            store=dist.ChunkStore(tmp_path, {"study": "squares"}))  # fmt: skip
    assert again == first
    assert CALLS == [chunks[1], chunks[2]]
    # another definition (or other chunks) is another study: nothing is reused
    CALLS.clear()
    dist.map_chunks(_square_chunk, chunks, shared=0, workers=1, progress=False,
                    store=dist.ChunkStore(tmp_path, {"study": "squares", "v": 2}))  # fmt: skip
    assert len(CALLS) == 3
    assert not list(tmp_path.rglob("*.tmp"))


def test_backend_and_chunk_size_are_validated():
    with pytest.raises(ConfigError, match="backend 'spark'.*allowed: local, ray"):
        dist.map_chunks(_square_chunk, [[1]], backend="spark")
    with pytest.raises(ConfigError, match="chunk size 0"):
        dist.chunked([1, 2], 0)
    with pytest.raises(ConfigError, match="--backend ray"):
        dist.map_chunks(_square_chunk, [[1]], address="auto")


def test_sensitivity_store_resumes_with_identical_numbers(paper_params, tmp_path):
    scales = ([0.6, 1.0, 1.4], [0.7, 1.3])
    fresh = sens.two_parameter(paper_params, ("Csy", "Kpy"), scales, workers=1)
    stored = sens.two_parameter(paper_params, ("Csy", "Kpy"), scales, workers=1, chunk_size=2, store_dir=tmp_path)
    files = sorted(tmp_path.rglob("chunk_*.json"))
    assert len(files) == 3
    files[0].unlink()
    resumed = sens.two_parameter(paper_params, ("Csy", "Kpy"), scales, workers=1, chunk_size=2, store_dir=tmp_path)
    assert fresh.critical_speed_kmh.tobytes() == stored.critical_speed_kmh.tobytes() == resumed.critical_speed_kmh.tobytes()
    # the bogie is part of the study's key
    sens.two_parameter(paper_params.scaled(Kpx=1.1), ("Csy", "Kpy"), scales, workers=1, chunk_size=2, store_dir=tmp_path)
    assert len([p for p in tmp_path.iterdir() if p.is_dir()]) == 2


# ---- on a local Ray cluster -----------------------------------------------------------------
@pytest.fixture(scope="module")
def ray_cluster():
    ray = pytest.importorskip("ray")
    import ray.cloudpickle

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers need not import tests/
    started = not ray.is_initialized()
    dist.init_ray(None, num_cpus=2)
    yield ray
    if started:
        ray.shutdown()


def test_ray_sensitivity_grid_equals_local_bitwise(ray_cluster, paper_params):
    scales = ([0.5, 0.9, 1.3], [0.6, 1.0, 1.8])
    local = sens.two_parameter(paper_params, ("Csy", "Kpz"), scales, workers=1)
    remote = sens.two_parameter(paper_params, ("Csy", "Kpz"), scales, backend="ray", chunk_size=2)
    assert remote.critical_speed_kmh.tobytes() == local.critical_speed_kmh.tobytes()
    assert np.isfinite(local.critical_speed_kmh).all()


def test_ray_killed_task_is_retried(ray_cluster, tmp_path):
    out = dist.map_chunks(_die_once, [[1, 2], [3]], shared=str(tmp_path), backend="ray", progress=False, max_retries=2)
    assert out == [[1.5, 2.5], [3.5]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["attempted_1", "attempted_3"]


def test_ray_killed_task_without_retries_fails(ray_cluster, tmp_path):
    from ray.exceptions import WorkerCrashedError

    with pytest.raises(WorkerCrashedError):
        dist.map_chunks(_die_once, [[7]], shared=str(tmp_path), backend="ray", progress=False, max_retries=0)


def _make_env_in_worker(_shared, chunk):
    """In a fresh worker: make the env by id after one import (the driver's registrations are not there)."""
    import importlib

    first, env_id = chunk
    importlib.import_module(first)
    import gymnasium as gym

    env = gym.make(env_id)
    obs, _ = env.reset(seed=0)
    env.close()
    return [env_id, list(obs.shape)]


@pytest.mark.parametrize("first, env_id", [("bogie_env", "Bogie/Hunting-v0"), ("gymnasium", "bogie_env:Bogie/HuntingPassive-v0")])
def test_ids_register_inside_ray_workers(ray_cluster, first, env_id):
    (made,) = dist.map_chunks(_make_env_in_worker, [[first, env_id]], backend="ray", progress=False)
    assert made[0] == env_id and len(made[1]) == 1


@pytest.mark.slow
def test_ray_full_study_equals_local_bitwise(ray_cluster, paper_params, tmp_path):
    local = sens.full_study(paper_params, workers=2, progress=False)
    remote = sens.full_study(paper_params, progress=False, backend="ray", store_dir=tmp_path)
    assert local.n_points == remote.n_points == 16065
    a, b = json.dumps(local.to_dict()), json.dumps(remote.to_dict())
    assert a == b
    for g, h in zip(local.grids, remote.grids):
        assert g.critical_speed_kmh.tobytes() == h.critical_speed_kmh.tobytes()


# ---- bogie tune --------------------------------------------------------------------------------
def test_tune_trial_config_keeps_the_agent_config_and_bounds_the_budget(tmp_path):
    from bogie_agents.training.train import load_run_config
    from bogie_agents.training.tune import SEARCH_SPACES, task_config, task_id, trial_config, write_best_config

    assert task_id() == "Bogie/Hunting-v1"  # the newest registered version
    base = load_run_config(None, "ppo")
    base.pop("source")
    assert set(SEARCH_SPACES["ppo"]) <= set(base["hyperparams"])  # only keys the config already has
    trial = trial_config(base, {"learning_rate": 1e-4, "gamma": 0.98}, 5000, 60.0)
    assert trial["total_timesteps"] == 5000 and trial["max_wall_time_s"] == 60.0
    assert trial["hyperparams"]["learning_rate"] == 1e-4 and trial["hyperparams"]["n_steps"] == base["hyperparams"]["n_steps"]
    assert base["hyperparams"]["learning_rate"] == 0.0003  # the base is not modified
    assert task_config(base, "Bogie/Hunting-v0")["env"] == base["env"]
    from bogie_env.envs.config import VARIANTS

    assert task_config(base, "Bogie/HuntingPassive-v0")["eval_env"]["actuators"] == VARIANTS["passive"]["actuators"]
    best = {"hyperparams": {"learning_rate": 1e-4, "gamma": 0.98}, "mean_return": 12.5, "timesteps": 5000}
    path = write_best_config(base, best, tmp_path / "ppo_tuned.yaml", "Bogie/Hunting-v0", 2, tmp_path)
    written = load_run_config(path, "ppo")
    assert written["hyperparams"]["learning_rate"] == 1e-4 and written["total_timesteps"] == base["total_timesteps"]


def test_tune_trial_with_fewer_envs_fits_the_minibatch_in_one_rollout():
    from bogie_agents.training.train import load_run_config, validate_run_config
    from bogie_agents.training.tune import trial_config

    base = load_run_config(None, "ppo")
    base["n_envs"] = 8  # bogie tune --n-envs 8: a rollout of 8 x n_steps is smaller than the shipped batch
    trial = trial_config(base, {"learning_rate": 1e-4}, 2048, 60.0)
    assert trial["hyperparams"]["batch_size"] == min(base["hyperparams"]["batch_size"], 8 * base["hyperparams"]["n_steps"])
    validate_run_config(trial, where="trial")


def test_tune_rejects_bad_budgets():
    from bogie_agents.training.tune import check_budget

    with pytest.raises(ConfigError, match="--trials = 0"):
        check_budget(0, 1000, None, 2)
    with pytest.raises(ConfigError, match="--trial-time-s = -1"):
        check_budget(2, 1000, -1.0, 2)


@pytest.mark.slow
def test_tune_two_trials_write_a_trainable_config_and_restore(ray_cluster, tmp_path):
    from bogie_agents.training.train import load_run_config
    from bogie_agents.training.tune import tune_agent

    kwargs = dict(trials=2, timesteps=2048, trial_time_s=120.0, episodes=1, write_config=tmp_path / "ppo_tuned.yaml",
                  n_envs=8, concurrent=2)  # fmt: skip
    summary = tune_agent("ppo", tmp_path / "exp", **kwargs)
    assert summary["trials_finished"] == 2 and not summary["restored"] and not summary["interrupted"]
    assert len({json.dumps(t["hyperparams"], sort_keys=True) for t in summary["trials"]}) == 2
    config = load_run_config(tmp_path / "ppo_tuned.yaml", "ppo")
    assert config["hyperparams"]["learning_rate"] == summary["best"]["hyperparams"]["learning_rate"]
    assert summary["best"]["mean_return"] == max(t["mean_return"] for t in summary["trials"])
    again = tune_agent("ppo", tmp_path / "exp", **kwargs)  # the finished experiment is restored, not rerun
    assert again["restored"] and again["best"] == summary["best"]


@pytest.mark.slow
def test_rl_zoo_trains_on_the_registered_id(tmp_path):
    """The documented RL Zoo command, with a short budget, in a fresh process."""
    pytest.importorskip("rl_zoo3")
    import subprocess

    root = Path(__file__).resolve().parents[1]
    command = [sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", "Bogie/Hunting-v0", "--gym-packages", "bogie_env",
               "--conf-file", str(root / "configs/zoo/ppo.yml"), "-n", "256", "--eval-freq", "-1", "--seed", "0",
               "-f", str(tmp_path), "-params", "n_envs:2", "n_steps:128", "batch_size:64"]  # fmt: skip
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    model = tmp_path / "ppo" / "Bogie-Hunting-v0_1" / "Bogie-Hunting-v0.zip"
    assert model.is_file()
    from stable_baselines3 import PPO

    assert PPO.load(model, device="cpu").observation_space.shape[0] > 0


# ---- the evaluation protocol as tasks ------------------------------------------------------------
def _small_settings():
    from bogie_agents.evaluation.evaluate import ProtocolSettings

    return ProtocolSettings(v_min_kmh=300.0, v_max_kmh=400.0, grid_step_kmh=50.0, tol_kmh=25.0, duration_s=11.0,
                            ramp_seeds=1, effort_duration_s=1.0, effort_seeds=1,
                            variants={"Csy-50%": {"Csy": 0.5}, "Wpa+50%": {"Wpa": 1.5}})  # fmt: skip


def _die_then_run_units(shared, chunk):
    """An evaluation task whose worker is killed on its first attempt."""
    from bogie_agents.evaluation.evaluation_tasks import run_units

    marker_dir, inner = shared
    marker = Path(marker_dir) / f"attempted_{chunk[0][0]}_{chunk[0][1]}"
    if not marker.exists():
        marker.write_text("1")
        os._exit(1)
    return run_units(inner, chunk)


def _evaluation_equals_local(tmp_path, specs, parts, n_units):
    from bogie_agents.evaluation.evaluate import evaluate_policy
    from bogie_agents.evaluation.evaluation_tasks import evaluate_many
    from bogie_agents.controllers.policies import load_policy
    from bogie_env.envs.config import make_config

    env_config, settings = make_config(), _small_settings()
    local = [evaluate_policy(load_policy(s, env_config), env_config, settings, parts) for s in specs]
    remote = evaluate_many(specs, env_config, settings, parts, "ray", store_dir=tmp_path, progress=False)
    assert json.dumps(remote, default=float) == json.dumps(local, default=float)
    stored = sorted(tmp_path.rglob("chunk_*.json"))
    assert len(stored) == n_units
    stored[-1].unlink()
    again = evaluate_many(specs, env_config, settings, parts, "ray", store_dir=tmp_path, progress=False)
    assert json.dumps(again, default=float) == json.dumps(local, default=float)
    return remote


def test_ray_evaluation_equals_local_bitwise_and_resumes(ray_cluster, tmp_path):
    remote = _evaluation_equals_local(tmp_path, ["passive", "skyhook"], ("effort",), 2)
    assert remote[1]["effort"]["rms_force"]["frame_lateral"] > 0  # skyhook acts: not a trivial all-zero result


@pytest.mark.slow
def test_ray_evaluation_of_critical_speeds_equals_local_bitwise(ray_cluster, tmp_path):
    remote = _evaluation_equals_local(tmp_path, ["passive", "lqr"], ("critical", "robustness"), 2 * 3)
    assert list(remote[1]["robustness"]) == ["Csy-50%", "Wpa+50%"]


def test_ray_killed_evaluation_task_is_retried(ray_cluster, tmp_path):
    from bogie_agents.evaluation.evaluation_tasks import run_units
    from bogie_env.envs.config import make_config

    env_config, settings = make_config(), _small_settings()
    chunks = [[["passive", "effort", None]], [["skyhook", "effort", None]]]
    out = dist.map_chunks(_die_then_run_units, chunks, shared=(str(tmp_path), (env_config, settings)), backend="ray",
                          progress=False)  # the default max_retries, as evaluate_many uses  # fmt: skip
    assert len(list(tmp_path.glob("attempted_*"))) == 2
    for chunk, result in zip(chunks, out):
        assert json.dumps(result, default=float) == json.dumps(run_units((env_config, settings), chunk), default=float)
