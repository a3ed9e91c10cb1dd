"""Evaluation protocols v3 and v2, for the ``Bogie/Hunting-v1`` tasks (``bogie evaluate --env Bogie/Hunting-v1``).

Protocol v1 (:mod:`bogie_agents.evaluation.evaluate`) stays the protocol of the ``-v0`` ids. v3 (the
default) and v2 (``Settings(version=2)``, ``bogie evaluate --protocol 2``) differ in one rule,
the flange-contact time's (below); everything else is shared. They judge a
controller the way a running-stability test judges a vehicle: under the v1 world (sensor
noise and bias, 10 ms loop delay, force-rate limits, an EN 13848-5 *alert* track), with EN
14363's running-stability quantities. The definitions, limits and sources are in
``docs/results.md``, section "Protocol v3 (v1 env)"; in short:

**Pass criterion** (:func:`bogie_agents.evaluation.criterion.assess`), on a fixed-speed run of ``duration_s`` seconds after the
first ``transient_s`` seconds:

- no blow-up (the env's ``blowup`` flag, or a non-finite state or action);
- EN 14363 running stability: the sliding rms over 100 m (step 10 m) of the sum of guiding
  forces ΣY of each wheelset, band-passed to f0 ± 2 Hz, at most :data:`SUM_Y_LIMIT_N`-type
  ``(10 kN + P0 / 3) / 2`` (30 kN for this bogie's 150 kN axle load), and of the bogie frame's
  lateral acceleration, same filter, at most ``(12 - m+ / 5) / 2`` m/s² (5.8 m/s² for the
  1.61 t frame); f0 is the run's instability frequency, taken as the peak of the summed
  spectra of the three signals, each relative to its limit, in :data:`F0_RANGE_HZ` (this
  model hunts at 2-10 Hz across speeds and conicities);
- flange-contact time: the fraction of the time during which either wheelset's lateral
  displacement relative to the rail reaches the flange clearance is at most
  ``flange_time_limit`` (0.01). This is the criterion that detects this model's hunting near
  its onset, where ΣY and the frame acceleration stay below EN 14363's limits: the model has no
  car body and a soft flange (measured in docs/results.md). **v3** counts the contact time only
  when the contact is sustained, present in at least ``flange_sustained_fraction`` (0.5) of the
  assessed time's ``flange_window_s`` (1 s) windows (:func:`sustained_flange_contact`): a
  hunting cycle touches on every cycle, a rough track at isolated defects. **v2** counts every
  contact, so on an EN 13848-5 intervention-level track the forced contacts at 40 km/h set
  columns (docs/studies/hunting_or_forced_contact.md).

**Closed-loop critical speed** of a *column* (a bogie, wheels and faults): for each of
``seeds`` seeds (a seed sets the start on the track's 262 km alignment profile, the sensor
noise and bias, and the initial perturbation: lateral offsets of both wheelsets and the frame
of 0.5-1 x ``perturbation_m`` = 12 mm with random signs, beyond the 9 mm flange clearance,
i.e. a flange impact as on a hunting cycle), the highest speed that passes, found on a
geometric grid from ``floor_kmh`` to ``ceiling_kmh`` and then by per-row bisection to
``tol_kmh``. All (column, seed, speed) rows of a round run in one batched
:class:`~bogie_env.envs.task.HuntingTask` (one more for the columns with a different loop
delay). Each seed's critical speed is the upper end of its highest passing speed range on
the grid, bisected: the stability boundary that hunting sets. Grid speeds below it where the
seed fails (e.g. a controller designed for 100-700 km/h misbehaving at 40 km/h) are reported
in ``fails_below_kmh`` and counted in ``non_monotonic_seeds``; they do not lower the value.
The column's value is the lowest per-seed value (under this definition, the highest speed up
to which every seed's top boundary reaches), reported with the spread (min / median / max).

**Columns**: ``nominal`` (v1 defaults, conicity 0.025, no per-episode randomisation), the
conicity grid (``by_conicity``), degraded bogies (``degraded``: primary longitudinal stiffness
-50 %, primary lateral stiffness -50 %, secondary dampers -50 %, creep -50 %), one actuator
channel failed (``actuator_failed``, each active channel), 20 ms total loop delay
(``delay_20ms``), and the worst case over ``worst_case_draws`` scenarios drawn from the env
config's randomisation ranges (``worst_case``, faults included).

**What a controller is told**: it is built (``load_policy``) from the column's env config
with the bogie's conicity replaced by the column's conicity, rounded to the nearest value of
the conicity grid (wheel-profile measurements give the conicity class, not its exact value):
a model-based controller (LQR, LQG) is gain-scheduled on that conicity; it is told nothing
about degraded parts, faults or the extra delay. A learned policy ignores its config.

**Parts** are a registry (:data:`PARTS`, :func:`register_part`): ``critical`` (all the columns
above), ``cost``, ``margins`` (:func:`bogie_agents.design.margins.margins_table`), ``ramp`` (the
env's own episode over 5 seeds, protocol v1's ramp onset) and ``ramp_down`` (per conicity of
the grid, the speed where the controller stops hunting that was fully developed at the ceiling:
the ramp-down method of the nonlinear critical speed, closed loop; :mod:`bogie_agents.evaluation.ramp_down`). Another module
adds a part by decorating ``fn(ctx: PartContext) -> dict`` with ``@register_part("name")``;
the dict is merged into the controller's result. A module in :data:`PART_MODULES` is imported
before the registry is read, so its parts are available to ``bogie evaluate --parts``
(``curving`` is expected there).
"""

from __future__ import annotations

import copy
import importlib
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES, active_channels
from bogie_env.analysis.en14363 import running_signals_rows
from bogie_env.envs import scenario as scenarios
from bogie_env.envs.config import bogie_params, make_config, merge_config
from bogie_env.envs.task import HuntingTask
from bogie_env.params import ConfigError

from .criterion import (F0_RANGE_HZ, Assessment, assess, band_pass, criterion_text, dominant_frequency,  # noqa: F401
                        flange_occupancy, frame_accel_limit, sliding_rms, sum_y_limit_n, sustained_flange_contact)

#: The protocol version :class:`Settings` gives by default. v3 judges flange contact only when it
#: is sustained (see :func:`sustained_flange_contact`); v2 counted every contact, so a track's
#: forced contacts failed a run (a rough track then set columns far below hunting); v2 stays
#: runnable (``Settings(version=2)``, ``bogie evaluate --protocol 2``).
PROTOCOL_VERSION = 3
PROTOCOL_VERSIONS = (2, 3)
#: Per version, the share of the assessed time's ``flange_window_s`` windows that must hold a
#: flange contact for the contact time to count (v2: any).
FLANGE_SUSTAINED_FRACTION = {2: 0.0, 3: 0.5}
#: Named degraded bogies: reset options of :mod:`bogie_env.envs.scenario`.
DEGRADED: dict[str, dict[str, float]] = {
    "Kpx-50%": {"primary_longitudinal_stiffness": 0.5},
    "Kpy-50%": {"primary_lateral_stiffness": 0.5},
    "dampers-50%": {"damper_factor": 0.5},
    "creep-50%": {"creep_factor": 0.5},
}
#: The scenario quantities a nominal row pins (everything the randomisation could draw).
NOMINAL_OPTIONS: dict[str, Any] = {
    "primary_longitudinal_stiffness": 1.0,
    "primary_lateral_stiffness": 1.0,
    "creep_factor": 1.0,
    "damper_factor": 1.0,
    "axle_load": 1.0,
    "actuator_gain": 1.0,
}


@dataclass
class Settings:
    """The protocol's settings (the defaults are protocol v3; ``version=2`` gives v2; tests shrink them)."""

    version: int = PROTOCOL_VERSION
    seeds: int = 10
    seed: int = 0
    floor_kmh: float = 40.0
    ceiling_kmh: float = 600.0
    grid_ratio: float = 1.4  # geometric coarse grid from the floor to the ceiling
    tol_kmh: float = 2.0
    duration_s: float = 20.0
    transient_s: float = 5.0
    perturbation_m: float = 0.012
    window_m: float = 100.0
    window_step_m: float = 10.0
    band_half_width_hz: float = 2.0
    flange_time_limit: float = 0.01
    #: v3: flange contact counts only when it is sustained: it occurs in at least this share of the
    #: assessed time's windows of ``flange_window_s`` (None: the version's, FLANGE_SUSTAINED_FRACTION;
    #: read it through :attr:`sustained_fraction`)
    flange_sustained_fraction: float | None = None
    flange_window_s: float = 1.0
    conicities: tuple[float, ...] = scenarios.CONICITY_GRID
    degraded: dict[str, dict[str, float]] = field(default_factory=lambda: copy.deepcopy(DEGRADED))
    actuator_faults: bool = True
    delay_steps: int = 2
    worst_case_draws: int = 10
    columns: tuple[str, ...] | None = None  # None: every column; else names (nominal, conicity:0.1, ...)
    cost_speed_kmh: float = 300.0
    cost_conicities: tuple[float, ...] = (0.025, 0.1)
    cost_duration_s: float = 20.0
    cost_seeds: int = 4
    margin_speeds_kmh: tuple[float, ...] = (300.0, 350.0, 400.0, 450.0, 500.0)
    ramp_down_decel: float = 0.25  # m/s^2: 600 -> 40 km/h in 622 s (part ramp_down)
    ramp_down_onset_s: float = 2.0  # passive hunting at the ceiling before the controller is switched on
    ramp_down_stride_kmh: float = 2.0  # a window of the ramp (duration_s - transient_s long) starts every this many km/h
    progress: bool = True
    #: a screening run (:func:`screening_settings`): fewer seeds and draws, marked in every result,
    #: never written into a results table
    screening: bool = False
    #: the scenario quantities every row pins (a column's own options override them); a
    #: sensitivity study may change one, e.g. ``damper_factor`` 1.0001
    nominal_options: dict[str, Any] = field(default_factory=lambda: dict(NOMINAL_OPTIONS))

    def __post_init__(self) -> None:
        if self.version not in PROTOCOL_VERSIONS:
            raise ConfigError(f"protocol version = {self.version!r} is not known; known: "
                              f"{', '.join(map(str, PROTOCOL_VERSIONS))}")  # fmt: skip

    @property
    def sustained_fraction(self) -> float:
        """The share of ``flange_window_s`` windows that makes flange contact count: the field, or
        the version's (resolved on use, so ``replace(settings, version=...)`` keeps its meaning)."""
        if self.flange_sustained_fraction is None:
            return FLANGE_SUSTAINED_FRACTION[self.version]
        return self.flange_sustained_fraction

    def grid_kmh(self) -> np.ndarray:
        """The coarse grid: geometric from the floor, the ceiling always included."""
        n = max(1, int(math.ceil(math.log(self.ceiling_kmh / self.floor_kmh) / math.log(self.grid_ratio))))
        return np.geomspace(self.floor_kmh, self.ceiling_kmh, n + 1)

    def check(self) -> None:
        if not 30.0 <= self.floor_kmh < self.ceiling_kmh <= 850.0:
            raise ConfigError(f"protocol floor_kmh = {self.floor_kmh:g}, ceiling_kmh = {self.ceiling_kmh:g}: "
                              "need 30 <= floor < ceiling <= 850 km/h (the env's speed range)")  # fmt: skip
        if self.seeds < 1 or self.worst_case_draws < 0:
            raise ConfigError(f"protocol seeds = {self.seeds} must be >= 1 and worst_case_draws >= 0")
        if not 0 < self.transient_s < self.duration_s:
            raise ConfigError(f"protocol transient_s = {self.transient_s:g} must be in (0, duration_s = {self.duration_s:g})")
        if self.grid_ratio <= 1.0 or self.tol_kmh <= 0:
            raise ConfigError("protocol grid_ratio must be > 1 and tol_kmh > 0")
        ramp_down = {"ramp_down_decel": (self.ramp_down_decel, 0.05, 2.0, "m/s^2"),
                     "ramp_down_onset_s": (self.ramp_down_onset_s, 0.0, 60.0, "s"),
                     "ramp_down_stride_kmh": (self.ramp_down_stride_kmh, 0.1, 100.0, "km/h")}  # fmt: skip
        flange = {}
        if self.version == 2 and self.sustained_fraction != 0.0:
            raise ConfigError(f"protocol flange_sustained_fraction = {self.flange_sustained_fraction!r} is not allowed "
                              "with version 2 (v2 counts every flange contact: 0); use version 3")  # fmt: skip
        if self.version == 3:  # v2 uses no window: its settings stay as they were
            half = 0.5 * (self.duration_s - self.transient_s)  # a ramp-down window's first centred span
            flange = {"flange_sustained_fraction": (self.sustained_fraction, 0.05, 1.0,
                                                    "(a share of the windows; 0 is protocol v2: use version 2)"),
                      "flange_window_s": (self.flange_window_s, 0.05, half, "s (at most half the assessed time)")}  # fmt: skip
        for name, (value, lo, hi, unit) in (ramp_down | flange).items():
            if not (math.isfinite(value) and lo <= value <= hi):
                raise ConfigError(f"protocol {name} = {value!r} is not allowed; allowed: a number in [{lo:g}, {hi:g}] {unit}")


#: What a screening run (``bogie evaluate --quick``) changes: 3 seeds instead of 10, 3 worst-case
#: draws instead of 10, bisection to 4 km/h instead of 2. The criterion, columns and runs are the
#: protocol's, so a screening value is an upper bound of the protocol's lowest seed in spirit but
#: not in fact (other seeds): it ranks candidates, it does not replace the protocol.
SCREENING: dict[str, Any] = {"seeds": 3, "worst_case_draws": 3, "tol_kmh": 4.0}


def screening_settings(**overrides: Any) -> Settings:
    """The protocol's settings for a screening run (:data:`SCREENING`, marked ``screening``)."""
    return Settings(**{**SCREENING, **overrides, "screening": True})


# ---- controllers by what they are told ----------------------------------------------------------
PolicyFactory = Callable[[dict], Any]


def factory_for(source: Any, trusted: bool = False) -> PolicyFactory:
    """A policy factory ``env_config -> policy`` from a name or path (``load_policy``: a
    classical controller is designed for the config's bogie), a factory, or a policy object
    (copied for each use: controllers keep per-row state)."""
    if isinstance(source, str):
        from ..controllers.policies import CLASSICAL, load_policy

        if source in CLASSICAL:
            return lambda cfg: load_policy(source, cfg, trusted)
        cache: dict[str, Any] = {}

        def learned(cfg: dict) -> Any:
            if "policy" not in cache:
                cache["policy"] = load_policy(source, cfg, trusted)
            return copy.deepcopy(cache["policy"])

        return learned
    if callable(source) and not hasattr(source, "act"):
        return source
    return lambda cfg: copy.deepcopy(source)


def told_conicity(conicity: float, grid: Iterable[float]) -> float:
    """The conicity a controller is told: the nearest grid value (in ratio)."""
    grid = np.asarray(list(grid), dtype=float)
    return float(grid[np.argmin(np.abs(np.log(grid / conicity)))])


def policy_config(env_config: dict, observation_type: str, conicity: float | None = None) -> dict:
    """``env_config`` as the controller sees it: its observation type (a full-state observation
    has no sensor model) and, if given, the bogie's conicity."""
    update: dict[str, Any] = {"observation": {"type": observation_type}}
    if observation_type != "sensors":
        update["sensors"] = {"enabled": False}
    if conicity is not None and not math.isclose(conicity, bogie_params(env_config).lam):
        update["bogie_overrides"] = {**env_config.get("bogie_overrides", {}), "lam": conicity}
    return make_config(merge_config(env_config, update))


class RowGroups:
    """One policy per group of rows of one task (e.g. per told conicity); acts on the batch."""

    def __init__(self, groups: list[tuple[np.ndarray, Any]], action_dim: int) -> None:
        self.groups = groups
        self.action_dim = action_dim

    def reset(self, n: int) -> None:
        for rows, policy in self.groups:
            policy.reset(len(rows))

    def act(self, obs: np.ndarray) -> np.ndarray:
        out = np.zeros((obs.shape[0], self.action_dim))
        for rows, policy in self.groups:
            out[rows] = np.asarray(policy.act(obs[rows]), dtype=float).reshape(len(rows), self.action_dim)
        return out


# ---- cases and columns ---------------------------------------------------------------------------
@dataclass
class Case:
    """One (column, seed): the scenario a row runs with, apart from its speed."""

    column: str
    seed: int
    options: dict[str, Any]  # reset options pinning the scenario
    conicity: float
    loop: str = "default"  # "default" or "delay": which task (loop delay is a task setting)
    scenario: dict[str, Any] | None = None  # worst case: the drawn scenario


def scenario_options(s: scenarios.Scenario) -> dict[str, Any]:
    """Reset options that reproduce a drawn scenario."""
    out: dict[str, Any] = {name: float(getattr(s, name)) for name in scenarios.RANGES if name not in ("conicity", "actuator_gain")}
    out["actuator_gain"] = {name: float(g) for name, g in zip(CHANNEL_NAMES, s.actuator_gain)}
    if s.failed_actuator is not None:
        out["failed_actuator"] = s.failed_actuator
    if s.stuck_actuator is not None:
        out["stuck_actuator"], out["stuck_command"] = s.stuck_actuator, float(s.stuck_command)
    return out


def columns(env_config: dict, settings: Settings) -> dict[str, list[Case]]:
    """Every column's cases (``seeds`` each; the worst case one per draw)."""
    nominal_lam = bogie_params(env_config).lam
    seeds = [settings.seed + i for i in range(settings.seeds)]
    active = [CHANNEL_NAMES[k] for k in active_channels(env_config["actuators"])]

    def cases(name: str, extra: Mapping[str, Any], lam: float = nominal_lam, loop: str = "default") -> list[Case]:
        return [Case(name, s, {**settings.nominal_options, "conicity": lam, **extra}, lam, loop) for s in seeds]

    out: dict[str, list[Case]] = {"nominal": cases("nominal", {})}
    for lam in settings.conicities:
        if not math.isclose(lam, nominal_lam):
            out[f"conicity:{lam:g}"] = cases(f"conicity:{lam:g}", {}, lam)
    for name, options in settings.degraded.items():
        out[f"degraded:{name}"] = cases(f"degraded:{name}", options)
    if settings.actuator_faults:
        for channel in active:
            out[f"failed:{channel}"] = cases(f"failed:{channel}", {"failed_actuator": channel})
    if settings.delay_steps != 1:
        out[f"delay:{settings.delay_steps * 10}ms"] = cases(f"delay:{settings.delay_steps * 10}ms", {}, loop="delay")
    ranges = env_config["randomize"]
    if settings.worst_case_draws and ranges:
        draws = []
        for i in range(settings.worst_case_draws):
            rng = np.random.default_rng([settings.seed, 14363, i])
            s = scenarios.draw_scenario(ranges, {}, rng, active)
            lam = s.conicity if s.conicity is not None else nominal_lam
            draws.append(Case("worst_case", settings.seed + i, {**settings.nominal_options, **scenario_options(s), "conicity": lam},
                              lam, scenario=s.as_dict()))  # fmt: skip
        out["worst_case"] = draws
    if settings.columns is not None:
        unknown = set(settings.columns) - set(out)
        if unknown:
            raise ConfigError(f"protocol columns {sorted(unknown)} are not known; known: {', '.join(out)}")
        out = {name: out[name] for name in settings.columns}
    return out


# ---- running rows --------------------------------------------------------------------------------
class Progress:
    """Progress with the time left, on stderr (never stdout: ``--json`` stays clean)."""

    def __init__(self, label: str, enabled: bool = True) -> None:
        self.label, self.enabled = label, enabled
        self.start = time.monotonic()
        self.work_done = 0.0
        self.last = 0.0

    def report(self, what: str, done: float, remaining: float) -> None:
        """``done``: work units finished so far in total; ``remaining``: an estimate of those left."""
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < 5.0 and remaining > 0:
            return
        self.last = now
        elapsed = now - self.start
        left = elapsed / done * remaining if done > 0 else float("nan")
        print(f"[protocol] {self.label}: {what}; {elapsed:.0f} s elapsed, ~{left:.0f} s left", file=sys.stderr, flush=True)


def protocol_config(env_config: dict, settings: Settings, observation_type: str, delay_steps: int | None = None,
                    world: Mapping[str, Any] | None = None) -> dict:  # fmt: skip
    """The task config of the protocol's runs: fixed speeds over the search range, the env's
    randomisation ranges kept (they set the integration step) but every draw pinned by reset
    options, no random faults, the large initial perturbation on every row. ``world``: a config
    overlay merged last, e.g. :data:`bogie_agents.evaluation.ramp_down.IDEAL_WORLD` (a perfect track, noise-free sensors)."""
    ranges = {k: v for k, v in env_config["randomize"].items() if k not in scenarios.PROBABILITIES}
    update: dict[str, Any] = {
        "speed": {"start_kmh": settings.floor_kmh, "end_kmh": settings.ceiling_kmh, "accel": 0.0,
                  "start_kmh_range": None, "end_kmh_range": None, "accel_range": None},
        "randomize": ranges,
        "large_perturbation_probability": 1.0,
        "large_perturbation": settings.perturbation_m,
        "observation": {"type": observation_type},
    }  # fmt: skip
    if observation_type != "sensors":
        update["sensors"] = {"enabled": False}
    if delay_steps is not None:
        update["actuators"] = {name: {"delay_steps": delay_steps} for name in CHANNEL_NAMES}
    config = merge_config(env_config, update)
    return make_config(merge_config(config, dict(world)) if world else config)


def step_guarded(task: HuntingTask, actions: Any) -> np.ndarray:
    """Step ``task`` with ``actions``, a row's non-finite action replaced by zero force; returns
    the rows that blew up in this step (a non-finite action or state, or the task's flag)."""
    actions = np.array(actions, dtype=float)
    bad = ~np.all(np.isfinite(actions), axis=1)
    actions[bad] = 0.0
    task.step(actions)
    return bad | task.blowup | ~np.all(np.isfinite(task.states), axis=1)


def flange_touching(task: HuntingTask) -> np.ndarray:
    """Rows whose wheelset (either) is displaced relative to the rail by the flange clearance."""
    return np.any(np.abs(task.relative_lateral_m) >= task.flange_clearance[:, None], axis=1)


class Runner:
    """Runs batches of (case, speed) rows for one controller."""

    def __init__(self, ctx: "PartContext") -> None:
        self.ctx = ctx
        self.settings = ctx.settings
        self.progress = ctx.progress
        self.row_steps_done = 0.0

    def _task(self, cases: list[Case], speeds: np.ndarray, loop: str,
              world: Mapping[str, Any] | None = None) -> tuple[HuntingTask, RowGroups]:  # fmt: skip
        s, ctx = self.settings, self.ctx
        cfg = protocol_config(ctx.env_config, s, ctx.observation_type, s.delay_steps if loop == "delay" else None, world)
        task = ctx.task(len(cases), cfg)
        rows = np.arange(len(cases))
        task.seed_rows(rows, [c.seed for c in cases])
        for i, (case, v) in enumerate(zip(cases, speeds)):
            task.reset_rows(np.array([i]), {**case.options, "start_kmh": float(v), "end_kmh": float(v), "accel": 0.0})
        if ctx.privileged:
            groups = ctx.scenario_groups(task, loop)
        else:
            told = np.array([told_conicity(c.conicity, s.conicities) for c in cases])
            groups = [(np.nonzero(told == lam)[0], ctx.reused_policy(float(lam), loop)) for lam in np.unique(told)]
        policy = RowGroups(groups, task.action_dim)
        policy.reset(len(cases))
        return task, policy

    def run(self, cases: list[Case], speeds_kmh: np.ndarray, what: str, remaining_rows: float) -> Assessment:
        """Fixed-speed runs of every (case, speed) row; the criterion per row."""
        s = self.settings
        n = len(cases)
        speeds_kmh = np.asarray(speeds_kmh, dtype=float)
        loops = {}
        for loop in ("default", "delay"):
            idx = np.array([i for i, c in enumerate(cases) if c.loop == loop], dtype=int)
            if idx.size:
                loops[loop] = (idx, *self._task([cases[i] for i in idx], speeds_kmh[idx], loop))
        dt = next(iter(loops.values()))[1].config["dt"]
        steps = int(round(s.duration_s / dt))
        first = int(round(s.transient_s / dt))
        history = np.zeros((n, 3, steps - first), dtype=np.float32)
        contact = np.zeros((n, steps - first), dtype=bool)
        offset = np.zeros((n, 2))
        blowup = np.zeros(n, dtype=bool)
        buffers = {loop: np.zeros((idx.size, 3)) for loop, (idx, _, _) in loops.items()}
        for k in range(steps):
            for loop, (idx, task, policy) in loops.items():
                blowup[idx] |= step_guarded(task, policy.act(task.obs))
                if k >= first:
                    running_signals_rows(task.sim.rows, buffers[loop])
                    history[idx, :, k - first] = buffers[loop]
                    contact[idx, k - first] = flange_touching(task)
                    offset[idx] += task.relative_lateral_m / task.flange_clearance[:, None]
            if k % 100 == 99:
                done = self.row_steps_done + n * (k + 1)
                self.progress.report(f"{what}: {k + 1}/{steps} steps of {n} rows", done,
                                     n * (steps - k - 1) + remaining_rows * steps)  # fmt: skip
        self.row_steps_done += n * steps
        axle = np.zeros(n)
        for loop, (idx, task, _) in loops.items():
            axle[idx] = [task.scenarios[i].axle_load * task.base_params.Wpa for i in range(idx.size)]
        frame_mass = next(iter(loops.values()))[1].base_params.mb
        mean_offset = np.abs(offset / (steps - first)).max(axis=1)
        occupancy = flange_occupancy(contact, dt, s.flange_window_s) if s.sustained_fraction else None
        return assess(history, contact.mean(axis=1), blowup, speeds_kmh / 3.6, dt, axle, frame_mass, s, mean_offset, occupancy)


# ---- the critical-speed search -------------------------------------------------------------------
def _value(result: Assessment, key: str, row: int) -> float:
    values = getattr(result, key)
    return float(values[row]) if values is not None else math.nan


def search(runner: Runner, cases: list[Case]) -> dict[str, np.ndarray]:
    """Per-case critical speed: coarse grid for every case, then per-case bisection; every round
    is one batch of rows."""
    s = runner.settings
    grid = s.grid_kmh()
    m = len(cases)
    rounds_left = int(math.ceil(math.log2(max(np.diff(grid).max() / s.tol_kmh, 1.0))))
    rows = [(i, j) for i in range(m) for j in range(grid.size)]
    result = runner.run([cases[i] for i, _ in rows], np.array([grid[j] for _, j in rows]), "coarse grid",
                        remaining_rows=m * rounds_left)  # fmt: skip
    passed = result.passed.reshape(m, grid.size)
    # the upper end of each case's highest passing range of the grid
    top_pass = np.where(passed.any(axis=1), grid.size - 1 - np.argmax(passed[:, ::-1], axis=1), -1)
    below = [[float(grid[j]) for j in range(max(top_pass[i], 0)) if not passed[i, j]] for i in range(m)]
    non_monotonic = np.array([bool(b) for b in below])
    lo = np.where(top_pass >= 0, grid[np.maximum(top_pass, 0)], np.nan)
    hi = np.where(top_pass < grid.size - 1, grid[np.minimum(top_pass + 1, grid.size - 1)], np.nan)
    first_fail = top_pass + 1  # the grid index where the search brackets the boundary
    failed_by: list[list[str]] = [[] for _ in range(m)]
    sample = {"f0_hz": np.full(m, np.nan), "sum_y_rms_n": np.full(m, np.nan), "frame_accel_rms": np.full(m, np.nan),
              "flange_time": np.full(m, np.nan), "mean_offset": np.full(m, np.nan),
              "flange_occupancy": np.full(m, np.nan)}  # fmt: skip
    for i in range(m):  # what the failing speed above the boundary fails by
        if first_fail[i] < grid.size:
            r = i * grid.size + first_fail[i]
            failed_by[i] = result.failed_by(r)
            for key in sample:
                sample[key][i] = _value(result, key, r)
    round_no = 0
    while True:
        active = np.nonzero(np.isfinite(lo) & np.isfinite(hi) & (hi - lo > s.tol_kmh))[0]
        if active.size == 0:
            break
        round_no += 1
        mid = 0.5 * (lo[active] + hi[active])
        left = max(0, int(math.ceil(math.log2(max((hi[active] - lo[active]).max() / s.tol_kmh, 1.0)))) - 1)
        r = runner.run([cases[i] for i in active], mid, f"bisection round {round_no}", remaining_rows=active.size * left)
        for a, i in enumerate(active):
            if r.passed[a]:
                lo[i] = mid[a]
            else:
                hi[i] = mid[a]
                failed_by[i] = r.failed_by(a)
                for key in sample:
                    sample[key][i] = _value(r, key, a)
    critical = np.where(np.isnan(lo), grid[0], lo)
    bound = np.where(first_fail == grid.size, "at_least", np.where(first_fail == 0, "at_most", "bisected"))
    return {"critical_kmh": critical, "bound": bound, "non_monotonic": non_monotonic, "failed_by": failed_by,
            "at_failure": sample, "fails_below": below}  # fmt: skip


def column_result(cases: list[Case], found: dict[str, Any], idx: np.ndarray, settings: Settings) -> dict[str, Any]:
    """One column: the highest speed all its seeds pass, with the spread over the seeds."""
    crit = found["critical_kmh"][idx]
    bounds = found["bound"][idx]
    worst = int(np.argmin(crit))
    value = float(crit[worst])
    bound = "at_least" if np.all(bounds == "at_least") else ("at_most" if bounds[worst] == "at_most" else "bisected")
    out: dict[str, Any] = {
        "kmh": round(value, 1),
        "bound": {"at_least": f"at least: every seed passes at the ceiling {settings.ceiling_kmh:g} km/h",
                  "at_most": f"at most: a seed fails at the floor {settings.floor_kmh:g} km/h",
                  "bisected": f"bisection to {settings.tol_kmh:g} km/h"}[bound],
        "floor_kmh": settings.floor_kmh,
        "ceiling_kmh": settings.ceiling_kmh,
        "seeds": [cases[i].seed for i in idx],
        "per_seed_kmh": [round(float(v), 1) for v in crit],
        "spread_kmh": {"min": round(float(crit.min()), 1), "median": round(float(np.median(crit)), 1),
                       "max": round(float(crit.max()), 1)},
        "non_monotonic_seeds": int(found["non_monotonic"][idx].sum()),
        # grid speeds below a seed's critical speed where it failed (they do not lower it)
        "fails_below_kmh": {str(cases[i].seed): [round(v, 1) for v in found["fails_below"][i]]
                            for i in idx if found["fails_below"][i]},
        "worst_seed_fails_by": found["failed_by"][idx[worst]],
    }  # fmt: skip
    at = found["at_failure"]
    if np.isfinite(at["f0_hz"][idx[worst]]):
        out["worst_seed_at_failure"] = {"f0_hz": round(float(at["f0_hz"][idx[worst]]), 2),
                                        "sum_y_rms_kn": round(float(at["sum_y_rms_n"][idx[worst]]) / 1e3, 2),
                                        "frame_accel_rms_m_per_s2": round(float(at["frame_accel_rms"][idx[worst]]), 2),
                                        "flange_time": round(float(at["flange_time"][idx[worst]]), 4),
                                        # a steady offset (e.g. from sensor bias) rather than an oscillation
                                        "mean_offset_over_clearance": round(float(at["mean_offset"][idx[worst]]), 3)}  # fmt: skip
        if np.isfinite(at["flange_occupancy"][idx[worst]]):  # v3: the share of 1 s windows with a contact
            out["worst_seed_at_failure"]["flange_occupancy"] = round(float(at["flange_occupancy"][idx[worst]]), 3)
    if cases[idx[worst]].scenario is not None:
        out["worst_scenario"] = cases[idx[worst]].scenario
    return out


def block_values(per_seed_kmh: Sequence[float], block: int = 10) -> list[float]:
    """Each block of ``block`` consecutive seeds' column value, as the protocol reports a column:
    its lowest seed (for scripts that split a long run of seeds into protocol-sized blocks)."""
    if block < 1 or len(per_seed_kmh) % block:
        raise ConfigError(f"block_values: {len(per_seed_kmh)} seeds do not split into blocks of {block}")
    return [min(per_seed_kmh[b:b + block]) for b in range(0, len(per_seed_kmh), block)]


def columns_by_conicity(result: Mapping[str, Any], nominal_conicity: float = 0.025) -> dict[str, Any]:
    """``{conicity: column}`` of a protocol-v2 result: the ``by_conicity`` columns and the nominal
    one under its conicity (v1's wheels: 0.025), for scripts that compare conicities."""
    nominal = {f"{nominal_conicity:g}": result["nominal"]} if "nominal" in result else {}
    return nominal | dict(result.get("by_conicity", {}))


# ---- parts ---------------------------------------------------------------------------------------
@dataclass
class PartContext:
    """What a part gets: the controller (as a factory of policies told their env config), the
    v1 env config, the settings, and the progress reporter."""

    factory: PolicyFactory
    env_config: dict
    settings: Settings
    observation_type: str
    progress: Progress
    n_sub: int | None = None  # the integration substeps of the protocol's tasks, once chosen
    privileged: bool = False  # the controller is told each row's true scenario (``tell``)
    _policies: dict = field(default_factory=dict)

    def task(self, n: int, config: dict) -> HuntingTask:
        """A task of the protocol (every task takes the substeps the first one chose: choosing
        them takes seconds, and they depend only on the speed and randomisation ranges)."""
        if self.n_sub is not None:
            config = merge_config(config, {"integration": {"n_sub": self.n_sub}})
        task = HuntingTask(n, config)
        if self.n_sub is None:
            self.n_sub = task.n_sub
        return task

    def policy(self, conicity: float | None = None) -> Any:
        """A fresh policy built for the env config (and, if given, told this conicity)."""
        return self.factory(policy_config(self.env_config, self.observation_type, conicity))

    def reused_policy(self, conicity: float, slot: str) -> Any:
        """The policy told ``conicity`` for one concurrent use ``slot``, built once and reused
        (every use starts with ``reset(n)``, which clears a controller's whole state; designing
        LQG takes seconds per conicity)."""
        key = (round(conicity, 12), slot)
        if key not in self._policies:
            self._policies[key] = self.policy(conicity)
        return self._policies[key]

    def scenario_groups(self, task: HuntingTask, slot: str) -> list[tuple[np.ndarray, Any]]:
        """A privileged controller's groups: one policy per distinct true scenario of the task's
        rows (after their reset), told that scenario and the task's loop (``policy.tell``)."""
        keys = [json.dumps(task.scenario(i), sort_keys=True, default=float) for i in range(task.num_envs)]
        groups = []
        for key in dict.fromkeys(keys):
            rows = np.array([i for i, k in enumerate(keys) if k == key])
            cache = (key, slot)
            if cache not in self._policies:
                self._policies[cache] = self.policy().tell(task.scenarios[int(rows[0])], task.config)
            groups.append((rows, self._policies[cache]))
        return groups


PartFunction = Callable[[PartContext], dict]
#: The protocol's parts, in their default order: name -> function(ctx) -> dict merged into the result.
PARTS: dict[str, PartFunction] = {}
#: Modules that register more parts when imported; imported lazily. ``curving``: the curving
#: columns on the shipped routes (:mod:`bogie_agents.evaluation.curving_evaluation`).
PART_MODULES: tuple[str, ...] = ("bogie_agents.evaluation.ramp_down", "bogie_agents.evaluation.curving_evaluation")
DEFAULT_PARTS = ("critical", "cost")


def register_part(name: str) -> Callable[[PartFunction], PartFunction]:
    """Decorator: add a part to :data:`PARTS` under ``name``."""

    def wrap(fn: PartFunction) -> PartFunction:
        PARTS[name] = fn
        return fn

    return wrap


def available_parts() -> dict[str, PartFunction]:
    """:data:`PARTS` after importing :data:`PART_MODULES` (a missing module is skipped)."""
    for module in PART_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError:
            pass
    return PARTS


@register_part("critical")
def critical_part(ctx: PartContext) -> dict[str, Any]:
    """Closed-loop critical speed of every column (one batched search)."""
    s = ctx.settings
    cols = columns(ctx.env_config, s)
    cases = [c for col in cols.values() for c in col]
    runner = Runner(ctx)
    found = search(runner, cases)
    results: dict[str, dict] = {}
    start = 0
    for name, col in cols.items():
        results[name] = column_result(cases, found, np.arange(start, start + len(col)), s)
        start += len(col)
    params = bogie_params(ctx.env_config)
    out: dict[str, Any] = {
        "search": {"floor_kmh": s.floor_kmh, "ceiling_kmh": s.ceiling_kmh, "grid_kmh": [round(v, 1) for v in s.grid_kmh()],
                   "tol_kmh": s.tol_kmh, "duration_s": s.duration_s, "seeds": s.seeds,
                   "perturbation_m": s.perturbation_m,
                   "definition": "a seed's critical speed is the upper end of its highest passing speed range on "
                                 "the grid, bisected; grid speeds below it where the seed fails are reported in "
                                 "fails_below_kmh and do not lower it"},
        "criterion": criterion_text(s, params.Wpa, params.mb),
        "told": "the true scenario of every row (privileged: conicity, degradation, faults, loop delay)" if ctx.privileged else
                "model-based controllers are designed for the column's conicity, rounded to the nearest of "
                f"{', '.join(f'{c:g}' for c in s.conicities)}; nothing about degradation, faults or extra delay",
    }  # fmt: skip
    if "nominal" in results:
        out["closed_loop_critical_speed_kmh"] = results["nominal"]["kmh"]
        out["nominal"] = results["nominal"]
    by_conicity = {}
    for lam in s.conicities:
        key = "nominal" if math.isclose(lam, params.lam) else f"conicity:{lam:g}"
        if key in results:
            by_conicity[f"{lam:g}"] = results[key]
    out["by_conicity"] = by_conicity
    out["degraded"] = {k.split(":", 1)[1]: v for k, v in results.items() if k.startswith("degraded:")}
    out["actuator_failed"] = {k.split(":", 1)[1]: v for k, v in results.items() if k.startswith("failed:")}
    for k, v in results.items():
        if k.startswith("delay:"):
            out[f"delay_{k.split(':', 1)[1]}"] = v
    if "worst_case" in results:
        out["worst_case"] = results["worst_case"]
    return out


@register_part("cost")
def cost_part(ctx: PartContext) -> dict[str, Any]:
    """Actuator cost and ride on the irregular track at a fixed speed, from a small perturbation."""
    s = ctx.settings
    out: dict[str, Any] = {}
    for lam in s.cost_conicities:
        cfg = protocol_config(ctx.env_config, s, ctx.observation_type)
        cfg = merge_config(cfg, {"large_perturbation_probability": 0.0})
        n = s.cost_seeds
        task = ctx.task(n, cfg)
        task.seed_rows(np.arange(n), [s.seed + i for i in range(n)])
        task.reset_rows(np.arange(n), {**s.nominal_options, "conicity": lam, "start_kmh": s.cost_speed_kmh,
                                       "end_kmh": s.cost_speed_kmh, "accel": 0.0})  # fmt: skip
        policy = ctx.policy(told_conicity(lam, s.conicities))
        policy.reset(n)
        dt = task.config["dt"]
        steps, first = int(round(s.cost_duration_s / dt)), int(round(s.transient_s / dt))
        k_count = steps - first
        force_sq = np.zeros((n, len(CHANNEL_NAMES)))
        rate_sq = np.zeros_like(force_sq)
        power = np.zeros_like(force_sq)
        accel_sq = np.zeros(n)
        contact = np.zeros(n)
        blowup = np.zeros(n, dtype=bool)
        buffer = np.zeros((n, 3))
        previous = task.actuator_force.copy()
        for k in range(steps):
            blowup |= step_guarded(task, policy.act(task.obs))
            f = task.actuator_force
            if k >= first:
                running_signals_rows(task.sim.rows, buffer)
                force_sq += f * f
                rate_sq += ((f - previous) / dt) ** 2
                power += task.actuator_power
                accel_sq += buffer[:, 2] ** 2
                contact += flange_touching(task)
            previous[:] = f
            ctx.progress.report(f"cost at conicity {lam:g}: {k + 1}/{steps} steps", k + 1, steps - k - 1)
        limits = task.actuator_limits
        active = [CHANNEL_NAMES[k] for k in task.active_channels]
        col = {
            "speed_kmh": s.cost_speed_kmh, "conicity": lam, "track": task.config["track"]["level"] or task.config["track"]["rms"],
            "seeds": n, "evaluated_s": [s.transient_s, s.cost_duration_s],
            "rms_force": {c: round(float(np.sqrt(force_sq[:, k].mean() / k_count)), 1) for k, c in enumerate(CHANNEL_NAMES) if c in active},
            "rms_force_rate": {c: round(float(np.sqrt(rate_sq[:, k].mean() / k_count)), 1) for k, c in enumerate(CHANNEL_NAMES) if c in active},
            "mean_power_w": {c: round(float(power[:, k].mean() / k_count), 2) for k, c in enumerate(CHANNEL_NAMES) if c in active},
            "limits": {c: float(limits[k]) for k, c in enumerate(CHANNEL_NAMES) if c in active},
            "frame_accel_rms_m_per_s2": round(float(np.sqrt(accel_sq.mean() / k_count)), 4),
            "flange_time": round(float(contact.mean() / k_count), 4),
            "blowup_seeds": int(blowup.sum()),
            "body_side": "not available: the model has no car body (the secondary suspension ends on a fixed body)",
        }  # fmt: skip
        out[f"{lam:g}"] = col
    return {"cost": out}


@register_part("margins")
def margins_part(ctx: PartContext) -> dict[str, Any]:
    """Stability margins at nominal conicity (:func:`bogie_agents.design.margins.margins_table`)."""
    from ..design.margins import margins_table

    return {"margins": margins_table(ctx.policy(), ctx.env_config, list(ctx.settings.margin_speeds_kmh))}


@register_part("ramp")
def ramp_part(ctx: PartContext) -> dict[str, Any]:
    """The env's own episode (its speed ramp, randomisation and hunting detector) over seeds:
    protocol v1's ramp onset (:func:`bogie_agents.evaluation.evaluate.ramp_onset`) on the v1 config."""
    from .evaluate import ProtocolSettings, ramp_onset

    config = policy_config(ctx.env_config, ctx.observation_type)
    return {"ramp": ramp_onset(ctx.policy(), config, ProtocolSettings(seed=ctx.settings.seed))}


# ---- the protocol ---------------------------------------------------------------------------------
def evaluate_policy_v2(source: Any, env_config: Mapping[str, Any] | None = None, settings: Settings | None = None,
                       parts: Iterable[str] = DEFAULT_PARTS, trusted: bool = False, label: str | None = None) -> dict:  # fmt: skip
    """The protocol (v3, or v2 with ``Settings(version=2)``) for one controller. ``source``: a policy name or path (``load_policy``; a
    path needs ``trusted``), a factory ``env_config -> policy``, or a policy object (copied for
    each use); ``env_config``: a v1 env config (default: the ``v1`` variant)."""
    settings = settings or Settings()
    settings.check()
    env_config = make_config(variant="v1") if env_config is None else make_config(dict(env_config))
    registry = available_parts()
    parts = tuple(parts)
    unknown = [p for p in parts if p not in registry]
    if unknown:
        raise ConfigError(f"protocol parts {unknown} are not known; known: {', '.join(registry)}")
    factory = factory_for(source, trusted)
    probe = factory(env_config)
    observation_type = getattr(probe, "observation_type", "sensors")
    name = label or (source if isinstance(source, str) else getattr(probe, "name", type(probe).__name__))
    ctx = PartContext(factory, env_config, settings, observation_type, Progress(str(name), settings.progress),
                      privileged=bool(getattr(probe, "privileged", False)))
    out: dict[str, Any] = {"policy": name, "observation_type": observation_type, "protocol_version": settings.version,
                           "knows": getattr(probe, "knows", "conicity class")}
    if ctx.privileged:
        out["privileged"] = True
    if settings.screening:
        out["screening"] = (f"screening, not the protocol: {settings.seeds} seeds, {settings.worst_case_draws} worst-case "
                            f"draws, bisection to {settings.tol_kmh:g} km/h")  # fmt: skip
    for part in parts:
        out.update(registry[part](ctx))
    return out


def settings_dict(settings: Settings) -> dict[str, Any]:
    """The settings as JSON (for the result and the distributed store key)."""
    return asdict(settings)
