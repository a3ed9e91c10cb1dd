"""A student distilled from the privileged reference: sensors and its own commands in, commands out.

:class:`DistilledPolicy` is a multilayer perceptron on the last ``history`` frames of what a
buildable controller has: each frame is the env's sensor observation (v1: six sensors, the
speed and the measured actuator forces) and the command the controller sent one step before.
It is trained by :mod:`bogie_agents.training.distill` (DAgger: Ross, Gordon & Bagnell 2011) to
give the command that the privileged reference (:mod:`bogie_agents.controllers.privileged`),
told the true scenario and seeing the full state, gives in the same state. It is told nothing.

**Files.** A student is a folder with ``student.npz`` (the weights and the frame normalisation,
plain arrays, read with ``allow_pickle=False``) and ``student.json`` (its shape, the env id it
was trained on, the training config). Neither holds code, so loading one needs no trust
(unlike an SB3 ``.zip``).

**On a classical baseline** (``residual``): the student's output is a correction on top of a
classical controller, ``u = clip(baseline(y) + scale * r, -1, 1)``, and ``r`` sees the last
``history`` frames of the baseline's washed-out design signals
(:class:`bogie_agents.controllers.residual.WashedOutFeatures`) and the speed
(:class:`ResidualFrames`); it is fitted to ``(teacher - baseline) / scale``. The design signals
are zero for any constant observation and the network is odd in them, so the correction is zero
at rest and has no state of its own beyond a finite history of filtered sensors: at low
frequency the loop is the baseline's, whose margins are designed; the student acts where the
signals move (hunting, 1-10 Hz). A plain student's own past commands are inputs, and nothing
holds its slow dynamics (docs/studies/distillation.md).

The frames and the network are one function, :meth:`StudentNetwork.forward`, and one history
class (:class:`FrameHistory` or :class:`ResidualFrames`), used by training and evaluation alike.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bogie_env.fileio import atomic_output, write_text_atomic
from bogie_env.params import ConfigError

WEIGHTS_FILE = "student.npz"
META_FILE = "student.json"
FORMAT = "bogie-distilled-1"


class FrameHistory:
    """Per row, the last ``history`` frames ``[observation, previous command]``, oldest first;
    zeros before an episode's first frame."""

    def __init__(self, history: int, obs_dim: int, action_dim: int) -> None:
        self.history, self.obs_dim, self.action_dim = int(history), int(obs_dim), int(action_dim)
        self.frames = np.zeros((0, self.history, self.frame_dim), dtype=np.float32)
        self.last_command = np.zeros((0, self.action_dim), dtype=np.float32)

    @property
    def frame_dim(self) -> int:
        return self.obs_dim + self.action_dim

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        if rows is None or self.frames.shape[0] != n_envs:
            self.frames = np.zeros((n_envs, self.history, self.frame_dim), dtype=np.float32)
            self.last_command = np.zeros((n_envs, self.action_dim), dtype=np.float32)
        else:
            self.frames[rows] = 0.0
            self.last_command[rows] = 0.0

    def push(self, obs: np.ndarray) -> np.ndarray:
        """Append each row's frame (``obs`` and its last command); the flat input, (n, history * frame_dim)."""
        if self.frames.shape[0] != obs.shape[0]:
            self.reset(obs.shape[0])
        self.frames[:, :-1] = self.frames[:, 1:]
        self.frames[:, -1, : self.obs_dim] = obs
        self.frames[:, -1, self.obs_dim :] = self.last_command
        return self.frames.reshape(obs.shape[0], -1)

    def sent(self, commands: np.ndarray) -> None:
        """The commands the env was given this step (they enter the next frame)."""
        self.last_command[:] = commands

    # the interface the student and the rollouts use (shared with ResidualFrames)
    def inputs(self, obs: np.ndarray) -> tuple[np.ndarray, None]:
        """The network's flat input for this step's observations, and no baseline command."""
        return self.push(obs), None

    @staticmethod
    def command(output: np.ndarray, base: None) -> np.ndarray:
        """The command sent for the network's ``output``."""
        return output

    @staticmethod
    def target(label: np.ndarray, base: None) -> np.ndarray:
        """What the network is fitted to for the teacher's ``label``."""
        return label


class ResidualFrames:
    """A student on a classical baseline (module docstring): per row the baseline, the washed-out
    feature filters and the last ``history`` frames ``[features, speed]``, oldest first."""

    def __init__(self, history: int, env_config: dict, baseline: str, scale: float | Mapping[str, Any], action_dim: int) -> None:
        from bogie_env.envs.task import speed_index

        from .classical import CLASSICAL
        from .residual import WashedOutFeatures

        self.baseline_name = baseline
        #: the correction's authority: a number, or None with :attr:`schedule` over speed
        self.scale: float | None = None if isinstance(scale, Mapping) else float(scale)
        #: (speeds in km/h, authorities), linear in between and constant beyond; None: :attr:`scale`
        self.schedule = None if self.scale is not None else (np.asarray(scale["speeds_kmh"], float), np.asarray(scale["scales"], float))
        self._row_scale: float | np.ndarray = self.scale if self.scale is not None else 1.0
        self.observation_type = env_config["observation"]["type"]
        self.baseline = CLASSICAL[baseline](env_config)
        self.features = WashedOutFeatures(env_config)
        self.obs_dim = self.features.filters.n_obs
        self.action_dim = int(action_dim)
        self.speed_column = speed_index(env_config["observation"]["type"])
        self.history = int(history)
        self.stack = FrameHistory(history, self.features.dim + 1, 0)

    @property
    def frame_dim(self) -> int:
        return self.stack.frame_dim

    def mirror_frame(self) -> np.ndarray:
        """-1 for the features (they change sign with the mirrored bogie), +1 for the speed."""
        return np.concatenate([-np.ones(self.features.dim), [1.0]]).astype(np.float32)

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        self.baseline.reset(n_envs, rows)
        self.features.reset(n_envs, rows)
        self.stack.reset(n_envs, rows)

    def scale_at(self, speed_kmh: float | np.ndarray) -> float | np.ndarray:
        """The correction's authority at ``speed_kmh``."""
        if self.schedule is None:
            return self.scale
        return np.interp(speed_kmh, *self.schedule)

    def inputs(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        obs = np.asarray(obs, dtype=np.float32)
        if self.schedule is not None:  # each row's authority at its speed, for command() and target()
            from bogie_env.envs.task import speed_kmh_from_observation

            self._row_scale = self.scale_at(speed_kmh_from_observation(obs, self.observation_type))[:, None]
        base = np.asarray(self.baseline.act(obs), dtype=np.float32)
        frame = np.concatenate([self.features(obs), obs[:, self.speed_column : self.speed_column + 1]], axis=1)
        return self.stack.push(frame), base

    def sent(self, commands: np.ndarray) -> None:
        """Nothing: the correction does not see its own commands."""

    def command(self, output: np.ndarray, base: np.ndarray) -> np.ndarray:
        from .residual import compose

        return compose(base, output, self._row_scale)

    def target(self, label: np.ndarray, base: np.ndarray) -> np.ndarray:
        return np.clip((np.asarray(label, dtype=np.float64) - base) / self._row_scale, -1.0, 1.0).astype(np.float32)


class StudentNetwork:
    """``u = clip(g(z), -1, 1)``, ``z = (x - mean) / std``, ``g`` a tanh MLP in numpy.

    With a mirror mask (``mirror``: -1 for the inputs that change sign when the bogie is mirrored
    about the track's centre line, +1 for the speed) the student is odd in them by construction:
    ``u = clip((g(z) - g(m z)) / 2, -1, 1)``, with ``mean`` zero on the mirrored inputs. On straight
    track the plant is mirror symmetric and the reference is linear, so its command is odd: zero at
    rest, the opposite for the mirrored state. An unconstrained fit leaves a command at rest (a
    steady force that pushes a wheelset towards its flange) and lets one side differ from the other."""

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray], mean: np.ndarray, std: np.ndarray,
                 mirror: np.ndarray | None = None) -> None:  # fmt: skip
        self.weights = [np.asarray(w, dtype=np.float32) for w in weights]
        self.biases = [np.asarray(b, dtype=np.float32) for b in biases]
        self.mean, self.std = np.asarray(mean, dtype=np.float32), np.asarray(std, dtype=np.float32)
        self.mirror = None if mirror is None else np.asarray(mirror, dtype=np.float32)

    def hidden(self, z: np.ndarray, dtype=np.float32) -> np.ndarray:
        """``g(z)``: the MLP on normalised inputs, unclipped."""
        h = z
        for w, b in zip(self.weights[:-1], self.biases[:-1]):
            h = np.tanh(h @ w.T.astype(dtype) + b.astype(dtype))
        return h @ self.weights[-1].T.astype(dtype) + self.biases[-1].astype(dtype)

    def forward(self, x: np.ndarray, dtype=np.float32) -> np.ndarray:
        """The commands for flat inputs ``x`` (n, inputs); ``dtype``: the arithmetic's (float32 as
        it runs; float64 for the margins' operating point)."""
        z = (np.asarray(x, dtype=dtype) - self.mean.astype(dtype)) / self.std.astype(dtype)
        g = self.hidden(z, dtype)
        if self.mirror is not None:
            g = (g - self.hidden(z * self.mirror.astype(dtype), dtype)) * dtype(0.5)
        return np.clip(g, -1.0, 1.0)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """d u / d x at one flat input ``x`` before the clip, float64 (n_act, inputs)."""
        z = (np.asarray(x, dtype=np.float64) - self.mean) / self.std

        def dg(z0: np.ndarray) -> np.ndarray:
            jac = np.eye(z0.size)
            h = z0
            for w, b in zip(self.weights[:-1], self.biases[:-1]):
                h = np.tanh(w.astype(np.float64) @ h + b)
                jac = (1.0 - h**2)[:, None] * (w.astype(np.float64) @ jac)
            return self.weights[-1].astype(np.float64) @ jac

        jac = dg(z) if self.mirror is None else 0.5 * (dg(z) - dg(z * self.mirror) * self.mirror[None, :])
        return jac / self.std.astype(np.float64)[None, :]


class DistilledPolicy:
    """A distilled student acting on sensor observations (module docstring); ``frames``: a
    :class:`ResidualFrames` for a student on a classical baseline (default: a plain
    :class:`FrameHistory`)."""

    observation_type = "sensors"
    knows = "nothing"

    def __init__(self, network: StudentNetwork, history: int, obs_dim: int, action_dim: int, name: str = "distilled",
                 meta: dict[str, Any] | None = None, frames: "ResidualFrames | None" = None) -> None:  # fmt: skip
        self.network = network
        self.frames = frames if frames is not None else FrameHistory(history, obs_dim, action_dim)
        self.name = name
        self.meta = meta or {}

    @property
    def residual(self) -> bool:
        return isinstance(self.frames, ResidualFrames)

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        self.frames.reset(n_envs, rows)

    def steady_action(self, y: np.ndarray) -> np.ndarray:
        """The command it holds at a constant observation (the margins' operating point)."""
        if not self.residual:
            return operating_command(self, y)
        self.reset(1)  # on a baseline: the correction is zero at rest, the baseline's filters settle
        y32 = np.asarray(y, dtype=np.float32).reshape(1, -1)
        u = self.act(y32)[0].astype(np.float64)
        for _ in range(1000):
            u_next = self.act(y32)[0].astype(np.float64)
            if np.max(np.abs(u_next - u)) <= 1e-7:
                break
            u = u_next
        return u_next

    def controller_model(self, n_obs: int, speed_kmh: float, y0: np.ndarray):
        """The margins' linear model (:func:`student_controller_model`, :func:`residual_student_model`)."""
        if self.residual:
            return residual_student_model(self, n_obs, speed_kmh, y0)
        return student_controller_model(self, y0)

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        if obs.shape[-1] != self.frames.obs_dim:
            raise ConfigError(f"policy {self.name!r} takes observations of {self.frames.obs_dim} entries; got {obs.shape[-1]}")
        x, base = self.frames.inputs(obs)
        u = self.frames.command(self.network.forward(x), base).astype(np.float32)
        self.frames.sent(u)
        return u


def operating_command(policy: "DistilledPolicy", y: np.ndarray) -> np.ndarray:
    """The command ``u0 = student(frames of [y, u0])`` the student holds at a constant observation
    ``y`` (float64): a root, not a settling run. The student's loop through its own commands, with
    the observation held, need not settle (in the plant the measured forces follow the commands)."""
    from scipy.optimize import root

    y = np.asarray(y, dtype=np.float64).reshape(-1)
    net, frames = policy.network, policy.frames

    def gap(u: np.ndarray) -> np.ndarray:
        return net.forward(np.tile(np.concatenate([y, u]), frames.history)[None], np.float64)[0] - u

    # from rest, then from seeded random commands: Powell's hybrid method and Levenberg-Marquardt
    # can stall on a clipped network from one start
    starts = [np.zeros(frames.action_dim)] + list(np.random.default_rng(0).uniform(-1.0, 1.0, (16, frames.action_dim)))
    residual, message = np.inf, ""
    for start, method in ((x, m) for x in starts for m in ("hybr", "lm")):
        sol = root(gap, start, method=method)
        residual, message = float(np.max(np.abs(gap(sol.x)))), sol.message
        if residual <= 1e-9:
            return sol.x
    raise ValueError(f"student {policy.name!r}: no operating command at this observation "
                     f"(fixed-point residual {residual:.2e}: {message})")  # fmt: skip


def student_controller_model(policy: "DistilledPolicy", y0: np.ndarray):
    """The linear model of a student at the operating observation ``y0`` (the margins' hook).

    The operating command ``u0`` solves ``u0 = student(frames of [y0, u0])``; the student is left
    in that state. About it, the network's Jacobian on the stacked frames is a
    frame shift register (:func:`bogie_agents.design.linear_models.stack_model`), and the frame's
    command part is closed through one more state, the last command: ``v+ = u``. A channel at
    the clip (|u0| = 1) has zero small-signal gain."""
    from ..design.margins import ControllerModel, stack_model

    y0 = np.asarray(y0, dtype=np.float64).reshape(-1)
    net, frames = policy.network, policy.frames
    u0 = operating_command(policy, y0)
    policy.reset(1)
    frames.frames[0] = np.tile(np.concatenate([y0, u0]), (frames.history, 1))
    frames.last_command[0] = u0
    jac = net.jacobian(frames.frames.reshape(-1))
    jac[np.abs(u0) >= 1.0 - 1e-9] = 0.0
    n_y, n_u = frames.obs_dim, frames.action_dim
    inner = stack_model(jac, frames.frame_dim, frames.history, "")
    e_y = np.vstack([np.eye(n_y), np.zeros((n_u, n_y))])
    e_u = np.vstack([np.zeros((n_y, n_u)), np.eye(n_u)])
    a = np.block([[inner.a, inner.b @ e_u], [inner.c, inner.d @ e_u]])
    b = np.vstack([inner.b @ e_y, inner.d @ e_y])
    c = np.hstack([inner.c, inner.d @ e_u])
    return ControllerModel(a, b, c, inner.d @ e_y, f"distilled student: analytic Jacobian about its operating command, "
                           f"{frames.history} frames and its last command as states")  # fmt: skip


def feature_frame_model(frames: ResidualFrames, n_obs: int, speed_kmh: float):
    """The newest frame ``[features, speed]`` as a linear model of the observation at a fixed
    speed (the feature filters' states; no clip)."""
    from ..design.margins import ControllerModel

    a, b, c, d = frames.features.linear_map(speed_kmh)
    speed_row = np.zeros((1, n_obs))
    speed_row[0, frames.speed_column] = 1.0
    return ControllerModel(a, b, np.vstack([c, np.zeros((1, a.shape[0]))]), np.vstack([d, speed_row]), "feature filters")


def residual_student_model(policy: DistilledPolicy, n_obs: int, speed_kmh: float, y0: np.ndarray):
    """The linear model of a student on a baseline at the operating observation ``y0``: the
    baseline's own model beside ``scale x J`` (``J`` the network's Jacobian on the stacked frames,
    a shift register) fed by the feature filters at the speed; the features are zero at rest. A
    channel whose command is clipped at ``y0`` has zero small-signal gain."""
    from ..design.margins import ControllerModel, controller_model, parallel, series, stack_model

    frames = policy.frames
    y0 = np.asarray(y0, dtype=np.float64).reshape(-1)
    scale = float(frames.scale_at(speed_kmh))
    method = (f"distilled correction on {frames.baseline_name}: its model + {scale:g} x analytic Jacobian on "
              f"{frames.history} frames of washed-out features and the speed")  # fmt: skip
    base = controller_model(frames.baseline, n_obs, speed_kmh, y0)
    u0 = policy.steady_action(y0)
    features = feature_frame_model(frames, n_obs, speed_kmh)
    x0 = np.tile(np.concatenate([np.zeros(frames.features.dim), [y0[frames.speed_column]]]), frames.history)
    inner = stack_model(scale * policy.network.jacobian(x0), frames.frame_dim, frames.history, method)
    total = parallel(base, series(features, inner, method), method)
    live = (np.abs(u0) < 1.0 - 1e-9).astype(np.float64)[:, None]
    return ControllerModel(total.a, total.b, live * total.c, live * total.d, method)


def save_student(folder: str | Path, network: StudentNetwork, history: int, obs_dim: int, action_dim: int,
                 meta: dict[str, Any]) -> Path:  # fmt: skip
    """Write ``student.npz`` and ``student.json`` into ``folder`` atomically."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {"mean": network.mean, "std": network.std}
    if network.mirror is not None:
        arrays["mirror"] = network.mirror
    for i, (w, b) in enumerate(zip(network.weights, network.biases)):
        arrays[f"w{i}"], arrays[f"b{i}"] = w, b
    with atomic_output(folder / WEIGHTS_FILE, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    info = {"format": FORMAT, "history": int(history), "obs_dim": int(obs_dim), "action_dim": int(action_dim),
            "layers": len(network.weights), **meta}  # fmt: skip
    write_text_atomic(folder / META_FILE, json.dumps(info, indent=1, default=float) + "\n")
    return folder


def is_student(path: str | Path) -> bool:
    path = Path(path)
    return path.is_dir() and (path / WEIGHTS_FILE).is_file() and (path / META_FILE).is_file()


def load_student(folder: str | Path) -> DistilledPolicy:
    """A :class:`DistilledPolicy` from a folder of :func:`save_student` (no code is loaded)."""
    folder = Path(folder)
    meta = json.loads((folder / META_FILE).read_text())
    if meta.get("format") != FORMAT:
        raise ConfigError(f"{folder / META_FILE}: 'format' = {meta.get('format')!r}; allowed: {FORMAT!r}")
    for key in ("history", "obs_dim", "action_dim", "layers"):
        if isinstance(meta.get(key), bool) or not isinstance(meta.get(key), int) or meta[key] < 1:
            raise ConfigError(f"{folder / META_FILE}: {key!r} = {meta.get(key)!r}; allowed: an integer >= 1")
    frames = None
    if meta.get("residual") is not None:
        frames = residual_frames(meta, folder)
    n = meta["layers"]
    names = ["mean", "std"] + [f"{k}{i}" for i in range(n) for k in "wb"]
    with np.load(folder / WEIGHTS_FILE, allow_pickle=False) as z:
        missing = [k for k in names if k not in z.files]
        if missing:
            raise ConfigError(f"{folder / WEIGHTS_FILE}: arrays {missing} are missing; {META_FILE} says {n} layers")
        network = StudentNetwork([z[f"w{i}"] for i in range(n)], [z[f"b{i}"] for i in range(n)], z["mean"], z["std"],
                                 z["mirror"] if "mirror" in z.files else None)  # fmt: skip
    expected = meta["history"] * (frames.frame_dim if frames is not None else meta["obs_dim"] + meta["action_dim"])
    width = expected
    for i, (w, b) in enumerate(zip(network.weights, network.biases)):
        if w.ndim != 2 or w.shape[1] != width or b.shape != (w.shape[0],):
            raise ConfigError(f"{folder / WEIGHTS_FILE}: layer {i} has weights {w.shape} and biases {b.shape}; "
                              f"allowed: ({{out}}, {width}) and ({{out}},) ({META_FILE}: history x frame = {expected})")  # fmt: skip
        width = w.shape[0]
    if width != meta["action_dim"]:
        raise ConfigError(f"{folder / WEIGHTS_FILE}: the last layer gives {width} commands; {META_FILE} says {meta['action_dim']}")
    for name in ("mean", "std", "mirror"):
        value = getattr(network, name)
        if value is not None and value.shape != (expected,):
            raise ConfigError(f"{folder / WEIGHTS_FILE}: {name!r} has shape {value.shape}; allowed: ({expected},)")
    return DistilledPolicy(network, meta["history"], meta["obs_dim"], meta["action_dim"], name=str(folder), meta=meta, frames=frames)


def checked_scale(scale: Any, where: str) -> float | dict[str, list[float]]:
    """A residual student's authority: a number in (0, 1], or a schedule over speed
    ``{"speeds_kmh": [increasing], "scales": [each in (0, 1]]}`` of equal lengths (>= 2)."""
    if isinstance(scale, Mapping):
        speeds, scales = scale.get("speeds_kmh"), scale.get("scales")
        ok = (set(scale) == {"speeds_kmh", "scales"} and isinstance(speeds, list) and isinstance(scales, list)
              and len(speeds) == len(scales) >= 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in speeds + scales)
              and all(b > a for a, b in zip(speeds, speeds[1:])) and all(0.0 < x <= 1.0 for x in scales))  # fmt: skip
        if not ok:
            raise ConfigError(f"{where} = {scale!r}; allowed: a number in (0, 1], or {{'speeds_kmh': [increasing], 'scales': "
                              "[each in (0, 1]]}} of equal lengths >= 2")  # fmt: skip
        return {"speeds_kmh": [float(x) for x in speeds], "scales": [float(x) for x in scales]}
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < scale <= 1.0:
        raise ConfigError(f"{where} = {scale!r}; allowed: a number in (0, 1], or a schedule over speed")
    return float(scale)


def residual_frames(meta: dict[str, Any], folder: Path | str = "student") -> ResidualFrames:
    """The :class:`ResidualFrames` a student file's ``residual`` (``{"baseline", "scale",
    "env_config"}``: the classical controller's name, the correction's authority and the env
    config the baseline is designed for) describes, checked by name."""
    from bogie_env.envs.config import make_config

    from .classical import CLASSICAL

    residual = meta["residual"]
    where = f"{Path(folder) / META_FILE}: 'residual'"
    if not isinstance(residual, dict) or set(residual) != {"baseline", "scale", "env_config"}:
        raise ConfigError(f"{where} = {residual!r}; allowed: a mapping with 'baseline', 'scale' and 'env_config'")
    if residual["baseline"] not in CLASSICAL:
        raise ConfigError(f"{where}.baseline = {residual['baseline']!r}; allowed: one of {', '.join(CLASSICAL)}")
    scale = checked_scale(residual["scale"], f"{where}.scale")
    env_config = make_config(residual["env_config"])
    frames = ResidualFrames(meta["history"], env_config, residual["baseline"], scale, meta["action_dim"])
    if frames.obs_dim != meta["obs_dim"]:
        raise ConfigError(f"{where}.env_config gives observations of {frames.obs_dim} entries; 'obs_dim' = {meta['obs_dim']}")
    return frames
