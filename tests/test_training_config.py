"""Training runs: every run-config key validated, named errors for bad step counts, seeds and
folders, locked run folders, and a resumed run that keeps its evaluation history."""

import numpy as np
import pytest

from bogie_agents.cli import main as cli_main
from bogie_env.params import ConfigError


def _run_config(**changes):
    config = {"algo": "ppo", "seed": 0, "total_timesteps": 2048, "n_envs": 4,
              "hyperparams": {"n_steps": 128, "batch_size": 256}, "eval": {"freq_steps": 1024},
              "checkpoint": {"freq_steps": 1024}}  # fmt: skip
    for key, value in changes.items():
        section, _, sub = key.partition(".")
        if sub:
            config.setdefault(section, {})[sub] = value
        else:
            config[key] = value
    return config


@pytest.mark.parametrize(
    "changes, message",
    [({"total_timesteps": 0}, "'total_timesteps' = 0 is not allowed; allowed: an integer"),
     ({"n_envs": 10**6}, r"'n_envs' = 1000000 is not allowed; allowed: an integer in \[1, 4096\]"),
     ({"seed": -1}, "'seed' = -1 is not allowed"),
     ({"checkpoint.freq_steps": -5}, "'checkpoint.freq_steps' = -5 is not allowed"),
     ({"eval.freq_steps": 0}, "'eval.freq_steps' = 0 is not allowed"),
     ({"eval.every": 3}, r"unknown key\(s\) \['every'\] in 'eval'"),
     ({"max_wall_time_s": -1}, "'max_wall_time_s' = -1 is not allowed; allowed: a number in"),
     ({"torch_threads": 0}, "'torch_threads' = 0 is not allowed"),
     ({"hyperparams.learning_rate": -3e-4}, "'hyperparams.learning_rate' = -0.0003 is not allowed"),
     ({"hyperparams.gamma": 1.5}, "'hyperparams.gamma' = 1.5 is not allowed"),
     ({"hyperparams.n_steps": 0}, "'hyperparams.n_steps' = 0 is not allowed"),
     ({"hyperparams.batch_size": 10**6}, r"at most n_steps x n_envs = 512"),
     ({"hyperparams.buffer_size": 100}, r"unknown key\(s\) \['buffer_size'\] in 'hyperparams'"),
     ({"hyperparams.ent_coef": "sometimes"}, "'hyperparams.ent_coef' = 'sometimes' is not allowed"),
     ({"policy": "CnnPolicy"}, "'policy' = 'CnnPolicy' is not allowed; allowed: MlpPolicy"),
     ({"policy_kwargs.net_arch": [64, -1]}, "'policy_kwargs.net_arch' = \\[64, -1\\] is not allowed"),
     ({"policy_kwargs.activation_fn": "sigmoid"}, "activation_fn = 'sigmoid'; allowed: tanh, relu, elu"),
     ({"policy_kwargs.dropout": 0.1}, r"unknown key\(s\) \['dropout'\] in 'policy_kwargs'"),
     ({"vecnormalize.clip_obs": -1}, "'vecnormalize.clip_obs' = -1 is not allowed"),
     ({"vecnormalize.norm_obs": "yes"}, "'vecnormalize.norm_obs' = 'yes' is not allowed; allowed: true or false"),
     ({"env": {"speed": {"accel": -5}}}, "in 'env': config 'speed.accel' = -5 is not allowed"),
     ({"eval_env": {"dt": 0}}, "in 'eval_env': config 'dt' = 0 is not allowed"),
     ({"algo": "dqn"}, "'algo' = 'dqn' is not allowed; allowed: ppo, sac, td3")],
)  # fmt: skip
def test_every_agent_config_key_is_validated(changes, message):
    from bogie_agents.training.train import validate_run_config

    with pytest.raises(ConfigError, match=message):
        validate_run_config(_run_config(**changes), "test.yaml")


def test_shipped_agent_configs_are_valid():
    from bogie_agents.training.train import load_run_config

    for algo in ("ppo", "sac", "td3"):
        load_run_config(None, algo)


@pytest.mark.parametrize("timesteps", [0, -5])
def test_bad_timesteps_are_named_errors(tmp_path, timesteps, capsys):
    from bogie_agents.training.train import train

    with pytest.raises(ConfigError, match=f"--timesteps \\(total_timesteps\\) = {timesteps} is not allowed"):
        train(_run_config(), tmp_path / "run", total_timesteps=timesteps)
    assert cli_main(["train", "--algo", "ppo", "--out", str(tmp_path / "run"), "--timesteps", str(timesteps)]) == 2
    assert "--timesteps" in capsys.readouterr().err
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_cli_train_names_seed_and_out(tmp_path, capsys):
    assert cli_main(["train", "--algo", "ppo", "--out", str(tmp_path / "r"), "--seed", "-1"]) == 2
    assert "--seed" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert cli_main(["train", "--algo", "ppo", "--out", str(tmp_path / "file"), "--timesteps", "64"]) == 2
    assert "--out" in capsys.readouterr().err


def test_progress_total_is_the_step_count_sb3_reaches():
    from bogie_agents.training.train import steps_learned

    assert steps_learned(_run_config(n_envs=64, **{"hyperparams.n_steps": 256}), 50_000) == 65_536
    assert steps_learned(_run_config(n_envs=64, **{"hyperparams.n_steps": 256}), 65_536) == 65_536
    assert steps_learned({"algo": "sac", "n_envs": 16, "hyperparams": {}}, 1000) == 1008


def test_a_second_training_into_a_locked_folder_fails(tmp_path):
    from bogie_agents.training.train import RunFolderLock, train

    with RunFolderLock(tmp_path / "run"):
        with pytest.raises(ConfigError, match="is in use by another training .*pid"):
            train(_run_config(), tmp_path / "run")
    with RunFolderLock(tmp_path / "run"):  # released: can be taken again
        pass


def test_no_resume_moves_the_old_run_aside(tmp_path):
    from bogie_agents.training.train import _latest_checkpoint, move_previous_run

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "rl_model_1024_steps.zip").write_bytes(b"old")
    (run / "best_model.zip").write_bytes(b"old best")
    moved = move_previous_run(run)
    assert moved.parent == run / "previous"
    assert (moved / "best_model.zip").read_bytes() == b"old best"
    assert not _latest_checkpoint(run / "checkpoints") if (run / "checkpoints").exists() else True
    assert sorted(p.name for p in run.iterdir()) == ["previous"]
    assert move_previous_run(run) is None


def test_resume_restores_the_evaluation_history(tmp_path):
    from types import SimpleNamespace

    from bogie_agents.training.train import restore_evaluations

    (tmp_path / "eval").mkdir()
    np.savez(tmp_path / "eval" / "evaluations.npz", timesteps=np.array([1024, 2048]),
             results=np.array([[5.0, 7.0], [9.0, 1.0]]), ep_lengths=np.array([[10, 10], [10, 10]]))  # fmt: skip
    callback = SimpleNamespace(best_mean_reward=-np.inf)
    restore_evaluations(callback, tmp_path)
    assert callback.best_mean_reward == 6.0
    assert callback.evaluations_timesteps == [1024, 2048] and len(callback.evaluations_results) == 2
