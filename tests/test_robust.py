"""The robust classical baseline (bogie_agents.controllers.robust) against oracles that did not produce it.

- the design plant (lateral linearisation, exact in speed) against margins' plant (full 20-state
  Jacobian at the equilibrium): the same frequency response;
- its sensor filters against the first-order filter's own transfer function;
- the shipped gains: closed-loop eigenvalues of the design model inside the unit circle over the
  conicity grid in each conicity's required speed range, also with every command doubled and
  with one more step of loop delay;
- the linear controller model against ``act`` on a random observation sequence;
- washout: a constant observation (a steady curve, a sensor bias) gives zero steady command,
  in ``act`` and as the model's exact DC gain; a reset transient of the accelerometer gives no
  fake velocity; the second-order washout against its transfer functions and a ramp;
- per-row state: ``reset(rows)`` restarts only those rows; a batch row equals a lone run;
- the report's margins (``design_margins`` on ``DesignModel.plant``) against the design
  plant's own transfer function and delays, and against ``bogie margins``' loop of the policy
  (full 20-state plant): the same closed-loop eigenvalues, gain and delay margins.
"""

import json

import numpy as np
import pytest

from bogie_agents.design import margins as M
from bogie_agents.controllers.policies import load_policy
from bogie_agents.controllers.robust import (
    DESIGN_CONICITIES,
    GAINS_FILE,
    DesignModel,
    RobustDampingController,
    closed_loop,
    design_margins,
    filter_bank,
    lead_command,
    lead_model,
    load_gains,
    save_gains,
)
from bogie_agents.design.robust_cli import main
from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.dynamics import state_index
from bogie_env.envs import task as T
from bogie_env.envs.config import make_config, merge_config
from bogie_env.envs.sensors import SENSOR_NAMES
from bogie_env.params import ConfigError

#: Speed ranges (km/h) where the shipped design must be stable, per conicity: at least the
#: passive linear critical speed + 100 km/h (issue 10), and 300-500 km/h at nominal conicity.
REQUIRED_KMH = {0.025: (60.0, 500.0), 0.05: (60.0, 340.0), 0.1: (60.0, 245.0), 0.2: (60.0, 120.0), 0.3: (60.0, 90.0)}


@pytest.fixture(scope="module")
def config():
    return make_config({"randomize": {}}, variant="v1")


@pytest.fixture(scope="module")
def controller(config):
    return RobustDampingController(config)


def _response(a, b, c, z):
    return c @ np.linalg.solve(z * np.eye(a.shape[0]) - a, b)


def test_design_plant_matches_the_margins_plant(config):
    plain = merge_config(config, {"sensors": {"enabled": False}})
    design = DesignModel(plain, 0.1)
    other = M.plant_model(plain, 250.0, model=design.model)
    mine = design.plant(250.0)
    for w in (0.3, 2.0, 15.0, 40.0, 200.0):  # rad/s
        z = np.exp(1j * w * config["dt"])
        expected = _response(other.a, other.b, other.c, z)
        got = _response(mine.a, mine.b, mine.c, z)
        assert np.allclose(got, expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())


def test_design_plant_sensor_filters(config):
    """Sensed rows are the unfiltered rows times w z / (z - (1 - w)); force rows are unfiltered."""
    plain = DesignModel(merge_config(config, {"sensors": {"enabled": False}}), 0.05).plant(300.0)
    filtered = DesignModel(config, 0.05).plant(300.0)
    n_sensed = len(T.SENSORS) + 1
    for w in (1.0, 20.0, 100.0):
        z = np.exp(1j * w * config["dt"])
        weight = np.array([1 - np.exp(-2 * np.pi * config["sensors"][name]["bandwidth_hz"] * config["dt"])
                           for name in SENSOR_NAMES])[:, None]
        expected = _response(plain.a, plain.b, plain.c, z)
        expected[:n_sensed] *= weight * z / (z - (1 - weight))
        assert np.allclose(_response(filtered.a, filtered.b, filtered.c, z), expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("conicity", DESIGN_CONICITIES)
def test_shipped_gains_stabilise_the_design_model(config, controller, conicity):
    model = DesignModel(config, conicity)
    late = DesignModel(merge_config(config, {"actuators": {n: {"delay_steps": 2} for n in config["actuators"]}}), conicity)
    lo, hi = REQUIRED_KMH[conicity]
    for v in np.arange(lo, hi + 1e-9, 10.0):
        ctrl = controller.controller_model(model.n_obs, v, None)
        bank = filter_bank(model.n_obs, config["dt"], controller.washout_hz, controller.leak_hz)
        gains = controller.gain_at(np.array([v]))[0]
        lead = float(controller.lead_at(np.array([v]))[0])
        expected = lead_model(bank, gains, lead, config["dt"], controller.lead_lowpass_hz)
        assert all(np.allclose(x, y) for x, y in zip(expected, (ctrl.a, ctrl.b, ctrl.c, ctrl.d)))
        for plant, factor in ((model.plant(v), 1.0), (model.plant(v), 2.0), (late.plant(v), 1.0)):
            radius = np.max(np.abs(np.linalg.eigvals(closed_loop(plant, bank, gains, factor, lead, config["dt"],
                                                                 controller.lead_lowpass_hz))))  # fmt: skip
            assert radius < 1.0, (conicity, v, factor, radius)


@pytest.mark.parametrize("speed_kmh", [330.0, 255.0])
def test_linear_model_matches_act(config, controller, speed_kmh):
    """At a fixed measured speed the controller is linear: act = the model, to float32 rounding
    (255 km/h: with the command lead, whose model has its own state)."""
    assert (controller.lead_at(np.array([speed_kmh]))[0] > 0) == (speed_kmh == 255.0)
    rng = np.random.default_rng(3)
    speed = len(T.SENSORS)
    y0 = 0.3 * rng.standard_normal(controller.n_obs)
    y0[speed] = (speed_kmh - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    model = controller.controller_model(controller.n_obs, speed_kmh, y0)
    dy = 0.003 * rng.standard_normal((30, controller.n_obs))
    dy[:, speed] = 0.0
    controller.reset(1)
    for _ in range(1500):  # settles the filters at y0 (the accelerometer chain starts at rest: 15 s)
        controller.act(y0[None].astype(np.float32))
    c = np.zeros(model.n_states)
    worst = scale = 0.0
    for step in range(30):
        y = (y0 + dy[step]).astype(np.float32).astype(float)
        u = controller.act(y[None].astype(np.float32))[0]
        u_lin = model.c @ c + model.d @ (y - y0)
        c = model.a @ c + model.b @ (y - y0)
        assert np.max(np.abs(u_lin)) < 1.0  # inside the clip
        worst, scale = max(worst, np.max(np.abs(u - u_lin))), max(scale, np.max(np.abs(u_lin)))
    assert scale > 1e-2 and worst / scale < 1e-5


def test_constant_observation_gives_zero_steady_command(config, controller):
    """A steady curve: constant wheelset offsets and relative yaws, frame yaw rate V/R, unbalanced
    lateral acceleration (here after a step from another constant observation), or sensor biases."""
    rng = np.random.default_rng(0)
    n = 5
    y_start = np.clip(0.5 * rng.standard_normal((n, controller.n_obs)), -3, 3)
    y_curve = np.clip(0.5 * rng.standard_normal((n, controller.n_obs)), -3, 3)
    for y in (y_start, y_curve):
        y[:, len(T.SENSORS)] = (300.0 - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    y_start[:, T.SENSOR_FRAME_LATERAL_ACCEL] = 0.0  # the accelerometer chain starts at rest (next test)
    controller.reset(n)
    first = controller.act(y_start.astype(np.float32))
    assert np.max(np.abs(first)) < 1e-6  # the filters start settled: no transient from a bias
    transient = [controller.act(y_curve.astype(np.float32)) for _ in range(800)]  # 8 s
    assert np.max(np.abs(transient[0])) > 1e-3  # the step is seen
    assert np.max(np.abs(transient[-1])) < 1e-4
    model = controller.controller_model(controller.n_obs, 300.0, None)
    dc = model.c @ np.linalg.solve(np.eye(model.n_states) - model.a, model.b) + model.d
    assert np.max(np.abs(dc)) < 1e-9


def test_a_reset_transient_of_the_accelerometer_is_not_taken_for_a_bias(config, controller):
    """At reset the bogie is at rest but displaced: the first acceleration sample is the
    suspension's pull, gone a step later. The lateral-velocity signal must stay at the velocity
    that pulse gives (|a0| dt), not report |a0| x the washout's time constant (the filters settled
    on the pulse: a fake velocity that saturated every actuator for 2-3 s on the routes)."""
    a0 = -25.0  # m/s^2, the size of a large initial perturbation's pull
    y = np.zeros((1, controller.n_obs))
    y[0, len(T.SENSORS)] = (250.0 - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    first = y.copy()
    first[0, T.SENSOR_FRAME_LATERAL_ACCEL] = a0 / T.ACCEL_SCALE
    controller.reset(1)
    velocity = [controller.signals(first)[0, 3]] + [controller.signals(y)[0, 3] for _ in range(300)]
    assert np.max(np.abs(velocity)) <= 1.01 * abs(a0) * config["dt"]
    assert abs(velocity[0]) > 0.5 * abs(a0) * config["dt"]  # the pulse itself is seen


def test_second_order_washout_against_the_first_order_high_pass(config):
    """``washout_order`` 2 against its transfer functions (H1(z) = alpha (z - 1) / (z - alpha), the
    first-order discrete high-pass): gyro path H1^2, wheelset yaw rates H1 x the difference
    quotient of the relative yaw plus the gyro path, lateral rates H1 x the quotient; order 1 is
    H1 and the plain quotient. Then a ramp in any observation gives zero steady signals with order
    2 (a clothoid transition), not with order 1."""
    dt, n_obs = config["dt"], RobustDampingController(config).n_obs
    alpha = np.exp(-2 * np.pi * 0.5 * dt)
    for order in (1, 2):
        bank = filter_bank(n_obs, dt, 0.5, 0.3, order)
        for hz in (0.2, 1.0, 3.0, 12.0):
            z = np.exp(2j * np.pi * hz * dt)
            h1 = alpha * (z - 1) / (z - alpha)
            quotient = (z - 1) / (dt * z) * (h1 if order == 2 else 1.0)
            gyro = T.YAW_RATE_SCALE * h1**order
            got = _response(bank.a, bank.b, bank.c, z) + bank.d
            assert np.isclose(got[2, T.SENSOR_FRAME_YAW_RATE], gyro, rtol=1e-9)
            assert np.isclose(got[0, T.SENSOR_FRAME_YAW_RATE], gyro, rtol=1e-9)
            assert np.isclose(got[0, T.SENSOR_WHEELSET1_YAW], T.REL_YAW_SCALE * quotient, rtol=1e-9)
            assert np.isclose(got[5, T.SENSOR_WHEELSET2_LATERAL], quotient, rtol=1e-9)
        ramp = np.arange(4000)[:, None] * 1e-3 * np.ones(n_obs)
        f = np.zeros(bank.a.shape[0])
        for y in ramp:
            s = bank.c @ f + bank.d @ y
            f = bank.a @ f + bank.b @ y
        if order == 2:
            assert np.max(np.abs(s)) < 1e-9
        else:
            assert np.min(np.abs(s)) > 1e-3  # every signal passes a ramp as a constant
    with pytest.raises(ConfigError, match="washout_order"):
        filter_bank(n_obs, dt, 0.5, 0.3, 3)


def test_gain_table_washout_order(tmp_path, config, controller):
    """Absent: order 1 (the shipped table); 2: the controller runs the order-2 bank with zero
    steady command; anything else is a named error."""
    table = load_gains()
    assert "washout_order" not in table and controller.washout_order == 1 and controller.bank.a.shape == (9, 9)
    table["washout_order"] = 2
    second = RobustDampingController(config, table)
    assert second.bank.a.shape == (15, 15)
    model = second.controller_model(second.n_obs, 300.0, None)
    assert np.max(np.abs(model.c @ np.linalg.solve(np.eye(model.n_states) - model.a, model.b) + model.d)) < 1e-9
    table["washout_order"] = 3
    path = tmp_path / "gains.json"
    save_gains(table, path)
    with pytest.raises(ConfigError, match="washout_order = 3"):
        load_gains(path)


@pytest.mark.parametrize("speed_kmh", [None, 250.0])
def test_rows_keep_their_own_state(config, speed_kmh):
    """Each row has its own filter and command-lead state; a row reset alone (``reset(n, rows)``)
    then acts as a fresh controller does (250 km/h: with the shipped command lead)."""
    rng = np.random.default_rng(1)
    a, b = RobustDampingController(config), RobustDampingController(config)
    obs = 0.2 * rng.standard_normal((40, 3, a.n_obs)).astype(np.float32)
    if speed_kmh is not None:
        assert a.lead_at(np.array([speed_kmh]))[0] > 0.0
        obs[:, :, len(T.SENSORS)] = (speed_kmh - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    a.reset(3)
    b.reset(1)
    for k in range(40):
        if k == 20:
            a.reset(3, rows=np.array([0]))
            b.reset(1)
        batch = a.act(obs[k])
        lone = b.act(obs[k, 0:1])
        if k >= 20:
            np.testing.assert_array_equal(batch[0], lone[0])
    assert batch.shape == (3, 4) and batch.dtype == np.float32 and np.all(np.abs(batch) <= 1.0)


def test_loaded_by_name_it_acts_as_the_controller_built_for_the_config(config):
    """``load_policy("robust_damping", config)`` (the name ``bogie evaluate`` takes) acts on a
    closed-loop observation sequence exactly as ``RobustDampingController(config)`` does, and
    commands something (a registry entry of another controller, or of passive, fails this)."""
    from bogie_env.envs.task import HuntingTask

    task = HuntingTask(2, config)
    task.seed_rows(np.arange(2), [3, 4])
    task.reset_rows(np.arange(2))
    loaded, built = load_policy("robust_damping", config), RobustDampingController(config)
    loaded.reset(2)
    built.reset(2)
    for _ in range(30):
        action = loaded.act(task.obs)
        np.testing.assert_array_equal(action, built.act(task.obs))
        task.step(action)
    assert loaded.observation_type == "sensors" and np.abs(action).max() > 1e-3


def test_bad_gain_table_is_named(tmp_path, controller):
    table = load_gains()
    table["gains"] = table["gains"][:, :, :3]
    path = tmp_path / "gains.json"
    save_gains(table, path)
    with pytest.raises(ConfigError, match="gains must be"):
        load_gains(path)
    with pytest.raises(ConfigError, match="observation.type"):
        RobustDampingController(make_config({"randomize": {}, "observation": {"type": "state"}}, variant="v1"))


def test_command_lead(tmp_path, config):
    """``lead_command`` is ``u + k d`` with ``d`` the low-passed command change (the plain change
    without low-pass); in ``act`` (no low-pass) it scales a sinusoidal command by the discrete
    lead's response ``1 + k (1 - 1/z)``, leaves a table without ``lead_s`` bit for bit as before,
    starts a row without a kick, and a table's bad ``lead_s`` / ``lead_lowpass_hz`` is a named error.
    (The low-passed lead in ``act`` is checked against its linear model in
    test_linear_model_matches_act at 255 km/h.)"""
    u, prev, d = np.array([[0.2, -0.1]]), np.array([[0.1, 0.1]]), np.array([[0.05, 0.0]])
    assert np.allclose(lead_command(u, prev, d, np.array([0.02]), 0.01)[0], u + 2.0 * (u - prev))
    alpha = np.exp(-2 * np.pi * 4.0 * 0.01)
    led_u, new_d = lead_command(u, prev, d, np.array([0.02]), 0.01, 4.0)
    assert np.allclose(new_d, alpha * d + (1 - alpha) * (u - prev)) and np.allclose(led_u, u + 2.0 * new_d)
    assert np.array_equal(lead_command(u, prev, d, np.array([0.0]), 0.01, 4.0)[0], u)
    table = load_gains()
    table.pop("lead_s")
    plain = RobustDampingController(config, table)
    table["lead_s"] = np.full(table["speeds_kmh"].size, 0.01)
    table["lead_lowpass_hz"] = None
    led = RobustDampingController(config, table)
    table["lead_s"] = np.zeros(table["speeds_kmh"].size)
    zero = RobustDampingController(config, table)
    rng = np.random.default_rng(5)
    n_obs, speed = plain.n_obs, len(T.SENSORS)
    hz, dt = 4.0, config["dt"]
    y = 0.05 * rng.standard_normal(n_obs)
    y[speed] = (250.0 - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    obs = np.array([y + 0.02 * np.sin(2 * np.pi * hz * dt * k) * (np.arange(n_obs) != speed) for k in range(600)])
    outs = []
    for ctrl in (plain, led, zero):
        ctrl.reset(1)
        outs.append(np.array([ctrl.act(o[None].astype(np.float32))[0] for o in obs]))
    np.testing.assert_array_equal(outs[0], outs[2])
    np.testing.assert_array_equal(outs[0][0], outs[1][0])  # the first command after reset has no lead
    assert np.max(np.abs(outs[0])) < 1.0  # inside the clip: the lead is linear here
    z = np.exp(2j * np.pi * hz * dt)
    expected = 1.0 + 1.0 * (1.0 - 1.0 / z)  # k = lead / dt = 1
    t = np.arange(300, 600)
    basis = np.exp(2j * np.pi * hz * dt * t)
    for ch in range(outs[0].shape[1]):
        a = np.vdot(basis, outs[0][t, ch] - outs[0][t, ch].mean())
        b = np.vdot(basis, outs[1][t, ch] - outs[1][t, ch].mean())
        assert np.isclose(b / a, expected, rtol=2e-3), (ch, b / a, expected)
    path = tmp_path / "gains.json"
    for bad in ([-0.01], [0.2], "short"):
        table["lead_s"] = np.zeros(3) if bad == "short" else np.full(table["speeds_kmh"].size, bad[0])
        save_gains(table, path)
        with pytest.raises(ConfigError, match="lead_s"):
            load_gains(path)
    table["lead_s"] = np.zeros(table["speeds_kmh"].size)
    for field, bad in (("lead_s", "abc"), ("lead_s", ["0.01"] * table["speeds_kmh"].size), ("lead_s", {"a": 1}),
                       ("lead_s", [[0.0]] + [0.0] * (table["speeds_kmh"].size - 1)), ("gains", "abc"), ("speeds_kmh", None)):
        text = json.loads(path.read_text())
        text[field] = bad
        path.write_text(json.dumps(text))
        with pytest.raises(ConfigError, match=f"{field} = "):
            load_gains(path)
    table["lead_lowpass_hz"] = -4.0
    save_gains(table, path)
    with pytest.raises(ConfigError, match="lead_lowpass_hz = -4.0"):
        load_gains(path)


def test_shipped_lead_spares_the_margin_speeds(controller):
    """The shipped command lead acts below 300 km/h only: the nominal conicity's margin speeds
    (300-450 km/h) see stage 1's controller model."""
    assert np.all(controller.lead_at(np.arange(300.0, 601.0, 10.0)) == 0.0)
    assert controller.lead_at(np.array([250.0]))[0] > 0.0
    model = controller.controller_model(controller.n_obs, 300.0, None)
    assert model.n_states == controller.bank.a.shape[0]


def test_design_plant_extra_delay_is_the_design_plant_of_a_longer_delay(config):
    """One more whole step, or ``dt`` more seconds, of delay in every channel of the design plant
    (``PlantModel.with_extra_delay``, ``with_delay_s``) gives the design plant of the config with
    ``delay_steps + 1``, and the plant keeps the config's channels and delay."""
    model = DesignModel(config, 0.1)
    late = DesignModel(merge_config(config, {"actuators": {n: {"delay_steps": 2} for n in config["actuators"]}}), 0.1)
    plant = model.plant(250.0)
    assert plant.delay_steps == (1,) * model.n_act and plant.channel_names == [CHANNEL_NAMES[k] for k in model.active]
    design_late = late.plant(250.0)
    for w in (0.3, 2.0, 15.0, 40.0, 200.0):  # rad/s
        z = np.exp(1j * w * config["dt"])
        expected = _response(design_late.a, design_late.b, design_late.c, z)
        assert not np.allclose(_response(plant.a, plant.b, plant.c, z), expected, rtol=1e-3)
        for other in (plant.with_extra_delay(1), plant.with_delay_s(config["dt"])):
            got = _response(other.a, other.b, other.c, z)
            assert np.allclose(got, expected, rtol=1e-9, atol=1e-12 * np.abs(expected).max())


def test_design_plant_settled_state_takes_the_lateral_states(config):
    """The design plant has 16 bogie states (``bogie_states``), the margins plant 20: a state
    deviation placed by ``settled_state`` gives the same clean observation in both (a layout that
    copies the 20 entries into the first 20 states misplaces the frame's and fails this)."""
    plain = merge_config(config, {"sensors": {"enabled": False}})
    design = DesignModel(plain, 0.1)
    mine, other = design.plant(250.0), M.plant_model(plain, 250.0, model=design.model)
    dx = np.zeros(20)
    for name, value in (("y1", 1e-3), ("psi2", 2e-4), ("yb", -5e-4), ("dpsib", 1e-3), ("phi1", 3e-4)):
        dx[state_index(name)] = value
    force = np.linspace(-0.2, 0.3, design.n_act)
    got = mine.c_clean @ mine.settled_state(dx, force)
    expected = other.c_clean @ other.settled_state(dx, force)
    assert np.allclose(got, expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())
    with pytest.raises(ValueError, match="dx has shape"):
        mine.settled_state(np.zeros(16))


def test_report_margins_agree_with_the_margins_loop(config, controller):
    """The report's margin row (``design_margins``, the design model through
    ``margins.loop_margins``) against ``bogie margins``' own loop of the policy at 450 km/h
    (20-state Jacobian at the equilibrium, the policy's controller model at its operating
    observation): the same closed-loop eigenvalues, the same whole-step delay margins by
    eigenvalues, and python-control's gain and delay margins to the accuracy of its frequency
    response (about 3e-4 of the loop's peak on these ill-conditioned state spaces)."""
    row = design_margins(controller, config, speeds_kmh=(450.0,))[0]
    full = M.linear_loop(load_policy("robust_damping", config), config, 450.0)
    mine = DesignModel(config)
    loop = M.LinearLoop(mine.plant(450.0), controller.controller_model(mine.n_obs, 450.0, None), 450.0, np.zeros(mine.n_act))
    eig, eig_full = loop.eigenvalues(), full.eigenvalues()
    assert max(np.min(np.abs(eig_full - e)) for e in eig) < 1e-9  # the full loop adds 4 vertical modes
    assert row["closed_loop_stable"] and row["closed_loop_growth_rate_per_s"] == pytest.approx(full.growth_rate(), abs=1e-8)
    assert list(row["loops"]) == full.plant.channel_names
    assert row["all_loops_extra_delay_steps"] == full.tolerated_extra_steps(None, M.MAX_EXTRA_DELAY_STEPS) == 2
    omega = M.frequency_grid(config["dt"])
    for k, (name, m) in enumerate(row["loops"].items()):
        assert m["existing_delay_s"] == pytest.approx(config["dt"])
        assert m["delay_margin_steps"] == full.tolerated_extra_steps(k, M.MAX_EXTRA_DELAY_STEPS), name
        other = M.siso_margins(full.broken_loop(k), omega)
        assert m["gain_margin"] == pytest.approx(other["gain_margin"], rel=2e-3), name
        assert (m["delay_margin_s"] is None) == (other["delay_margin_s"] is None), name
        if m["delay_margin_s"] is not None:
            assert m["delay_margin_s"] == pytest.approx(other["delay_margin_s"], rel=2e-3), name
            assert m["delay_margin_steps"] in (None, int(m["delay_margin_s"] / config["dt"])), name


@pytest.mark.slow
def test_report_runs(config, capsys):
    """``python -m bogie_agents.design.robust_cli report`` end to end: the onsets and one stable margin row
    per speed, each loop named."""
    main(["report"])
    out = capsys.readouterr().out
    assert "conicity 0.025: first unstable > 600 km/h" in out
    rows = [line for line in out.splitlines() if line.strip().split(" ")[1:2] == ["km/h:"]]
    assert len(rows) == 5 and not any("unstable" in r for r in rows), out
    assert all(all(name in r for name in CHANNEL_NAMES) and "disk margin" in r for r in rows), out


def test_progress_printer_counts_and_estimates_the_time_left(capsys):
    from bogie_agents.design.robust_cli import _progress_printer

    progress = _progress_printer(3)
    progress("row a")
    progress("row b")
    lines = capsys.readouterr().err.splitlines()
    assert lines[0].startswith("[1/3] row a; ") and lines[1].startswith("[2/3] row b; ")
    assert all(line.endswith(" s left") for line in lines)


@pytest.mark.parametrize("w_track, message", [("a", "--w-track = 'a'"), ("0.1,0.2", "has 2 values")])
def test_retune_w_track_names_a_bad_value(w_track, message, capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["retune", "--base", str(GAINS_FILE.with_name("robust_gains_stage1.json")), "--w-track", w_track,
              "--out", str(tmp_path / "g.json")])  # fmt: skip
    assert message in capsys.readouterr().err and not (tmp_path / "g.json").exists()


@pytest.mark.parametrize("w_yaw", ["-0.1", "nan"])
def test_retune_w_yaw_names_a_bad_value(w_yaw, capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["retune", "--base", str(GAINS_FILE.with_name("robust_gains_stage1.json")), "--w-yaw", w_yaw,
              "--out", str(tmp_path / "g.json")])  # fmt: skip
    assert "--w-yaw" in capsys.readouterr().err and not (tmp_path / "g.json").exists()
