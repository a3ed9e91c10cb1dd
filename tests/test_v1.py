"""Bogie/Hunting-v1: sensors, loop delay, rate limits, track levels, scenarios, integration.

Oracles: the sampled step response of a first-order filter; noise statistics against the
datasheet formula; a delayed loop equals the undelayed loop fed the previous actions; the
rate-limited lag against a fine numerical integration of its ODE; the EN 13848-5 level
against the profile's own section peaks; RK4's effective eigenvalue against an actual RK4 run.
"""

import math

import gymnasium as gym
import numpy as np
import pytest
from numba import njit

import bogie_env  # noqa: F401
from bogie_env import actuators as A
from bogie_env.envs import sensors as S
from bogie_env.envs.config import V1_RATE_LIMITS, make_config
from bogie_env.envs.scenario import RANGES
from bogie_env.envs.task import HuntingTask
from bogie_env.integrate import accurate_substep, eigenvalue_errors, rk4_effective_eigenvalue
from bogie_env.params import ConfigError
from bogie_env.track import ALIGNMENT_LEVELS, alignment_profile_at_level, section_crest_factor

#: v1 at one speed, nothing drawn: a quick, controlled v1 task.
FIXED = {"speed": {"start_kmh": 300.0, "end_kmh": 300.0, "accel": 0.0}, "randomize": {}}


def v1_task(n=1, **overrides):
    return HuntingTask(n, make_config(overrides.pop("config", FIXED), variant="v1", **overrides))


# ---- actuators ---------------------------------------------------------------------------------
@njit
def _lagged_force(start, target, weight, decay, rate):
    return A.lagged_force(start, target, weight, decay, rate)


@pytest.mark.parametrize("start,target", [(0.0, 10e3), (3e3, -8e3), (1e3, 1.5e3)])
def test_rate_limited_lag_solves_its_ode(start, target):
    """f' = clip(k (target - f), -R, R), integrated finely, equals the closed form."""
    k, rate = 2 * math.pi * 10.0, 2.0e5
    h, f = 1e-6, start
    for n in range(1, 40_001):
        f += h * min(max(k * (target - f), -rate), rate)
        if n % 5000 == 0:
            assert _lagged_force(start, target, math.exp(-k * n * h), k, rate) == pytest.approx(f, abs=2.0)


def test_rate_limit_is_honoured_in_the_env():
    """A full-scale command step: the force moves by at most rate_limit * dt per step."""
    task = v1_task(config={**FIXED, "actuators": {n: {"delay_steps": 0} for n in A.CHANNEL_NAMES}})
    task.seed_rows(np.array([0]), [0])
    task.reset_rows(np.array([0]))
    limits = np.array([V1_RATE_LIMITS[n] for n in A.CHANNEL_NAMES])
    previous = np.zeros(4)
    rises = []
    for a in [1.0] * 8 + [-1.0] * 8:
        task.step(np.full((1, 4), a))
        force = task.sim.lag[0, A.FORCE].copy()
        rises.append(np.abs(force - previous) / task.config["dt"])
        previous = force
    rises = np.array(rises)
    assert np.all(rises <= limits * (1 + 1e-12))
    assert np.max(rises[:, 0]) == pytest.approx(limits[0])  # the limit binds on a full-scale step


def test_delay_is_exactly_one_step():
    """The v1 loop (one step of delay) fed a_0, a_1, ... moves exactly like the undelayed loop
    fed 0, a_0, a_1, ..."""
    undelayed = {**FIXED, "actuators": {n: {"delay_steps": 0} for n in A.CHANNEL_NAMES}}
    delayed, direct = v1_task(), v1_task(config=undelayed)
    assert delayed.config["actuators"]["frame_yaw"]["delay_steps"] == 1
    actions = np.random.default_rng(1).uniform(-1, 1, (30, 1, 4))
    for task in (delayed, direct):
        task.seed_rows(np.array([0]), [5])
        task.reset_rows(np.array([0]))
    delayed.step(actions[0])
    direct.step(np.zeros((1, 4)))
    assert np.array_equal(delayed.states, direct.states)
    assert np.all(delayed.actuator_force == 0.0)  # the first command has not arrived yet
    for j in range(1, len(actions)):
        delayed.step(actions[j])
        direct.step(actions[j - 1])
        assert np.array_equal(delayed.states, direct.states)
        if j == 1:
            assert np.all(delayed.actuator_force != 0.0)  # the first command arrives one step late
    # and without delay a command acts within its own step
    fresh = v1_task(config=undelayed)
    fresh.seed_rows(np.array([0]), [5])
    fresh.reset_rows(np.array([0]))
    fresh.step(actions[0])
    assert np.all(fresh.actuator_force != 0.0)


def test_failed_and_stuck_actuators():
    task = v1_task(2)
    task.seed_rows(np.arange(2), [0, 1])
    task.reset_rows(np.array([0]), {"failed_actuator": "frame_yaw"})
    task.reset_rows(np.array([1]), {"stuck_actuator": "frame_lateral", "stuck_command": 0.4})
    assert task.scenario(0)["failed_actuator"] == "frame_yaw" and task.scenario(1)["stuck_actuator"] == "frame_lateral"
    rng = np.random.default_rng(0)
    for _ in range(20):
        task.step(rng.uniform(-1, 1, (2, 4)))
        assert task.actuator_force[0, 1] == 0.0
        assert task.actuator_force[1, 0] == 0.4 * 10e3
    assert np.all(task.actuator_force[0, [0, 2, 3]] != 0.0)


# ---- sensors -----------------------------------------------------------------------------------
def test_sensor_noise_and_bias_match_their_specification():
    """Filters wide open (weight ~1): measured - true = bias + noise, per channel, with the noise
    rms of the datasheet formula density * sqrt(pi/2 * bandwidth)."""
    bandwidth = 1e4
    sensors = {name: {"bandwidth_hz": bandwidth} for name in S.SENSOR_NAMES}
    task = v1_task(config={**FIXED, "sensors": sensors})
    task.seed_rows(np.array([0]), [3])
    task.reset_rows(np.array([0]))
    errors = []
    for _ in range(3000):
        task.step(np.zeros((1, 4)))
        measured = task.obs[0, : S.N_SENSED].astype(float).copy()
        clean = task.observe(np.array([0]))[0, : S.N_SENSED].astype(float)
        errors.append((measured - clean) * task.sensor_scale[0])
    errors = np.array(errors)
    expected_rms = np.array([S.noise_rms(m.noise_density, bandwidth) for m in S.SENSOR_MODELS])
    np.testing.assert_allclose(errors.std(axis=0), expected_rms, rtol=0.06)
    assert np.all(np.abs(errors.mean(axis=0) - task.sensor_bias[0]) <= 4 * expected_rms / math.sqrt(3000))


def test_sensor_biases_are_drawn_with_their_spread_and_per_seed():
    cfg = make_config(variant="v1")["sensors"]
    biases = np.array([S.draw_biases(cfg, np.random.default_rng(s)) for s in range(3000)])
    np.testing.assert_allclose(biases.std(axis=0), [m.bias for m in S.SENSOR_MODELS], rtol=0.06)
    assert np.array_equal(S.draw_biases(cfg, np.random.default_rng(9)), S.draw_biases(cfg, np.random.default_rng(9)))


@pytest.mark.parametrize("paired", [False, True])
def test_sensor_noise_draws_are_independent_standard_normals(paired):
    """Both ways of drawing (sensors.NOISE_DRAWS): per channel unit variance, zero mean, no
    correlation between channels (the paired draw's cosine and sine branches included) or
    between samples; normal tails (fraction beyond 2 sigma 0.0455). The planted bug of a paired
    draw that reuses the cosine for the odd channel fails the correlation check."""
    n_channels, samples = 5, 20000
    table = np.zeros((n_channels, 2))
    table[:, 0] = 1.0  # no filtering: each sample is the clean value plus noise
    table[:, 1] = 1.0
    obs, filt = np.zeros((1, n_channels)), np.zeros((1, n_channels))
    state = np.array([12345], dtype=np.uint64)
    rows, one, bias = np.array([0]), np.ones((1, n_channels)), np.zeros((1, n_channels))
    draws = np.empty((samples, n_channels))
    for k in range(samples):
        obs[:] = 0.0
        S.sense_rows(rows, obs, filt, bias, one, state, table, True, 100.0, paired)
        draws[k] = obs[0]
    tolerance = 4 / math.sqrt(samples)
    assert np.all(np.abs(draws.mean(axis=0)) < tolerance)
    assert np.all(np.abs(draws.std(axis=0) - 1) < tolerance)
    corr = np.corrcoef(draws.T)
    assert np.max(np.abs(corr - np.eye(n_channels))) < tolerance
    lagged = np.corrcoef(draws[:-1, 0], draws[1:, 0])[0, 1]
    assert abs(lagged) < tolerance
    assert abs(np.mean(np.abs(draws) > 2) - 0.0455) < 0.005


def test_sensor_noise_draws_are_checked_by_name():
    with pytest.raises(ConfigError, match="'sensors.noise_draws' = 'both' is not allowed; allowed: per_channel, paired"):
        make_config({"sensors": {"noise_draws": "both"}}, variant="v1")
    assert make_config(variant="v3")["sensors"]["noise_draws"] == "paired"
    assert make_config(variant="v2")["sensors"]["noise_draws"] == "per_channel"


def test_sensor_filter_has_the_first_order_step_response():
    """A unit step sampled every dt: y_n = 1 - exp(-2 pi f_c n dt), the continuous filter's."""
    dt, fc = 0.01, 7.0
    table = np.array([[S.filter_weight(fc, dt), 0.0]])
    obs, filt = np.zeros((1, 1)), np.zeros((1, 1))
    state = np.ones(1, dtype=np.uint64)
    rows, one = np.array([0]), np.ones((1, 1))
    S.sense_rows(rows, obs, filt, np.zeros((1, 1)), one, state, table, True, 10.0)
    for n in range(1, 20):
        obs[0, 0] = 1.0
        S.sense_rows(rows, obs, filt, np.zeros((1, 1)), one, state, table, False, 10.0)
        assert obs[0, 0] == pytest.approx(1 - math.exp(-2 * math.pi * fc * n * dt), rel=1e-12)


# ---- track ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("level", list(ALIGNMENT_LEVELS))
def test_track_level_meets_its_mean_to_peak_limit(level):
    profile = alignment_profile_at_level(level, n_samples=2**16)
    n = int(200.0 / profile.dx)
    sections = np.abs(profile.values[: (profile.values.size // n) * n].reshape(-1, n)).max(axis=1)
    assert np.median(sections) == pytest.approx(ALIGNMENT_LEVELS[level], rel=1e-9)
    assert 2.0 < section_crest_factor(profile) < 4.5


def test_v1_runs_on_the_alert_level_track():
    task = v1_task()
    assert task.config["track"]["level"] == "alert"
    assert task.track.rms == pytest.approx(ALIGNMENT_LEVELS["alert"] / section_crest_factor(task.track))


# ---- scenarios -----------------------------------------------------------------------------------
def test_randomisation_draws_inside_named_ranges_and_per_seed():
    task = HuntingTask(1, make_config({"speed": {"start_kmh": 300.0, "end_kmh": 300.0, "accel": 0.0}}, variant="v1"))
    ranges = task.config["randomize"]
    seen = []
    for seed in range(40):
        task.seed_rows(np.array([0]), [seed])
        task.reset_rows(np.array([0]))
        s = task.scenario(0)
        seen.append(s)
        assert ranges["conicity"][0] <= s["conicity"] <= ranges["conicity"][1]
        assert task.P[0, bogie_env.dynamics.P_LAM] == s["conicity"]
        for name in ("primary_longitudinal_stiffness", "primary_lateral_stiffness", "creep_factor", "damper_factor", "axle_load"):
            assert ranges[name][0] <= s[name] <= ranges[name][1]
        assert all(ranges["actuator_gain"][0] <= g <= ranges["actuator_gain"][1] for g in s["actuator_gain"].values())
    faults = [s for s in seen if s["failed_actuator"] or s["stuck_actuator"]]
    assert 0 < len(faults) < 20
    task.seed_rows(np.array([0]), [7])
    task.reset_rows(np.array([0]))
    assert task.scenario(0) == seen[7]


def test_reset_options_pin_a_scenario():
    task = v1_task()
    task.seed_rows(np.array([0]), [0])
    task.reset_rows(np.array([0]), {"conicity": 0.2, "creep_factor": 0.5, "failed_actuator": "frame_yaw"})
    s = task.scenario(0)
    assert s["conicity"] == 0.2 and s["creep_factor"] == 0.5 and s["failed_actuator"] == "frame_yaw"
    nominal = v1_task()
    nominal.seed_rows(np.array([0]), [0])
    nominal.reset_rows(np.array([0]), {"conicity": 0.2})
    for name in ("P_F11", "P_F12", "P_F22", "P_F33"):
        k = getattr(bogie_env.dynamics, name)
        assert task.P[0, k] == pytest.approx(0.5 * nominal.P[0, k], rel=1e-12)


@pytest.mark.parametrize(
    "options,message",
    [
        ({"conicity": 0.9}, "reset option 'conicity' = 0.9"),
        ({"failed_actuator": "bogus"}, "'failed_actuator' = 'bogus' is not an active channel"),
        ({"failed_actuator": "frame_yaw", "stuck_actuator": "frame_lateral"}, "give at most one"),
        ({"actuator_gain": {"nope": 1.0}}, "unknown channel 'nope'"),
        ({"conicty": 0.2}, "unknown reset option"),
    ],
)
def test_bad_reset_options_name_the_problem(options, message):
    task = v1_task()
    task.seed_rows(np.array([0]), [0])
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        task.reset_rows(np.array([0]), options)


@pytest.mark.parametrize(
    "randomize,message",
    [
        ({"conicity": [0.0, 0.3]}, "randomize.conicity"),
        ({"actuator_failure_probability": 0.7, "actuator_stuck_probability": 0.7}, "must be <= 1"),
        ({"conicity": [0.1, 0.2], "lam": [1.0, 2.0]}, "both 'conicity' and 'lam'"),
    ],
)
def test_bad_randomize_config_names_the_entry(randomize, message):
    with pytest.raises(ConfigError, match=message):
        make_config({"randomize": randomize}, variant="v1")


# ---- integration -------------------------------------------------------------------------------
def test_effective_eigenvalue_equals_an_rk4_run():
    lam, h = complex(-10.0, 2 * math.pi * 85), 1e-3
    y, f = 1.0 + 0j, lambda y: lam * y
    for _ in range(100):
        k1 = f(y)
        k2 = f(y + h / 2 * k1)
        k3 = f(y + h / 2 * k2)
        k4 = f(y + h * k3)
        y += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert y == pytest.approx(np.exp(100 * h * rk4_effective_eigenvalue(np.array([lam]), h)[0]), rel=1e-9)


def test_accuracy_criterion_rejects_the_stable_step(paper_model):
    """The v0 step (stability only) damps the wheelset modes far too much; v1's does not."""
    v0 = HuntingTask(1, make_config())
    choice = accurate_substep(paper_model, 300 / 3.6, 600 / 3.6, 0.01, tolerance=0.1)
    from bogie_env.integrate import spectrum

    eig = spectrum(paper_model, np.linspace(300 / 3.6, 600 / 3.6, 7)).ravel()
    assert eigenvalue_errors(eig, 0.01 / v0.n_sub)[0] > 1.0  # the decay rate off by > 100 %
    assert max(eigenvalue_errors(eig, choice.substep)) <= 0.1
    assert choice.n_sub > v0.n_sub
    task = v1_task(config={**FIXED, "speed": {"start_kmh": 300.0, "end_kmh": 600.0, "accel": 1.0}})
    assert task.n_sub >= choice.n_sub


def test_v1_state_converges_when_the_step_halves():
    """Closed loop with the v1 delay, 2 s at 400 km/h with conicity 0.1: the chosen step and its
    half agree to a small fraction of the motion; the stability-only step does not."""
    cfg = {**FIXED, "speed": {"start_kmh": 400.0, "end_kmh": 400.0, "accel": 0.0}}
    finals = {}
    chosen = v1_task(config=cfg).n_sub
    for n_sub in (2, chosen, 2 * chosen):
        task = v1_task(config={**cfg, "integration": {"n_sub": n_sub}})
        task.seed_rows(np.array([0]), [2])
        task.reset_rows(np.array([0]), {"conicity": 0.1})
        for _ in range(200):
            obs = task.obs[0]
            task.step(np.clip(-0.5 * obs[[2, 4, 4, 5]], -1, 1)[None])
        finals[n_sub] = task.states[0].copy()
    scale = np.max(np.abs(finals[2 * chosen]))
    assert np.max(np.abs(finals[chosen] - finals[2 * chosen])) < 0.02 * scale
    assert np.max(np.abs(finals[2] - finals[2 * chosen])) > np.max(np.abs(finals[chosen] - finals[2 * chosen]))


def test_v1_ids_make_and_named_ranges_are_documented():
    env = gym.make("Bogie/Hunting-v1")
    doc = type(env.unwrapped).__doc__
    for name in list(RANGES) + ["Bogie/HuntingPassive-v1", "alert", "delay_steps", "rate_limit"]:
        assert name in doc, name
    assert gym.make("Bogie/HuntingPassive-v1").unwrapped.task.passive


def test_evaluate_names_the_env_it_ran(capsys):
    import json

    from bogie_agents.cli import main

    assert main(["evaluate", "--env", "Bogie/Hunting-v9", "--policy", "passive", "--parts", "ramp", "--json"]) == 2
    assert "--env 'Bogie/Hunting-v9' is not a bogie-env id" in capsys.readouterr().err
    env_config = {"speed": {"start_kmh": 300.0, "end_kmh": 310.0, "accel": 5.0}}
    import tempfile, yaml  # noqa: E401

    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as handle:
        yaml.safe_dump(env_config, handle)
    # protocol v1's ramp part (v0 ids): the JSON names the env and its version
    assert main(["evaluate", "--env", "Bogie/HuntingPassive-v0", "--env-config", handle.name, "--policy", "passive",
                 "--parts", "ramp", "--json"]) == 0  # fmt: skip
    payload = json.loads(capsys.readouterr().out)
    assert payload["env_id"] == "Bogie/HuntingPassive-v0" and payload["env_version"] == "v0"
    assert payload["policies"][0]["ramp"]["start_kmh"] == 300.0
