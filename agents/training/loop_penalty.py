"""A penalty on a distilled correction's linearised loops, added to the distillation fit.

Behaviour cloning fits the teacher's commands where the data are (hunting, 2-8 Hz) and holds
nothing else: a student that imitates the privileged reference well can still destabilise the
loop's slower modes, as the distilled students of docs/studies/distillation.md do (a 1-2 Hz mode
growing at 2-4 1/s on new wheels). The margins are a property of the linear loop, so the fit
can be told them.

For a student linearised at rest on straight track, its Jacobian ``J`` (n_act x history*frame)
enters the closed loop affinely:

    A(J) = A0 + B (scale J) Phi

``A0``: the loop with the network cut, balanced by a diagonal similarity
(``scipy.linalg.matrix_balance``: same eigenvalues); ``B``: where the commands enter the loop,
times the loop gains of a variant; ``Phi``: the stacked frames (oldest first) in terms of the
loop's state. For a student on a classical baseline
(:class:`bogie_agents.controllers.distilled.ResidualFrames`) the loop holds the plant, the
baseline, the feature filters and the frame register, the frames are ``[features, speed]``, and
``scale`` is the correction's authority. For a plain mirrored student
(:class:`bogie_agents.controllers.distilled.FrameHistory`) the loop holds the plant, the frame
register and the last command (which enters the next frame), the frames are ``[observation,
last command]``, and ``scale`` is 1. Both are mirror-odd networks, so at rest (every mirrored
input zero) the command is zero and the operating point is the passive bogie's. ``A0``, ``B`` and
``Phi`` are built once per operating point by the margins' own tools
(:func:`bogie_agents.design.margins.linear_loop`); ``J`` comes from the network being fitted, by
torch, so the penalty has gradients.

The penalty bounds each loop's growth rate from above by Gelfand's formula,
``sigma_K = ln ||A^K||_F / (K dt) >= ln rho(A) / dt`` (``K`` a power of two, by repeated
squaring with normalisation), and adds ``weight x mean(relu(sigma_K - max_growth))^2`` over the
operating points and the variants: at ``points`` the nominal loop, each loop's command times
``gain`` (the gain-margin floor) and ``extra_delay_steps`` more delay in every channel (the
delay-margin floor); at ``stable_points`` the nominal loop only; at ``fault_points`` the loop
with each actuator failed in turn and the loop of each of the protocol's degraded bogies named
in ``fault_degraded`` (default half the creep). The bound is conservative (it never
under-estimates the growth), so a loop it calls stable is stable; ``bogie margins`` measures the
margins afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg

from bogie_env.params import ConfigError

from ..controllers.distilled import DistilledPolicy, FrameHistory, ResidualFrames, StudentNetwork, feature_frame_model
from ..design.margins import linear_loop, plant_bogie

#: The penalty's settings (``fit.loop_penalty`` in a distill config).
DEFAULTS: dict[str, Any] = {
    # (speed km/h, conicity) of each linearised loop: the margins floor's speeds on new wheels and
    # operating speeds on conicity-0.1 wheels (issue 25)
    "points": [[300.0, 0.025], [350.0, 0.025], [400.0, 0.025], [450.0, 0.025], [150.0, 0.1], [200.0, 0.1], [250.0, 0.1]],
    # (speed km/h, conicity) where only the nominal loop must be stable: the worn-wheel speeds the
    # reference reaches, and conicity 0.05, which the margin floor does not name
    "stable_points": [[350.0, 0.05], [450.0, 0.05], [130.0, 0.2], [160.0, 0.2], [110.0, 0.3], [130.0, 0.3]],
    # (speed km/h, conicity) where the nominal loop must stay stable with half the creep
    # (``creep_factor`` 0.5, the protocol's creep -50 %) and with each actuator failed in turn (its
    # command times 0, the protocol's failed actuators); none by default
    "fault_points": [],
    # the protocol's degraded bogies (``stability_protocol.DEGRADED``) whose nominal loop must stay
    # stable at each fault point, each on its own plant
    "fault_degraded": ["creep-50%"],
    "weight": 0.05,
    "gain": 2.0,  # each loop's command times this stays stable (gain margin)
    "extra_delay_steps": 1,  # this many more control steps of delay in every channel stay stable (delay margin)
    "max_growth_per_s": 0.0,
    "horizon_log2": 11,  # K = 2**11 steps (20.48 s at 100 Hz)
    "every": 20,  # evaluated on every n-th batch (weighted by n)
}


def check_penalty_config(value: Any, where: str = "fit.loop_penalty") -> dict[str, Any] | None:
    """``None`` (no penalty) or a mapping of :data:`DEFAULTS`' keys, merged into them and checked."""
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) - set(DEFAULTS):
        raise ConfigError(f"distill config {where!r} = {value!r}; allowed: null or a mapping with keys {', '.join(DEFAULTS)}")
    cfg = {**DEFAULTS, **value}
    for key in ("points", "stable_points", "fault_points"):
        points = cfg[key]
        if (not isinstance(points, list) or (key == "points" and not points)
                or not all(isinstance(p, (list, tuple)) and len(p) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
                           and 0.0 < p[0] <= 700.0 and 0.0 < p[1] <= 0.5 for p in points)):  # fmt: skip
            raise ConfigError(f"distill config '{where}.{key}' = {points!r}; allowed: a {'non-empty ' if key == 'points' else ''}"
                              f"list of [speed km/h in (0, 700], conicity in (0, 0.5]]")  # fmt: skip
    for key, low in (("weight", 0.0), ("gain", 1.0)):
        v = cfg[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < low:
            raise ConfigError(f"distill config '{where}.{key}' = {v!r}; allowed: a finite number >= {low:g}")
    from ..evaluation.stability_protocol import DEGRADED

    v = cfg["fault_degraded"]
    if not isinstance(v, list) or not all(isinstance(name, str) and name in DEGRADED for name in v) or len(set(v)) != len(v):
        raise ConfigError(f"distill config '{where}.fault_degraded' = {v!r}; allowed: a list of distinct names from {', '.join(DEGRADED)}")
    v = cfg["max_growth_per_s"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ConfigError(f"distill config '{where}.max_growth_per_s' = {v!r}; allowed: a finite number (1/s)")
    for key, low, high in (("extra_delay_steps", 0, 30), ("horizon_log2", 1, 16), ("every", 1, 10_000)):
        v = cfg[key]
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
            raise ConfigError(f"distill config '{where}.{key}' = {v!r}; allowed: an integer in [{low}, {high}]")
    return cfg


@dataclass
class LoopTerms:
    """One operating point's affine closed loops ``A(J) = a0[v] + b[v] (scale J) phi`` for the
    variants ``v`` that share a plant (the nominal plant and its gain variants; the plant with
    more delay has more states and its own terms)."""

    speed_kmh: float
    conicity: float
    a0: np.ndarray  # (variants, n, n)
    b: np.ndarray  # (variants, n, n_act)
    phi: np.ndarray  # (history * frame, n)
    x0: np.ndarray  # (history * frame,) the network's input at this point
    dt: float
    variants: tuple[str, ...]
    similarity: np.ndarray  # (n,) the balancing: these matrices are the loop's in states x / similarity
    kind: str = "margins"  # the settings' list of the point: margins, stable or faults


def plain_frame_map(frames: FrameHistory, plant_c: np.ndarray) -> np.ndarray:
    """``Phi`` of a plain student: the stacked frames ``[observation, last command]`` (oldest
    first) as a linear map of the loop state ``[plant; frame register (newest first); last command]``
    (:func:`bogie_agents.controllers.distilled.student_controller_model`'s states)."""
    width, history, n_y = frames.frame_dim, frames.history, frames.obs_dim
    n_p, n_reg = plant_c.shape[1], (history - 1) * width
    phi = np.zeros((history * width, n_p + n_reg + frames.action_dim))
    newest = (history - 1) * width
    phi[newest : newest + n_y, :n_p] = plant_c
    phi[newest + n_y : newest + width, n_p + n_reg :] = np.eye(frames.action_dim)
    for j in range(1, history):  # frame history-1-j is register slot j-1
        rows = slice((history - 1 - j) * width, (history - j) * width)
        start = n_p + (j - 1) * width
        phi[rows, start : start + width] = np.eye(width)
    return phi


def frame_map(frames: ResidualFrames, n_obs: int, speed_kmh: float, plant_c: np.ndarray, n_base: int) -> np.ndarray:
    """``Phi``: the stacked frames (oldest first) as a linear map of the loop state
    ``[plant; baseline; feature filters; frame register (newest first)]`` at ``speed_kmh``."""
    feat = feature_frame_model(frames, n_obs, speed_kmh)
    width, history = frames.frame_dim, frames.history
    n_f, n_reg = feat.n_states, (history - 1) * width
    n_p = plant_c.shape[1]
    phi = np.zeros((history * width, n_p + n_base + n_f + n_reg))
    newest = slice((history - 1) * width, history * width)
    phi[newest, :n_p] = feat.d @ plant_c
    phi[newest, n_p + n_base : n_p + n_base + n_f] = feat.c
    for j in range(1, history):  # frame history-1-j is register slot j-1
        rows = slice((history - 1 - j) * width, (history - j) * width)
        start = n_p + n_base + n_f + (j - 1) * width
        phi[rows, start : start + width] = np.eye(width)
    return phi


def _probe(frames: ResidualFrames | FrameHistory) -> DistilledPolicy:
    """The student with a zero network: its linear model is the loop without the network."""
    n_in = frames.history * frames.frame_dim
    network = StudentNetwork([np.zeros((frames.action_dim, n_in))], [np.zeros(frames.action_dim)], np.zeros(n_in), np.ones(n_in))
    if isinstance(frames, FrameHistory):
        return DistilledPolicy(network, frames.history, frames.obs_dim, frames.action_dim)
    return DistilledPolicy(network, frames.history, frames.obs_dim, frames.action_dim, frames=frames)


def loop_terms(frames: ResidualFrames | FrameHistory, env_config: dict, speed_kmh: float, conicity: float, gain: float,
               extra_delay_steps: int, faults: bool = False, degraded: tuple[str, ...] = ("creep-50%",)) -> list[LoopTerms]:  # fmt: skip
    """The affine closed loops at one operating point: the nominal loop and each channel's
    command times ``gain`` on one plant, and ``extra_delay_steps`` more delay in every channel;
    with ``faults`` instead each channel failed (times 0) and, each on its own plant, the
    ``degraded`` bogies of the protocol (default half the creep)."""
    probe = _probe(frames)
    loop = linear_loop(probe, env_config, speed_kmh, plant_bogie(env_config, conicity))
    n_act, n_obs = loop.plant.n_act, loop.plant.c.shape[0]
    plain = isinstance(frames, FrameHistory)
    if plain:  # the loop's command enters the plant and the last-command state (the next frame's)
        x0 = np.tile(np.concatenate([loop.y_eq, np.zeros(n_act)]), frames.history)
        into_ctrl = np.vstack([np.zeros((loop.ctrl.n_states - n_act, n_act)), np.eye(n_act)])
    else:
        n_base = loop.ctrl.n_states - feature_frame_model(frames, n_obs, speed_kmh).n_states - (frames.history - 1) * frames.frame_dim
        mirror = np.tile(frames.mirror_frame(), frames.history)
        x0 = np.where(mirror > 0, _speed_input(speed_kmh), 0.0)  # the features are zero at rest
        into_ctrl = np.zeros((loop.ctrl.n_states, n_act))
    if faults:
        from bogie_env.envs.config import bogie_params
        from bogie_env.envs.scenario import Scenario, scenario_model

        from ..evaluation.stability_protocol import DEGRADED

        nominal = plant_bogie(env_config, conicity)
        groups = [(loop, [(f"{loop.plant.channel_names[k]} failed", np.where(np.arange(n_act) == k, 0.0, 1.0)) for k in range(n_act)])]
        for name in degraded:
            plant = scenario_model(bogie_params(env_config), Scenario(conicity=conicity, **DEGRADED[name]), nominal)
            groups.append((linear_loop(probe, env_config, speed_kmh, plant), [(name.replace("-", " -"), np.ones(n_act))]))
    else:
        groups = [(loop, [("nominal", np.ones(n_act))] + ([(f"gain {gain:g} on channel {k}", np.where(np.arange(n_act) == k, gain, 1.0))
                                                           for k in range(n_act)] if gain > 1.0 else []))]  # fmt: skip
        if extra_delay_steps:
            groups.append((loop.with_extra_delay(extra_delay_steps), [(f"{extra_delay_steps} more delay steps", np.ones(n_act))]))
    out = []
    for lp, variants in groups:
        a0 = np.stack([lp.closed_loop_matrix(g) for _, g in variants])
        b = np.stack([np.vstack([lp.plant.b * g[None, :], into_ctrl]) for _, g in variants])
        phi = plain_frame_map(frames, lp.plant.c) if plain else frame_map(frames, n_obs, speed_kmh, lp.plant.c, n_base)
        # a diagonal similarity that balances the nominal loop (the states are in mixed SI units):
        # eigenvalues unchanged, the transient of ||A^K|| and with it the bound's excess far smaller
        _, (t, _) = scipy.linalg.matrix_balance(a0[0], permute=False, separate=True)
        a0, b, phi = a0 * t[None, None, :] / t[None, :, None], b / t[None, :, None], phi * t[None, :]
        out.append(LoopTerms(float(speed_kmh), float(conicity), a0, b, phi, x0, lp.dt, tuple(v[0] for v in variants), t))
    return out


def _speed_input(speed_kmh: float) -> float:
    """The observation's speed entry at ``speed_kmh`` (the env's scaling)."""
    from bogie_env.envs.task import SPEED_CENTRE_KMH, SPEED_SCALE_KMH

    return (speed_kmh - SPEED_CENTRE_KMH) / SPEED_SCALE_KMH


class LoopPenalty:
    """The penalty of the module docstring for one student shape, in torch (float64)."""

    def __init__(self, frames: ResidualFrames | FrameHistory, env_config: dict, settings: dict[str, Any], progress=None,
                 mirror: np.ndarray | None = None) -> None:  # fmt: skip
        """``mirror``: the student's input signs under the mirror (``distill.mirror_signs``); a
        residual student's are its frames' own, a plain student must be given them."""
        import torch

        if mirror is None:
            if isinstance(frames, FrameHistory):
                raise ValueError("LoopPenalty: a plain student's loop penalty needs its mirror signs (a mirrored student)")
            mirror = np.tile(frames.mirror_frame(), frames.history)
        mirror = np.asarray(mirror, dtype=np.float64)
        self.settings = settings
        self.frames = frames
        self.terms = []
        points = [(p, "margins") for p in settings["points"]] + [(p, "stable") for p in settings["stable_points"]] + \
                 [(p, "faults") for p in settings["fault_points"]]  # fmt: skip
        for k, ((speed, lam), kind) in enumerate(points):
            margins = kind == "margins"
            self.terms += [replace(t, kind=kind) for t in loop_terms(
                frames, env_config, float(speed), float(lam), settings["gain"] if margins else 1.0,
                settings["extra_delay_steps"] if margins else 0, faults=kind == "faults", degraded=tuple(settings["fault_degraded"]))]  # fmt: skip
            if progress:
                progress(k + 1, len(points))
        for t in self.terms:  # the odd part's Jacobian below needs a mirror-symmetric operating input
            if np.max(np.abs(t.x0[mirror < 0]), initial=0.0) > 1e-9:
                raise ValueError(f"LoopPenalty: the input at rest at {t.speed_kmh} km/h is not mirror-symmetric "
                                 f"(largest mirrored entry {np.max(np.abs(t.x0[mirror < 0])):.3g})")  # fmt: skip
        self.mask = torch.from_numpy((1.0 - mirror) / 2.0)
        self._x0 = [torch.from_numpy(np.where(mirror < 0, 0.0, t.x0)) for t in self.terms]
        self._a0 = [torch.from_numpy(t.a0) for t in self.terms]
        self._b = [torch.from_numpy(t.b) for t in self.terms]
        self._phi = [torch.from_numpy(t.phi) for t in self.terms]

    def scale(self, term: LoopTerms) -> float:
        """The network's authority at the term's speed: a correction's scale, 1 for a plain student."""
        return 1.0 if isinstance(self.frames, FrameHistory) else float(self.frames.scale_at(term.speed_kmh))

    def jacobian(self, linears: list, mean, std, x0):
        """d u / d x of the mirror-odd network ``(g(z) - g(m z)) / 2`` at the mirror-symmetric
        input ``x0`` (``m x0 = x0``; torch, float64, differentiable)."""
        import torch

        h = (x0 - mean.double()) / std.double()
        jac = None
        for i, lin in enumerate(linears):
            w = lin.weight.double()
            pre = h @ w.T + lin.bias.double()
            jac = w if jac is None else w @ jac
            if i < len(linears) - 1:
                h = torch.tanh(pre)
                jac = (1.0 - h**2)[:, None] * jac
        return jac * (self.mask / std.double())[None, :]  # at m z0 = z0 the odd part keeps the mirrored columns

    def growth_bounds(self, linears: list, mean, std):
        """Per point and variant (in :attr:`terms` order, flat), the upper bound ``sigma_K`` on the
        growth rate (1/s), torch."""
        import torch

        log2 = self.settings["horizon_log2"]
        out = []
        for t, a0, b, phi, x0 in zip(self.terms, self._a0, self._b, self._phi, self._x0):
            j = self.scale(t) * self.jacobian(linears, mean, std, x0)
            m = a0 + b @ (j @ phi)
            logs = torch.zeros(m.shape[0], dtype=torch.float64)
            for _ in range(log2):
                m = m @ m
                norm = torch.linalg.matrix_norm(m, dim=(-2, -1)).clamp_min(1e-300)
                m = m / norm[:, None, None]
                logs = 2.0 * logs + torch.log(norm)
            out.append(logs / (2**log2 * t.dt))
        return torch.cat(out)

    def __call__(self, linears: list, mean, std):
        import torch

        excess = torch.relu(self.growth_bounds(linears, mean, std) - self.settings["max_growth_per_s"])
        return self.settings["weight"] * torch.mean(excess**2)

    def growth_bounds_of(self, network: StudentNetwork) -> np.ndarray:
        """:meth:`growth_bounds` of a fitted numpy network (per point and variant, 1/s)."""
        import torch

        with torch.no_grad():
            return self.growth_bounds(*_torch_network(network)).numpy()

    def eigenvalues_of(self, network: StudentNetwork) -> list[np.ndarray]:
        """The eigenvalues of each loop of :meth:`growth_bounds_of`, per term (variants, n)."""
        import torch

        linears, mean, std = _torch_network(network)
        with torch.no_grad():
            return [np.linalg.eigvals((a0 + b @ (self.scale(t) * self.jacobian(linears, mean, std, x0) @ phi)).numpy())
                    for t, a0, b, phi, x0 in zip(self.terms, self._a0, self._b, self._phi, self._x0)]  # fmt: skip

    def growth_rates_of(self, network: StudentNetwork) -> np.ndarray:
        """The exact growth rate (1/s: largest log|eigenvalue| / dt) of each loop of
        :meth:`growth_bounds_of`, in the same order; below zero the loop is stable."""
        return np.concatenate([np.log(np.abs(z).max(axis=-1)) / t.dt for t, z in zip(self.terms, self.eigenvalues_of(network))])

    def named_rows(self) -> list[tuple[float, float, str, str]]:
        """Per loop of :meth:`growth_bounds_of`, in order: (speed km/h, conicity, kind, variant)."""
        return [(t.speed_kmh, t.conicity, t.kind, v) for t in self.terms for v in t.variants]


def _torch_network(network: StudentNetwork):
    """A fitted numpy network as :meth:`LoopPenalty.growth_bounds`' arguments (float64 torch)."""
    import torch

    linears = [_Linear(torch.from_numpy(np.asarray(w, dtype=np.float64)), torch.from_numpy(np.asarray(b, dtype=np.float64)))
               for w, b in zip(network.weights, network.biases)]  # fmt: skip
    return linears, torch.from_numpy(network.mean), torch.from_numpy(network.std)


@dataclass
class _Linear:
    weight: Any
    bias: Any
