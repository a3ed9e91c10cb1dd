"""Policies with memory: a recurrent policy (sb3-contrib's RecurrentPPO) or an observation history.

Two ways, both chosen in the agent config (``bogie train``, :mod:`bogie_agents.training.train`):

- ``algo: recurrent_ppo``: sb3-contrib's ``RecurrentPPO`` with ``policy: MlpLstmPolicy``; the
  LSTM's size is set with ``policy_kwargs`` (``lstm_hidden_size``, ``n_lstm_layers``,
  ``shared_lstm``, ``enable_critic_lstm``). The hidden state starts at zero in each episode.
- ``frame_stack: K`` (any on-policy or off-policy algorithm): the network sees the last ``K``
  observations (oldest first), through SB3's ``VecFrameStack`` on top of ``VecNormalize``; so
  each frame is normalised with the single-observation statistics, and a new episode starts
  with the earlier frames zero. With a residual on ``washed_out`` features the frames are the
  features (zero at rest), so the residual stays zero at rest.

At evaluation :class:`bogie_agents.controllers.policies.SB3Policy` keeps the same memory per row:
:class:`ObservationHistory` replicates ``VecFrameStack`` and :class:`RecurrentState` holds the
LSTM state; ``reset(n, rows)`` starts the given rows afresh (a zero history, a zero LSTM state).
"""

from __future__ import annotations

import numpy as np

from bogie_env.params import ConfigError

#: The largest ``frame_stack``.
MAX_FRAME_STACK = 64
#: ``policy_kwargs`` that only a recurrent policy takes: key -> (kind, low, high).
RECURRENT_POLICY_KWARGS = {"lstm_hidden_size": ("int", 1, 4096), "n_lstm_layers": ("int", 1, 8),
                           "shared_lstm": ("bool", 0, 1), "enable_critic_lstm": ("bool", 0, 1)}  # fmt: skip
RECURRENT_ALGOS = ("recurrent_ppo",)
RECURRENT_POLICY = "MlpLstmPolicy"


def check_frame_stack(value, where: str) -> int:
    """``frame_stack``: an integer in [1, :data:`MAX_FRAME_STACK`] (1: no history)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_FRAME_STACK:
        raise ConfigError(f"agent config {where}: 'frame_stack' = {value!r} is not allowed; allowed: an integer in "
                          f"[1, {MAX_FRAME_STACK}] (the observations the policy sees; 1: the current one only)")  # fmt: skip
    return value


def check_memory_config(config: dict, where: str) -> None:
    """The memory keys of an agent config: ``frame_stack``, the policy class and the LSTM's ``policy_kwargs``."""
    algo = config.get("algo")
    if config.get("frame_stack") is not None:
        check_frame_stack(config["frame_stack"], where)
    policy = config.get("policy", RECURRENT_POLICY if algo in RECURRENT_ALGOS else "MlpPolicy")
    allowed = RECURRENT_POLICY if algo in RECURRENT_ALGOS else "MlpPolicy"
    if policy != allowed:
        raise ConfigError(f"agent config {where}: 'policy' = {policy!r} is not allowed; allowed: {allowed} (with algo "
                          f"{algo!r}; the observations are flat vectors)")  # fmt: skip
    pk = config.get("policy_kwargs") or {}
    for key, value in pk.items() if isinstance(pk, dict) else ():
        if key not in RECURRENT_POLICY_KWARGS:
            continue
        if algo not in RECURRENT_ALGOS:
            raise ConfigError(f"agent config {where}: 'policy_kwargs.{key}' = {value!r} is not allowed with algo "
                              f"{algo!r}; allowed: only with algo {', '.join(RECURRENT_ALGOS)}")  # fmt: skip
        kind, low, high = RECURRENT_POLICY_KWARGS[key]
        if kind == "bool" and not isinstance(value, bool):
            raise ConfigError(f"agent config {where}: 'policy_kwargs.{key}' = {value!r} is not allowed; allowed: "
                              "true or false")  # fmt: skip
        if kind == "int" and (isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high):
            raise ConfigError(f"agent config {where}: 'policy_kwargs.{key}' = {value!r} is not allowed; allowed: an "
                              f"integer in [{low}, {high}]")  # fmt: skip


def frame_stack_of(config: dict) -> int:
    return int(config.get("frame_stack") or 1)


def stack_env(venv, config: dict):
    """``VecFrameStack(venv, K)`` for ``frame_stack: K`` > 1, else ``venv``."""
    k = frame_stack_of(config)
    if k == 1:
        return venv
    from stable_baselines3.common.vec_env import VecFrameStack

    return VecFrameStack(venv, n_stack=k)


def unstack_env(venv):
    """The env under a ``VecFrameStack`` (``venv`` itself if it is not one) and a function that puts the stack back."""
    from stable_baselines3.common.vec_env import VecFrameStack

    if isinstance(venv, VecFrameStack):
        k = venv.stacked_obs.n_stack
        return venv.venv, lambda inner: VecFrameStack(inner, n_stack=k)
    return venv, lambda inner: inner


class ObservationHistory:
    """The last ``k`` observations of each row, oldest first, as SB3's ``VecFrameStack`` stacks them
    (a 1-D observation: along the last axis): a row that starts afresh has zeros before its first
    observation."""

    def __init__(self, k: int) -> None:
        self.k = int(k)
        self.stack: np.ndarray | None = None
        self.fresh = np.zeros(0, dtype=bool)

    def reset(self, n_envs: int, rows=None) -> None:
        if rows is None or self.stack is None or self.fresh.size != n_envs:
            self.stack, self.fresh = None, np.ones(n_envs, dtype=bool)
        else:
            self.fresh[np.asarray(rows, dtype=int)] = True

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        n, d = obs.shape
        if self.stack is None or self.stack.shape[0] != n:
            self.stack = np.zeros((n, self.k * d), dtype=np.float32)
            self.fresh = np.ones(n, dtype=bool)
        self.stack[self.fresh] = 0.0
        self.stack = np.roll(self.stack, -d, axis=-1)
        self.stack[:, -d:] = obs
        self.fresh[:] = False
        return self.stack.copy()


class RecurrentState:
    """A recurrent SB3 model's LSTM state per row, and which rows start an episode at the next step."""

    def __init__(self) -> None:
        self.state: tuple[np.ndarray, ...] | None = None
        self.episode_start = np.zeros(0, dtype=bool)

    def reset(self, n_envs: int, rows=None) -> None:
        if rows is None or self.episode_start.size != n_envs:
            self.state, self.episode_start = None, np.ones(n_envs, dtype=bool)
        else:
            self.episode_start[np.asarray(rows, dtype=int)] = True

    def predict(self, model, obs: np.ndarray) -> np.ndarray:
        n = obs.shape[0]
        if self.episode_start.size != n:
            self.reset(n)
        actions, self.state = model.predict(obs, state=self.state, episode_start=self.episode_start, deterministic=True)
        self.episode_start = np.zeros(n, dtype=bool)
        return actions


def is_recurrent(model) -> bool:
    return hasattr(getattr(model, "policy", None), "lstm_actor")


def zero_lstm_biases(model) -> None:
    """Zero and freeze the actor LSTM's biases (``residual.features: washed_out``): from a zero
    state, zero features give a zero output, so the residual stays zero at rest. (An LSTM is not
    an odd function, unlike the feed-forward actor: the sign symmetry is not kept.)"""
    import torch

    lstm = getattr(model.policy, "lstm_actor", None)
    if lstm is None:
        return
    with torch.no_grad():
        for name, param in lstm.named_parameters():
            if name.startswith("bias"):
                param.zero_()
                param.requires_grad_(False)
