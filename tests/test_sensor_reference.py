"""The privileged references seeing only the sensors (privileged_sensors, privileged_mpc_sensors):
their Kalman filter, designed on the told scenario, recovers the simulator's lateral states."""

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
    controller = SensorPrivilegedController(policy_config(task.config, "sensors")).tell(told_scenario, task.config)
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


def test_it_sees_the_sensors_and_has_no_margins_model():
    controller = SensorPrivilegedController(policy_config(make_config(variant="v1"), "sensors"))
    assert controller.observation_type == "sensors" and controller.privileged
    with pytest.raises(NotImplementedError, match="privileged_sensors"):
        controller.controller_model(8, 300.0, np.zeros(8))
