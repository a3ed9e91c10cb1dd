"""Learning curves (agents/training/learning_curves.py): eval.seed runs the same episodes at every
evaluation; bogie results --curves draws mean and min-max over seeds and names bad input."""

import json

import numpy as np
import pytest
import yaml

from bogie_agents.cli import main as cli_main
from bogie_agents.training.learning_curves import curves, parse_row
from bogie_agents.training.train import load_run_config, train, validate_run_config
from bogie_env.params import ConfigError

SHORT = {"speed": {"start_kmh": 300.0, "end_kmh": 304.0, "accel": 5.0}}


def _fake_run(folder, seed, steps, returns):
    (folder / "eval").mkdir(parents=True)
    np.savez(folder / "eval" / "evaluations.npz", timesteps=np.array(steps), results=np.array(returns),
             ep_lengths=np.ones_like(np.array(returns), dtype=int))  # fmt: skip
    (folder / "config.json").write_text(json.dumps({"seed": seed, "source": "configs/agents/x.yaml", "eval": {"seed": 7}}))


def test_curves_are_mean_and_min_max_over_seeds(tmp_path):
    for seed, offset in enumerate([0.0, 2.0, 4.0]):
        _fake_run(tmp_path / "row" / f"seed_{seed}", seed, [10, 20], [[1.0 + offset, 3.0 + offset], [5.0 + offset, 5.0 + offset]])
    _fake_run(tmp_path / "other" / "seed_0", 0, [10, 20], [[0.0], [1.0]])
    assert cli_main(["results", "--out", str(tmp_path / "out"), "--curves", f"row={tmp_path}/row/seed_*",
                     "--curves", f"other={tmp_path}/other/seed_0"]) == 0  # fmt: skip
    data = json.loads((tmp_path / "out" / "learning_curves.json").read_text())["rows"]
    assert (tmp_path / "out" / "learning_curves.png").stat().st_size > 1000
    row = data[0]
    assert row["row"] == "row" and row["seeds"] == [0, 1, 2] and row["timesteps"] == [10, 20]
    assert row["mean"] == [4.0, 7.0] and row["min"] == [2.0, 5.0] and row["max"] == [6.0, 9.0]
    assert data[1]["mean"] == [0.0, 1.0]


def test_curves_name_bad_input(tmp_path):
    with pytest.raises(ConfigError, match="allowed: NAME=GLOB"):
        parse_row("no_equals_sign")
    with pytest.raises(ConfigError, match="matches no run folder"):
        parse_row(f"row={tmp_path}/nothing_*")
    _fake_run(tmp_path / "a", 0, [10, 20], [[1.0], [2.0]])
    _fake_run(tmp_path / "b", 1, [10], [[1.0]])
    with pytest.raises(ConfigError, match="evaluated at steps"):
        curves([parse_row(f"row={tmp_path}/a,{tmp_path}/b")])
    with pytest.raises(ConfigError, match="'eval.seed' = -1 is not allowed; allowed: an integer in"):
        validate_run_config({"algo": "ppo", "total_timesteps": 10, "n_envs": 1, "eval": {"seed": -1}}, "test.yaml")


@pytest.mark.parametrize("eval_seed", [None, 3])
def test_eval_seed_runs_the_same_episodes_at_every_evaluation(tmp_path, eval_seed):
    """A policy that does not change (learning rate 1e-12, no observation statistics) scores the same at every
    evaluation with eval.seed."""
    config = {"algo": "ppo", "seed": 0, "total_timesteps": 512, "n_envs": 2, "env_id": "Bogie/Hunting-v1",
              "env": SHORT, "eval_env": SHORT, "policy_kwargs": {"net_arch": [8]},
              "vecnormalize": {"norm_obs": False}, "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1, "learning_rate": 1e-12},
              "eval": {"freq_steps": 128, "n_envs": 2, "episodes": 2, **({"seed": eval_seed} if eval_seed is not None else {})},
              "checkpoint": {"freq_steps": 512}}  # fmt: skip
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config))
    train(load_run_config(path, None), tmp_path / "run", progress_bar=False)
    results = np.load(tmp_path / "run" / "eval" / "evaluations.npz")["results"]
    assert results.shape == (4, 2)
    same = np.allclose(results, results[0], rtol=1e-5)
    assert same == (eval_seed is not None)
