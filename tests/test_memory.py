"""Policies with memory (agents/controllers/memory.py): RecurrentPPO and frame stacking train, save, reload
and act with the right shapes; the memory is reset per row; the memory keys are validated."""

import json

import numpy as np
import pytest
import yaml

from bogie_agents.controllers.memory import ObservationHistory
from bogie_agents.controllers.policies import SB3Policy, load_policy
from bogie_agents.controllers.residual import ResidualPolicy
from bogie_agents.training.train import load_run_config, train, validate_run_config
from bogie_env.envs.config import make_config
from bogie_env.params import ConfigError

SHORT = {"speed": {"start_kmh": 300.0, "end_kmh": 305.0, "accel": 5.0}}


def _config(**changes):
    config = {
        "algo": "ppo", "seed": 1, "total_timesteps": 256, "n_envs": 2, "env_id": "Bogie/Hunting-v1",
        "env": SHORT, "eval_env": SHORT, "policy_kwargs": {"net_arch": [8], "activation_fn": "tanh"},
        "hyperparams": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
        "eval": {"freq_steps": 128, "n_envs": 2, "episodes": 2}, "checkpoint": {"freq_steps": 256},
    }  # fmt: skip
    config.update(changes)
    return config


def _train(tmp_path, config):
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "run.yaml"
    path.write_text(yaml.safe_dump(config))
    out = tmp_path / "run"
    summary = train(load_run_config(path, None), out, progress_bar=False)
    assert summary["timesteps"] >= config["total_timesteps"]
    return out


def test_observation_history_replicates_vec_frame_stack():
    from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack
    import gymnasium as gym

    class Counter(gym.Env):
        observation_space = gym.spaces.Box(-1e9, 1e9, (2,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (1,), np.float32)

        def __init__(self, length):
            self.length, self.t = length, 0

        def reset(self, seed=None, options=None):
            self.t = 0
            return np.array([self.t, -self.t], np.float32) + 100 * self.length, {}

        def step(self, action):
            self.t += 1
            obs = np.array([self.t, -self.t], np.float32) + 100 * self.length
            return obs, 0.0, self.t >= self.length, False, {}

    venv = VecFrameStack(DummyVecEnv([lambda: Counter(3), lambda: Counter(5)]), n_stack=3)
    history = ObservationHistory(3)
    raw = DummyVecEnv([lambda: Counter(3), lambda: Counter(5)])
    history.reset(2)
    expected, obs = venv.reset(), raw.reset()
    assert np.array_equal(history(obs), expected)
    for _ in range(8):
        expected, _, dones, _ = venv.step(np.zeros((2, 1)))
        obs, _, raw_dones, _ = raw.step(np.zeros((2, 1)))
        assert np.array_equal(dones, raw_dones)
        history.reset(2, np.nonzero(dones)[0])
        assert np.array_equal(history(obs), expected)


@pytest.mark.parametrize("memory", [{"algo": "recurrent_ppo", "policy_kwargs": {"net_arch": [8], "lstm_hidden_size": 4}},
                                    {"frame_stack": 3}])  # fmt: skip
def test_memory_training_saves_reloads_and_acts_per_row(tmp_path, memory):
    out = _train(tmp_path, _config(**memory))
    assert json.loads((out / "config.json").read_text()).get("frame_stack", 1) == memory.get("frame_stack", 1)
    env_config = make_config(SHORT, variant="v1")
    policy = load_policy(str(out), env_config, trusted=True)
    assert isinstance(policy, SB3Policy)
    assert (policy.recurrent is not None) == (memory.get("algo") == "recurrent_ppo")
    assert (policy.history is not None) == ("frame_stack" in memory)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(5, 3, policy.frame_shape[0])).astype(np.float32)  # 3 rows, 5 steps
    policy.reset(3)
    actions = np.stack([policy.act(o) for o in obs])
    assert actions.shape == (5, 3, policy.model.action_space.shape[0]) and np.all(np.abs(actions) <= 1.0)
    # a row reset mid-run acts as a fresh policy would on its observations from then on; the others keep their memory
    policy.reset(3)
    for o in obs[:3]:
        policy.act(o)
    policy.reset(3, [1])
    again = np.stack([policy.act(o) for o in obs[3:]])
    assert np.array_equal(again[:, [0, 2]], actions[3:, [0, 2]])
    fresh = load_policy(str(out), env_config, trusted=True)
    fresh.reset(1)
    alone = np.stack([fresh.act(o[1:2]) for o in obs[3:]])
    assert np.allclose(again[:, 1], alone[:, 0], atol=1e-6)
    assert not np.allclose(again[:, 1], actions[3:, 1], atol=1e-6)  # the memory mattered


def test_recurrent_washed_out_residual_trains_and_its_residual_is_zero_at_rest(tmp_path):
    config = _config(algo="recurrent_ppo", residual={"baseline": "robust_damping", "scale": 0.2, "features": "washed_out"},
                     vecnormalize={"norm_obs": False}, policy_kwargs={"net_arch": [8], "lstm_hidden_size": 4})  # fmt: skip
    out = _train(tmp_path, config)
    policy = load_policy(str(out), make_config(SHORT, variant="v1"), trusted=True)
    assert isinstance(policy, ResidualPolicy) and policy.network.recurrent is not None
    lstm = policy.model.policy.lstm_actor
    assert all(float(p.detach().abs().max()) == 0.0 for name, p in lstm.named_parameters() if name.startswith("bias"))
    policy.network.reset(2)
    zero = np.zeros((2, policy.network.frame_shape[0]), np.float32)
    for _ in range(3):
        assert np.array_equal(policy.network.act(zero), np.zeros((2, policy.model.action_space.shape[0]), np.float32))


def test_frame_stack_residual_trains(tmp_path):
    config = _config(frame_stack=2, residual={"baseline": "robust_damping", "scale": 0.2, "features": "washed_out"},
                     vecnormalize={"norm_obs": False})  # fmt: skip
    out = _train(tmp_path, config)
    policy = load_policy(str(out), make_config(SHORT, variant="v1"), trusted=True)
    assert isinstance(policy, ResidualPolicy) and policy.network.frame_stack == 2
    assert policy.model.observation_space.shape == (24,)


@pytest.mark.parametrize(
    "changes, message",
    [({"frame_stack": 0}, r"'frame_stack' = 0 is not allowed; allowed: an integer in \[1, 64\]"),
     ({"frame_stack": 2.5}, r"'frame_stack' = 2.5 is not allowed"),
     ({"algo": "recurrent_ppo", "policy": "MlpPolicy"}, "'policy' = 'MlpPolicy' is not allowed; allowed: MlpLstmPolicy"),
     ({"policy_kwargs": {"lstm_hidden_size": 8}}, "'policy_kwargs.lstm_hidden_size' = 8 is not allowed with algo 'ppo'; "
                                                  "allowed: only with algo recurrent_ppo"),
     ({"algo": "recurrent_ppo", "policy_kwargs": {"lstm_hidden_size": 0}},
      r"'policy_kwargs.lstm_hidden_size' = 0 is not allowed; allowed: an integer in \[1, 4096\]"),
     ({"algo": "recurrent_ppo", "policy_kwargs": {"shared_lstm": "yes"}}, "'policy_kwargs.shared_lstm' = 'yes' is not allowed; allowed: true or false"),
     ({"algo": "recurrent_ppo", "hyperparams": {"buffer_size": 10}}, r"unknown key\(s\) \['buffer_size'\]")],
)  # fmt: skip
def test_memory_config_errors_name_field_value_and_allowed(changes, message):
    with pytest.raises(ConfigError, match=message):
        validate_run_config(_config(**changes), "test.yaml")


@pytest.mark.parametrize("memory", [{"algo": "recurrent_ppo", "policy_kwargs": {"net_arch": [8], "lstm_hidden_size": 4}},
                                    {"frame_stack": 2}])  # fmt: skip
def test_memory_training_is_reproducible_for_a_seed(tmp_path, memory):
    import torch

    params = []
    for k in range(2):
        out = _train(tmp_path / str(k), _config(**memory))
        model = load_policy(str(out / "final_model.zip"), make_config(SHORT, variant="v1"), trusted=True).model
        params.append(torch.nn.utils.parameters_to_vector(model.policy.parameters()).detach().numpy())
    assert np.array_equal(params[0], params[1])


@pytest.mark.parametrize("memory", [{"algo": "recurrent_ppo", "policy_kwargs": {"net_arch": [8], "lstm_hidden_size": 4}},
                                    {"frame_stack": 2}])  # fmt: skip
def test_memory_training_resumes_from_its_checkpoint(tmp_path, memory):
    config = _config(**memory, checkpoint={"freq_steps": 128})
    out = _train(tmp_path, config)
    summary = train(load_run_config(tmp_path / "run.yaml", None), out, total_timesteps=512, progress_bar=False)
    assert summary["resumed_from"] and summary["timesteps"] >= 512
    policy = load_policy(str(out), make_config(SHORT, variant="v1"), trusted=True)
    policy.reset(2)
    assert policy.act(np.zeros((2, policy.frame_shape[0]), np.float32)).shape == (2, policy.model.action_space.shape[0])


def _steady_loop(policy, speed_kmh=300.0):
    """The policy linearised in the v1 loop (margins.linear_loop) and its operating observation."""
    from bogie_agents.design import margins as M

    env_config = make_config(variant="v1")
    loop = M.linear_loop(policy, env_config, speed_kmh)
    config = M.policy_config(env_config, policy)
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, speed_kmh / 3.6, config, loop.plant.model)[0]
    return M, loop, y0


def _louder(network_policy) -> None:
    """Scale up an SB3 actor's action head (SB3 initialises it at gain 0.01, and a few hundred
    training steps leave it small), so that the network's part of the response is visible."""
    import torch

    with torch.no_grad():
        network_policy.model.policy.action_net.weight.mul_(30.0)


def _untrained_policy(algo: str, frames: int, policy_kwargs: dict) -> SB3Policy:
    """An untrained SB3 model on v1's observation (``frames`` stacked) as an SB3Policy with
    random normalisation statistics."""
    import gymnasium as gym
    import torch
    from sb3_contrib import RecurrentPPO
    from stable_baselines3 import PPO

    n_obs = gym.make("Bogie/Hunting-v1").observation_space.shape[0]

    class Spaces(gym.Env):
        observation_space = gym.spaces.Box(-10.0, 10.0, (frames * n_obs,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)

    cls, name = (RecurrentPPO, "MlpLstmPolicy") if algo == "recurrent_ppo" else (PPO, "MlpPolicy")
    model = cls(name, Spaces(), policy_kwargs={"activation_fn": torch.nn.Tanh, **policy_kwargs}, seed=3, device="cpu")
    rng = np.random.default_rng(1)
    policy = SB3Policy(model, rng.normal(scale=0.1, size=n_obs), rng.uniform(0.5, 2.0, n_obs), 10.0, 1e-8, algo,
                       make_config(variant="v1"), frame_stack=frames)  # fmt: skip
    _louder(policy)
    return policy


def _trained_residual(tmp_path, **changes):
    """A washed-out residual on robust_damping, trained for 256 steps, with a louder network."""
    config = _config(residual={"baseline": "robust_damping", "scale": 0.2, "features": "washed_out"},
                     vecnormalize={"norm_obs": False}, **changes)  # fmt: skip
    policy = load_policy(str(_train(tmp_path, config)), make_config(SHORT, variant="v1"), trusted=True)
    _louder(policy.network)
    return policy


def test_frame_stack_policy_linear_model_follows_its_act():
    """A frame-stacked SB3 policy is linearised with its history as controller state (a shift
    register of the earlier observations): its model follows ``act`` on a random sequence, and
    the same Jacobian with the frames in the wrong order does not."""
    from bogie_agents.design.linear_models import stack_model

    frames = 3
    policy = _untrained_policy("ppo", frames, {"net_arch": [16]})
    M, loop, y0 = _steady_loop(policy)
    n_obs = y0.size
    assert loop.ctrl.n_states == (frames - 1) * n_obs
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3) < 2e-2  # float32 act
    jac = M.sb3_jacobian_autograd(policy, y0)
    reversed_frames = np.hstack([jac[:, j * n_obs:(j + 1) * n_obs] for j in reversed(range(frames))])
    wrong = stack_model(reversed_frames, n_obs, frames, "frames reversed")
    assert M.check_controller_model(policy, wrong, y0, loop.u_eq, amplitude=1e-3) > 0.1
    margins = M.loop_margins(loop)  # the margins are computed, not refused
    assert margins["loops"] and margins["controller_model"].endswith("3 stacked frames")


def test_recurrent_policy_linear_model_follows_its_act():
    """A RecurrentPPO policy is linearised about its LSTM's steady state, the hidden and cell
    states as controller states: its model follows ``act``, and the same model without the
    state's own dynamics does not."""
    import dataclasses

    policy = _untrained_policy("recurrent_ppo", 1, {"net_arch": [16], "lstm_hidden_size": 8})
    M, loop, y0 = _steady_loop(policy)
    assert loop.ctrl.n_states == 2 * 8
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3) < 2e-2  # float32 act
    frozen = dataclasses.replace(loop.ctrl, a=np.zeros_like(loop.ctrl.a))
    assert M.check_controller_model(policy, frozen, y0, loop.u_eq, amplitude=1e-3) > 0.1
    assert M.loop_margins(loop)["loops"]


@pytest.mark.parametrize("memory, method", [({"frame_stack": 2}, "2 stacked frames"),
                                            ({"algo": "recurrent_ppo", "policy_kwargs": {"net_arch": [8], "lstm_hidden_size": 4}},
                                             "LSTM state")])  # fmt: skip
def test_residual_with_memory_linear_model_follows_its_act(tmp_path, memory, method):
    """The washed-out residual with memory: baseline, feature filters and the network with its
    memory in one model, which follows the composite's ``act``."""
    policy = _trained_residual(tmp_path, **memory)
    M, loop, y0 = _steady_loop(policy)
    assert method in loop.ctrl.method
    error = M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3)
    # the network's share is visible: the baseline's model alone misses by far more
    baseline_only = M.controller_model(policy.baseline, y0.size, 300.0, y0)
    miss = M.check_controller_model(policy, baseline_only, y0, loop.u_eq, amplitude=1e-3)
    assert error < 2e-2 and error < 0.5 * miss  # seen: 0.003 against 0.045 (frames) and 0.015 (LSTM)
