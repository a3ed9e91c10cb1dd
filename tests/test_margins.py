"""Stability margins (bogie_agents.margins) against independent oracles.

- the linear sampled plant against one interval of the compiled nonlinear simulator (signs of the
  force map, the lag, the delay);
- the sensor map against the env's own observation;
- each controller's linear model against the controller's ``act`` on a small sequence;
  the policy Jacobian by autograd against finite differences;
- python-control's gain margins against closed-loop eigenvalues;
- the linear growth rate and the margins against nonlinear time simulation: a loop scaled to
  0.9 / 1.1 of its gain margin, or delayed by 0.9 / 1.1 of its delay margin, must decay / grow.
"""

import json
import math

import numpy as np
import pytest

pytest.importorskip("control")

from bogie_agents import margins as M
from bogie_agents.cli import main as cli_main
from bogie_agents.controllers import LQGController, LQRController, PassiveController, SkyhookController
from bogie_env.actuators import channel_table
from bogie_env.dynamics import BogieModel, N_STATES
from bogie_env.envs.config import bogie_params, make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.simulator import BatchSimulator

SPEED_KMH = 450.0  # above the passive critical speed (356 km/h): the plant alone is unstable


@pytest.fixture(scope="module")
def env_config():
    return make_config(track={"rms": 0.0})


@pytest.fixture(scope="module")
def model(env_config):
    return BogieModel(bogie_params(env_config))


@pytest.fixture(scope="module")
def lqr(env_config):
    return LQRController(env_config, v_range_kmh=(400.0, 500.0))


@pytest.fixture(scope="module")
def lqr_loop(lqr, env_config, model):
    return M.linear_loop(lqr, env_config, SPEED_KMH, model=model)


@pytest.fixture(scope="module")
def lqr_margins(lqr_loop):
    return M.loop_margins(lqr_loop)


@pytest.mark.parametrize("observation_type", ["sensors", "state"])
def test_observation_matches_the_env(env_config, model, observation_type):
    config = make_config(env_config, observation={"type": observation_type})
    task = HuntingTask(3, config)
    rng = np.random.default_rng(1)
    x = model.equilibrium(SPEED_KMH / 3.6) + rng.normal(0, 1e-3, (3, N_STATES))
    forces = rng.uniform(-5e3, 5e3, (3, 4))
    task.reset_rows(np.arange(3), {"start_kmh": SPEED_KMH, "end_kmh": SPEED_KMH, "accel": 0.0})
    task.sim.x[:] = x
    task.sim.output[:, 0, :] = forces
    expected = task.observe()
    ours = M.observe(x, forces, SPEED_KMH / 3.6, config, model)
    np.testing.assert_allclose(ours, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("delay_steps", [0, 2])
def test_plant_model_predicts_the_nonlinear_interval(env_config, model, delay_steps):
    """A small command, held over the intervals, moves the nonlinear bogie as the linear model says."""
    actuators = {name: {"delay_steps": delay_steps} for name in ("frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw")}
    config = make_config(env_config, actuators=actuators)
    plant = M.plant_model(config, SPEED_KMH, model=model)
    u = np.array([1e-3, -2e-3, 1.5e-3, 0.5e-3])  # normalised commands
    table = channel_table(config["actuators"])
    sim = BatchSimulator(model, 1, dt=config["dt"], speed_range=(SPEED_KMH / 3.6,) * 2, channels=table, n_sub=40)
    sim.set_rows(slice(None), plant.x_eq, SPEED_KMH / 3.6)
    s = np.zeros(plant.a.shape[0])
    for step in range(delay_steps + 3):
        sim.step(force_target=(u * plant.max_force)[None])
        s = plant.a @ s + plant.b @ u
        y_nonlinear = M.observe(sim.x, sim.channel_output, SPEED_KMH / 3.6, config, model)[0]
        y_linear = plant.c @ s
        scale = max(np.max(np.abs(y_linear)), 1e-12)
        assert np.max(np.abs((y_nonlinear - M.observe(plant.x_eq, np.zeros(4), SPEED_KMH / 3.6, config, model)[0])
                             - y_linear)) <= 1e-3 * scale + 1e-12, step  # fmt: skip
        if step < delay_steps:
            assert np.max(np.abs(y_linear)) == 0.0  # nothing arrives before the delay
    assert np.max(np.abs(y_linear)) > 0.0


def _controllers(env_config):
    return [SkyhookController(env_config), LQRController(env_config, v_range_kmh=(400.0, 500.0)),
            LQGController(env_config, v_range_kmh=(400.0, 500.0))]  # fmt: skip


def test_controller_models_match_act(env_config, model):
    for policy in _controllers(env_config):
        loop = M.linear_loop(policy, env_config, SPEED_KMH, model=model)
        config = M.policy_config(env_config, policy)
        y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, config, model)[0]
        error = M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3)
        assert error < 1e-3, (policy.name, error)  # float32 rounding of act()


def test_controller_model_check_can_fail(env_config, model):
    """Not vacuous: a controller model with a wrong gain is caught."""
    policy = LQGController(env_config, v_range_kmh=(400.0, 500.0))
    loop = M.linear_loop(policy, env_config, SPEED_KMH, model=model)
    config = M.policy_config(env_config, policy)
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, config, model)[0]
    wrong = M.ControllerModel(loop.ctrl.a, loop.ctrl.b, loop.ctrl.c, loop.ctrl.d * 1.1, "wrong")
    assert M.check_controller_model(policy, wrong, y0, loop.u_eq) > 1e-2


def test_gain_margins_match_closed_loop_eigenvalues(lqr_loop, lqr_margins):
    assert lqr_margins["closed_loop_stable"]
    found = 0
    for k, name in enumerate(lqr_loop.plant.channel_names):
        gm = lqr_margins["loops"][name]["gain_margin"]
        gains = np.ones(lqr_loop.plant.n_act)
        if gm is None:  # unbounded: large gains stay stable
            gains[k] = 1e3
            assert lqr_loop.growth_rate(gains) < 0, name
            continue
        found += 1
        gains[k] = 0.99 * gm
        assert lqr_loop.growth_rate(gains) < 0, name
        gains[k] = 1.01 * gm
        assert lqr_loop.growth_rate(gains) > 0, name
    assert found >= 1


def test_passive_growth_rate_matches_simulation(env_config, model):
    """The linear loop's leading eigenvalue is the nonlinear bogie's growth rate at small amplitude."""
    passive = PassiveController(env_config)
    loop = M.linear_loop(passive, env_config, SPEED_KMH, model=model)
    predicted = loop.growth_rate()
    assert predicted > 1.0  # the passive bogie hunts at 450 km/h
    x0 = loop.plant.x_eq.copy()
    x0[0] += 1e-9
    out = M.simulate_loop(passive, env_config, SPEED_KMH, x0, loop.plant.force_eq, loop.u_eq, 4.0, substeps=2, model=model)
    measured = M.envelope_growth_rate(out["t"], M.deviation(out["x"], loop.plant.x_eq)[:, 0], skip_s=1.0)
    assert np.isfinite(measured)
    assert measured == pytest.approx(predicted, rel=0.05)


def _verdicts(policy, env_config, model, loop, margins, duration_s=6.0):
    """Growth rates in the nonlinear simulation at 0.9 / 1.1 of the worst loop's gain and delay margins."""
    loops = list(margins["loops"].values())
    k_gain = int(np.argmin([m["gain_margin"] or math.inf for m in loops]))
    k_delay = int(np.argmin([m["delay_margin_s"] or math.inf for m in loops]))
    gm, dm = loops[k_gain]["gain_margin"], loops[k_delay]["delay_margin_s"]
    n_act = loop.plant.n_act
    gains = np.ones((5, n_act))
    gains[1, k_gain], gains[2, k_gain] = 0.9 * gm, 1.1 * gm
    delays = np.zeros((5, n_act))
    delays[3, k_delay], delays[4, k_delay] = 0.9 * dm, 1.1 * dm
    x0 = np.repeat(loop.plant.x_eq[None], 5, axis=0)
    x0[:, 0] += 1e-8  # room for four decades of growth before the actuators saturate
    x0[:, 8] -= 1e-8
    out = M.simulate_loop(policy, env_config, SPEED_KMH, x0, loop.plant.force_eq, loop.u_eq, duration_s,
                          gains=gains, extra_delay_s=delays, substeps=10, model=model)  # fmt: skip
    dev = M.deviation(out["x"], loop.plant.x_eq)
    rates = np.array([M.envelope_growth_rate(out["t"], dev[:, r], floor=1e-9, skip_s=1.0) for r in range(5)])
    return rates, dev[0], np.nan_to_num(dev[-1], nan=np.inf), np.nan_to_num(np.max(dev, axis=0), nan=np.inf)


def _assert_verdicts(verdicts):
    """Rows: nominal, 0.9 x gain margin, 1.1 x gain margin, 0.9 x delay margin, 1.1 x delay margin.
    A row decays (grows) when its envelope's growth rate is below -0.1 (above 0.1) 1/s or, when it
    leaves the linear range too fast to fit, when it ends 100 x smaller (larger)."""
    rates, first, last, _peak = verdicts
    decays = (rates < -0.1) | (np.isnan(rates) & (last < 1e-2 * first))
    grows = (rates > 0.1) | (np.isnan(rates) & (last > 1e2 * first))
    assert decays[0] and decays[1] and decays[3], verdicts
    assert grows[2] and grows[4], verdicts


def test_lqr_margins_hold_in_nonlinear_simulation(lqr, env_config, model, lqr_loop, lqr_margins):
    _assert_verdicts(_verdicts(lqr, env_config, model, lqr_loop, lqr_margins))


@pytest.mark.slow
def test_pretrained_margins_hold_in_nonlinear_simulation(env_config, model):
    from bogie_agents.policies import load_policy

    policy = load_policy("pretrained", env_config)
    loop = M.linear_loop(policy, env_config, SPEED_KMH, model=model)
    margins = M.loop_margins(loop)
    assert margins["closed_loop_stable"]
    _assert_verdicts(_verdicts(policy, env_config, model, loop, margins, duration_s=6.0))


def test_policy_jacobian_autograd_matches_finite_differences(env_config, model):
    from bogie_agents.policies import load_policy

    policy = load_policy("pretrained", env_config)
    config = M.policy_config(env_config, policy)
    x, force, u = M.operating_point(policy, config, SPEED_KMH, model)
    assert np.max(np.abs(force)) > 0  # the learned policy commands a bias at rest
    y0 = M.observe(x[None], force[None], SPEED_KMH / 3.6, config, model)[0]
    autograd = M.sb3_jacobian_autograd(policy, y0)
    fd = M.finite_difference_jacobian(policy, y0, step=1e-4)
    np.testing.assert_allclose(fd, autograd, rtol=0.02, atol=0.02 * np.max(np.abs(autograd)))
    # the equilibrium is one: the float64 action there is the force that holds it
    assert np.allclose(M.sb3_action(policy, y0), u)


def test_unstable_nominal_loop_reports_no_margins(env_config, model):
    table = M.margins_table(PassiveController(env_config), env_config, speeds_kmh=(300.0, 450.0))
    assert table["unstable_at_kmh"] == [450.0]
    assert table["gain_margin"] is None and table["delay_margin_s"] is None
    assert table["by_speed"][0]["closed_loop_stable"]
    assert table["by_speed"][0]["loops"]["frame_yaw"]["gain_margin"] is None  # zero loop gain: unbounded


def test_semi_active_channels_are_refused(env_config):
    from bogie_env.params import ConfigError

    config = make_config(env_config, variant=None, actuators={"frame_yaw": {"mode": "semi_active"}})
    with pytest.raises(ConfigError, match="frame_yaw.mode"):
        M.plant_model(config, SPEED_KMH)


def test_cli_margins_json(capsys, tmp_path):
    out = tmp_path / "m.json"
    code = cli_main(["margins", "--policy", "lqr", "--speeds", "450", "--json", "--out", str(out)])
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    entry = payload["policies"][0]
    assert entry["policy"] == "lqr"
    margins = entry["margins"]
    assert set(margins) >= {"gain_margin", "delay_margin_s", "by_speed", "speeds_kmh"}
    loops = margins["by_speed"][0]["loops"]
    assert set(loops) == {"frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw"}
    assert margins["gain_margin"] == min(v["gain_margin"] for v in loops.values() if v["gain_margin"] is not None)
    assert json.loads(out.read_text()) == payload


def test_evaluate_can_report_margins(capsys):
    code = cli_main(["evaluate", "--policy", "passive", "--parts", "margins", "--json"])
    assert code == 0
    entry = json.loads(capsys.readouterr().out)["policies"][0]
    assert entry["policy"] == "passive"
    assert entry["margins"]["unstable_at_kmh"] == [400.0, 450.0, 500.0]  # passive hunts above 356 km/h
    assert entry["margins"]["gain_margin"] is None


def test_passive_loop_loses_stability_at_the_linear_critical_speed(env_config, model):
    """The sampled loop's eigenvalues (exact ZOH, actuator lags) against bogie_env.stability's
    continuous eigenvalue search: the same crossing."""
    from bogie_env.stability import critical_speed

    v_cr = critical_speed(model).speed_kmh
    passive = PassiveController(env_config)
    assert M.linear_loop(passive, env_config, v_cr - 0.2, model=model).growth_rate() < 0
    assert M.linear_loop(passive, env_config, v_cr + 0.2, model=model).growth_rate() > 0


@pytest.mark.parametrize("speeds", ["", "abc", "nan", "1e9", "300,-5"])
def test_cli_margins_bad_speeds_are_named(capsys, speeds):
    assert cli_main(["margins", "--policy", "passive", "--speeds", speeds]) == 2
    assert "--speeds" in capsys.readouterr().err
