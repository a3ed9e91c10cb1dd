"""The references told the true scenario but seeing only the sensors (privileged_sensors,
privileged_mpc_sensors) and the MPC told the conicity class (mpc): their Kalman filter recovers
the simulator's lateral states, and their margins model is what they do."""

from __future__ import annotations

import numpy as np
import pytest

from bogie_agents.controllers.lqr import LAT, N_LAT
from bogie_agents.controllers.privileged import SensorPrivilegedController
from bogie_agents.evaluation.stability_protocol import policy_config
from bogie_env.envs.config import make_config, merge_config
from bogie_env.envs.task import HuntingTask

#: the v1 loop (filters, delay, lag, limits) with noise-free, bias-free sensors on a perfect track:
#: nothing the filter cannot know, so its estimate must converge to the simulator's states
CLEAN = {"track": {"level": None, "rms": 0.0}, "observation": {"noise": 0.0},
         "sensors": {"noise_scale": 0.0, "bias_scale": 0.0}}  # fmt: skip
SPEED_KMH = 60.0  # below passive's critical speed at conicity 0.3: the commands alone move the bogie


def _task(options: dict) -> HuntingTask:
    cfg = make_config(merge_config(make_config(variant="v1"), {
        **CLEAN, "randomize": {}, "large_perturbation_probability": 0.0,
        "speed": {"start_kmh": SPEED_KMH, "end_kmh": SPEED_KMH, "accel": 0.0, "start_kmh_range": None,
                  "end_kmh_range": None, "accel_range": None}}))  # fmt: skip
    task = HuntingTask(2, cfg)
    task.seed_rows(np.arange(2), [0, 1])
    task.reset_rows(np.arange(2), options)
    return task


def estimate_error(options: dict, filter_options: dict | None = None) -> float:
    """RMS of (estimate - true lateral states) over RMS of the states (per state), steps 150-300
    of a run driven by random commands (the filter told them), the filter designed on
    ``filter_options`` (default: the true scenario)."""
    task = _task(options)
    told_scenario = task.scenarios[0] if filter_options is None else _task(filter_options).scenarios[0]
    design = SensorPrivilegedController(policy_config(task.config, "sensors"), step_kmh=10.0, v_range_kmh=(50.0, 70.0))
    controller = design.tell(told_scenario, task.config)
    controller.reset(2)
    commands = np.random.default_rng(0).uniform(-0.5, 0.5, (300, 2, controller.n_act))
    errors, states = [], []
    for k in range(300):
        estimate = controller.state_estimate(task.obs)  # the states of this observation, before the step
        if k >= 150:
            errors.append(estimate - task.states[:, LAT])
            states.append(task.states[:, LAT])
        controller.advance(commands[k])
        task.step(commands[k].astype(np.float32))
    e, x = np.concatenate(errors), np.concatenate(states)
    return float(np.sqrt(np.mean(e**2 / np.mean(x**2, axis=0))))


def test_the_filter_recovers_the_states_it_is_told_about():
    """With nothing unknown (no noise, bias or track input), the estimate from the six sensors
    converges to the simulator's 16 lateral states: an independent check of the filter's
    model (sensor rows, filters, command registers and lags, the told conicity)."""
    assert estimate_error({"conicity": 0.3}) < 0.06
    assert estimate_error({"conicity": 0.3}, {"conicity": 0.1}) > 0.3  # told the wrong conicity


def test_the_filter_knows_a_failed_channel():
    """Told a failed frame-yaw actuator, the filter's error is half of what it is when it
    assumes the channel works (its commands then move nothing it predicts)."""
    faulty = {"conicity": 0.1, "failed_actuator": "frame_yaw"}
    assert estimate_error(faulty) < 0.5 * estimate_error(faulty, {"conicity": 0.1, "failed_actuator": "none"})


@pytest.mark.parametrize("name", ["privileged_sensors", "mpc"])
def test_the_margins_model_is_what_it_does(name):
    """The margins' linear model (filter, last command, replicated lag and registers, the LQR
    gains) is what ``act`` does about the operating point (``mpc`` without active constraints,
    where its first command is its LQR's); a wrong model fails the same check."""
    if name == "mpc":
        pytest.importorskip("osqp")
    from bogie_agents.controllers.policies import load_policy
    from bogie_agents.design import margins as M

    v1 = make_config(variant="v1")
    policy = load_policy(name, policy_config(v1, "sensors", 0.1))
    loop = M.linear_loop(policy, v1, 200.0)
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, 200.0 / 3.6, M.policy_config(v1, policy), loop.plant.model)[0]
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3) < 5e-3  # float32 act, OSQP tolerance
    wrong = M.ControllerModel(loop.ctrl.a, loop.ctrl.b, loop.ctrl.c, loop.ctrl.d * 1.1, "wrong")
    assert M.check_controller_model(policy, wrong, y0, loop.u_eq, amplitude=1e-3) > 2e-2


def test_mpc_is_told_the_class_only_and_acts_on_the_sensors():
    """``mpc`` is a baseline: the protocol builds it for the told conicity class (no scenario),
    and it commands a task's rows from the sensors within the force limit."""
    pytest.importorskip("osqp")
    from bogie_agents.controllers.mpc import SensorMPC
    from bogie_agents.evaluation import stability_protocol as sp

    v1 = make_config(variant="v1")
    settings = sp.screening_settings(columns=("conicity:0.3",), progress=False)
    ctx = sp.PartContext(sp.factory_for("mpc"), v1, settings, "sensors", sp.Progress("p", False))
    cases = [c for col in sp.columns(v1, settings).values() for c in col]
    task, groups = sp.Runner(ctx)._task(cases, np.full(len(cases), 150.0), "default")
    (rows, controller), = groups.groups
    assert isinstance(controller, SensorMPC) and not controller.privileged and controller.observation_type == "sensors"
    assert controller.model.params.lam == pytest.approx(0.3) and controller.r == 10.0
    controller.reset(len(rows))
    actions = controller.act(task.obs[rows])
    assert actions.shape == (len(rows), controller.n_act) and np.all(np.abs(actions) <= 1.0)
