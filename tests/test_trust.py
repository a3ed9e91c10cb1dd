"""Safe loading, atomic files with normal permissions, strict YAML (issue 13, items 1 and 6)."""

import json
import os
import pickle
import shutil
import stat

import numpy as np
import pytest

import bogie_agents.policies as policies
from bogie_agents.policies import (
    MANIFEST_FILE,
    NORMALISATION_FILE,
    PRETRAINED_DIR as PRETRAINED_ROOT,
    load_normalisation,
    load_policy,
    load_sb3_policy,
    verify_manifest,
)
from bogie_agents.cli import main as cli_main
from bogie_env.envs.config import make_config
from bogie_env.fileio import load_yaml, write_text_atomic
from bogie_env.params import BogieParams, ConfigError

PRETRAINED_DIR = PRETRAINED_ROOT / "v0"  # the v0 policy (these tests use v0's default config)


class _RunsCode:
    """A pickle that runs code when loaded: it creates a marker file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture(scope="module")
def env_config():
    return make_config()


def _pretrained_copy(tmp_path, monkeypatch):
    root = tmp_path / "pretrained"
    shutil.copytree(PRETRAINED_ROOT, root)
    monkeypatch.setattr(policies, "PRETRAINED_DIR", root)
    return root / "v0"


def test_shipped_policy_has_a_manifest_and_data_only_statistics():
    names = verify_manifest(PRETRAINED_DIR)
    assert {"best_model.zip", NORMALISATION_FILE, "config.json"} <= set(names)
    assert not list(PRETRAINED_DIR.glob("*.pkl")), "the shipped statistics must not be a pickle"
    stats = load_normalisation(PRETRAINED_DIR / NORMALISATION_FILE)
    assert stats["mean"].shape == (11,) and np.all(stats["var"] > 0) and stats["count"] > 1e6


def test_tampered_pretrained_policy_is_refused(tmp_path, monkeypatch, env_config):
    folder = _pretrained_copy(tmp_path, monkeypatch)
    data = bytearray((folder / "best_model.zip").read_bytes())
    data[-10] ^= 0xFF
    (folder / "best_model.zip").write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="does not match its SHA-256"):
        load_policy("pretrained", env_config)


def test_unlisted_file_beside_the_pretrained_policy_is_refused(tmp_path, monkeypatch, env_config):
    folder = _pretrained_copy(tmp_path, monkeypatch)
    (folder / "vecnormalize.pkl").write_bytes(pickle.dumps(_RunsCode(tmp_path / "ran")))
    with pytest.raises(ConfigError, match="not in SHA256SUMS: vecnormalize.pkl"):
        load_policy("pretrained", env_config)
    assert not (tmp_path / "ran").exists()
    (folder / "vecnormalize.pkl").unlink()
    (folder / MANIFEST_FILE).unlink()
    with pytest.raises(ConfigError, match="SHA256SUMS' is missing"):
        load_policy("pretrained", env_config)


def test_a_policy_path_needs_the_trust_flag_and_runs_nothing_without_it(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    (run / NORMALISATION_FILE).unlink()
    (run / "vecnormalize.pkl").write_bytes(pickle.dumps(_RunsCode(tmp_path / "ran")))
    for spec in (str(run), str(run / "best_model.zip")):
        with pytest.raises(ConfigError, match="--trust-policy"):
            load_policy(spec, env_config)
        with pytest.raises(ConfigError, match="code"):
            load_sb3_policy(spec)
    assert not (tmp_path / "ran").exists()


def test_cli_names_the_trust_flag(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    assert cli_main(["evaluate", "--policy", str(run), "--parts", "critical"]) == 2
    err = capsys.readouterr().err
    assert "--trust-policy" in err and "code" in err


def test_data_only_statistics_match_the_model_and_are_checked(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    trusted = load_policy(str(run), env_config, trusted=True)
    shipped = load_policy("pretrained", env_config)
    obs = np.random.default_rng(0).uniform(-1, 1, (4, 11)).astype(np.float32)
    assert np.array_equal(trusted.act(obs), shipped.act(obs))
    stats = json.loads((run / NORMALISATION_FILE).read_text())
    for key, value, message in [("obs_var", [-1.0] * 11, "obs_var finite and >= 0"),
                                ("obs_mean", [0.0] * 3, "same length"),
                                ("format", "pickle", "is not a 'bogie-vecnormalize-1' file"),
                                ("clip_obs", "ten", "non-numeric")]:  # fmt: skip
        (run / NORMALISATION_FILE).write_text(json.dumps({**stats, key: value}))
        with pytest.raises(ConfigError, match=message):
            load_policy(str(run), env_config, trusted=True)
    (run / NORMALISATION_FILE).write_text("{not json")
    with pytest.raises(ConfigError, match="not readable JSON"):
        load_policy(str(run), env_config, trusted=True)


def test_corrupt_model_zip_is_a_named_error(tmp_path, env_config, capsys):
    bad = tmp_path / "model.zip"
    bad.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(ConfigError, match="could not load .* as a PPO, SAC or TD3 model"):
        load_policy(str(bad), env_config, trusted=True)
    assert cli_main(["evaluate", "--trust-policy", "--policy", str(bad), "--parts", "critical"]) == 2
    assert "could not load" in capsys.readouterr().err


def test_corrupt_legacy_pickle_is_a_named_error(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    (run / NORMALISATION_FILE).unlink()
    (run / "vecnormalize.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(ConfigError, match="not a readable VecNormalize pickle"):
        load_policy(str(run), env_config, trusted=True)


def test_policy_env_shape_mismatch_fails_at_load(tmp_path, env_config):
    passive_env = make_config({"actuators": {"frame_lateral": {"mode": "off"}}})
    with pytest.raises(ConfigError, match=r"expects observations of shape \(11,\) but the env config gives \(10,\)"):
        load_policy("pretrained", passive_env)
    policy = load_policy("pretrained", env_config)
    with pytest.raises(ConfigError, match=r"takes observations of shape \(11,\); got \(7,\)"):
        policy.act(np.zeros((2, 7), dtype=np.float32))


# ---- files: normal permissions, atomic --------------------------------------------------
def test_atomic_writes_have_normal_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
        from bogie_env.analysis.plots import plt, save

        fig, _ = plt.subplots()
        save(fig, tmp_path / "f.png")
    finally:
        os.umask(old)
    for name in ("a.txt", "f.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "f.png"]  # no temporary left


def test_write_to_a_folder_is_a_named_error(tmp_path):
    with pytest.raises(ConfigError, match="is a folder"):
        write_text_atomic(tmp_path, "x")


# ---- YAML: duplicates and syntax errors are named ---------------------------------------------
@pytest.mark.parametrize(
    "text, message",
    [("a: 1\na: 2\n", "duplicate key 'a'"), ("speed: {accel: 1, accel: 2}\n", "duplicate key 'accel'"),
     ("a: [1, 2\n", "malformed"), ("a: !!python/object/apply:os.system ['true']\n", "malformed")],
)  # fmt: skip
def test_yaml_duplicates_and_syntax_errors(tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_yaml(path)


def test_every_project_yaml_loader_rejects_duplicates(tmp_path):
    from bogie_agents.train import load_run_config

    path = tmp_path / "dup.yaml"
    path.write_text("speed:\n  accel: 1.0\n  accel: 2.0\n")
    with pytest.raises(ConfigError, match="duplicate key 'accel'"):
        make_config(str(path))
    path.write_text("algo: ppo\nalgo: sac\n")
    with pytest.raises(ConfigError, match="duplicate key 'algo'"):
        load_run_config(path, None)
    from bogie_env.params import DEFAULT_BOGIE_CONFIG

    text = DEFAULT_BOGIE_CONFIG.read_text()
    first = next(line for line in text.splitlines() if line and not line.startswith((" ", "#")) and ":" in line)
    path.write_text(text + "\n" + first + "\n")
    with pytest.raises(ConfigError, match="duplicate key"):
        BogieParams.from_yaml(path)
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        make_config(str(path))
    with pytest.raises(ConfigError, match="must hold a mapping"):
        BogieParams.from_yaml(path)


# ---- training: validated configs, locked folders, no lost best model ----------------------------
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
    from bogie_agents.train import validate_run_config

    with pytest.raises(ConfigError, match=message):
        validate_run_config(_run_config(**changes), "test.yaml")


def test_shipped_agent_configs_are_valid():
    from bogie_agents.train import load_run_config

    for algo in ("ppo", "sac", "td3"):
        load_run_config(None, algo)


@pytest.mark.parametrize("timesteps", [0, -5])
def test_bad_timesteps_are_named_errors(tmp_path, timesteps, capsys):
    from bogie_agents.train import train

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
    from bogie_agents.train import steps_learned

    assert steps_learned(_run_config(n_envs=64, **{"hyperparams.n_steps": 256}), 50_000) == 65_536
    assert steps_learned(_run_config(n_envs=64, **{"hyperparams.n_steps": 256}), 65_536) == 65_536
    assert steps_learned({"algo": "sac", "n_envs": 16, "hyperparams": {}}, 1000) == 1008


def test_a_second_training_into_a_locked_folder_fails(tmp_path):
    from bogie_agents.train import RunFolderLock, train

    with RunFolderLock(tmp_path / "run"):
        with pytest.raises(ConfigError, match="is in use by another training .*pid"):
            train(_run_config(), tmp_path / "run")
    with RunFolderLock(tmp_path / "run"):  # released: can be taken again
        pass


def test_no_resume_moves_the_old_run_aside(tmp_path):
    from bogie_agents.train import _latest_checkpoint, move_previous_run

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

    from bogie_agents.train import restore_evaluations

    (tmp_path / "eval").mkdir()
    np.savez(tmp_path / "eval" / "evaluations.npz", timesteps=np.array([1024, 2048]),
             results=np.array([[5.0, 7.0], [9.0, 1.0]]), ep_lengths=np.array([[10, 10], [10, 10]]))  # fmt: skip
    callback = SimpleNamespace(best_mean_reward=-np.inf)
    restore_evaluations(callback, tmp_path)
    assert callback.best_mean_reward == 6.0
    assert callback.evaluations_timesteps == [1024, 2048] and len(callback.evaluations_results) == 2


# ---- env and CLI: absurd input is a named error ------------------------------------------------
def test_negative_reset_accel_is_rejected():
    from bogie_env.envs.hunting_env import BogieHuntingEnv

    env = BogieHuntingEnv()
    with pytest.raises(ConfigError, match=r"reset option 'accel' = -5 is not allowed; allowed: \[0, 10\]"):
        env.reset(seed=0, options={"accel": -5})
    with pytest.raises(ConfigError, match="reset option 'accel' = 1e\\+09 is not allowed"):
        env.reset(seed=0, options={"accel": 1e9})


@pytest.mark.parametrize(
    "config, message",
    [({"actuators": {"frame_lateral": {"bandwidth_hz": 0}}}, r"'actuators.frame_lateral.bandwidth_hz' = 0 is not allowed; allowed: \(0"),
     ({"actuators": {"frame_yaw": {"mode": "semi_active", "c_max": 1e8}}}, "c_max' = 100000000.0 is not allowed.*smaller substeps"),
     ({"randomize": {"lam": [0.5, 100.0]}}, r"'randomize.lam' = \[0.5, 100\]: the scale 100 gives an invalid bogie .*'lam'"),
     ({"randomize": {"Kpx": [1.0, 50.0]}}, r"'randomize.Kpx' = \[1, 50\]: the scale 50"),
     ({"speed": {"accel": -5}}, "'speed.accel' = -5 is not allowed")],
)  # fmt: skip
def test_env_config_rejected_at_construction(config, message):
    from bogie_env.envs.hunting_env import BogieHuntingEnv

    with pytest.raises(ConfigError, match=message):
        BogieHuntingEnv(config=config)


def test_num_envs_is_capped():
    from bogie_env.envs.config import MAX_NUM_ENVS
    from bogie_env.envs.vector import BogieHuntingVectorEnv

    with pytest.raises(ConfigError, match=f"num_envs = 1000000 is not allowed; allowed: an integer in \\[1, {MAX_NUM_ENVS}\\]"):
        BogieHuntingVectorEnv(10**6)


def test_stepping_before_reset_raises_reset_needed():
    import gymnasium as gym

    from bogie_env.envs.hunting_env import BogieHuntingEnv

    env = BogieHuntingEnv()
    with pytest.raises(gym.error.ResetNeeded):
        env.step(env.action_space.sample())
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert np.all(np.isfinite(obs))
    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=3, vectorization_mode="vector_entry_point")
    with pytest.raises(gym.error.ResetNeeded):
        vec.step(vec.action_space.sample())
    vec.reset(seed=0, options={"reset_mask": np.array([True, False, True])})
    with pytest.raises(gym.error.ResetNeeded, match=r"env\(s\) \[1\]"):
        vec.step(vec.action_space.sample())


def test_vector_reset_takes_a_list_of_seeds():
    import gymnasium as gym

    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=3, vectorization_mode="vector_entry_point")
    by_list, _ = vec.reset(seed=[5, 7, 5])
    by_int, _ = vec.reset(seed=5)  # env i gets 5 + i
    assert np.array_equal(by_list[0], by_list[2]) and np.array_equal(by_list[0], by_int[0])
    assert np.array_equal(by_list[1], by_int[2])
    with pytest.raises(ValueError, match="got 2 seeds for 3 environments"):
        vec.reset(seed=[1, 2])


def test_render_fps_is_one_over_dt():
    import gymnasium as gym

    from bogie_env.envs.hunting_env import BogieHuntingEnv

    assert BogieHuntingEnv().metadata["render_fps"] == 100
    assert BogieHuntingEnv(config={"dt": 0.02}).metadata["render_fps"] == 50
    vec = gym.make_vec("Bogie/Hunting-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert vec.metadata["render_fps"] == 100


def test_sb3_set_attr_and_env_method_honour_indices():
    from bogie_agents.vec_env import BogieHuntingSB3VecEnv

    venv = BogieHuntingSB3VecEnv(3, seed=0)
    venv.reset()
    venv.set_attr("difficulty", 2.0, indices=[1])
    assert venv.get_attr("difficulty", indices=[1]) == [2.0]
    with pytest.raises(AttributeError):
        venv.get_attr("difficulty", indices=[0])
    assert not hasattr(venv, "difficulty")  # not the VecEnv's own attribute
    venv.set_attr("config", venv.task.config)  # a task attribute: all sub-envs at once
    with pytest.raises(ValueError, match="set it without indices"):
        venv.set_attr("config", {}, indices=[0])
    before = venv.task.obs.copy()
    venv.task.sim.x[:] += 1e-3
    out = venv.env_method("observe", indices=[2])
    assert len(out) == 1
    after = venv.task.obs
    assert np.array_equal(after[:2], before[:2]) and not np.array_equal(after[2], before[2])
    with pytest.raises(IndexError):
        venv.env_method("observe", indices=[5])


def test_critical_speed_json_reports_a_stable_window(capsys):
    assert cli_main(["critical-speed", "--json", "--v-max-kmh", "200"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["critical_speed_kmh"] is None and payload["stable_over_window"] is True
    assert payload["search_window_kmh"] == [50.0, 200.0] and payload["eigenvalue"] is None


@pytest.mark.parametrize(
    "argv, message",
    [(["ramp", "--accel", "1e9"], "argument --accel: '1e9' is not allowed; allowed: a number in (0, 10] m/s^2"),
     (["ramp", "--offset", "10"], "argument --offset: '10' is not allowed"),
     (["ramp", "--track-rms", "-0.001"], "argument --track-rms: '-0.001' is not allowed"),
     (["ramp", "--v-start-kmh", "-300"], "argument --v-start-kmh"),
     (["evaluate", "--policy", "passive", "--seed", "-1"], "argument --seed: '-1' is not allowed"),
     (["root-locus", "--n-speeds", "1"], "argument --n-speeds"),
     (["sensitivity", "--param", "Csy", "--workers", "0"], "argument --workers")],
)  # fmt: skip
def test_cli_rejects_absurd_numbers_naming_the_option(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, message",
    [(["bifurcation", "--rates", "1,x"], "--rates '1,x': every entry must be a number"),
     (["bifurcation", "--rates", "1,-2"], "--rates '1,-2': every entry must be a finite number > 0"),
     (["sensitivity", "--param", "Csy", "--scales", ""], "--scales '' is empty")],
)  # fmt: skip
def test_cli_list_options_are_named(argv, message, capsys):
    assert cli_main(argv) == 2
    assert message in capsys.readouterr().err


def test_cli_malformed_yaml_and_out_file_are_clean_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("Csy: [1, 2\n")
    assert cli_main(["critical-speed", "--config", str(bad)]) == 2
    assert "is malformed" in capsys.readouterr().err
    bad.write_text("speed: {accel: 1}\nspeed: {accel: 2}\n")
    assert cli_main(["evaluate", "--policy", "passive", "--env-config", str(bad)]) == 2
    assert "duplicate key 'speed'" in capsys.readouterr().err
    out_file = tmp_path / "taken"
    out_file.write_text("x")
    assert cli_main(["results", "--policy", "passive", "--out", str(out_file)]) == 2
    assert "is an existing file" in capsys.readouterr().err
    assert cli_main(["ramp", "--v-start-kmh", "300", "--v-end-kmh", "301", "--accel", "10", "--out", str(out_file)]) == 2
    assert "bogie ramp: error:" in capsys.readouterr().err


def test_cli_version_and_help(capsys):
    with pytest.raises(SystemExit):
        cli_main(["--version"])
    from bogie_env import __version__

    assert capsys.readouterr().out.strip() == f"bogie {__version__}"
    for command in ("ramp", "evaluate", "bifurcation", "sensitivity", "train"):
        with pytest.raises(SystemExit):
            cli_main([command, "--help"])
        text = capsys.readouterr().out
        assert "``" not in text, command
    with pytest.raises(SystemExit):
        cli_main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Protocol v2 (-v1 ids): critical, cost, margins (default: these three" in text and "robustness (default: all)" in text


def test_figures_name_units_and_label_every_line(tmp_path):
    from types import SimpleNamespace

    from bogie_env.analysis import plots

    assert plots.param_label("Kpx") == "primary longitudinal stiffness Kpx (N/m)"
    assert plots.param_label("Csy").endswith("Csy (N s/m)")
    captured = {}
    real_save = plots.save

    def keep(fig, path, dpi=130):
        captured["axes"] = [(ax.get_xlabel(), [t.get_text() for t in ax.get_legend().get_texts()]) for ax in fig.axes
                            if ax.get_legend() is not None]  # fmt: skip
        return real_save(fig, path, dpi)

    curve = SimpleNamespace(param="Kpz", values=[4e5, 5e5, 6e5], critical_speed_kmh=[300.0, 350.0, 380.0])
    plots.save, saved = keep, plots.save
    try:
        plots.curves_figure([curve], 358.6, tmp_path / "c.png")
    finally:
        plots.save = saved
    (xlabel, legend), = captured["axes"]
    assert xlabel == "primary vertical stiffness Kpz (N/m)"
    assert legend == ["linear critical speed", "nominal bogie 358.6 km/h", "EN 14363 requirement 330 km/h"]
