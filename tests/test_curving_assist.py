"""The curving assist (``bogie_agents.controllers.curving_assist``) against the classic steady-curving result
and on straight track with sensor biases.

Oracle: a wheelset whose primary yaw springs' moment at the radial position, ``k_psi L1 kappa``
(``k_psi = 2 Kpx b1^2``), is cancelled runs radially and rolls purely: angle of attack zero and
lateral offset ``-e r0 kappa / lambda`` at balanced cant (docs/model.md, C5). The assist reads
the curve from the v1 sensors only; the time simulation in the route world (sensor filters,
loop delay, actuator lag and rate limits) must end there. Planted bugs that fail it: the
wheelset torques with the wrong sign (AoA grows), the estimate without the assist's own
deflection (half the torque: the wheelsets stop halfway), a wrong yaw stiffness (b2 for b1).
"""

import copy

import numpy as np
import pytest

from bogie_agents.controllers.curving_assist import CurvingAssist, SteeringController
from bogie_agents.evaluation.curving_evaluation import constant_curve_run
from bogie_agents.controllers.policies import load_policy
from bogie_agents.controllers.robust import RobustDampingController
from bogie_env.dynamics import state_index
from bogie_env.envs.config import bogie_params, make_config
from bogie_env.envs.task import SENSOR_WHEELSET1_YAW, SENSOR_WHEELSET2_YAW, SENSORS, HuntingTask
from bogie_env.params import ConfigError
from bogie_env.route import equilibrium_cant_m

NO_SENSOR_ERRORS = {name: {"noise_density": 0.0, "bias": 0.0} for name in (
    "frame_lateral_accel", "frame_yaw_rate", "wheelset1_lateral_rel", "wheelset2_lateral_rel", "wheelset1_yaw_rel",
    "wheelset2_yaw_rel", "speed")}  # fmt: skip


def curve_run(policy_factory, radius_m: float, cant_m: float, speed_kmh: float, curve_m: float, sensors: dict | None = None,
              direction: str = "left", extra: dict | None = None):  # fmt: skip
    """One row on a perfect track: 50 m tangent, 100 m transition, then ``curve_m`` of a curve
    (``direction``); ``extra``: more config; returns the task at the end of the curve and the policy."""
    update = {} if sensors is None else {"sensors": sensors}
    update.update(extra or {})
    task, policy, _ = constant_curve_run(radius_m, cant_m, speed_kmh, curve_m, direction, transition_m=100.0, update=update,
                                         policy_factory=policy_factory)  # fmt: skip
    return task, policy


def wheelsets(task) -> tuple[np.ndarray, np.ndarray]:
    x = task.states[0]
    return (np.array([x[state_index("y1")], x[state_index("y2")]]), np.array([x[state_index("psi1")], x[state_index("psi2")]]))


@pytest.mark.slow  # 12-15 s: make test stays within 3 minutes from a clean clone
def test_assist_steers_the_wheelsets_radially_at_balanced_cant():
    """R 20 km at 250 km/h, balanced cant, deadband 0, torque not limited: the closed loop ends
    with the wheelsets radial (AoA <= 5 % of passive's) at the pure-rolling offset (2 %), and the
    torque is the formula's ``k_psi L1 kappa`` (2 %). Passive: AoA -89/+60 urad, offsets ~3 mm."""
    radius, speed = 20000.0, 250.0
    cant = equilibrium_cant_m(speed, radius)
    passive, _ = curve_run(lambda c: load_policy("passive", c), radius, cant, speed, 800.0, NO_SENSOR_ERRORS)
    steered, assist = curve_run(lambda c: CurvingAssist(c, deadband_1pm=0.0, fraction=1.0), radius, cant, speed, 800.0,
                                NO_SENSOR_ERRORS)  # fmt: skip
    p = bogie_params(steered.config)
    kappa = 1.0 / radius
    y0, aoa0 = wheelsets(passive)
    y, aoa = wheelsets(steered)
    assert np.max(np.abs(aoa0)) > 5e-5  # passive: the yaw-stiff bogie's angles of attack
    assert np.max(np.abs(aoa)) < 0.05 * np.max(np.abs(aoa0))
    np.testing.assert_allclose(y, -p.e * p.r0 * kappa / p.lam, rtol=0.02)
    torque = 2 * p.Kpx * p.b1**2 * p.L1 * kappa
    forces = dict(zip(["frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw"], steered.actuator_force[0]))
    assert forces["wheelset1_yaw"] == pytest.approx(torque, rel=0.02)
    assert forces["wheelset2_yaw"] == pytest.approx(-torque, rel=0.02)
    assert assist.curvature_estimate[0] == pytest.approx(kappa, rel=0.02)


def test_limited_torque_on_the_s_curves_curve_moves_the_wheelsets_towards_radial():
    """The S-curve's steady curve (R 3000 m, 160 mm, 250 km/h: on the flange), sensor biases of
    seed 0: the assist at its limit (0.8 x 15 kN m) lowers the leading wheelset's |AoA|."""
    passive, _ = curve_run(lambda c: load_policy("passive", c), 3000.0, 0.16, 250.0, 500.0)
    steered, _ = curve_run(lambda c: CurvingAssist(c), 3000.0, 0.16, 250.0, 500.0)
    _, aoa0 = wheelsets(passive)
    _, aoa = wheelsets(steered)
    assert abs(aoa[0]) < 0.85 * abs(aoa0[0])
    assert steered.actuator_force[0][2] == pytest.approx(0.8 * 15e3, rel=0.03)


@pytest.mark.parametrize("seed", range(4))
def test_zero_command_on_straight_track_with_sensor_biases(seed):
    """The v1 world (per-episode sensor biases and noise, alert-level track, random start) on
    straight track at 300 km/h: the curvature estimate stays inside the deadband, the assist's
    command is exactly zero at every step."""
    config = make_config({"randomize": {}}, variant="v1")
    task = HuntingTask(1, config)
    task.seed_rows(np.array([0]), [seed])
    task.reset_rows(np.array([0]))
    assist = CurvingAssist(config)
    assist.reset(1)
    base = RobustDampingController(config)
    base.reset(1)
    for _ in range(300):
        obs = task.obs
        assert not np.any(assist.command(obs))
        task.step(base.act(obs))
    assert abs(assist.curvature_estimate[0]) < 0.5 * assist.deadband


def test_registered_and_small_signal_model_is_the_base():
    config = make_config({}, variant="v1")
    policy = load_policy("robust_steering", config)
    assert isinstance(policy, SteeringController)
    base = RobustDampingController(config)
    a = policy.controller_model(base.n_obs, 300.0, None)
    b = base.controller_model(base.n_obs, 300.0, None)
    for name in ("a", "b", "c", "d"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_bad_settings_are_named():
    config = make_config({}, variant="v1")
    with pytest.raises(ConfigError, match="fraction"):
        CurvingAssist(config, fraction=1.5)
    with pytest.raises(ConfigError, match="lowpass_hz"):
        CurvingAssist(config, lowpass_hz=0.0)


def test_a_right_curve_gives_the_mirrored_command():
    """Left/right symmetry: the S-curve's curve to the right, no sensor errors, gives the left
    curve's assist command with the opposite sign, to rounding (a one-sided deadband fails it)."""
    commands = {}
    for direction in ("left", "right"):
        task, assist = curve_run(lambda c: CurvingAssist(c), 3000.0, 0.16, 250.0, 300.0, NO_SENSOR_ERRORS, direction)
        commands[direction] = assist.command(task.obs)[0]
    assert np.max(np.abs(commands["left"])) > 0.5
    np.testing.assert_allclose(commands["right"], -commands["left"], atol=1e-9)


def test_reset_of_some_rows_clears_only_their_filters():
    """Vector envs reset finished rows only: those rows' estimates restart from zero, the others
    keep theirs (a reset that ignores ``rows`` fails it)."""
    config = make_config({}, variant="v1")
    assist = CurvingAssist(config)
    assist.reset(3)
    obs = np.zeros((3, len(SENSORS) + 1 + assist.max_force.size), dtype=np.float32)
    obs[:, SENSOR_WHEELSET1_YAW], obs[:, SENSOR_WHEELSET2_YAW] = -0.1, 0.1  # r1 - r2 = -1 mrad: kappa 3.3e-4 1/m to the left
    for _ in range(500):
        assist.command(obs)
    before = assist.curvature_estimate
    assert before[0] == pytest.approx(1e-3 / (2 * bogie_params(config).L1), rel=0.05)
    assist.reset(3, np.array([1]))
    after = assist.curvature_estimate
    assert after[1] == 0.0 and assist.torque[1] == 0.0
    np.testing.assert_array_equal(after[[0, 2]], before[[0, 2]])


@pytest.mark.parametrize("failed", [None, "wheelset2_yaw"])
def test_estimate_without_observed_forces_uses_the_commanded_torques(failed):
    """Forces not observed: the estimate removes the assist's own commanded torques, the wheelset
    channels' difference. R 10 km (the torque within its limit), no sensor errors: the same steady
    estimate as with the forces observed, 2 %; with ``wheelset2_yaw`` off only wheelset 1's torque
    deflects the springs (2 x one channel's torque, or ignoring it, fails it)."""
    actuators = copy.deepcopy(make_config({}, variant="v1")["actuators"])
    if failed is not None:
        actuators[failed]["mode"] = "off"
    update = {"observation": {"type": "sensors", "noise": 0.0, "include_actuators": False}, "actuators": actuators}
    task, assist = curve_run(lambda c: CurvingAssist(c), 10000.0, 0.0, 200.0, 500.0, {**NO_SENSOR_ERRORS}, extra=update)
    torque = dict(zip(["frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw"], task.actuator_force[0]))
    assert torque["wheelset1_yaw"] > 1e3
    assert assist.curvature_estimate[0] == pytest.approx(1e-4, rel=0.02)


def test_semi_active_channels_are_not_commanded():
    """A semi-active channel's action is a damper's coefficient, not a torque: the assist leaves
    it at zero (a steady offset would unbalance the dampers in every curve)."""
    config = make_config({}, variant="v1_semi_active")
    assist = CurvingAssist(config)
    assist.reset(1)
    obs = np.zeros((1, len(SENSORS) + 1 + assist.max_force.size), dtype=np.float32)
    obs[:, SENSOR_WHEELSET1_YAW], obs[:, SENSOR_WHEELSET2_YAW] = -0.2, 0.2
    for _ in range(300):
        u = assist.command(obs)
    assert assist.curvature_estimate[0] > 1e-4
    assert not np.any(u)
