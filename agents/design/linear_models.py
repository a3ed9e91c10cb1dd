"""Linear models of controllers: what a policy does to a small change of its observation.

Shared by :mod:`bogie_agents.controllers.lqr` (a controller may describe itself) and
:mod:`bogie_agents.design.margins` (which puts the model in the loop), with no import of either, so
neither imports the other through it.

:class:`ControllerModel` is a discrete state space at the env's step ``dt``:
``c+ = a c + b dy``, ``du = c_ c + d dy``, from the deviation ``dy`` of the (scaled) observation
from the operating observation ``y0`` to the deviation ``du`` of the normalised action (the env's
action box [-1, 1]) from the action at rest.

**The hook.** A policy object may provide

    controller_model(n_obs: int, speed_kmh: float, y0: np.ndarray) -> ControllerModel

and :func:`bogie_agents.design.margins.controller_model` uses it instead of its own rules. ``y0`` is
the observation the env gives at the operating point (the closed loop's equilibrium at
``speed_kmh`` on perfect track, sensor noise and bias off, the anti-alias filters settled);
``n_obs == y0.size``.

**SB3 policies.** :func:`sb3_controller_model` (policy, y0) is the API for an SB3 policy (or any
object with an SB3 ``model`` and, optionally, VecNormalize statistics ``obs_mean``,
``obs_var``, ``clip_obs``, ``epsilon``): a static model whose ``d`` is the Jacobian of the
deterministic action by torch autograd (:func:`sb3_jacobian_autograd`); with frame stacking the
earlier frames are its states (:func:`stack_model`), a recurrent policy's its LSTM state
(:func:`lstm_controller_model`). A residual policy,
``action = clip(baseline(obs) + scale * NN(obs), -1, 1)``, is
:func:`residual_controller_model` (baseline's model, ``sb3_jacobian_autograd(nn, y0)``,
scale, action at ``y0``): the baseline's model with ``scale * J`` added to its
feedthrough, and the rows of channels clipped at ``y0`` zeroed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class ControllerModel:
    """``c+ = a c + b y``, ``u = c_ c + d y`` (y: observation deviation, u: normalised command deviation).

    ``a`` (n_c, n_c), ``b`` (n_c, n_obs), ``c`` (n_act, n_c), ``d`` (n_act, n_obs); ``method``
    says how the model was obtained (it is printed beside the margins).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    method: str  # how it was obtained

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    def dc_gain(self) -> np.ndarray:
        """(n_act, n_obs) the steady-state change of the command per steady change of the
        observation: ``d + c (I - a)^-1 b`` (an integrating controller has none: LinAlgError)."""
        if not self.n_states:
            return self.d
        return self.d + self.c @ np.linalg.solve(np.eye(self.n_states) - self.a, self.b)

    def check_shapes(self, n_obs: int, n_act: int) -> None:
        """Raise ValueError naming the matrix whose shape does not fit ``n_obs`` and ``n_act``."""
        n_c = self.a.shape[0] if self.a.ndim == 2 else -1
        expected = {"a": (n_c, n_c), "b": (n_c, n_obs), "c": (n_act, n_c), "d": (n_act, n_obs)}
        for name, shape in expected.items():
            value = np.asarray(getattr(self, name))
            if value.shape != shape:
                raise ValueError(f"ControllerModel ({self.method}): {name} has shape {value.shape}; expected {shape} "
                                 f"(n_states {n_c}, n_obs {n_obs}, n_act {n_act})")  # fmt: skip
            if not np.all(np.isfinite(value)):
                raise ValueError(f"ControllerModel ({self.method}): {name} contains NaN or inf")


def static_model(d: np.ndarray, method: str) -> ControllerModel:
    """A memoryless controller ``u = d y``."""
    d = np.asarray(d, dtype=float)
    m, p = d.shape
    return ControllerModel(np.zeros((0, 0)), np.zeros((0, p)), np.zeros((m, 0)), d, method)


def series(first: ControllerModel, second: ControllerModel, method: str) -> ControllerModel:
    """``second`` fed by ``first``'s output: states ``[first; second]``."""
    n1, n2 = first.n_states, second.n_states
    a = np.block([[first.a, np.zeros((n1, n2))], [second.b @ first.c, second.a]])
    b = np.vstack([first.b, second.b @ first.d])
    c = np.hstack([second.d @ first.c, second.c])
    return ControllerModel(a, b, c, second.d @ first.d, method)


def parallel(first: ControllerModel, second: ControllerModel, method: str) -> ControllerModel:
    """The sum of two models' outputs for the same input: states ``[first; second]``."""
    n1, n2 = first.n_states, second.n_states
    a = np.block([[first.a, np.zeros((n1, n2))], [np.zeros((n2, n1)), second.a]])
    return ControllerModel(a, np.vstack([first.b, second.b]), np.hstack([first.c, second.c]), first.d + second.d, method)


def stack_model(jacobian: np.ndarray, n_in: int, frames: int, method: str) -> ControllerModel:
    """The linear model of a network fed the last ``frames`` inputs side by side, oldest first (as
    SB3's ``VecFrameStack`` and :class:`bogie_agents.controllers.memory.ObservationHistory` stack
    them), from its Jacobian (n_act, frames * n_in) on the stack.

    The state holds the ``frames - 1`` previous inputs, newest first: ``c+ = [x, c_1, ...,
    c_{frames-2}]`` (a shift register), and ``u = J_newest x + sum_j J_(newest - j) c_j``.
    One frame: the static model ``u = J x``."""
    jacobian = np.asarray(jacobian, dtype=float)
    if jacobian.shape[1] != frames * n_in:
        raise ValueError(f"stack_model: Jacobian has {jacobian.shape[1]} columns; expected frames x n_in = {frames * n_in}")
    blocks = [jacobian[:, j * n_in:(j + 1) * n_in] for j in range(frames)]  # oldest first
    if frames == 1:
        return static_model(blocks[0], method)
    n_c = (frames - 1) * n_in
    a = np.zeros((n_c, n_c))
    a[n_in:, :n_c - n_in] = np.eye(n_c - n_in)
    b = np.zeros((n_c, n_in))
    b[:n_in] = np.eye(n_in)
    c = np.hstack([blocks[frames - 2 - j] for j in range(frames - 1)])
    return ControllerModel(a, b, c, blocks[-1], method)


def residual_controller_model(baseline: ControllerModel, nn_jacobian: np.ndarray, scale: float | np.ndarray,
                              action_at_rest: np.ndarray | None = None) -> ControllerModel:  # fmt: skip
    """The linear model of ``action = clip(baseline(y) + scale * NN(y), -1, 1)`` at ``y0``.

    ``baseline``: the baseline's model at ``y0``; ``nn_jacobian`` (n_act, n_obs): d NN / d y at
    ``y0`` (e.g. :func:`sb3_jacobian_autograd`); ``scale``: scalar or per channel;
    ``action_at_rest``: the clipped total action at ``y0`` (a channel at the clip, ``|u| >= 1``,
    has zero small-signal gain; None: nothing clipped).
    """
    scale = np.broadcast_to(np.asarray(scale, dtype=float), (baseline.d.shape[0],))
    d = baseline.d + scale[:, None] * np.asarray(nn_jacobian, dtype=float)
    c = baseline.c.copy()
    if action_at_rest is not None:
        clipped = np.abs(np.asarray(action_at_rest, dtype=float)) >= 1.0
        d[clipped] = 0.0
        c[clipped] = 0.0
    return ControllerModel(baseline.a, baseline.b, c, d, f"residual: {baseline.method} + scale x NN Jacobian")


# ---- SB3 policies ------------------------------------------------------------------------------
def _normalisation(policy):
    """VecNormalize statistics of the policy (mean, var, epsilon, clip) or the identity."""
    mean = getattr(policy, "obs_mean", None)
    if mean is None:
        return None, None, 0.0, math.inf
    return mean, policy.obs_var, policy.epsilon, policy.clip_obs


def frames_of(policy) -> int:
    """How many observations side by side the SB3 policy's network takes (its ``frame_stack``)."""
    return int(getattr(policy, "frame_stack", 1)) if getattr(policy, "history", None) is not None else 1


def sb3_action_function(policy):
    """The SB3 policy's deterministic action as a float64 torch function of its network's input:
    :func:`frames_of` raw observations side by side, oldest first (one, without frame stacking),
    each through the VecNormalize scaling and clipping, then the network (a float64 copy for
    PPO/A2C) and the action-box clip. ``policy.model`` is the SB3 algorithm;
    ``obs_mean``/``obs_var``/``epsilon``/``clip_obs`` (optional attributes) the statistics of one
    observation. A recurrent (LSTM) policy is refused: its action depends on its state too
    (:func:`lstm_step_function`)."""
    import copy

    import torch

    from stable_baselines3.common.policies import ActorCriticPolicy

    if getattr(policy, "recurrent", None) is not None:
        from bogie_env.params import ConfigError

        raise ConfigError(f"policy {getattr(policy, 'name', '?')!r} is recurrent (an LSTM): its action is not a "
                          "function of the observation alone; use lstm_step_function")  # fmt: skip
    frames = frames_of(policy)
    net = policy.model.policy
    # PPO/A2C: the actor's layers in float64 (SB3's own _predict casts observations to float32)
    double = isinstance(net, ActorCriticPolicy) and not net.squash_output
    dtype = torch.float64 if double else torch.float32
    if double:
        net = copy.deepcopy(net).double()
    mean_np, var_np, eps, clip = _normalisation(policy)
    mean = torch.as_tensor(0.0 if mean_np is None else mean_np, dtype=dtype)
    var = torch.as_tensor(1.0 if var_np is None else var_np, dtype=dtype)

    def deterministic(z: torch.Tensor) -> torch.Tensor:
        if double:
            return net.action_net(net.mlp_extractor.forward_actor(net.pi_features_extractor(z)))
        return net._predict(z, deterministic=True)

    def action(y: torch.Tensor) -> torch.Tensor:
        y = y.to(dtype).reshape(frames, -1)
        z = torch.clamp((y - mean) / torch.sqrt(var + eps), -clip, clip).reshape(-1)
        return torch.clamp(deterministic(z[None])[0], -1.0, 1.0).double()

    return action


def _steady_input(policy, y: np.ndarray) -> np.ndarray:
    """The network's input while the observation stays at ``y``: ``y`` in every frame."""
    return np.tile(np.asarray(y, dtype=np.float64), frames_of(policy))


def sb3_action(policy, y: np.ndarray) -> np.ndarray:
    """The SB3 policy's action at a steady observation ``y``, in float64 (``act`` rounds to float32);
    a recurrent policy's at its LSTM's steady state (:func:`lstm_steady_state`)."""
    import torch

    if getattr(policy, "recurrent", None) is not None:
        step = lstm_step_function(policy)
        with torch.no_grad():
            return step(lstm_steady_state(policy, y), torch.as_tensor(np.asarray(y, dtype=np.float64)))[1].numpy()
    with torch.no_grad():
        return sb3_action_function(policy)(torch.as_tensor(_steady_input(policy, y))).numpy()


def sb3_jacobian_autograd(policy, y0: np.ndarray) -> np.ndarray:
    """(n_act, frames x n_obs) d(action)/d(network input) of an SB3 policy at the steady
    observation ``y0`` (``frames`` = :func:`frames_of`; one: d(action)/d(observation)).

    Through the VecNormalize scaling and clipping (attributes ``obs_mean``, ``obs_var``,
    ``epsilon``, ``clip_obs`` of ``policy``, if present) and the action-box clip, by torch
    autograd on the deterministic action (float64 for PPO/A2C). ``policy.model`` is the SB3
    algorithm (PPO, SAC, TD3, ...). ``y0`` is the raw (env-scaled, un-normalised) observation.
    For a residual policy, call this on the network part and combine with
    :func:`residual_controller_model`.
    """
    import torch

    jac = torch.autograd.functional.jacobian(sb3_action_function(policy), torch.as_tensor(_steady_input(policy, y0)))
    return jac.detach().numpy()


def lstm_step_function(policy):
    """One step of a recurrent (sb3-contrib RecurrentPPO) policy as a float64 torch function
    ``(state, y) -> (next state, action)``: ``state`` the actor LSTM's hidden and cell states
    flattened, ``y`` the raw observation (VecNormalize scaling and clipping, the LSTM, the actor's
    layers, the deterministic action and the action-box clip, as ``predict`` computes them)."""
    import copy

    import torch

    net = copy.deepcopy(policy.model.policy).double()
    lstm = net.lstm_actor
    layers, hidden = lstm.num_layers, lstm.hidden_size
    size = layers * hidden
    mean_np, var_np, eps, clip = _normalisation(policy)
    mean = torch.as_tensor(0.0 if mean_np is None else mean_np, dtype=torch.float64)
    var = torch.as_tensor(1.0 if var_np is None else var_np, dtype=torch.float64)

    def step(state: torch.Tensor, y: torch.Tensor):
        z = torch.clamp((y.double() - mean) / torch.sqrt(var + eps), -clip, clip)
        features = net.pi_features_extractor(z[None])
        h, c = state[:size].reshape(layers, 1, hidden), state[size:].reshape(layers, 1, hidden)
        out, (h_next, c_next) = lstm(features[None], (h, c))
        action = net.action_net(net.mlp_extractor.forward_actor(out[0]))[0]
        return torch.cat([h_next.reshape(-1), c_next.reshape(-1)]), torch.clamp(action, -1.0, 1.0)

    step.state_size = 2 * size
    return step


def lstm_steady_state(policy, y0: np.ndarray, max_steps: int = 5000, tol: float = 1e-12) -> "torch.Tensor":
    """The actor LSTM's state after the observation has stayed at ``y0`` long enough: iterated
    from the episode start's zero state until it changes by at most ``tol``."""
    import torch

    step = lstm_step_function(policy)
    y = torch.as_tensor(np.asarray(y0, dtype=np.float64))
    state = torch.zeros(step.state_size, dtype=torch.float64)
    with torch.no_grad():
        for _ in range(max_steps):
            following = step(state, y)[0]
            if float(torch.max(torch.abs(following - state))) <= tol:
                return following
            state = following
    raise ValueError(f"policy {getattr(policy, 'name', '?')!r}: its LSTM state did not settle at the operating "
                     f"observation within {max_steps} steps (no steady state to linearise about)")  # fmt: skip


def lstm_controller_model(policy, y0: np.ndarray) -> ControllerModel:
    """The linear model of a recurrent policy about its steady state at ``y0``: the LSTM's hidden
    and cell states are the controller's states, ``a``, ``b`` the Jacobians of the next state and
    ``c``, ``d`` those of the action, with respect to the state and the observation (torch autograd)."""
    import torch

    step = lstm_step_function(policy)
    state = lstm_steady_state(policy, y0)
    y = torch.as_tensor(np.asarray(y0, dtype=np.float64))
    (a, b), (c, d) = torch.autograd.functional.jacobian(step, (state, y))
    return ControllerModel(*(m.detach().numpy() for m in (a, b, c, d)),
                           "SB3 recurrent policy, torch autograd about its LSTM's steady state")  # fmt: skip


def sb3_controller_model(policy, y0: np.ndarray) -> ControllerModel:
    """The linear model of an SB3 policy at the raw observation ``y0``: static, ``d`` =
    :func:`sb3_jacobian_autograd` (policy, y0); with frame stacking, :func:`stack_model` of it;
    a recurrent policy, :func:`lstm_controller_model`."""
    if getattr(policy, "recurrent", None) is not None:
        return lstm_controller_model(policy, y0)
    frames = frames_of(policy)
    method = "SB3 policy, torch autograd through VecNormalize" + (f", {frames} stacked frames" if frames > 1 else "")
    return stack_model(sb3_jacobian_autograd(policy, y0), np.asarray(y0).size, frames, method)


def finite_difference_jacobian(policy, y0: np.ndarray, step: float = 1e-3) -> np.ndarray:
    """Central differences of ``policy.act`` at ``y0`` (a stateless policy); ``step`` in the
    observation's scaled units (float32 policies need about 1e-3)."""
    y0 = np.asarray(y0, dtype=np.float64)
    n = y0.size
    probes = np.repeat(y0[None], 2 * n, axis=0)
    probes[np.arange(n), np.arange(n)] += step
    probes[n + np.arange(n), np.arange(n)] -= step
    policy.reset(2 * n)
    out = np.asarray(policy.act(probes.astype(np.float32)), dtype=np.float64)
    return ((out[:n] - out[n:]) / (2 * step)).T
