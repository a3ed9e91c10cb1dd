"""Stability margins (bogie_agents.design.margins) against independent oracles.

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

from bogie_agents.design import margin_oracles as O
from bogie_agents.design import margins as M
from bogie_agents.cli import main as cli_main
from bogie_agents.controllers.lqr import LQGController, LQRController, PassiveController, SkyhookController
from bogie_env.actuators import channel_table
from bogie_env.dynamics import BogieModel, N_STATES
from bogie_env.envs.config import bogie_params, make_config
from bogie_env.envs.task import SENSORS, HuntingTask
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
def pretrained_v0():
    """The shipped v0 PPO (v1 keeps v0's spaces), loaded once for the module."""
    from bogie_agents.controllers.policies import load_policy

    return load_policy("pretrained", make_config())


@pytest.fixture(scope="module")
def lqg(env_config):
    return LQGController(env_config, v_range_kmh=(400.0, 500.0))


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


def test_controller_models_match_act(env_config, model, lqr, lqg):
    for policy in (SkyhookController(env_config), lqr, lqg):
        loop = M.linear_loop(policy, env_config, SPEED_KMH, model=model)
        config = M.policy_config(env_config, policy)
        y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, config, model)[0]
        error = M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3)
        assert error < 1e-3, (policy.name, error)  # float32 rounding of act()


def test_controller_model_check_can_fail(env_config, model, lqg):
    """Not vacuous: a controller model with a wrong gain is caught."""
    policy = lqg
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
    out = O.simulate_loop(passive, env_config, SPEED_KMH, x0, loop.plant.force_eq, loop.u_eq, 4.0, substeps=2, model=model)
    measured = O.envelope_growth_rate(out["t"], O.deviation(out["x"], loop.plant.x_eq)[:, 0], skip_s=1.0)
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
    out = O.simulate_loop(policy, env_config, SPEED_KMH, x0, loop.plant.force_eq, loop.u_eq, duration_s,
                          gains=gains, extra_delay_s=delays, substeps=10, model=model)  # fmt: skip
    dev = O.deviation(out["x"], loop.plant.x_eq)
    rates = np.array([O.envelope_growth_rate(out["t"], dev[:, r], floor=1e-9, skip_s=1.0) for r in range(5)])
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
    from bogie_agents.controllers.policies import load_policy

    policy = load_policy("pretrained", env_config)
    loop = M.linear_loop(policy, env_config, SPEED_KMH, model=model)
    margins = M.loop_margins(loop)
    assert margins["closed_loop_stable"]
    _assert_verdicts(_verdicts(policy, env_config, model, loop, margins, duration_s=6.0))


def test_policy_jacobian_autograd_matches_finite_differences(env_config, model, pretrained_v0):
    policy = pretrained_v0
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
    code = cli_main(["evaluate", "--env", "Bogie/Hunting-v0", "--policy", "passive", "--parts", "margins", "--json"])
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


# ---- Bogie/Hunting-v1: sensor filters, loop delay, conicity ------------------------------------


@pytest.fixture(scope="module")
def v1_config():
    return make_config(variant="v1")


@pytest.fixture(scope="module")
def v1_lqg(v1_config):
    """The LQG designed without the sensor model on the v1 plant: its loops are near their
    limits (a 34-39 ms frame-lateral delay margin), which makes the delay oracles below
    discriminating; the shipped v1 design is checked in test_v1_sensor_model_lqg_*."""
    return LQGController(v1_config, sensor_model=False, v_range_kmh=(400.0, 500.0))


@pytest.fixture(scope="module")
def v1_sensor_lqg(v1_config):
    return LQGController(v1_config, v_range_kmh=(400.0, 500.0))


@pytest.fixture(scope="module")
def v1_lqg_loop(v1_lqg, v1_config):
    return M.linear_loop(v1_lqg, v1_config, SPEED_KMH)


@pytest.fixture(scope="module")
def v1_lqg_margins(v1_lqg_loop):
    return M.loop_margins(v1_lqg_loop)


def test_v1_plant_matches_the_env_observation_response(v1_config):
    """The v1 linear plant (anti-alias filters, one step of delay, lags) against the env's own
    observations (HuntingTask, noise and bias off, perfect track, RK4 at 0.25 ms) after a small
    random start offset and small random actions."""
    from bogie_env.envs.task import HuntingTask

    passive = PassiveController(v1_config)
    config = O.quiet_env_config(v1_config, passive, SPEED_KMH, initial_perturbation_m=1e-7, n_sub=40)
    task = HuntingTask(1, config)
    task.seed_rows(np.array([0]), [3])
    task.reset_rows(np.array([0]))
    plant = M.plant_model(config, SPEED_KMH, model=task.model)
    assert plant.filter_rows and plant.delay_steps == (1, 1, 1, 1)
    y_eq = M.observe(plant.x_eq, np.zeros(4), SPEED_KMH / 3.6, config, task.model)[0]
    s = plant.settled_state(task.states[0] - plant.x_eq)
    rng = np.random.default_rng(0)
    worst = np.zeros(task.observation_dim)
    size = np.full(task.observation_dim, 1e-12)
    unfiltered = M.plant_model(make_config(config, sensors={"enabled": False}), SPEED_KMH, model=task.model)
    s_unf = unfiltered.settled_state(task.states[0] - plant.x_eq)
    unfiltered_error = 0.0
    for step in range(8):
        y_env = task.obs[0].astype(float) - y_eq
        y_lin = plant.c @ s
        worst = np.maximum(worst, np.abs(y_env - y_lin))
        size = np.maximum(size, np.abs(y_lin))
        unfiltered_error = max(unfiltered_error, float(np.max(np.abs(y_env - unfiltered.c @ s_unf) / (np.abs(y_lin) + 1e-9))))
        u = 1e-4 * rng.standard_normal(4)
        task.step(u[None])
        s = plant.a @ s + plant.b @ u
        s_unf = unfiltered.a @ s_unf + unfiltered.b @ u
    assert np.all(worst <= 2e-3 * size + 1e-9), (worst / size)
    assert unfiltered_error > 1e-2  # not vacuous: leaving the filters out is seen


def test_v1_delay_margin_matches_closed_loop_eigenvalues(v1_config, v1_lqg, v1_lqg_loop, v1_lqg_margins):
    """delay_margin_s (python-control: phase margin / crossover) against whole extra steps of
    delay put into the env config (delay_steps) and the closed-loop eigenvalues."""
    loop, margins = v1_lqg_loop, v1_lqg_margins
    assert margins["closed_loop_stable"] and margins["existing_delay_s"] == pytest.approx(0.01)
    config = M.policy_config(v1_config, v1_lqg)
    dt = config["dt"]

    def stable_with(delays):
        acts = {name: {"delay_steps": int(d)} for name, d in zip(loop.plant.channel_names, delays)}
        plant = M.plant_model(make_config(config, actuators=acts), SPEED_KMH, model=loop.plant.model)
        return np.max(np.abs(M.LinearLoop(plant, loop.ctrl, SPEED_KMH, loop.u_eq).eigenvalues())) < 1.0

    checked = 0
    for j, name in enumerate(loop.plant.channel_names):
        m = margins["loops"][name]
        if m["delay_margin_s"] is None:
            assert m["delay_margin_steps"] is None
            continue
        k = int(math.floor(m["delay_margin_s"] / dt))
        assert m["delay_margin_steps"] == k, name
        assert k * dt <= m["delay_margin_sampled_s"] < (k + 1) * dt, name  # the exact figure, same whole step
        delays = np.ones(4, dtype=int)
        delays[j] = 1 + k
        assert stable_with(delays), name
        delays[j] = 2 + k
        assert not stable_with(delays), name
        checked += 1
    assert checked >= 2
    k_all = margins["all_loops_extra_delay_steps"]
    assert k_all is not None and k_all <= min(m["delay_margin_steps"] for m in margins["loops"].values() if m["delay_margin_steps"] is not None)
    assert stable_with(np.full(4, 1 + k_all)) and not stable_with(np.full(4, 2 + k_all))
    assert k_all * dt <= margins["all_loops_delay_margin_s"] < (k_all + 1) * dt


def test_fractional_delay_model_matches_whole_steps_and_simulation(v1_config, v1_lqg, v1_lqg_loop, v1_lqg_margins):
    """The exact sampled model of a fractional delay (PlantModel.with_delay_s): at whole steps
    the shift register's eigenvalues; between them the nonlinear simulation's growth rates
    (simulate_loop applies the delay to 1 ms), around the frame-lateral loop's margin, where the
    phase-lag account (delay_margin_s) is 9 % short of it."""
    loop = v1_lqg_loop
    for k in (1, 2):
        np.testing.assert_allclose(np.sort(np.abs(loop.with_delay_s(k * loop.dt).eigenvalues())),
                                   np.sort(np.abs(loop.with_extra_delay(k).eigenvalues())), atol=1e-6)  # fmt: skip
    j = loop.plant.channel_names.index("frame_lateral")
    taus = np.array([0.034, 0.037, 0.039])
    extra = np.zeros((taus.size, 4))
    extra[:, j] = taus
    predicted = np.array([loop.with_delay_s(e).growth_rate() for e in extra])
    assert predicted[0] < 0 < predicted[-1]
    x0 = np.repeat(loop.plant.x_eq[None], taus.size, axis=0)
    x0[:, 0] += 1e-8
    out = O.simulate_loop(v1_lqg, v1_config, SPEED_KMH, x0, loop.plant.force_eq, loop.u_eq, 8.0, extra_delay_s=extra,
                          substeps=10, model=loop.plant.model)  # fmt: skip
    dev = O.deviation(out["x"], loop.plant.x_eq)
    measured = np.array([O.envelope_growth_rate(out["t"], dev[:, r], floor=1e-10, skip_s=1.0) for r in range(taus.size)])
    np.testing.assert_allclose(measured, predicted, rtol=0.05, atol=0.02)
    sampled = v1_lqg_margins["loops"]["frame_lateral"]["delay_margin_sampled_s"]
    assert taus[1] < sampled < taus[2]


def test_v1_passive_growth_and_frequency_match_the_env(v1_config):
    """The v1 loop's leading eigenvalue against the env's own simulation (passive, 450 km/h)."""
    passive = PassiveController(v1_config)
    loop = M.linear_loop(passive, v1_config, SPEED_KMH)
    eig = loop.eigenvalues()
    lead = eig[np.argmax(np.abs(eig))]
    out = O.simulate_env(passive, v1_config, SPEED_KMH, 4.0)
    dev = O.deviation(out["x"][:, None, :], loop.plant.x_eq)[:, 0]
    assert O.envelope_growth_rate(out["t"], dev, skip_s=1.0) == pytest.approx(loop.growth_rate(), rel=0.05)
    y1 = out["x"][:, 0] - loop.plant.x_eq[0]
    assert O.dominant_frequency_hz(out["t"], y1, skip_s=1.0) == pytest.approx(abs(np.angle(lead)) / loop.dt / (2 * np.pi), rel=0.01)


def test_v1_extra_delay_verdicts_hold_in_the_env(v1_config, v1_lqg, v1_lqg_loop, v1_lqg_margins):
    """The env itself (nonlinear bogie, its integrator, rate limits, filters) with the LQG at
    450 km/h: the all-loop extra delay the margins tolerate decays, one step more grows, at
    the growth rates of the linear loop (within 10 %)."""
    k = v1_lqg_margins["all_loops_extra_delay_steps"]
    for extra, sign in ((k, -1), (k + 1, 1)):
        predicted = v1_lqg_loop.with_extra_delay(extra).growth_rate()
        assert np.sign(predicted) == sign and abs(predicted) > 0.5  # a discriminating speed
        out = O.simulate_env(v1_lqg, v1_config, SPEED_KMH, 5.0, extra_delay_steps=extra)
        dev = O.deviation(out["x"][:, None, :], v1_lqg_loop.plant.x_eq)[:, 0]
        measured = O.envelope_growth_rate(out["t"], dev, skip_s=1.0)
        assert measured == pytest.approx(predicted, rel=0.1), extra


def test_v1_conicity_moves_the_plant(v1_config):
    """--conicity replaces lam: the passive v1 loop at 0.1 is unstable at 300 km/h (linear critical
    speed 141 km/h), at the nominal 0.025 stable."""
    passive = PassiveController(v1_config)
    assert M.margins_table(passive, v1_config, (300.0,))["summary"]["closed_loop_stable"]
    table = M.margins_table(passive, v1_config, (300.0,), conicity=0.1)
    assert table["conicity"] == 0.1 and table["unstable_at_kmh"] == [300.0]
    from bogie_env.params import ConfigError

    with pytest.raises(ConfigError, match="conicity"):
        M.margins_table(passive, v1_config, (300.0,), conicity=2.0)


class _HookedLQG(LQGController):
    """An LQG that describes itself through the controller_model hook, at half its gain."""

    def act(self, obs):
        return 0.5 * super().act(obs)

    def controller_model(self, n_obs, speed_kmh, y0):
        full = M.lqg_model(self, n_obs, speed_kmh)
        return M.ControllerModel(full.a, full.b, 0.5 * full.c, 0.5 * full.d, "hooked LQG at half gain")


def test_controller_model_hook_is_used(v1_config, v1_lqg_loop):
    policy = _HookedLQG(v1_config, sensor_model=False, v_range_kmh=(400.0, 500.0))
    loop = M.linear_loop(policy, v1_config, SPEED_KMH)
    assert loop.ctrl.method == "hooked LQG at half gain"
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, M.policy_config(v1_config, policy), loop.plant.model)[0]
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq) < 1e-3
    # the hooked loop is the LQG loop with every command scaled by 0.5
    ours = np.sort_complex(loop.eigenvalues())
    scaled = np.sort_complex(v1_lqg_loop.eigenvalues(gains=np.full(4, 0.5)))
    np.testing.assert_allclose(ours, scaled, atol=1e-9)


@pytest.mark.slow  # 2.4-6 s warm: make test's 3 minutes on a clean clone
def test_residual_policy_model(v1_config, v1_lqg, pretrained_v0):
    """A residual policy clip(LQG + scale * PPO): the baseline's model plus scale x the PPO's
    autograd Jacobian (linear_models.residual_controller_model), against its act, at its own
    closed-loop equilibrium (the PPO part commands a bias)."""
    from bogie_agents.design.linear_models import residual_controller_model, sb3_jacobian_autograd

    ppo = pretrained_v0  # the shipped v0 PPO: v1 keeps v0's spaces

    class Residual(LQGController):
        scale = 0.2

        def act(self, obs):
            return np.clip(super().act(obs) + self.scale * ppo.act(obs), -1, 1).astype(np.float32)

        def controller_model(self, n_obs, speed_kmh, y0):
            return residual_controller_model(M.lqg_model(self, n_obs, speed_kmh), sb3_jacobian_autograd(ppo, y0), self.scale)

    policy = Residual(v1_config, v_range_kmh=(400.0, 500.0))
    loop = M.linear_loop(policy, v1_config, SPEED_KMH)
    assert np.max(np.abs(loop.u_eq)) > 1e-3  # the operating point carries the bias
    config = M.policy_config(v1_config, policy)
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, config, loop.plant.model)[0]
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3) < 2e-2  # float32 act
    assert M.loop_margins(loop)["closed_loop_stable"]


def test_cli_margins_v1_json(capsys):
    code = cli_main(["margins", "--env", "Bogie/Hunting-v1", "--policy", "passive", "--speeds", "300,450",
                     "--conicity", "0.05", "--json"])  # fmt: skip
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["env_id"] == "Bogie/Hunting-v1" and payload["env_version"] == "v1"
    margins = payload["policies"][0]["margins"]
    assert margins["conicity"] == 0.05 and margins["delay_steps"]["frame_yaw"] == 1
    assert margins["sensor_filters_hz"]["frame_yaw_rate"] == 40.0
    assert margins["unstable_at_kmh"] == [300.0, 450.0]  # passive at 0.05: critical speed 237 km/h
    assert set(margins["summary"]) >= {"gain_margin", "delay_margin_s", "closed_loop_stable", "all_loops_extra_delay_steps"}
    assert margins["summary"]["closed_loop_stable"] is False


def test_cli_margins_tell_a_controller_the_conicity(capsys):
    """At --conicity a controller told the conicity class is designed for it, as the protocol
    tells it its column's: lqg_rate designed for 0.1 holds the 0.1 loop at 200 km/h, where the
    design for new wheels on worn ones grows at 3.8 1/s."""
    code = cli_main(["margins", "--env", "Bogie/Hunting-v1", "--policy", "lqg_rate", "--speeds", "200",
                     "--conicity", "0.1", "--json"])  # fmt: skip
    assert code == 0
    margins = json.loads(capsys.readouterr().out)["policies"][0]["margins"]
    assert margins["unstable_at_kmh"] == [] and margins["gain_margin"] > 1.4


def test_cli_margins_bad_conicity_is_named(capsys):
    assert cli_main(["margins", "--policy", "passive", "--conicity", "-1"]) == 2
    assert "--conicity" in capsys.readouterr().err


@pytest.mark.slow
def test_v1_lqg_margins_hold_in_nonlinear_simulation(v1_config, v1_lqg, v1_lqg_loop, v1_lqg_margins):
    """v1 (one step of delay, sensor filters in simulate_loop as in the env): the worst loop at
    0.9 / 1.1 x its gain margin and 0.9 / 1.1 x its delay margin (to 1 ms) decays / grows."""
    model = v1_lqg_loop.plant.model
    _assert_verdicts(_verdicts(v1_lqg, v1_config, model, v1_lqg_loop, v1_lqg_margins))


@pytest.mark.slow  # 2.4-6 s warm: make test's 3 minutes on a clean clone
def test_v1_sensor_model_lqg_model_matches_act_and_its_delay_verdicts_hold(v1_config, v1_sensor_lqg):
    """The v1 LQG (delay registers, sensor filters and bias states in its filter): its linear
    controller model reproduces act(), and in the env itself (nonlinear bogie, rate limits,
    filters) the all-loop extra delay its margins tolerate decays and one step more grows."""
    policy = v1_sensor_lqg
    assert policy.sensor_model
    loop = M.linear_loop(policy, v1_config, SPEED_KMH)
    config = M.policy_config(v1_config, policy)
    y0 = M.observe(loop.plant.x_eq, loop.plant.force_eq, SPEED_KMH / 3.6, config, loop.plant.model)[0]
    assert M.check_controller_model(policy, loop.ctrl, y0, loop.u_eq, amplitude=1e-3) < 1e-3
    margins = M.loop_margins(loop)
    assert margins["closed_loop_stable"]
    k = margins["all_loops_extra_delay_steps"]
    for extra, sign in ((k, -1), (k + 1, 1)):
        predicted = loop.with_extra_delay(extra).growth_rate()
        assert np.sign(predicted) == sign and abs(predicted) > 0.2, (extra, predicted)
        out = O.simulate_env(policy, v1_config, SPEED_KMH, 6.0, extra_delay_steps=extra)
        dev = O.deviation(out["x"][:, None, :], loop.plant.x_eq)[:, 0]
        assert np.sign(O.envelope_growth_rate(out["t"], dev, skip_s=1.0)) == sign, extra


def test_v1_lqg_design_model_is_the_margins_plant(v1_config, v1_sensor_lqg):
    """Independent formulation: the v1 LQG's design model without its bias states (lateral
    Jacobian, delay registers, sensor filters) has the transfer matrix, command to the six
    sensors, of the margins' plant built from the full 20-state Jacobian and validated against
    the env (test_v1_plant_matches_the_env_observation_response), at frequencies across the
    hunting band and above."""
    ad, bd, cd = v1_sensor_lqg.sampled_model(SPEED_KMH / 3.6)
    n = ad.shape[0] - len(SENSORS)
    plant = M.plant_model(M.policy_config(v1_config, v1_sensor_lqg), SPEED_KMH, model=v1_sensor_lqg.model)

    def transfer(a, b, c, f_hz):
        z = np.exp(2j * np.pi * f_hz * plant.dt)
        return c @ np.linalg.solve(z * np.eye(a.shape[0]) - a, b)

    for f_hz in (0.5, 2.0, 5.0, 12.0, 30.0):
        ours = transfer(ad[:n, :n], bd[:n], cd[:, :n], f_hz)
        reference = transfer(plant.a, plant.b, plant.c[: len(SENSORS)], f_hz)
        assert np.max(np.abs(ours - reference)) <= 1e-8 * np.max(np.abs(reference)), f_hz
