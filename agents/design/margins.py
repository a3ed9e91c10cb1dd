"""Stability margins of any controller in the hunting loop, learned or not (v0 and v1 tasks).

The closed loop is linearised at a fixed speed on straight, perfect track, about its
equilibrium, and analysed as the discrete-time system it is: the env applies one action per
control interval ``dt`` (10 ms) and holds it (zero-order hold) into the actuators' first-order
lag. The linear model is exact for that sampled loop; no Padé approximation is needed, because
the config's command delay is a whole number of intervals (a shift register per channel).

Pieces (all discrete at ``dt``):

- **Plant** (:func:`plant_model`): the bogie's exact Jacobian at the equilibrium
  (:meth:`BogieModel.jacobian`; :func:`plant_bogie` puts a chosen conicity into ``lam``), its
  input matrix, the channel-to-generalised-force map (wheelset torques react on the frame), the
  actuators' lags ``dF/dt = w (u F_max - F)``, discretised exactly with the block exponential;
  each channel's command delay (``delay_steps``); the env's observation (sensors or full state,
  with the env's scalings) and, with ``sensors.enabled`` (v1), the sensors' first-order
  anti-alias filters exactly as the env applies them to the samples
  (:func:`sensor_filters`). Noise and bias do not enter; the force-rate limit never binds at
  small amplitude and is left out.
- **Controller** (:func:`controller_model`): a discrete state space
  (:class:`bogie_agents.design.linear_models.ControllerModel`) from the observation to the normalised
  command. A policy's own ``controller_model(n_obs, speed_kmh, y0)`` method first; then
  skyhook, LQR and LQG from their own matrices (LQG with its Kalman filter states); SB3
  policies by the derivative of the deterministic action through the VecNormalize scaling and
  clipping (torch autograd, checked against finite differences); any other stateless policy
  by finite differences of ``act``.
- **Margins** (:func:`loop_margins`): loop at a time, broken at each actuator command with the
  other loops closed: upper and lower gain margin, phase margin, delay margin, disk margin; and
  the disk margin for simultaneous perturbations of all loops. python-control computes them
  (``stability_margins`` on the frequency response up to the Nyquist frequency,
  ``disk_margins``). The closed-loop eigenvalues check the delay margins: whole extra steps per
  loop and in all loops at once, and the exact sampled model of a fractional delay
  (:meth:`PlantModel.with_delay_s`).

Conventions: a loop's gain margin is the factor by which its command may be scaled before the
loop goes unstable (``gain_margin`` above 1, ``gain_margin_lower`` below 1; 0 when any gain down
to zero is stable). The delay margin is the extra pure delay (s), beyond the delay the config
already has (``existing_delay_s``; v1: 10 ms), at which the loop goes unstable: the least
``phase margin / crossover frequency`` over the gain crossovers (``delay_margin_s``), exact at
whole steps; ``delay_margin_sampled_s`` is the exact figure between them. Margins are
meaningful only when the nominal closed loop is stable (``closed_loop_stable``); otherwise
they are reported as None.

Oracles (:mod:`bogie_agents.design.margin_oracles`): ``simulate_loop``, the same controller on the
compiled nonlinear bogie with per-loop gain factors and extra delays (to a fraction of
``dt``), and ``simulate_env``, the env's own task (``HuntingTask``) under ``quiet_env_config``.

Entry point: :func:`margins_table` ``(policy, env_config, speeds_kmh, conicity=None)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES, force_matrix
from bogie_env.dynamics import N_INPUTS, N_STATES, BogieModel, state_index
from bogie_env.envs import task as T
from bogie_env.envs.config import bogie_params, merge_config
from bogie_env.envs.scenario import RANGES
from bogie_env.envs.sensors import SENSOR_NAMES
from bogie_env.envs.task import STATE_SCALES
from bogie_env.params import ConfigError
from bogie_env.sampled_plant import PlantModel, actuated, sampled_plant, sensor_filters
from bogie_env.stability import KMH

from .linear_models import (ControllerModel, finite_difference_jacobian, frames_of, lstm_controller_model, parallel,  # noqa: F401
                            residual_controller_model, sb3_action, sb3_action_function, sb3_controller_model,
                            sb3_jacobian_autograd, series, stack_model, static_model)  # fmt: skip

_static = static_model

CHANNELS = CHANNEL_NAMES
#: The speeds of the margins table, km/h.
DEFAULT_SPEEDS_KMH = (300.0, 350.0, 400.0, 450.0, 500.0)


# =============================================================================================
# Plant: bogie + actuators + delay + sensors, discrete at dt
# =============================================================================================


def force_channels(config: dict) -> list[int]:
    """The active channels (indices into ``CHANNEL_NAMES``), each in ``force`` mode (else a named error)."""
    active = [k for k, name in enumerate(CHANNELS) if config["actuators"][name]["mode"] != "off"]
    for k in active:
        if config["actuators"][CHANNELS[k]]["mode"] != "force":
            raise ConfigError(
                f"margins: actuators.{CHANNELS[k]}.mode = {config['actuators'][CHANNELS[k]]['mode']!r} is not supported; "
                "allowed: 'force' or 'off' (a semi-active damper's command has zero small-signal gain at rest)"
            )
    return active


def command_delay_steps(config: dict, active: list[int]) -> tuple[int, ...]:
    """Each active channel's command delay, whole control steps."""
    return tuple(int(config["actuators"][CHANNELS[k]]["delay_steps"]) for k in active)


def observe(x: np.ndarray, force: np.ndarray, speed: float, plant_config: dict, model: BogieModel) -> np.ndarray:
    """The env's observation (N, n_obs) from states (N, 20) and active-channel forces (N, n_act).

    The same formulas and scalings as the compiled env (``bogie_env.envs.kernel._observe``),
    in float64 and unclipped.
    """
    active = force_channels(plant_config)
    x = np.atleast_2d(x)
    force = np.atleast_2d(force)
    n = x.shape[0]
    max_force = np.array([plant_config["actuators"][CHANNELS[k]]["max_force"] for k in active])
    columns = []
    if plant_config["observation"]["type"] == "state":
        columns.append(x / STATE_SCALES)
    else:
        u4 = np.zeros((n, N_INPUTS))
        u4[:, active] = force
        accel = model.rhs(x, speed, inputs=u4 @ force_matrix().T)[:, state_index("dyb")]
        L1, delta = model.params.L1, model.params.delta
        psib = x[:, state_index("psib")]
        yb = x[:, state_index("yb")]
        sensors = np.empty((n, len(T.SENSORS)))
        sensors[:, T.SENSOR_FRAME_LATERAL_ACCEL] = accel / T.ACCEL_SCALE
        sensors[:, T.SENSOR_FRAME_YAW_RATE] = x[:, state_index("dpsib")] / T.YAW_RATE_SCALE
        sensors[:, T.SENSOR_WHEELSET1_LATERAL] = (x[:, state_index("y1")] - yb - L1 * psib) / delta
        sensors[:, T.SENSOR_WHEELSET2_LATERAL] = (x[:, state_index("y2")] - yb + L1 * psib) / delta
        sensors[:, T.SENSOR_WHEELSET1_YAW] = (x[:, state_index("psi1")] - psib) / T.REL_YAW_SCALE
        sensors[:, T.SENSOR_WHEELSET2_YAW] = (x[:, state_index("psi2")] - psib) / T.REL_YAW_SCALE
        columns.append(sensors)
    columns.append(np.full((n, 1), (speed * KMH - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH))
    if plant_config["observation"]["include_actuators"]:
        columns.append(force / max_force)
    return np.concatenate(columns, axis=1)


def _observation_jacobian(x_eq, force_eq, speed, config, model) -> np.ndarray:
    """d(observation)/d[x, F] at the operating point: exact (the observation is linear in x and
    F except the acceleration, whose row is the Jacobian's dyb row)."""
    active = force_channels(config)
    n_act = len(active)
    y0 = observe(x_eq[None], force_eq[None], speed, config, model)[0]
    jac = np.zeros((y0.size, N_STATES + n_act))
    # every entry but the acceleration is linear; one unit step per column is exact for them
    for j in range(N_STATES + n_act):
        dx = np.zeros(N_STATES + n_act)
        dx[j] = 1.0
        jac[:, j] = observe((x_eq + dx[:N_STATES])[None], (force_eq + dx[N_STATES:])[None], speed, config, model)[0] - y0
    if config["observation"]["type"] != "state":
        u4 = np.zeros(N_INPUTS)
        u4[active] = force_eq
        q = force_matrix() @ u4
        j_x = model.jacobian(x_eq, speed, inputs=q)
        b_u = model.input_matrix() @ force_matrix(active)
        row = state_index("dyb")
        jac[T.SENSOR_FRAME_LATERAL_ACCEL, :N_STATES] = j_x[row] / T.ACCEL_SCALE
        jac[T.SENSOR_FRAME_LATERAL_ACCEL, N_STATES:] = b_u[row] / T.ACCEL_SCALE
    return jac


def plant_model(config: dict, speed_kmh: float, force_eq: np.ndarray | None = None,
                x_eq: np.ndarray | None = None, model: BogieModel | None = None) -> PlantModel:  # fmt: skip
    """The sampled plant at ``speed_kmh`` about ``(x_eq, force_eq)`` (default: the passive
    equilibrium with zero forces)."""
    active = force_channels(config)
    if not active:
        raise ConfigError("margins: no active actuator channel; every actuators.*.mode is 'off'")
    if model is None:
        model = BogieModel(bogie_params(config))
    speed = speed_kmh / KMH
    n_act = len(active)
    max_force = np.array([config["actuators"][CHANNELS[k]]["max_force"] for k in active])
    bandwidth = np.array([2 * math.pi * config["actuators"][CHANNELS[k]]["bandwidth_hz"] for k in active])
    force_eq = np.zeros(n_act) if force_eq is None else np.asarray(force_eq, dtype=float)
    if x_eq is None:
        u4 = np.zeros(N_INPUTS)
        u4[active] = force_eq
        x_eq = model.equilibrium(speed, inputs=force_matrix() @ u4)
    u4 = np.zeros(N_INPUTS)
    u4[active] = force_eq
    j_x = model.jacobian(x_eq, speed, inputs=force_matrix() @ u4)
    a_c, b_c = actuated(j_x, model.input_matrix() @ force_matrix(active), bandwidth, max_force)
    c_xf = _observation_jacobian(x_eq, force_eq, speed, config, model)
    return sampled_plant(a_c, b_c, c_xf, config, active, command_delay_steps(config, active), speed, x_eq, force_eq, model)


# =============================================================================================
# Controllers as discrete state spaces
# =============================================================================================


def skyhook_model(policy, n_obs: int) -> ControllerModel:
    """Skyhook: a leaky integrator of the frame acceleration and difference quotients of the
    relative yaws (their previous values are the states)."""
    dt, leak = policy.dt, policy.leak
    m = policy.action_dim
    acc, yaw_rate = T.SENSOR_FRAME_LATERAL_ACCEL, T.SENSOR_FRAME_YAW_RATE
    rel = (T.SENSOR_WHEELSET1_YAW, T.SENSOR_WHEELSET2_YAW)
    # states: frame lateral velocity, previous relative yaw 1 and 2 (SI)
    a = np.diag([leak, 0.0, 0.0])
    b = np.zeros((3, n_obs))
    b[0, acc] = dt * T.ACCEL_SCALE
    b[1, rel[0]] = T.REL_YAW_SCALE
    b[2, rel[1]] = T.REL_YAW_SCALE
    # each channel's rate as (state, y) -> rate
    rate_c = {name: np.zeros(3) for name in CHANNEL_NAMES}
    rate_d = {name: np.zeros(n_obs) for name in CHANNEL_NAMES}
    rate_c["frame_lateral"][0], rate_d["frame_lateral"][acc] = leak, dt * T.ACCEL_SCALE
    rate_d["frame_yaw"][yaw_rate] = T.YAW_RATE_SCALE
    for i, name in enumerate(("wheelset1_yaw", "wheelset2_yaw")):
        rate_c[name][1 + i] = -1.0 / dt
        rate_d[name][rel[i]] = T.REL_YAW_SCALE / dt
        rate_d[name][yaw_rate] = T.YAW_RATE_SCALE
    c = np.zeros((m, 3))
    d = np.zeros((m, n_obs))
    for j, k in enumerate(policy.active):
        name = CHANNEL_NAMES[k]
        if name in policy.gains:
            c[j] = -policy.gains[name] * rate_c[name] / policy.max_force[j]
            d[j] = -policy.gains[name] * rate_d[name] / policy.max_force[j]
    return ControllerModel(a, b, c, d, "skyhook matrices")


def lqr_model(policy, n_obs: int, speed_kmh: float) -> ControllerModel:
    """LQR: u = -K [x_lat; F_hat], with F_hat the controller's replica of the actuator lag."""
    from bogie_env.dynamics import LATERAL_STATES

    gain = policy.gain_at(np.array([speed_kmh]))[0]
    lat = list(LATERAL_STATES)
    n_lat, m = len(lat), policy.n_act
    select = np.zeros((n_lat, n_obs))  # x_lat from the state observation
    for i, s in enumerate(lat):
        select[i, s] = STATE_SCALES[s]
    kx, kf = gain[:, :n_lat], gain[:, n_lat:]
    w = np.exp(-policy.bandwidth * policy.dt)
    g = np.diag((1 - w) * policy.max_force)
    d = -kx @ select
    c = -kf
    a = np.diag(w) + g @ c
    b = g @ d
    return ControllerModel(a, b, c, d, "LQR gains (interpolated at the speed)")


def privileged_model(policy, n_obs: int, speed_kmh: float, to_lateral: np.ndarray | None = None) -> ControllerModel:
    """The privileged reference (:class:`bogie_agents.controllers.privileged.PrivilegedController`): states ``[F_hat, registers]`` (the replicated lag and command registers),
    ``u = -K [x_lat(y), F_hat, registers]`` at the speed; exactly what its ``act`` does without clipping.
    ``to_lateral`` (16, n_obs): its input's map to the lateral states (default: the full-state observation's)."""
    from bogie_env.dynamics import LATERAL_STATES

    gain = policy.gain_at(np.array([speed_kmh]))[0]
    lat = list(LATERAL_STATES)
    n_lat, m = len(lat), policy.n_act
    if to_lateral is None:
        to_lateral = np.zeros((n_lat, n_obs))
        for i, state in enumerate(lat):
            to_lateral[i, state] = STATE_SCALES[state]
    n_in = to_lateral.shape[1]
    n_c = gain.shape[1] - n_lat
    c = -gain[:, n_lat:]
    d = -gain[:, :n_lat] @ to_lateral
    a, b = np.zeros((n_c, n_c)), np.zeros((n_c, n_in))
    w = np.exp(-policy.bandwidth * policy.dt)
    pos = m
    for j, delay in enumerate(policy.delays):
        g = (1 - w[j]) * policy.max_force[j] * policy.channel_gain[j]
        a[j, j] = w[j]
        if delay == 0:
            a[j] += g * c[j]
            b[j] += g * d[j]
        else:
            a[j, pos + delay - 1] += g
            a[pos] = c[j]
            b[pos] = d[j]
            for i in range(1, delay):
                a[pos + i, pos + i - 1] = 1.0
            pos += delay
    return ControllerModel(a, b, c, d, "privileged LQR gains with the replicated lag and registers (at the speed)")


def sensor_fed_model(policy, n_obs: int, speed_kmh: float) -> ControllerModel:
    """A privileged design on a Kalman estimate (:class:`bogie_agents.controllers.privileged.SensorFed`:
    ``privileged_sensors``, and ``mpc`` / ``privileged_mpc_sensors`` without active constraints,
    where an MPC's first command is its LQR's): states ``[estimate, last command, F_hat,
    registers]``; the filter's corrected lateral states feed :func:`privileged_model`."""
    from bogie_env.dynamics import LATERAL_STATES

    e_e, e_l, e_y = filter_update(policy.filter, n_obs, speed_kmh)  # the corrected estimate
    n_aug, m, n_lat = e_e.shape[0], policy.n_act, len(LATERAL_STATES)
    inner = privileged_model(policy, n_lat, speed_kmh, to_lateral=np.eye(n_lat))  # input: the estimated lateral states
    n_q = inner.a.shape[0]
    x_e, x_l, x_y = e_e[:n_lat], e_l[:n_lat], e_y[:n_lat]
    c = np.hstack([inner.d @ x_e, inner.d @ x_l, inner.c])
    a = np.block([[e_e, e_l, np.zeros((n_aug, n_q))], [c], [inner.b @ x_e, inner.b @ x_l, inner.a]])
    b = np.vstack([e_y, inner.d @ x_y, inner.b @ x_y])
    assert a.shape == (n_aug + m + n_q, n_aug + m + n_q)
    return ControllerModel(a, b, c, inner.d @ x_y, "privileged LQR gains on the told scenario's Kalman filter (at the speed)")


def filter_update(policy, n_obs: int, speed_kmh: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An LQG filter's corrected estimate ``e+ = E_e e + E_l u_last + E_y y`` at the speed:
    ``(E_e, E_l, E_y)``, ``y`` the observation (its first entries the sensors)."""
    v = np.array([speed_kmh])
    ad, bd = policy._interp(policy.ads, v)[0], policy._interp(policy.bds, v)[0]
    cd, kal = policy._interp(policy.cds, v)[0], policy._interp(policy.kalmans, v)[0]
    n_s = len(T.SENSORS)
    s6 = np.zeros((n_s, n_obs))
    s6[:, :n_s] = np.eye(n_s)
    mm = np.eye(ad.shape[0]) - kal @ cd
    return mm @ ad, mm @ bd - kal @ policy.feedthrough, kal @ s6


def lqg_model(policy, n_obs: int, speed_kmh: float) -> ControllerModel:
    """LQG: the Kalman filter's estimate and the last command are the states."""
    e_e, e_l, e_y = filter_update(policy, n_obs, speed_kmh)
    gain = policy.gain_at(np.array([speed_kmh]))[0]
    n_aug, m = e_e.shape[0], policy.n_act
    a = np.block([[e_e, e_l], [-gain @ e_e, -gain @ e_l]])
    b = np.vstack([e_y, -gain @ e_y])
    c = np.hstack([-gain @ e_e, -gain @ e_l])
    d = -gain @ e_y
    assert a.shape == (n_aug + m, n_aug + m)
    return ControllerModel(a, b, c, d, "LQG gains and Kalman filter (interpolated at the speed)")


def _is_sb3(policy) -> bool:
    return hasattr(getattr(getattr(policy, "model", None), "policy", None), "_predict")


def controller_model(policy, n_obs: int, speed_kmh: float, y0: np.ndarray) -> ControllerModel:
    """The controller's linear model at the operating observation ``y0``.

    A policy's own ``controller_model(n_obs, speed_kmh, y0)`` method comes first (the hook of
    :mod:`bogie_agents.design.linear_models`); then the classical controllers' matrices, SB3 policies by
    autograd, anything else by finite differences of ``act`` (assumed stateless).
    """
    from ..controllers.lqr import LQGController, LQRController, PassiveController, SkyhookController
    from ..controllers.privileged import PrivilegedController, SensorFed

    hook = getattr(policy, "controller_model", None)
    if callable(hook):
        ctrl = hook(n_obs, speed_kmh, np.asarray(y0, dtype=float))
        if not isinstance(ctrl, ControllerModel):
            raise TypeError(f"{type(policy).__name__}.controller_model returned {type(ctrl).__name__}; "
                            "expected bogie_agents.design.linear_models.ControllerModel")  # fmt: skip
        ctrl.check_shapes(n_obs, ctrl.d.shape[0])
        return ctrl
    if isinstance(policy, PassiveController):
        return _static(np.zeros((policy.action_dim, n_obs)), "zero (passive)")
    if isinstance(policy, SkyhookController):
        return skyhook_model(policy, n_obs)
    if isinstance(policy, LQGController):
        return lqg_model(policy, n_obs, speed_kmh)
    if isinstance(policy, SensorFed):
        return sensor_fed_model(policy, n_obs, speed_kmh)
    if isinstance(policy, PrivilegedController):
        return privileged_model(policy, n_obs, speed_kmh)
    if isinstance(policy, LQRController):
        return lqr_model(policy, n_obs, speed_kmh)
    if _is_sb3(policy):
        return sb3_controller_model(policy, y0)
    return _static(finite_difference_jacobian(policy, y0), "finite differences of act (assumed stateless)")


def check_controller_model(policy, ctrl: ControllerModel, y0: np.ndarray, u0: np.ndarray, steps: int = 8,
                           amplitude: float = 1e-3, seed: int = 0) -> float:  # fmt: skip
    """Largest deviation between ``policy.act`` and the linear model on a small random
    observation sequence about ``y0``, after a few steps at ``y0`` (relative to the linear
    response's size)."""
    rng = np.random.default_rng(seed)
    dy = amplitude * rng.standard_normal((steps, y0.size))
    policy.reset(1)
    previous = None
    for i in range(1000 if ctrl.n_states else 3):  # settle at the operating point (skyhook's first step has no previous yaw)
        u = np.asarray(policy.act(y0[None].astype(np.float32)), dtype=float)
        if i >= 3 and np.max(np.abs(u - previous)) <= 1e-7:
            break
        previous = u
    c = np.zeros(ctrl.n_states)
    worst, scale = 0.0, 1e-12
    for n in range(steps):
        y = y0 + dy[n]
        u = np.asarray(policy.act(y[None].astype(np.float32)), dtype=float)[0] - u0
        u_lin = ctrl.c @ c + ctrl.d @ dy[n]
        c = ctrl.a @ c + ctrl.b @ dy[n]
        worst = max(worst, float(np.max(np.abs(u - u_lin))))
        scale = max(scale, float(np.max(np.abs(u_lin))))
    return worst / scale


# =============================================================================================
# Operating point and the closed loop
# =============================================================================================


def policy_config(env_config: dict, policy) -> dict:
    """The env config the policy runs in: its observation type. A full-state observation has
    no sensor model (the env refuses ``sensors.enabled`` with it), so it is switched off."""
    observation_type = getattr(policy, "observation_type", "sensors")
    update: dict[str, Any] = {"observation": {"type": observation_type}}
    if observation_type == "state":
        update["sensors"] = {"enabled": False}
    return merge_config(env_config, update)


def check_conicity(conicity: float | None) -> float | None:
    """``conicity`` validated against the v1 scenario's allowed range (None: the bogie's own)."""
    if conicity is None:
        return None
    r = RANGES["conicity"]
    if isinstance(conicity, bool) or not isinstance(conicity, (int, float)) or not r.low <= conicity <= r.high:
        raise ConfigError(f"margins: conicity = {conicity!r} is not allowed; allowed: a number in [{r.low:g}, {r.high:g}] "
                          "(the equivalent conicity lam, as the v1 scenario's 'conicity')")  # fmt: skip
    return float(conicity)


def plant_bogie(config: dict, conicity: float | None = None) -> BogieModel:
    """The nominal bogie of ``config`` with the equivalent conicity ``lam`` replaced (as the v1
    scenario's ``conicity`` does; None: the preset's own)."""
    params = bogie_params(config)
    conicity = check_conicity(conicity)
    return BogieModel(params if conicity is None else params.replace(lam=conicity))


def _command(policy, y: np.ndarray, n_states: int) -> np.ndarray:
    """The policy's steady action at a constant observation ``y`` (float64 where possible)."""
    steady = getattr(policy, "steady_action", None)
    if callable(steady):
        return np.asarray(steady(np.asarray(y, dtype=float)), dtype=float)
    if _is_sb3(policy) and not callable(getattr(policy, "controller_model", None)):
        return sb3_action(policy, y)
    policy.reset(1)
    u = np.asarray(policy.act(y[None].astype(np.float32)), dtype=float)[0]
    for _ in range(1000 if n_states else 0):  # a dynamic controller: until its states settle
        u_next = np.asarray(policy.act(y[None].astype(np.float32)), dtype=float)[0]
        if np.max(np.abs(u_next - u)) <= 1e-7:
            return u_next
        u = u_next
    return u


def operating_point(policy, config: dict, speed_kmh: float, model: BogieModel,
                    tol: float = 1e-12, max_iter: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The closed loop's equilibrium ``(x, F, u)`` at a fixed speed on perfect track.

    Linear controllers command zero at rest; a learned policy may not (a bias), so its
    equilibrium is solved by Newton's method on ``f(x, G F) = 0, F = F_max u(y(x, F))``, with the
    controller's steady-state gain (:meth:`ControllerModel.dc_gain`) in the Jacobian. The sensor
    filters are settled there (their output is the clean observation).
    """
    active = force_channels(config)
    n_act = len(active)
    speed = speed_kmh / KMH
    max_force = np.array([config["actuators"][CHANNELS[k]]["max_force"] for k in active])
    x = model.equilibrium(speed)
    force = np.zeros(n_act)
    y = observe(x[None], force[None], speed, config, model)[0]
    ctrl = controller_model(policy, y.size, speed_kmh, y)
    u = _command(policy, y, ctrl.n_states)
    if np.max(np.abs(u)) < 1e-9:  # linear controllers: zero up to rounding of the zero lateral states
        return x, force, np.zeros(n_act)
    precise = callable(getattr(policy, "steady_action", None)) or (_is_sb3(policy) and not callable(getattr(policy, "controller_model", None)))
    force_tol = 1e-6 if precise else 1e-2  # N: float32 actions round at about 1e-7 of max_force
    b_f = model.input_matrix() @ force_matrix(active)
    for _ in range(max_iter):
        u4 = np.zeros(N_INPUTS)
        u4[active] = force
        q = force_matrix() @ u4
        f = model.rhs(x, speed, inputs=q)
        g = force - max_force * u
        residual = np.concatenate([f, g])
        ctrl = controller_model(policy, y.size, speed_kmh, y)
        c_xf = _observation_jacobian(x, force, speed, config, model)
        jac = np.zeros((N_STATES + n_act, N_STATES + n_act))
        jac[:N_STATES, :N_STATES] = model.jacobian(x, speed, inputs=q)
        jac[:N_STATES, N_STATES:] = b_f
        jac[N_STATES:] = -np.diag(max_force) @ ctrl.dc_gain() @ c_xf
        jac[N_STATES:, N_STATES:] += np.eye(n_act)
        step = np.linalg.solve(jac, -residual)  # lstsq would drop the stiff-soft direction (cond ~1e15)
        x, force = x + step[:N_STATES], force + step[N_STATES:]
        y = observe(x[None], force[None], speed, config, model)[0]
        u = _command(policy, y, ctrl.n_states)
        if np.max(np.abs(step[:N_STATES])) < (tol if precise else 1e-9) and np.max(np.abs(step[N_STATES:])) < force_tol:
            break
    else:
        raise RuntimeError(f"margins: the closed-loop equilibrium at {speed_kmh} km/h did not converge "
                           f"(residual {np.max(np.abs(residual)):.3g})")  # fmt: skip
    return x, force, u


@dataclass
class LinearLoop:
    """Plant and controller at one speed, with helpers for the closed loop and broken loops."""

    plant: PlantModel
    ctrl: ControllerModel
    speed_kmh: float
    u_eq: np.ndarray
    y_eq: np.ndarray | None = None  # the observation at the operating point

    @property
    def dt(self) -> float:
        return self.plant.dt

    def closed_loop_matrix(self, gains: np.ndarray | None = None) -> np.ndarray:
        """A of the closed loop with each command scaled by ``gains`` (default 1)."""
        p, k = self.plant, self.ctrl
        g = np.diag(np.ones(p.n_act) if gains is None else np.asarray(gains, float))
        top = np.hstack([p.a + p.b @ g @ k.d @ p.c, p.b @ g @ k.c])
        bottom = np.hstack([k.b @ p.c, k.a])
        return np.vstack([top, bottom])

    def eigenvalues(self, gains: np.ndarray | None = None) -> np.ndarray:
        return np.linalg.eigvals(self.closed_loop_matrix(gains))

    def growth_rate(self, gains: np.ndarray | None = None) -> float:
        """ln|z|max / dt: the slowest decay (negative) or fastest growth (positive), 1/s."""
        return float(np.log(np.max(np.abs(self.eigenvalues(gains)))) / self.dt)

    def with_extra_delay(self, extra_steps) -> "LinearLoop":
        """The loop with ``extra_steps`` (scalar: every channel; or per channel) more whole steps
        of command delay."""
        return replace(self, plant=self.plant.with_extra_delay(extra_steps))

    def with_delay_s(self, extra_s) -> "LinearLoop":
        """The loop with ``extra_s`` seconds more command delay (not necessarily whole steps;
        :meth:`PlantModel.with_delay_s`)."""
        return replace(self, plant=self.plant.with_delay_s(extra_s))

    def delay_margin_by_eigenvalues(self, channel: int | None = None, tol_s: float = 1e-5, max_steps: int = 30,
                                    whole_steps: int | None | str = "compute") -> float | None:  # fmt: skip
        """The extra delay (s; in ``channel`` alone, or every channel for None) at which the
        closed loop first loses stability, from the closed-loop eigenvalues of the exact
        sampled model with a fractional delay: whole steps first
        (:meth:`tolerated_extra_steps`), then bisection within the step that loses stability
        (to ``tol_s``). None: stable up to ``max_steps`` whole steps. ``whole_steps``: the
        result of :meth:`tolerated_extra_steps` if already known."""
        k = self.tolerated_extra_steps(channel, max_steps) if whole_steps == "compute" else whole_steps
        if k is None:
            return None
        if k < 0:
            return 0.0

        def extra(tau: float) -> np.ndarray:
            e = np.zeros(self.plant.n_act)
            if channel is None:
                e[:] = tau
            else:
                e[channel] = tau
            return e

        lo, hi = k * self.dt, (k + 1) * self.dt
        while hi - lo > tol_s:
            mid = 0.5 * (lo + hi)
            if np.max(np.abs(self.with_delay_s(extra(mid)).eigenvalues())) < 1.0:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def tolerated_extra_steps(self, channel: int | None = None, max_steps: int = 30) -> int | None:
        """The most whole extra steps of delay (in ``channel`` only, or in every channel at once
        for None) for which the closed-loop matrix stays stable, every count from 0 up to it
        stable; None: stable up to ``max_steps``; -1: the nominal loop is unstable."""
        for k in range(max_steps + 1):
            extra = np.zeros(self.plant.n_act, dtype=int)
            if channel is None:
                extra[:] = k
            else:
                extra[channel] = k
            if np.max(np.abs(self.with_extra_delay(extra).eigenvalues())) >= 1.0:
                return k - 1
        return None

    def broken_loop(self, k: int):
        """L_k: loop k broken at its command, the others closed (negative-feedback convention)."""
        import control

        p, c = self.plant, self.ctrl
        keep = np.eye(p.n_act)
        keep[k, k] = 0.0
        top = np.hstack([p.a + p.b @ keep @ c.d @ p.c, p.b @ keep @ c.c])
        bottom = np.hstack([c.b @ p.c, c.a])
        a = np.vstack([top, bottom])
        b = np.concatenate([p.b[:, k], np.zeros(c.n_states)])[:, None]
        out = -np.hstack([c.d[k] @ p.c, c.c[k]])[None, :]
        return control.ss(a, b, out, np.zeros((1, 1)), self.dt)

    def input_loop(self):
        """The MIMO loop broken at all commands (for the simultaneous disk margin)."""
        import control

        p, c = self.plant, self.ctrl
        a = np.block([[p.a, np.zeros((p.a.shape[0], c.n_states))], [c.b @ p.c, c.a]])
        b = np.vstack([p.b, np.zeros((c.n_states, p.n_act))])
        out = -np.hstack([c.d @ p.c, c.c])
        return control.ss(a, b, out, np.zeros((p.n_act, p.n_act)), self.dt)


def linear_loop(policy, env_config: dict, speed_kmh: float, model: BogieModel | None = None,
                conicity: float | None = None) -> LinearLoop:  # fmt: skip
    """Linearise ``policy`` in the loop at ``speed_kmh``: the nominal bogie of ``env_config``
    (with ``conicity`` as its ``lam`` if given; ``model`` overrides both), its actuators'
    lags and delays, its sensor filters if ``sensors.enabled``."""
    config = policy_config(env_config, policy)
    if model is None:
        model = plant_bogie(config, conicity)
    x_eq, force_eq, u_eq = operating_point(policy, config, speed_kmh, model)
    plant = plant_model(config, speed_kmh, force_eq=force_eq, x_eq=x_eq, model=model)
    y0 = observe(x_eq[None], force_eq[None], speed_kmh / KMH, config, model)[0]
    if np.any(np.abs(y0) >= T.OBS_BOUND):
        raise ConfigError(f"margins: the operating observation is clipped at +-{T.OBS_BOUND} ({y0}); no linear model")
    ctrl = controller_model(policy, y0.size, speed_kmh, y0)
    if ctrl.d.shape[0] != plant.n_act:
        raise ConfigError(f"margins: the policy commands {ctrl.d.shape[0]} channels, the env has {plant.n_act} active")
    policy.reset(1)
    return LinearLoop(plant, ctrl, speed_kmh, u_eq, y0)


# =============================================================================================
# Margins (python-control)
# =============================================================================================


def frequency_grid(dt: float, n: int = 1000) -> np.ndarray:
    """Log-spaced frequencies (rad/s) from 0.01 rad/s to just below the Nyquist frequency
    (1000 points: the margins agree with a 4000-point grid to 1e-7)."""
    return np.logspace(-2, np.log10(0.9999 * math.pi / dt), n)


def _none_if_inf(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def siso_margins(loop, omega: np.ndarray) -> dict[str, Any]:
    """Margins of one broken loop (a discrete SISO ``control`` system) with a stable closed loop."""
    import control

    frd = control.frd(loop, omega)
    gm, pm, _sm, w180, wc, _ws = control.stability_margins(frd, returnall=True)
    gm, pm, w180, wc = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (gm, pm, w180, wc))
    # the frequency response is real at z = 1 (DC) and z = -1 (Nyquist): a negative value there is a
    # phase crossover that the interpolated response cannot find
    a, b, c, d = (np.asarray(m) for m in (loop.A, loop.B, loop.C, loop.D))
    for z in (1.0, -1.0):
        try:
            value = float(np.real((c @ np.linalg.solve(z * np.eye(a.shape[0]) - a, b) + d)[0, 0]))
        except np.linalg.LinAlgError:
            continue
        if value < 0:
            gm = np.append(gm, 1.0 / -value)
    upper = gm[gm > 1.0]
    lower = gm[gm < 1.0]
    gain_upper = float(np.min(upper)) if upper.size else math.inf
    gain_lower = float(np.max(lower)) if lower.size else 0.0
    # delay margin: the extra phase lag that brings a gain crossover onto -1, over its frequency
    delays = np.array([np.deg2rad(np.remainder(p, 360.0)) / w if w > 0 else math.inf for p, w in zip(pm, wc)])
    k_delay = int(np.argmin(delays)) if delays.size else -1
    k_pm = int(np.argmin(np.abs(pm))) if pm.size else -1
    dm, dgm, dpm = control.disk_margins(loop, omega, skew=0.0)
    return {
        "gain_margin": _none_if_inf(gain_upper),
        "gain_margin_lower": gain_lower,
        "gain_margin_db": _none_if_inf(20 * math.log10(gain_upper)),
        "phase_margin_deg": None if k_pm < 0 else float(pm[k_pm]),
        "gain_crossover_hz": None if k_pm < 0 else float(wc[k_pm] / (2 * math.pi)),
        "delay_margin_s": None if k_delay < 0 else _none_if_inf(float(delays[k_delay])),
        "delay_margin_crossover_hz": None if k_delay < 0 else float(wc[k_delay] / (2 * math.pi)),
        "disk_margin": _none_if_inf(float(dm)),
        "disk_gain_margin_db": _none_if_inf(float(dgm)),
        "disk_phase_margin_deg": _none_if_inf(float(dpm)),
    }


#: Whole extra steps of delay checked by the closed-loop eigenvalues (0.3 s at dt = 10 ms).
MAX_EXTRA_DELAY_STEPS = 30
#: The speeds of the summary (issue 10's floors: 300-450 km/h).
SUMMARY_SPEEDS_KMH = (300.0, 450.0)


def loop_margins(loop: LinearLoop, omega: np.ndarray | None = None) -> dict[str, Any]:
    """Margins of every actuator loop and the simultaneous disk margin, at one speed.

    Per loop, beside python-control's margins: ``delay_margin_steps``, the most whole extra
    steps of delay in that loop alone for which the closed-loop matrix stays stable (None:
    stable up to :data:`MAX_EXTRA_DELAY_STEPS`); it agrees with ``delay_margin_s`` as
    ``floor(delay_margin_s / dt)`` (a whole-step delay ``z^-k`` is exactly the phase lag
    ``omega k dt`` of the sampled loop). ``delay_margin_sampled_s``: the extra delay at which the
    exact sampled model with a fractional delay (:meth:`PlantModel.with_delay_s`) loses
    stability, by its eigenvalues: between whole steps a delayed held command is not a pure
    phase lag, and this is the exact figure (same whole step as ``delay_margin_s``).
    ``all_loops_extra_delay_steps`` / ``all_loops_delay_margin_s``: the same with every channel
    delayed at once (a slower loop computer).
    """
    import control

    omega = frequency_grid(loop.dt) if omega is None else omega
    eig = loop.eigenvalues()
    radius = float(np.max(np.abs(eig)))
    stable = radius < 1.0
    names = loop.plant.channel_names
    delays_s = [d * loop.dt for d in loop.plant.delay_steps]
    out: dict[str, Any] = {
        "speed_kmh": loop.speed_kmh,
        "closed_loop_stable": bool(stable),
        "closed_loop_growth_rate_per_s": math.log(radius) / loop.dt,
        "existing_delay_s": max(delays_s) if delays_s else 0.0,
        "controller_model": loop.ctrl.method,
        "command_at_rest": [float(v) for v in loop.u_eq],
        "loops": {},
    }
    if not stable:
        out["loops"] = {name: None for name in names}
        out["simultaneous_disk_margin"] = None
        out["gain_margin"] = out["delay_margin_s"] = out["all_loops_extra_delay_steps"] = out["all_loops_delay_margin_s"] = None
        out["gain_margin_lower"] = None
        return out
    for k, name in enumerate(names):
        m = siso_margins(loop.broken_loop(k), omega)
        m["existing_delay_s"] = delays_s[k]
        m["delay_margin_steps"] = loop.tolerated_extra_steps(k, MAX_EXTRA_DELAY_STEPS)
        m["delay_margin_sampled_s"] = loop.delay_margin_by_eigenvalues(k, max_steps=MAX_EXTRA_DELAY_STEPS,
                                                                       whole_steps=m["delay_margin_steps"])  # fmt: skip
        out["loops"][name] = m
    out["all_loops_extra_delay_steps"] = loop.tolerated_extra_steps(None, MAX_EXTRA_DELAY_STEPS)
    out["all_loops_delay_margin_s"] = loop.delay_margin_by_eigenvalues(None, max_steps=MAX_EXTRA_DELAY_STEPS,
                                                                       whole_steps=out["all_loops_extra_delay_steps"])  # fmt: skip
    try:
        dm, dgm, dpm = control.disk_margins(loop.input_loop(), omega, skew=0.0)
        out["simultaneous_disk_margin"] = {"disk_margin": _none_if_inf(float(dm)), "disk_gain_margin_db": _none_if_inf(float(dgm)),
                                           "disk_phase_margin_deg": _none_if_inf(float(dpm))}  # fmt: skip
    except control.ControlMIMONotImplemented:  # python-control needs slycot for MIMO disk margins
        out["simultaneous_disk_margin"] = None
    gms = [v["gain_margin"] for v in out["loops"].values() if v["gain_margin"] is not None]
    dms = [v["delay_margin_s"] for v in out["loops"].values() if v["delay_margin_s"] is not None]
    out["gain_margin"] = min(gms) if gms else None  # worst loop; None: unbounded
    out["gain_margin_lower"] = max(v["gain_margin_lower"] for v in out["loops"].values())
    out["delay_margin_s"] = min(dms) if dms else None
    return out


def _worst(rows: list[dict[str, Any]], key: str, pick=min) -> Any:
    """The worst ``key`` over rows whose closed loop is stable (None entries: unbounded)."""
    values = [r[key] for r in rows if r[key] is not None]
    return pick(values) if values else None


def summarise(per_speed: list[dict[str, Any]], low_kmh: float, high_kmh: float) -> dict[str, Any]:
    """Worst margins over the rows with ``low_kmh <= speed <= high_kmh``; the margins are None
    (meaningless) when the closed loop is unstable at one of them."""
    rows = [r for r in per_speed if low_kmh <= r["speed_kmh"] <= high_kmh]
    unstable = [r["speed_kmh"] for r in rows if not r["closed_loop_stable"]]
    ok = bool(rows) and not unstable
    return {
        "speed_range_kmh": [low_kmh, high_kmh],
        "speeds_kmh": [r["speed_kmh"] for r in rows],
        "closed_loop_stable": ok,
        "unstable_at_kmh": unstable,
        "gain_margin": _worst(rows, "gain_margin") if ok else None,
        "gain_margin_lower": _worst(rows, "gain_margin_lower", max) if ok else None,
        "delay_margin_s": _worst(rows, "delay_margin_s") if ok else None,
        "all_loops_extra_delay_steps": _worst(rows, "all_loops_extra_delay_steps") if ok else None,
        "all_loops_delay_margin_s": _worst(rows, "all_loops_delay_margin_s") if ok else None,
    }


def margins_table(policy, env_config: dict, speeds_kmh=DEFAULT_SPEEDS_KMH, conicity: float | None = None) -> dict[str, Any]:
    """The ``margins`` entry: per speed and per loop, the worst case over the speeds, and the
    ``summary`` over 300-450 km/h.

    ``env_config``: a full env config (``make_config``; v0 or v1 variant); the plant is its
    nominal bogie, with ``conicity`` as ``lam`` if given, its actuators' lags and delays, and
    its sensor filters if ``sensors.enabled``; noise, bias and track irregularity are off, the
    force-rate limit is inactive (small signals). Worst case: the least gain and delay margins
    over speeds and loops; None when the nominal loop is unstable at some speed
    (``unstable_at_kmh`` lists where). ``delay_margin_s`` is the extra delay beyond the
    config's own (``existing_delay_s``).
    """
    config = policy_config(env_config, policy)
    model = plant_bogie(config, conicity)
    per_speed = [loop_margins(linear_loop(policy, env_config, float(v), model=model)) for v in speeds_kmh]
    unstable = [r["speed_kmh"] for r in per_speed if not r["closed_loop_stable"]]
    rows, _ = sensor_filters(config)
    active = force_channels(config)

    def worst(key, pick=min):
        return None if unstable else _worst(per_speed, key, pick)

    return {
        "speeds_kmh": [float(v) for v in speeds_kmh],
        "dt_s": config["dt"],
        "conicity": float(model.params.lam),
        "observation_type": config["observation"]["type"],
        "delay_steps": dict(zip([CHANNELS[k] for k in active], command_delay_steps(config, active))),
        "sensor_filters_hz": {SENSOR_NAMES[r]: config["sensors"][SENSOR_NAMES[r]]["bandwidth_hz"] for r in rows} or None,
        "model": ("discrete at the control rate: exact ZOH of bogie and actuator lag, command delay shift registers"
                  + (", the sensors' first-order anti-alias filters" if rows else "")
                  + "; no noise, bias, track irregularity or saturation; force-rate limit inactive (small signal)"),
        "gain_margin": worst("gain_margin"),
        "gain_margin_lower": worst("gain_margin_lower", max),
        "delay_margin_s": worst("delay_margin_s"),
        "all_loops_extra_delay_steps": worst("all_loops_extra_delay_steps"),
        "all_loops_delay_margin_s": worst("all_loops_delay_margin_s"),
        "unstable_at_kmh": unstable,
        "summary": summarise(per_speed, *SUMMARY_SPEEDS_KMH),
        "by_speed": per_speed,
    }


def _fmt(value: float | None, spec: str) -> str:
    return "inf" if value is None else format(value, spec)


def _ms(value: float | None) -> str:
    return f">{MAX_EXTRA_DELAY_STEPS}st" if value is None else format(value * 1e3, ".1f")


def _steps(value: int | None) -> str:
    return f">{MAX_EXTRA_DELAY_STEPS}" if value is None else str(value)


def format_table(table: dict[str, Any]) -> str:
    """A plain-text table: per speed and loop, gain margin (lower-upper), phase margin, delay
    margin (ms beyond the existing delay, and whole extra steps by eigenvalues), disk margin,
    crossover; then the worst case and the 300-450 km/h summary."""
    lines = [f"conicity {table['conicity']:g}, delay steps {table['delay_steps']}, sensor filters "
             f"{'none' if not table['sensor_filters_hz'] else sorted(set(table['sensor_filters_hz'].values()))} Hz",
             f"{'km/h':>6} {'loop':<14} {'GM':>14} {'PM deg':>8} {'fc Hz':>6} {'DM ms':>8} {'exact':>8} {'steps':>5} {'disk':>6}"]  # fmt: skip
    for row in table["by_speed"]:
        if not row["closed_loop_stable"]:
            lines.append(f"{row['speed_kmh']:>6g} {'(unstable: growth ' + format(row['closed_loop_growth_rate_per_s'], '.2f') + ' 1/s)':<40}")
            continue
        for name, m in row["loops"].items():
            gm = f"{m['gain_margin_lower']:.3g}-{_fmt(m['gain_margin'], '.3g')}"
            dm = None if m["delay_margin_s"] is None else m["delay_margin_s"] * 1e3
            lines.append(f"{row['speed_kmh']:>6g} {name:<14} {gm:>14} {_fmt(m['phase_margin_deg'], '.1f'):>8} "
                         f"{_fmt(m['gain_crossover_hz'], '.2f'):>6} {_fmt(dm, '.1f'):>8} {_ms(m['delay_margin_sampled_s']):>8} "
                         f"{_steps(m['delay_margin_steps']):>5} "
                         f"{_fmt(m['disk_margin'], '.2f'):>6}")  # fmt: skip
        sim = row["simultaneous_disk_margin"] or {"disk_margin": math.nan}  # NaN: slycot missing
        lines.append(f"{row['speed_kmh']:>6g} {'all loops':<14} {'':>14} {'':>8} {'':>6} {'':>8} {_ms(row['all_loops_delay_margin_s']):>8} "
                     f"{_steps(row['all_loops_extra_delay_steps']):>5} {_fmt(sim['disk_margin'], '.2f'):>6}")  # fmt: skip
    dm = table["delay_margin_s"]
    if table["unstable_at_kmh"]:
        lines.append(f"worst case: none (the nominal loop is unstable at {table['unstable_at_kmh']} km/h)")
    else:
        lines.append(f"worst case: gain margin {_fmt(table['gain_margin'], '.3g')}, delay margin "
                     f"{_fmt(None if dm is None else dm * 1e3, '.1f')} ms beyond the existing delay, "
                     f"all loops {_steps(table['all_loops_extra_delay_steps'])} extra steps ({_ms(table['all_loops_delay_margin_s'])} ms)")  # fmt: skip
    su = table["summary"]
    lo, hi = su["speed_range_kmh"]
    if not su["speeds_kmh"]:
        lines.append(f"summary {lo:g}-{hi:g} km/h: no speed in range")
    elif not su["closed_loop_stable"]:
        lines.append(f"summary {lo:g}-{hi:g} km/h: closed loop unstable at {su['unstable_at_kmh']} km/h")
    else:
        dm = su["delay_margin_s"]
        lines.append(f"summary {lo:g}-{hi:g} km/h: stable; gain margin {_fmt(su['gain_margin'], '.3g')} "
                     f"(lower {_fmt(su['gain_margin_lower'], '.3g')}), delay margin "
                     f"{_fmt(None if dm is None else dm * 1e3, '.1f')} ms, all loops "
                     f"{_steps(su['all_loops_extra_delay_steps'])} extra steps ({_ms(su['all_loops_delay_margin_s'])} ms)")  # fmt: skip
    return "\n".join(lines)
