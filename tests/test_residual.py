"""Residual RL (agents/controllers/residual.py), v1 training configs and the pretrained policy per env version."""

import json
import shutil

import numpy as np
import pytest
import torch
import yaml

import bogie_agents.controllers.policies as policies
from bogie_agents.controllers.lqr import PassiveController, SkyhookController
from bogie_agents.controllers.curving_assist import SteeringController
from bogie_agents.design.margins import check_controller_model, finite_difference_jacobian
from bogie_agents.controllers.policies import PRETRAINED_DIR, SB3Policy, env_version, load_policy, pretrained_dir
from bogie_agents.controllers.residual import (ResidualPolicy, ResidualVecEnv, WashedOutFeatures, check_residual_config, compose,
                                   odd_actor)
from bogie_agents.controllers.robust import RobustDampingController
from bogie_agents.training.train import env_config_of, load_run_config, validate_run_config
from bogie_agents.training.vec_env import BogieHuntingSB3VecEnv
from bogie_env.envs import task as T
from bogie_env.envs.config import make_config
from bogie_env.params import CONFIG_DIR, ConfigError


@pytest.fixture(scope="module")
def v1_config():
    # short episodes, randomisation off (a pinned conicity), so a few hundred steps finish some
    return make_config({"randomize": {}, "speed": {"start_kmh": 350.0, "end_kmh": 360.0, "accel": 5.0}}, variant="v1")


def _network(config, seed=0, zero=False, features=None):
    """An untrained SB3 PPO policy on the config's spaces (or the features'), as the residual's network."""
    from stable_baselines3 import PPO

    venv = BogieHuntingSB3VecEnv(1, config, seed=0)
    if features is not None:
        venv = ResidualVecEnv(venv, PassiveController(config), 0.1, features)
    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", n_steps=8, batch_size=8,
                policy_kwargs={"net_arch": [8, 8], "activation_fn": torch.nn.Tanh})  # fmt: skip
    with torch.no_grad():
        if zero:
            model.policy.action_net.weight.zero_()
            model.policy.action_net.bias.zero_()
        else:  # make the residual's Jacobian large enough to matter
            model.policy.action_net.weight.mul_(100.0)
    n = venv.observation_space.shape[0]
    if features is not None:
        odd_actor(model)
        return SB3Policy(model, None, None, 10.0, 1e-8, "test", config)
    rng = np.random.default_rng(seed)
    return SB3Policy(model, rng.standard_normal(n) * 0.1, rng.uniform(0.5, 2.0, n), 10.0, 1e-8, "test", config)


def test_zero_residual_reproduces_the_baseline_exactly(v1_config):
    n = 4
    venv = BogieHuntingSB3VecEnv(n, v1_config, seed=5)
    wrapped = ResidualVecEnv(BogieHuntingSB3VecEnv(n, v1_config, seed=5), SkyhookController(v1_config), 0.3)
    reference = SkyhookController(v1_config)
    residual = ResidualPolicy(SkyhookController(v1_config), _network(v1_config, zero=True), 0.3, "zero")
    obs, obs_w = venv.reset(), wrapped.reset()
    reference.reset(n)
    residual.reset(n)
    finished = 0
    for _ in range(250):
        action = reference.act(obs)
        assert np.array_equal(residual.act(obs), action)
        obs, _, dones, _ = venv.step(action)
        obs_w, _, dones_w, _ = wrapped.step(np.zeros((n, venv.action_space.shape[0]), np.float32))
        assert np.array_equal(obs, obs_w) and np.array_equal(dones, dones_w)
        if dones.any():  # the baseline's rows restart with their episodes
            reference.reset(n, np.nonzero(dones)[0])
            residual.reset(n, np.nonzero(dones)[0])
            finished += int(dones.sum())
    assert finished > 0, "no episode ended: the reset path was not exercised"


def test_residual_is_bounded_by_its_scale():
    base = np.array([[0.1, -0.95, 0.0, 0.5]])
    out = compose(base, np.array([[5.0, -5.0, 0.3, -1.0]]), 0.2)
    assert np.allclose(out, [[0.3, -1.0, 0.06, 0.3]])


def test_controller_model_is_the_true_jacobian(v1_config):
    net = _network(v1_config, seed=1)
    n_obs = net.model.observation_space.shape[0]
    y0 = np.random.default_rng(2).uniform(-0.3, 0.3, n_obs)
    # static baseline: the model is the finite-difference Jacobian of act
    residual = ResidualPolicy(PassiveController(v1_config), net, 0.25, "passive+nn")
    ctrl = residual.controller_model(n_obs, 400.0, y0)
    fd = finite_difference_jacobian(residual, y0, step=1e-3)
    assert np.abs(ctrl.d).max() > 0.05, "vacuous: the residual has no gain"
    assert np.allclose(ctrl.d, fd, atol=2e-3 * np.abs(fd).max())
    # a wrong scale (a planted bug) is caught
    assert not np.allclose(0.5 * ctrl.d, fd, atol=2e-3 * np.abs(fd).max())
    # stateful baseline: the composite model predicts act on a small input sequence (about rest,
    # where skyhook's integrator is settled)
    residual = ResidualPolicy(SkyhookController(v1_config), net, 0.25, "skyhook+nn")
    y0 = np.zeros(n_obs)
    ctrl = residual.controller_model(n_obs, 400.0, y0)
    assert ctrl.n_states > 0
    u0 = np.asarray(residual.act(y0[None].astype(np.float32)), dtype=float)[0]
    assert check_controller_model(residual, ctrl, y0, u0) < 0.02


def test_washed_out_residual_is_zero_at_rest_and_for_constant_observations(v1_config):
    """features: washed_out with an odd actor: a constant observation (rest, a steady curve, a
    sensor bias) gives exactly the baseline's command; a changing one does not."""
    net = _network(v1_config, seed=3, features=WashedOutFeatures(v1_config))
    residual = ResidualPolicy(RobustDampingController(v1_config), net, 0.3, "robust+nn", WashedOutFeatures(v1_config))
    baseline = RobustDampingController(v1_config)
    rng = np.random.default_rng(4)
    n_obs = net.model.observation_space.shape[0]
    y = rng.uniform(-0.5, 0.5, (3, 11)).astype(np.float32)
    y[:, 6] = 0.6  # speed
    biased = y.copy()
    y[:, T.SENSOR_FRAME_LATERAL_ACCEL] = 0.0  # the accelerometer chain starts at rest (robust.start_state)
    residual.reset(3)
    baseline.reset(3)
    for _ in range(5):
        assert np.allclose(residual.act(y), baseline.act(y), rtol=0, atol=1e-9)  # rounding of the filters
    residual.reset(3)
    baseline.reset(3)
    for _ in range(1500):  # a constant acceleration: zero once its start has washed out (15 s)
        u_residual, u_baseline = residual.act(biased), baseline.act(biased)
    assert np.allclose(u_residual, u_baseline, rtol=0, atol=1e-7)
    assert np.allclose(net.act(np.zeros((1, n_obs), np.float32)), 0.0)
    moved = y + rng.uniform(-0.05, 0.05, y.shape).astype(np.float32)
    assert not np.allclose(residual.act(moved), baseline.act(moved))


def test_washed_out_controller_model_predicts_act(v1_config):
    net = _network(v1_config, seed=5, features=WashedOutFeatures(v1_config))
    residual = ResidualPolicy(RobustDampingController(v1_config), net, 0.3, "robust+nn", WashedOutFeatures(v1_config))
    y0 = np.zeros(11)
    y0[6] = (400.0 - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH  # the speed entry: 400 km/h
    ctrl = residual.controller_model(11, 400.0, y0)
    u0 = np.asarray(residual.act(y0[None].astype(np.float32)), dtype=float)[0]
    base = RobustDampingController(v1_config).controller_model(11, 400.0, y0)
    assert ctrl.n_states == 2 * base.n_states and not np.allclose(ctrl.c[:, base.n_states:], 0.0)
    assert check_controller_model(residual, ctrl, y0, u0) < 0.02
    # the baseline's model alone misses the residual (not vacuous)
    wrong = type(ctrl)(ctrl.a, ctrl.b, np.hstack([base.c, 0 * ctrl.c[:, base.n_states:]]), base.d, "baseline only")
    assert check_controller_model(residual, wrong, y0, u0) > 0.05


def test_residual_config_is_checked():
    assert check_residual_config({"baseline": "skyhook", "scale": 0.2}) == {"baseline": "skyhook", "scale": 0.2,
                                                                           "features": "observation"}
    for bad, message in [({"baseline": "hinf"}, "baseline = 'hinf'"), ({"baseline": "lqr", "scale": 0.0}, "scale = 0.0"),
                         ({"baseline": "lqr", "scale": 2}, "scale = 2"), ({"scale": 0.1}, "'baseline'"),
                         ({"baseline": "lqr", "gain": 1}, "'baseline'")]:  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            check_residual_config(bad)


def test_v1_agent_config_validates_and_resolves_the_env_id(tmp_path):
    config = load_run_config(None, "ppo")
    assert env_config_of(config)["sensors"]["enabled"] is False  # no env_id: v0
    v1 = load_run_config(CONFIG_DIR / "agents" / "ppo_v1.yaml", None)
    resolved = env_config_of(v1)
    assert resolved["sensors"]["enabled"] is True and resolved["actuators"]["frame_yaw"]["delay_steps"] == 1
    assert tuple(resolved["randomize"]["conicity"]) == (0.025, 0.3)
    for key, value, message in [("env_id", "Bogie/Hunting-v9", "'env_id' = 'Bogie/Hunting-v9'"),
                                ("residual", {"baseline": "nope"}, "baseline = 'nope'")]:  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            validate_run_config({**v1, key: value}, where="test")


def test_env_version_picks_the_shipped_policy():
    assert env_version(make_config()) == "v0"
    assert env_version(make_config(variant="v1")) == "v1"
    assert env_version(None, "Bogie/HuntingPassive-v1") == "v1"
    assert env_version(make_config(variant="v1"), "Bogie/Hunting-v0") == "v0"  # the id wins
    with pytest.raises(ConfigError, match="Bogie/Hunting-v7"):
        env_version(None, "Bogie/Hunting-v7")
    assert pretrained_dir(make_config()) == PRETRAINED_DIR / "v0"
    for folder in PRETRAINED_DIR.iterdir():  # each shipped policy says which env it was trained on
        if folder.is_dir() and folder.name != "__pycache__":  # v0, v1 (SB3 runs), distilled_v1 (a student)
            meta = folder / "config.json" if (folder / "config.json").is_file() else folder / "student.json"
            config = json.loads(meta.read_text())
            assert config.get("env_id", "Bogie/Hunting-v0").endswith("-" + folder.name.rsplit("_", 1)[-1])


def test_pretrained_v0_still_loads_for_v0_and_a_missing_version_is_named(tmp_path, monkeypatch):
    v0 = load_policy("pretrained", make_config())
    assert isinstance(v0, SB3Policy) and v0.model.observation_space.shape == (11,)
    folder = tmp_path / "pretrained"
    shutil.copytree(PRETRAINED_DIR / "v0", folder / "v0")
    monkeypatch.setattr(policies, "PRETRAINED_DIR", folder)
    with pytest.raises(ConfigError, match="no pretrained policy for env version 'v1'.*shipped: v0"):
        load_policy("pretrained", make_config(variant="v1"))


def test_pretrained_v1_is_the_washed_out_residual_and_is_verified_before_loading(tmp_path, monkeypatch):
    v1 = load_policy("pretrained", make_config(variant="v1"))
    assert isinstance(v1, ResidualPolicy) and isinstance(v1.baseline, SteeringController)
    assert isinstance(v1.baseline.base, RobustDampingController)
    assert v1.features is not None and v1.scale == 0.3
    assert load_policy("pretrained", make_config(variant="v1_route")).features is not None  # routes: v1 too
    folder = tmp_path / "pretrained"
    shutil.copytree(PRETRAINED_DIR, folder)
    monkeypatch.setattr(policies, "PRETRAINED_DIR", folder)
    data = bytearray((folder / "v1" / "best_model.zip").read_bytes())
    data[-10] ^= 0xFF
    (folder / "v1" / "best_model.zip").write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="does not match its SHA-256"):
        load_policy("pretrained", make_config(variant="v1"))
    assert isinstance(load_policy("pretrained", make_config()), SB3Policy)  # v0 untouched


@pytest.mark.parametrize("features", ["observation", "washed_out"])
def test_residual_training_smoke(tmp_path, features):
    """A v1 residual run (with a route task beside the tangent one) trains, saves and loads as a
    ResidualPolicy; the washed-out run's actor has no biases."""
    config = {
        "algo": "ppo", "seed": 1, "total_timesteps": 512, "n_envs": 3, "env_id": "Bogie/Hunting-v1",
        "residual": {"baseline": "robust_damping", "scale": 0.2, "features": features},
        "env": {"speed": {"start_kmh": 300.0, "end_kmh": 310.0, "accel": 5.0}},
        "extra_envs": [{"env_id": "Bogie/HuntingRoute-v1", "n_envs": 1}],
        "eval_env": {"speed": {"start_kmh": 300.0, "end_kmh": 305.0, "accel": 5.0}},
        "vecnormalize": {"norm_obs": features == "observation"},
        "policy_kwargs": {"net_arch": [8], "activation_fn": "tanh"},
        "hyperparams": {"n_steps": 64, "batch_size": 128, "n_epochs": 1},
        "eval": {"freq_steps": 256, "n_envs": 2, "episodes": 2}, "checkpoint": {"freq_steps": 512},
    }  # fmt: skip
    path = tmp_path / "ppo_v1.yaml"
    path.write_text(yaml.safe_dump(config))
    from bogie_agents.training.train import train

    out = tmp_path / "run"
    summary = train(load_run_config(path, "ppo"), out, progress_bar=False)
    assert summary["timesteps"] >= 512
    saved = json.loads((out / "config.json").read_text())
    assert saved["env_id"] == "Bogie/Hunting-v1" and saved["residual"]["baseline"] == "robust_damping"
    policy = load_policy(str(out), make_config(variant="v1"), trusted=True)
    assert isinstance(policy, ResidualPolicy) and isinstance(policy.baseline, RobustDampingController)
    assert (policy.features is not None) == (features == "washed_out")
    if features == "washed_out":
        actor = policy.model.policy
        assert all(float(layer.bias.abs().max()) == 0.0 for layer in [*actor.mlp_extractor.policy_net, actor.action_net]
                   if hasattr(layer, "bias") and layer.bias is not None)  # fmt: skip
        with pytest.raises(ConfigError, match="norm_obs"):
            validate_run_config({**load_run_config(path, "ppo"), "vecnormalize": {"norm_obs": True}}, where="test")
