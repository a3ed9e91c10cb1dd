"""Distil the privileged reference into a student that sees only the sensors (DAgger).

The privileged reference (:class:`bogie_agents.controllers.privileged.PrivilegedController`) is
told each run's true scenario and sees the full state; it is the headroom on worn wheels. A
student that sees what a buildable controller sees (the v1 sensors and its own past commands,
:class:`bogie_agents.controllers.distilled.DistilledPolicy`) learns its commands by DAgger
(Ross, Gordon & Bagnell, AISTATS 2011), the teacher-student route of legged locomotion:

The teacher is ``privileged`` (default) or, with ``teacher: privileged_mpc``, the MPC reference
with the force and rate limits as hard constraints
(:class:`bogie_agents.controllers.mpc.MPCReference`, :class:`MPCTeacherBank`: one QP per row
and step, about 1 ms in Python).

1. **Scenario bank.** ``bank.size`` scenarios drawn from the env's own randomisation
   (``Bogie/Hunting-v1``: conicity 0.025-0.3, stiffnesses, creep, dampers, axle load, actuator
   gains, failed actuators; ``bank.randomize`` may widen it; stuck actuators are left out, the
   reference does not model them), the reference designed once for each. Every episode runs one
   of them (reset options).
2. **Rollouts.** ``n_envs`` rows run the configured episodes (``env.speed``: ramps or near-fixed
   speeds; ``episode_steps`` caps them). A row's driver is drawn when an iteration starts and
   when the row starts an episode: in iteration 0 the teacher; in iteration ``k`` the teacher
   with probability ``beta0 * beta_decay**k``, else the current student. Every step is labelled
   with the teacher's command in the state the rollout reached, the teacher's lag and delay
   registers following the commands actually sent; every ``dagger.keep_every``-th step is kept.
3. **Fit.** The student is fitted to every kept label so far (mean squared error, Adam),
   continuing from the last iteration's weights.

``bogie distill --config configs/agents/distill_v1.yaml --out runs/distill_v1`` writes the
student (``student.npz``, ``student.json``) after every iteration, atomically, into ``out`` and
into ``out/iterations/NNN`` (iteration NNN's student: students of neighbouring iterations can
differ by hundreds of km/h in a column, so one is chosen by evaluation on validation seeds,
``studies/distill_select.py``), and a ``progress.json`` with each iteration's figures.
"""

from __future__ import annotations

import copy
import json
import math
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from bogie_env.envs.config import make_config, merge_config
from bogie_env.envs.registration import IDS
from bogie_env.envs.scenario import NO_FAULT, RANGES, Scenario
from bogie_env.envs.task import OBS_BOUND, SPEED_CENTRE_KMH, SPEED_SCALE_KMH, HuntingTask, speed_index
from bogie_env.fileio import atomic_output, load_yaml, write_text_atomic
from bogie_env.params import ConfigError

from ..controllers.distilled import FrameHistory, ResidualFrames, StudentNetwork, save_student
from ..controllers.lqr import interpolation_weights
from ..controllers.mpc import MPCReference
from ..controllers.privileged import PrivilegedController

def default_config() -> dict[str, Any]:
    """Every key ``bogie distill`` reads; a user's config merges into it."""
    return {
        "seed": 0,
        "env_id": "Bogie/Hunting-v1",
        # the env config merged into the id's variant (ppo_v1's ramps over the whole speed range)
        "env": {"speed": {"start_kmh_range": [100.0, 550.0], "end_kmh": 600.0, "accel": 1.5},
                "large_perturbation_probability": 0.2},  # fmt: skip
        "n_envs": 64,
        # rows on the shipped routes (curves, cant, transitions at their line speeds) beside the
        # n_envs rows, on the scenarios of the same bank: n_envs 0 for none; env merged into env_id's variant
        "routes": {"n_envs": 0, "env_id": "Bogie/HuntingRoute-v1", "env": {}},
        "episode_steps": None,  # an episode's longest run (env steps; None: the ramp's end or hunting ends it)
        # randomize: entries merged into the env's randomisation for the bank's draws only (e.g. wider
        # degradation ranges or more failed actuators than the env's episodes draw)
        "bank": {"size": 96, "randomize": {}},
        # the reference that labels: "privileged" (LQR, the force-rate limit as a soft cost) or
        # "privileged_mpc" (the MPC with the force and rate limits as hard constraints, one QP per row and step)
        "teacher": "privileged",
        # mirror: the student is odd in every input but the speed (StudentNetwork); false: a plain MLP.
        # residual: null, or {baseline: a classical controller, scale: (0, 1]}: the student is a
        # correction on that baseline from its washed-out design signals (distilled.ResidualFrames)
        "student": {"history": 16, "hidden": [256, 256], "mirror": True, "residual": None},
        # keep_every: keep every k-th step's sample (neighbouring steps are nearly the same sample)
        "dagger": {"iterations": 6, "steps": 3000, "beta0": 1.0, "beta_decay": 0.5, "keep_every": 1},
        # loop_penalty: null, or a penalty on a mirrored student's linearised loops (loop_penalty.DEFAULTS)
        "fit": {"epochs": 3, "batch_size": 2048, "learning_rate": 1.0e-3, "torch_threads": 2, "loop_penalty": None},
        "max_wall_time_s": 3600,
    }


def load_config(path: str | Path | None, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The default config, the YAML file's keys and ``overrides`` merged, every known key checked."""
    user = load_yaml(Path(path)) if path else {}
    cfg = _merge(default_config(), user or {}, "")
    cfg = _merge(cfg, dict(overrides or {}), "")
    if cfg["env_id"] not in IDS:
        raise ConfigError(f"distill config 'env_id' = {cfg['env_id']!r}; allowed: one of {', '.join(IDS)}")
    for where, value, low in (("n_envs", cfg["n_envs"], 1), ("bank.size", cfg["bank"]["size"], 1),
                              ("student.history", cfg["student"]["history"], 1),
                              ("dagger.iterations", cfg["dagger"]["iterations"], 1), ("dagger.steps", cfg["dagger"]["steps"], 1),
                              ("dagger.keep_every", cfg["dagger"]["keep_every"], 1),
                              ("fit.epochs", cfg["fit"]["epochs"], 1), ("fit.batch_size", cfg["fit"]["batch_size"], 1)):  # fmt: skip
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"distill config {where!r} = {value!r}; allowed: an integer >= {low}")
    if cfg["episode_steps"] is not None and (isinstance(cfg["episode_steps"], bool) or not isinstance(cfg["episode_steps"], int)
                                             or cfg["episode_steps"] < 1):  # fmt: skip
        raise ConfigError(f"distill config 'episode_steps' = {cfg['episode_steps']!r}; allowed: an integer >= 1 or null")
    for where, value in (("dagger.beta0", cfg["dagger"]["beta0"]), ("dagger.beta_decay", cfg["dagger"]["beta_decay"])):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
            raise ConfigError(f"distill config {where!r} = {value!r}; allowed: a number in [0, 1]")
    for where, value, low in (("seed", cfg["seed"], 0), ("fit.torch_threads", cfg["fit"]["torch_threads"], 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"distill config {where!r} = {value!r}; allowed: an integer >= {low}")
    for where, value in (("fit.learning_rate", cfg["fit"]["learning_rate"]), ("max_wall_time_s", cfg["max_wall_time_s"])):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise ConfigError(f"distill config {where!r} = {value!r}; allowed: a finite number > 0")
    routes = {**default_config()["routes"], **cfg["routes"]} if isinstance(cfg["routes"], Mapping) else cfg["routes"]
    if not isinstance(routes, Mapping) or set(routes) - {"n_envs", "env_id", "env"}:
        raise ConfigError(f"distill config 'routes' = {cfg['routes']!r}; allowed: a mapping with 'n_envs', 'env_id' and 'env'")
    n_route = routes["n_envs"]
    if isinstance(n_route, bool) or not isinstance(n_route, int) or n_route < 0:
        raise ConfigError(f"distill config 'routes.n_envs' = {n_route!r}; allowed: an integer >= 0")
    if routes["env_id"] not in IDS:
        raise ConfigError(f"distill config 'routes.env_id' = {routes['env_id']!r}; allowed: one of {', '.join(IDS)}")
    cfg["routes"] = {"n_envs": n_route, "env_id": routes["env_id"], "env": dict(routes["env"] or {})}
    if cfg["teacher"] not in TEACHERS:
        raise ConfigError(f"distill config 'teacher' = {cfg['teacher']!r}; allowed: one of {', '.join(TEACHERS)}")
    hidden = cfg["student"]["hidden"]
    if not isinstance(hidden, list) or not hidden or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in hidden):
        raise ConfigError(f"distill config 'student.hidden' = {hidden!r}; allowed: a non-empty list of layer widths >= 1")
    if not isinstance(cfg["student"]["mirror"], bool):
        raise ConfigError(f"distill config 'student.mirror' = {cfg['student']['mirror']!r}; allowed: true or false")
    residual = cfg["student"]["residual"]
    if residual is not None:
        from ..controllers.classical import CLASSICAL

        if not isinstance(residual, Mapping) or set(residual) - {"baseline", "scale"} or "baseline" not in residual:
            raise ConfigError(f"distill config 'student.residual' = {residual!r}; allowed: null or a mapping with "
                              f"'baseline' (one of {', '.join(CLASSICAL)}) and 'scale' (a number in (0, 1], default 1)")  # fmt: skip
        if residual["baseline"] not in CLASSICAL:
            raise ConfigError(f"distill config 'student.residual.baseline' = {residual['baseline']!r}; allowed: one of {', '.join(CLASSICAL)}")
        scale = residual.get("scale", 1.0)
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0.0 < scale <= 1.0:
            raise ConfigError(f"distill config 'student.residual.scale' = {scale!r}; allowed: a number in (0, 1]")
        if not cfg["student"]["mirror"]:
            raise ConfigError("distill config 'student.mirror' = false is not allowed with 'student.residual'; allowed: true "
                              "(the correction must be zero at rest, where its features are zero)")  # fmt: skip
        cfg["student"]["residual"] = {"baseline": residual["baseline"], "scale": float(scale)}
    from .loop_penalty import check_penalty_config

    cfg["fit"]["loop_penalty"] = check_penalty_config(cfg["fit"]["loop_penalty"])
    if cfg["fit"]["loop_penalty"] is not None and not cfg["student"]["mirror"]:
        raise ConfigError("distill config 'fit.loop_penalty' is not allowed with 'student.mirror' = false; allowed: null "
                          "(the penalty linearises a mirror-odd student about rest, where its command is zero)")  # fmt: skip
    return cfg


def _merge(base: dict, user: Mapping[str, Any], where: str) -> dict:
    out = copy.deepcopy(base)
    for key, value in user.items():
        name = f"{where}{key}"
        if key not in base:
            raise ConfigError(f"distill config key {name!r} is not known; known here: {', '.join(base)}")
        if isinstance(base[key], dict) and key not in ("env", "randomize", "residual", "loop_penalty", "routes"):
            if not isinstance(value, Mapping):
                raise ConfigError(f"distill config {name!r} must be a mapping; got {value!r}")
            out[key] = _merge(base[key], value, name + ".")
        else:
            out[key] = _deep_update(base[key], value) if key in ("env", "randomize") else copy.deepcopy(value)
    return out


def _deep_update(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict:
    """A partial env config merged into another (checked later, by ``make_config``)."""
    if not isinstance(update, Mapping):
        raise ConfigError(f"distill config 'env' or 'bank.randomize': {update!r} is not allowed; allowed: a mapping of env config keys")
    out = copy.deepcopy(dict(base))
    for key, value in update.items():
        out[key] = _deep_update(out[key], value) if isinstance(out.get(key), Mapping) and isinstance(value, Mapping) else copy.deepcopy(value)
    return out


def env_config(cfg: Mapping[str, Any]) -> dict:
    """The env config of the rollouts: the id's variant with the distill config's ``env``."""
    return make_config(cfg["env"], variant=IDS[cfg["env_id"]])


def route_env_config(cfg: Mapping[str, Any]) -> dict | None:
    """The env config of the route rows (``routes.env_id``'s variant with ``routes.env``), or None without them."""
    routes = cfg["routes"]
    return make_config(routes["env"], variant=IDS[routes["env_id"]]) if routes["n_envs"] else None


# ---- the scenario bank and its teachers ---------------------------------------------------------
def scenario_options(s: Scenario) -> dict[str, Any]:
    """Reset options that make an episode run scenario ``s`` (whatever the row's RNG draws)."""
    options: dict[str, Any] = {name: float(getattr(s, name)) for name in RANGES if name not in ("actuator_gain", "conicity")}
    if s.conicity is not None:
        options["conicity"] = float(s.conicity)
    options["actuator_gain"] = float(s.actuator_gain[0]) if np.all(s.actuator_gain == s.actuator_gain[0]) else None
    if options["actuator_gain"] is None:
        from bogie_env.actuators import CHANNEL_NAMES

        options["actuator_gain"] = dict(zip(CHANNEL_NAMES, map(float, s.actuator_gain)))
    if s.factors:  # v0-form bogie parameter factors (e.g. bank.randomize: {Csy: [0.5, 1.0]})
        options["params"] = dict(s.factors)
    options["failed_actuator"] = s.failed_actuator or NO_FAULT
    options["stuck_actuator"] = NO_FAULT
    return options


def bank_config(env_cfg: dict, randomize: Mapping[str, Any] | None = None) -> dict:
    """The env config with the bank's ``randomize`` entries merged into its randomisation; the
    rollouts run it too, so a quantity the bank does not draw is not drawn by an episode either."""
    return merge_config(env_cfg, {"randomize": {**env_cfg["randomize"], **randomize}}) if randomize else env_cfg


def draw_bank(env_cfg: dict, size: int, seed: int, randomize: Mapping[str, Any] | None = None) -> list[Scenario]:
    """``size`` scenarios of :func:`bank_config` (stuck actuators left out), drawn by a task's own
    reset with seeds ``seed + i``."""
    task = HuntingTask(size, bank_config(env_cfg, randomize))
    task.seed_rows(np.arange(size), [seed + i for i in range(size)])
    task.reset_rows(np.arange(size), {"stuck_actuator": NO_FAULT})
    return [copy.deepcopy(task.scenarios[i]) for i in range(size)]


class TeacherBank:
    """The reference designed for every bank scenario; each row labelled by its scenario's design.

    The first design (a :attr:`reference`) holds the rows' loop states (lag, command registers);
    the gains and channel gains are the row's scenario's."""

    reference: type[PrivilegedController] = PrivilegedController

    def __init__(self, env_cfg: dict, bank: list[Scenario], progress=None) -> None:
        self.designs: list[PrivilegedController] = []
        for k, s in enumerate(bank):
            self.designs.append(self.reference(env_cfg).tell(s, env_cfg) if k == 0 else self.designs[0].tell(s, env_cfg))
            if progress:
                progress(k + 1, len(bank))
        self.speeds_kmh = self.designs[0].speeds_kmh
        self.gains = np.stack([d.gains for d in self.designs])  # (M, S, n_act, n_z)
        self.channel_gains = np.stack([d.channel_gain for d in self.designs])  # (M, n_act)
        self.loop = self.designs[0]
        self.row_scenario = np.zeros(0, dtype=np.int64)

    def reset(self, n_envs: int, rows: np.ndarray | None = None, scenarios: np.ndarray | None = None) -> None:
        if rows is None or self.row_scenario.shape[0] != n_envs:
            self.row_scenario = np.zeros(n_envs, dtype=np.int64)
            rows = np.arange(n_envs)
            self.loop.reset(n_envs)
        else:
            self.loop.reset(n_envs, rows)
        if scenarios is not None:
            self.row_scenario[rows] = scenarios

    def command(self, state_obs: np.ndarray) -> np.ndarray:
        """Each row's reference command for its full-state observation (:func:`state_observation`):
        the reference acts on the float32 observation the protocol gives it, whose rounding moves
        its command by up to 1e-2 at hunting amplitudes (gains with large, cancelling terms)."""
        i0, i1, w = interpolation_weights(self.speeds_kmh, self.loop.speed_kmh(state_obs))
        m = self.row_scenario
        gains = (1 - w) * self.gains[m, i0] + w * self.gains[m, i1]
        return self.loop.command(self.loop.state_estimate(state_obs), gains)

    def advance(self, sent: np.ndarray) -> None:
        self.loop.advance(sent, self.channel_gains[self.row_scenario])


class MPCTeacherBank(TeacherBank):
    """``privileged_mpc`` designed for every bank scenario; each row's QP is its scenario's.

    The first design holds every row's loop states (lag, command registers, the plans that warm-start
    OSQP); a row's QPs, rate rows and fallback gains are its scenario's design's."""

    reference = MPCReference

    def command(self, state_obs: np.ndarray) -> np.ndarray:
        """Each row's MPC command for its full-state observation (:func:`state_observation`)."""
        speed = np.asarray(self.loop.speed_kmh(state_obs), dtype=float).reshape(-1)
        designs = [self.designs[m] for m in self.row_scenario.tolist()]
        return self.loop.planned_command(self.loop.state_estimate(state_obs), speed, designs)


#: ``teacher`` of the distill config: the reference bank that labels
TEACHERS = {"privileged": TeacherBank, "privileged_mpc": MPCTeacherBank}


def state_observation(task: HuntingTask) -> np.ndarray:
    """The observation ``observation.type = "state"`` would give for the task's rows now (scaled
    states, then the speed; float32, clipped as the env clips), without noise."""
    states = np.clip(task.states / task.state_scales, -OBS_BOUND, OBS_BOUND)
    speed = np.clip((task.speed_kmh - SPEED_CENTRE_KMH) / SPEED_SCALE_KMH, -OBS_BOUND, OBS_BOUND)
    return np.concatenate([states, speed[:, None]], axis=1).astype(np.float32)


# ---- rollouts -----------------------------------------------------------------------------------
class Rollouts:
    """``n_envs`` rows of the task, each episode on a bank scenario, the teacher labelling every step."""

    def __init__(self, env_cfg: dict, n_envs: int, bank: list[Scenario], teacher: TeacherBank, history: int, seed: int,
                 episode_steps: int | None = None, residual: Mapping[str, Any] | None = None, stream: int = 0) -> None:  # fmt: skip
        self.task = HuntingTask(n_envs, env_cfg)
        self.n = n_envs
        self.episode_steps = episode_steps
        self.steps = np.zeros(n_envs, dtype=np.int64)
        self.options = [scenario_options(s) for s in bank]
        self.teacher = teacher
        # stream: a second set of rows (the route rows) draws its own picks and episode seeds
        self.rng = np.random.default_rng(seed if stream == 0 else [seed, stream])
        self.next_seed = seed * 1_000_003 + 1 + stream * 10**12
        self.frames = student_frames(env_cfg, history, self.task, residual)
        self.by_teacher = np.ones(n_envs, dtype=bool)
        self.teacher.reset(n_envs)
        self.frames.reset(n_envs)
        self.beta = 1.0
        self._start(np.arange(n_envs))

    def _start(self, rows: np.ndarray) -> None:
        picks = self.rng.integers(len(self.options), size=rows.size)
        self.task.seed_rows(rows, [self.next_seed + i for i in range(rows.size)])
        self.next_seed += rows.size
        for r, m in zip(rows, picks):
            self.task.reset_rows(np.array([r]), self.options[int(m)])
        self.teacher.reset(self.n, rows, picks)
        self.frames.reset(self.n, rows)
        self.steps[rows] = 0
        self.by_teacher[rows] = self.rng.random(rows.size) < self.beta

    def run(self, steps: int, student: StudentNetwork | None, beta: float, keep_every: int = 1) -> tuple[np.ndarray, np.ndarray, dict]:
        """``steps`` env steps of every row: the student's inputs and the teacher's labels (of
        every ``keep_every``-th step), as the network's fit targets (on a baseline: the
        correction the teacher's command asks for)."""
        self.beta = beta if student is not None else 1.0
        self.by_teacher[:] = self.rng.random(self.n) < self.beta
        kept = -(-steps // keep_every)
        inputs = np.empty((kept, self.n, self.frames.history * self.frames.frame_dim), dtype=np.float32)
        labels = np.empty((kept, self.n, self.task.action_dim), dtype=np.float32)
        episodes = 0
        for t in range(steps):
            x, base = self.frames.inputs(self.task.obs)
            label = self.teacher.command(state_observation(self.task))
            if t % keep_every == 0:
                inputs[t // keep_every] = x
                labels[t // keep_every] = self.frames.target(label, base)
            sent = label if student is None else np.where(self.by_teacher[:, None], label, self.frames.command(student.forward(x), base))
            self.task.step(sent)
            self.teacher.advance(sent)
            self.frames.sent(sent)
            self.steps += 1
            done = self.task.done if self.episode_steps is None else self.task.done | (self.steps >= self.episode_steps)
            done = np.nonzero(done)[0]
            if done.size:
                episodes += done.size
                self._start(done)
        return inputs.reshape(-1, inputs.shape[-1]), labels.reshape(-1, labels.shape[-1]), {"episodes": episodes}


# ---- fitting ------------------------------------------------------------------------------------
def fit(x: np.ndarray, y: np.ndarray, hidden: list[int], epochs: int, batch_size: int, learning_rate: float,
        seed: int, init: StudentNetwork | None = None, mean: np.ndarray | None = None, std: np.ndarray | None = None,
        threads: int = 2, mirror: np.ndarray | None = None, penalty=None) -> tuple[StudentNetwork, float]:  # fmt: skip
    """A tanh MLP fitted to ``y`` from ``x`` (MSE, Adam), odd in the inputs ``mirror`` flips
    (:class:`StudentNetwork`), with ``penalty`` (a :class:`loop_penalty.LoopPenalty`) added on
    every ``every``-th batch, times ``every``; returns it and the last epoch's mean squared error."""
    import torch

    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    sizes = [x.shape[1], *hidden, y.shape[1]]
    layers: list[Any] = []
    for i in range(len(sizes) - 1):
        layers.append(torch.nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(torch.nn.Tanh())
    net = torch.nn.Sequential(*layers)
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    if init is not None:
        with torch.no_grad():
            for lin, w, b in zip(linears, init.weights, init.biases):
                lin.weight.copy_(torch.from_numpy(w))
                lin.bias.copy_(torch.from_numpy(b))
    mean_t, std_t = torch.from_numpy(mean), torch.from_numpy(std)
    mirror_t = None if mirror is None else torch.from_numpy(np.asarray(mirror, dtype=np.float32))

    def student(z):
        return net(z) if mirror_t is None else 0.5 * (net(z) - net(z * mirror_t))

    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    opt = torch.optim.Adam(net.parameters(), lr=learning_rate)
    gen = torch.Generator().manual_seed(seed)
    loss_value = math.nan
    for _ in range(epochs):
        order = torch.randperm(xt.shape[0], generator=gen)
        total, count = 0.0, 0
        for batch, start in enumerate(range(0, xt.shape[0], batch_size)):
            idx = order[start : start + batch_size]
            pred = student((xt[idx] - mean_t) / std_t)
            loss = torch.mean((pred - yt[idx]) ** 2)
            total_loss = loss
            if penalty is not None and batch % penalty.settings["every"] == 0:
                total_loss = loss + penalty.settings["every"] * penalty(linears, mean_t, std_t)
            opt.zero_grad()
            total_loss.backward()
            opt.step()
            total += float(loss.detach()) * idx.numel()
            count += idx.numel()
        loss_value = total / count
    weights = [lin.weight.detach().numpy().copy() for lin in linears]
    biases = [lin.bias.detach().numpy().copy() for lin in linears]
    return StudentNetwork(weights, biases, mean, std, mirror), loss_value


def frame_statistics(x: np.ndarray, history: int, mirror: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-entry mean and std of one frame (the same for every frame of the history), tiled; the
    mean is zero on mirrored entries (the mirror's sign flip is about zero)."""
    frames = x.reshape(x.shape[0], history, -1)[:, -1]
    mean, rms = frames.mean(axis=0), np.sqrt(np.mean(frames.astype(np.float64) ** 2, axis=0))
    std = np.maximum(frames.std(axis=0), 1e-3)
    mean, std, rms = np.tile(mean, history), np.tile(std, history), np.tile(np.maximum(rms, 1e-3), history)
    if mirror is not None:  # about zero: the spread is the RMS
        mean = np.where(mirror < 0, 0.0, mean)
        std = np.where(mirror < 0, rms, std)
    return mean.astype(np.float32), std.astype(np.float32)


def student_frames(env_cfg: dict, history: int, task: HuntingTask, residual: Mapping[str, Any] | None = None):
    """The student's frames: a plain :class:`FrameHistory`, or :class:`ResidualFrames` on a baseline."""
    if residual is None:
        return FrameHistory(history, task.observation_dim, task.action_dim)
    return ResidualFrames(history, env_cfg, residual["baseline"], residual["scale"], task.action_dim)


def mirror_signs(task: HuntingTask, history: int, frames=None) -> np.ndarray:
    """Per flat student input, -1 where mirroring the bogie about the track's centre line flips the
    sign (the lateral and yaw sensors, actuator forces and commands; a residual student's
    features), +1 for the speed."""
    if isinstance(frames, ResidualFrames):
        return np.tile(frames.mirror_frame(), history)
    frame = -np.ones(task.observation_dim + task.action_dim, dtype=np.float32)
    frame[speed_index(task.config["observation"]["type"])] = 1.0
    return np.tile(frame, history)


# ---- the command --------------------------------------------------------------------------------
def distill(cfg: dict[str, Any], out: str | Path, progress: bool = True) -> Path:
    """Run DAgger with ``cfg`` (:func:`load_config`) and write the student into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    env_cfg = env_config(cfg)
    seed = int(cfg["seed"])

    def say(text: str) -> None:
        if progress:
            print(f"[distill {time.time() - t0:7.1f} s] {text}", flush=True)

    bank = draw_bank(env_cfg, cfg["bank"]["size"], seed * 100_000 + 50_000, cfg["bank"]["randomize"])
    teacher = TEACHERS[cfg["teacher"]](env_cfg, bank, (lambda k, m: say(f"designed {k}/{m} scenarios") if k % 16 == 0 or k == m else None))
    residual = cfg["student"]["residual"]
    roll = Rollouts(bank_config(env_cfg, cfg["bank"]["randomize"]), cfg["n_envs"], bank, teacher, cfg["student"]["history"], seed,
                    cfg["episode_steps"], residual)  # fmt: skip
    route_cfg = route_env_config(cfg)
    route_roll = None
    if route_cfg is not None:  # its own teacher: the designs hold the rows' loop states
        route_teacher = TEACHERS[cfg["teacher"]](route_cfg, bank)
        route_roll = Rollouts(bank_config(route_cfg, cfg["bank"]["randomize"]), cfg["routes"]["n_envs"], bank, route_teacher,
                              cfg["student"]["history"], seed, cfg["episode_steps"], residual, stream=1)  # fmt: skip
        if route_roll.task.observation_dim != roll.task.observation_dim:
            raise ConfigError(f"distill config 'routes.env_id' = {cfg['routes']['env_id']!r} gives {route_roll.task.observation_dim} "
                              f"observations; allowed: an id with env_id's {roll.task.observation_dim}")  # fmt: skip
        say(f"{cfg['routes']['n_envs']} route rows ({cfg['routes']['env_id']})")
    mirror = mirror_signs(roll.task, cfg["student"]["history"], roll.frames) if cfg["student"]["mirror"] else None
    meta: dict[str, Any] = {"env_id": cfg["env_id"], "config": cfg}
    penalty = None
    if cfg["fit"]["loop_penalty"] is not None:
        from .loop_penalty import LoopPenalty

        penalty = LoopPenalty(roll.frames, env_cfg, cfg["fit"]["loop_penalty"], lambda k, m: say(f"linearised loop {k}/{m}"),
                              mirror_signs(roll.task, cfg["student"]["history"], roll.frames))  # fmt: skip
    if residual is not None:  # the baseline is designed for the env config the episodes ran
        meta["residual"] = {**residual, "env_config": env_cfg}
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    student: StudentNetwork | None = None
    mean = std = None
    record: list[dict[str, Any]] = []
    d, f = cfg["dagger"], cfg["fit"]
    for k in range(d["iterations"]):
        beta = float(d["beta0"]) * float(d["beta_decay"]) ** k
        t_roll = time.time()
        x, y, info = roll.run(d["steps"], student, beta, d["keep_every"])
        if route_roll is not None:
            x_route, y_route, info_route = route_roll.run(d["steps"], student, beta, d["keep_every"])
            x, y = np.concatenate([x, x_route]), np.concatenate([y, y_route])
            info = {"episodes": info["episodes"] + info_route["episodes"]}
        t_fit = time.time()
        xs.append(x)
        ys.append(y)
        if mean is None:
            mean, std = frame_statistics(x, cfg["student"]["history"], mirror)
        student, loss = fit(np.concatenate(xs), np.concatenate(ys), list(cfg["student"]["hidden"]), f["epochs"], f["batch_size"],
                            f["learning_rate"], seed + k, student, mean, std, f["torch_threads"], mirror, penalty)  # fmt: skip
        if penalty is not None:
            growth = penalty.growth_bounds_of(student)
            say(f"growth bounds (1/s): worst {growth.max():.2f}, over 0 in {int((growth > penalty.settings['max_growth_per_s']).sum())}/{growth.size} loops")
        record.append({"iteration": k, "beta": beta, "samples": int(sum(a.shape[0] for a in xs)), "episodes": info["episodes"],
                       "loss": loss, "label_variance": float(np.concatenate(ys).var(axis=0).mean()), "rollout_s": t_fit - t_roll, "fit_s": time.time() - t_fit,
                       "growth_bound_max_per_s": None if penalty is None else float(growth.max())})  # fmt: skip
        for folder in (out / "iterations" / f"{k + 1:03d}", out):  # every iteration's student, and the last one
            save_student(folder, student, cfg["student"]["history"], roll.task.observation_dim, roll.task.action_dim,
                         {**meta, "iterations_done": k + 1})  # fmt: skip
        write_text_atomic(out / "progress.json", json.dumps({"iterations": record, "wall_time_s": time.time() - t0}, indent=1) + "\n")
        left = (time.time() - t0) / (k + 1) * (d["iterations"] - k - 1)
        say(f"iteration {k + 1}/{d['iterations']}: beta {beta:.3f}, {record[-1]['samples']} samples, loss {loss:.4g}, "
            f"rollout {record[-1]['rollout_s']:.0f} s, fit {record[-1]['fit_s']:.0f} s; about {left:.0f} s left")  # fmt: skip
        if time.time() - t0 > cfg["max_wall_time_s"]:
            say(f"max_wall_time_s = {cfg['max_wall_time_s']} reached; the student of iteration {k + 1} is kept")
            break
    return out
