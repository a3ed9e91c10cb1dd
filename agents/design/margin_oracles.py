"""The margins' nonlinear oracles: the closed loop of :mod:`bogie_agents.design.margins` run in time.

- :func:`simulate_loop`: the same controller on the compiled nonlinear bogie
  (``BatchSimulator``), with per-loop gain factors and extra command delays applied to a
  fraction of ``dt`` (``substeps``), the sensor filters as the env applies them;
- :func:`simulate_env`: the env's own task (``HuntingTask``) under :func:`quiet_env_config`
  (a fixed speed on perfect track, no noise or bias, a small start offset);
- :func:`deviation`, :func:`envelope_growth_rate`, :func:`dominant_frequency_hz`: what a run
  is compared with the linear loop by (``LinearLoop.growth_rate``, its eigenvalues).

They check the linear models and the margins (``tests/test_margins.py``, docs/margins.md); the
margins themselves never run them.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bogie_env.actuators import CH_DELAY_STEPS, CHANNEL_NAMES, FORCE, channel_table
from bogie_env.dynamics import N_STATES, BogieModel
from bogie_env.envs import task as T
from bogie_env.envs.config import merge_config
from bogie_env.envs.sensors import SENSOR_NAMES
from bogie_env.envs.task import STATE_SCALES
from bogie_env.sampled_plant import sensor_filters
from bogie_env.stability import KMH

from .margins import CHANNELS, check_conicity, command_delay_steps, force_channels, observe, plant_bogie, policy_config


def simulate_loop(policy, env_config: dict, speed_kmh: float, x0: np.ndarray, force0: np.ndarray, u0: np.ndarray,
                  duration_s: float, gains: np.ndarray | None = None, extra_delay_s: np.ndarray | float = 0.0,
                  substeps: int = 20, model: BogieModel | None = None) -> dict[str, np.ndarray]:  # fmt: skip
    """Run the policy on the nonlinear bogie at a fixed speed on perfect track.

    Rows: ``x0`` (N, 20) start states, all with channel forces ``force0`` and a command history
    ``u0`` (the operating point). ``gains`` (N, n_act) scale each row's commands;
    ``extra_delay_s`` (N,) or (N, n_act) delays them beyond the env's delay, rounded to
    ``dt / substeps``. The physics is the compiled RK4 kernel of :class:`BatchSimulator`, at
    ``dt / substeps`` (finer than the env's step, so it does not damp the fast modes); no
    saturation or rate limit. With ``sensors.enabled`` the observation passes the sensors'
    anti-alias filters as in the env (settled on the first sample; no noise or bias).
    Returns ``t`` (steps,), ``x`` (steps, N, 20) at the control instants.
    """
    from bogie_env.simulator import BatchSimulator

    config = policy_config(env_config, policy)
    active = force_channels(config)
    if model is None:
        model = plant_bogie(config)
    x0 = np.atleast_2d(np.asarray(x0, float))
    n, n_act = x0.shape[0], len(active)
    dt = config["dt"]
    speed = speed_kmh / KMH
    gains = np.ones((n, n_act)) if gains is None else np.broadcast_to(np.asarray(gains, float), (n, n_act))
    d_env = np.array(command_delay_steps(config, active), dtype=int)
    filter_rows, filter_weight = sensor_filters(config)
    filter_rows = list(filter_rows)
    extra = np.asarray(extra_delay_s, float)
    extra = extra.reshape(-1, 1) if extra.ndim == 1 else extra
    if np.any(~np.isfinite(extra)) or np.any(extra < 0):
        raise ValueError(f"simulate_loop: extra_delay_s = {extra_delay_s!r} must be finite and >= 0")
    lag = np.broadcast_to(np.rint(extra * substeps / dt).astype(int), (n, n_act)) + d_env[None, :] * substeps  # substeps
    max_force = np.array([config["actuators"][CHANNELS[k]]["max_force"] for k in active])
    table = channel_table(config["actuators"])
    table[:, CH_DELAY_STEPS] = 0  # the delay is applied here, to a fraction of dt
    sim = BatchSimulator(model, n, dt=dt / substeps, speed_range=(speed, speed), channels=table)
    sim.set_rows(slice(None), x0, speed)
    sim.lag[:, FORCE, active] = force0
    sim.output[:, 0, active] = force0
    n_steps = int(round(duration_s / dt))
    max_lag = int(lag.max())
    history = np.empty((n_steps + max_lag // substeps + 2, n, n_act))  # commands per control step
    policy.reset(n)
    xs = np.empty((n_steps + 1, n, N_STATES))
    xs[0] = sim.x
    target = np.zeros((n, len(CHANNEL_NAMES)))
    rows = np.arange(n)[:, None]
    filtered = None
    for step in range(n_steps):
        y = np.clip(observe(sim.x, sim.channel_output[:, active], speed, config, model), -T.OBS_BOUND, T.OBS_BOUND)
        if filter_rows:
            if filtered is None:
                filtered = y[:, filter_rows].copy()  # settled on the first sample
            else:
                filtered += filter_weight * (y[:, filter_rows] - filtered)
            y[:, filter_rows] = np.clip(filtered, -T.OBS_BOUND, T.OBS_BOUND)
        y = y.astype(np.float32)
        history[step] = np.asarray(policy.act(y), dtype=float)
        for j in range(substeps):
            s = step * substeps + j - lag  # substep index the command was issued at
            m = np.floor_divide(s, substeps)
            cmd = np.where(m >= 0, history[np.maximum(m, 0), rows, np.arange(n_act)[None, :]], u0[None, :])
            target[:, active] = np.clip(gains * (cmd - u0) + u0, -1.0, 1.0) * max_force
            sim.step(force_target=target)
        if np.any(sim.status != 0):
            xs[step + 1:] = np.nan
            break
        xs[step + 1] = sim.x
    return {"t": np.arange(n_steps + 1) * dt, "x": xs}


def deviation(x: np.ndarray, x_eq: np.ndarray) -> np.ndarray:
    """The largest scaled lateral deviation from the operating point, per time and row."""
    from bogie_env.dynamics import LATERAL_STATES

    lat = list(LATERAL_STATES)
    return np.max(np.abs(x[..., lat] - x_eq[lat]) / STATE_SCALES[lat], axis=-1)


def envelope_growth_rate(t: np.ndarray, signal: np.ndarray, window_s: float = 0.25, floor: float = 1e-12,
                         ceiling: float = 1e-2, skip_s: float = 0.5) -> float:  # fmt: skip
    """Growth rate (1/s) of a signal's envelope: a line through log(max |s|) over windows of
    ``window_s``, using only windows after ``skip_s`` whose peak lies in ``[floor, ceiling]``
    (above round-off, below the nonlinear range). NaN with fewer than three such windows."""
    dt = t[1] - t[0]
    w = max(2, int(round(window_s / dt)))
    start = int(round(skip_s / dt))
    n = (len(t) - start) // w
    peaks = np.array([np.max(np.abs(signal[start + i * w:start + (i + 1) * w])) for i in range(n)])
    centres = np.array([t[start + i * w + w // 2] for i in range(n)])
    keep = (peaks >= floor) & (peaks <= ceiling)
    if np.count_nonzero(keep) < 3:
        return math.nan
    return float(np.polyfit(centres[keep], np.log(peaks[keep]), 1)[0])


def dominant_frequency_hz(t: np.ndarray, signal: np.ndarray, skip_s: float = 0.5) -> float:
    """The oscillation frequency (Hz) from the mean spacing of a signal's upward zero crossings
    after ``skip_s`` (linear interpolation between samples); NaN with fewer than three."""
    start = int(round(skip_s / (t[1] - t[0])))
    s, tt = signal[start:], t[start:]
    up = np.nonzero((s[:-1] < 0) & (s[1:] >= 0))[0]
    if up.size < 3:
        return math.nan
    crossings = tt[up] - s[up] * (tt[up + 1] - tt[up]) / (s[up + 1] - s[up])
    return float((up.size - 1) / (crossings[-1] - crossings[0]))


# =============================================================================================
# The env itself as the oracle
# =============================================================================================


def quiet_env_config(env_config: dict, policy, speed_kmh: float, conicity: float | None = None,
                     extra_delay_steps=0, initial_perturbation_m: float = 1e-7, n_sub: int | None = None) -> dict:  # fmt: skip
    """The env config whose small-signal loop :func:`linear_loop` describes, for running the
    env itself: the policy's observation type, sensor noise and bias zero (the anti-alias
    filters stay), perfect track, no per-episode randomisation (the conicity pinned if given),
    a fixed speed, a small random start offset (``initial_perturbation_m``); ``extra_delay_steps``
    (scalar or per active channel) added to the channels' ``delay_steps``; ``n_sub`` fixes the
    RK4 substeps (None: the config's criterion)."""
    from bogie_env.envs.config import make_config

    config = policy_config(env_config, policy)
    active = force_channels(config)
    extra = np.broadcast_to(np.asarray(extra_delay_steps, dtype=int), (len(active),))
    update: dict[str, Any] = {
        "speed": {"start_kmh": float(speed_kmh), "end_kmh": float(speed_kmh), "accel": 0.0, "start_kmh_range": None,
                  "end_kmh_range": None, "accel_range": None},  # fmt: skip
        "track": {"level": None, "rms": 0.0},
        "randomize": {} if conicity is None else {"conicity": [check_conicity(conicity)] * 2},
        "initial_perturbation": float(initial_perturbation_m),
        "large_perturbation_probability": 0.0,
        "observation": {"noise": 0.0},
        "actuators": {CHANNELS[k]: {"delay_steps": int(config["actuators"][CHANNELS[k]]["delay_steps"] + e)}
                      for k, e in zip(active, extra)},  # fmt: skip
    }
    if config["sensors"]["enabled"]:
        update["sensors"] = {name: {"noise_density": 0.0, "bias": 0.0} for name in SENSOR_NAMES}
    if n_sub is not None:
        update["integration"] = {"n_sub": int(n_sub)}
    return make_config(merge_config(config, update))


def simulate_env(policy, env_config: dict, speed_kmh: float, duration_s: float, conicity: float | None = None,
                 extra_delay_steps=0, initial_perturbation_m: float = 1e-7, seed: int = 0,
                 n_sub: int | None = None) -> dict[str, np.ndarray]:  # fmt: skip
    """Run ``policy`` in the env's own task (``HuntingTask``, one row) under
    :func:`quiet_env_config`: the nonlinear bogie, the env's integrator, delays, lags, rate
    limits, saturation and sensor filters, at a fixed speed on perfect track. Returns ``t``
    (steps + 1,), ``x`` (steps + 1, 20) states, ``obs`` (steps + 1, n_obs), ``actions`` (steps,
    n_act), ``n_sub`` the RK4 substeps used."""
    from bogie_env.envs.task import HuntingTask

    config = quiet_env_config(env_config, policy, speed_kmh, conicity, extra_delay_steps, initial_perturbation_m, n_sub)
    task = HuntingTask(1, config)
    task.seed_rows(np.array([0]), [seed])
    task.reset_rows(np.array([0]))
    n_steps = int(round(duration_s / config["dt"]))
    xs = np.empty((n_steps + 1, N_STATES))
    obs = np.empty((n_steps + 1, task.observation_dim))
    actions = np.empty((n_steps, task.action_dim))
    xs[0], obs[0] = task.states[0], task.obs[0]
    policy.reset(1)
    for n in range(n_steps):
        actions[n] = np.asarray(policy.act(task.obs.copy()), dtype=float)[0]
        task.step(actions[n][None])
        xs[n + 1], obs[n + 1] = task.states[0], task.obs[0]
        if task.blowup[0]:
            xs[n + 2:] = np.nan
            obs[n + 2:] = np.nan
            actions[n + 1:] = np.nan
            break
    return {"t": np.arange(n_steps + 1) * config["dt"], "x": xs, "obs": obs, "actions": actions, "n_sub": task.n_sub}
