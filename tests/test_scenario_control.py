"""Scenario control through the public API: faults off on request, the scenario summary at
reset, one sensor-noise knob, the per-step criterion fields, autoreset with the last options,
and the supported speed range.

Oracles: a fault switched off leaves the actuator healthy and the other draws where they
were; the summary's initial offsets rebuild the start state from the equilibrium; one scale
factor equals editing every channel; ΣY equals the stability protocol's function and, from a
second code path, the per-wheel Y; flange flags on states placed on either flange; an
autoreset row restarts exactly like a row reset by hand with the same options.
"""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bogie_agents.evaluation.stability_protocol import flange_touching
from bogie_agents.training.vec_env import BogieHuntingSB3VecEnv
from bogie_env.actuators import H_GAIN, H_HELD_FORCE
from bogie_env.analysis.en14363 import running_signals_rows
from bogie_env.contact import creep_coefficients
from bogie_env.envs import scenario as scenarios
from bogie_env.dynamics import P_WPA, BogieModel, state_index
from bogie_env.envs.config import bogie_params, make_config
from bogie_env.envs.hunting_env import BogieHuntingEnv
from bogie_env.envs.sensors import S_NOISE_RMS, SENSOR_NAMES
from bogie_env.envs import task as task_module
from bogie_env.envs.task import CRITERION_FIELDS, FANCY_RESET_MIN_ROWS, Y1, Y2, HuntingTask
from bogie_env.envs.vector import BogieHuntingVectorEnv
from bogie_env.params import ConfigError
from bogie_env.track import ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2

#: v1 at one speed, nothing drawn: a quick, controlled v1 world.
FIXED = {"speed": {"start_kmh": 300.0, "end_kmh": 300.0, "accel": 0.0}, "randomize": {}}
#: every episode draws a fault: failed with probability 1/2, else stuck
ALWAYS_FAULTY = {**FIXED, "randomize": {"conicity": [0.05, 0.2], "actuator_failure_probability": 0.5,
                                        "actuator_stuck_probability": 0.5}}  # fmt: skip
SHORT = {"speed": {"start_kmh": 300.0, "end_kmh": 306.0, "accel": 5.0}}  # 0.33 s episodes
CRITERION = {"info": {"criterion": True}}


def v1_task(config=FIXED, n=1):
    return HuntingTask(n, make_config(config, variant="v1"))


def reset(task, seed, options=None):
    task.seed_rows(np.array([0]), [seed])
    task.reset_rows(np.array([0]), options)
    return task.scenario(0)


# ---- faults off on request ---------------------------------------------------------------------
def test_no_fault_options_switch_the_drawn_faults_off_without_moving_other_draws():
    task = v1_task(ALWAYS_FAULTY)
    for seed in range(12):
        drawn = reset(task, seed)
        assert (drawn["failed_actuator"] is None) != (drawn["stuck_actuator"] is None)  # always one fault
        clean = reset(task, seed, dict(scenarios.NO_FAULTS))
        assert clean["failed_actuator"] is None and clean["stuck_actuator"] is None
        assert clean["conicity"] == drawn["conicity"]  # the random stream is not shifted
        assert np.all(task.health[0, H_GAIN] == 1.0) and np.all(np.isnan(task.health[0, H_HELD_FORCE]))
        # each "none" only switches its own fault off
        only_failed_off = reset(task, seed, {"failed_actuator": "none"})
        assert only_failed_off["failed_actuator"] is None and only_failed_off["stuck_actuator"] == drawn["stuck_actuator"]
        only_stuck_off = reset(task, seed, {"stuck_actuator": "none"})
        assert only_stuck_off["stuck_actuator"] is None and only_stuck_off["failed_actuator"] == drawn["failed_actuator"]


def test_a_fault_free_episode_drives_every_channel():
    """With the failure probability 1, every channel the action drives gives force only when
    asked for a fault-free episode."""
    config = {**FIXED, "randomize": {"actuator_failure_probability": 1.0}}
    env = BogieHuntingEnv(config, variant="v1")
    for options, expect_all in ((None, False), ({"failed_actuator": "none"}, True)):
        env.reset(seed=3, options=options)
        for _ in range(5):
            _, _, _, _, info = env.step(np.ones(4))
        assert bool(np.all(np.abs(info["actuator_force"]) > 0)) == expect_all


@pytest.mark.parametrize(
    "options,message",
    [
        ({"failed_actuator": "None"}, "'failed_actuator' = 'None' is not an active channel; allowed: 'none'"),
        ({"stuck_actuator": 3}, "'stuck_actuator' = 3 is not an active channel"),
        ({"failed_actuator": "frame_yaw", "stuck_actuator": "frame_lateral"}, "give at most one"),
    ],
)
def test_bad_fault_options_name_the_value_and_what_is_allowed(options, message):
    with pytest.raises(ConfigError, match=message):
        reset(v1_task(), 0, options)


def test_a_fault_with_the_other_switched_off_is_allowed():
    s = reset(v1_task(ALWAYS_FAULTY), 1, {"failed_actuator": "frame_yaw", "stuck_actuator": "none"})
    assert s["failed_actuator"] == "frame_yaw" and s["stuck_actuator"] is None


# ---- the scenario summary at reset --------------------------------------------------------------
def test_reset_info_states_every_drawn_value():
    env = BogieHuntingEnv({"randomize": {**ALWAYS_FAULTY["randomize"], "damper_factor": [0.5, 1.0], "Csy": [0.5, 1.0]}},
                          variant="v1")  # fmt: skip
    _, info = env.reset(seed=4, options={"start_kmh": 250.0})
    task = env.unwrapped.task
    summary = info["scenario"]
    fields = {f.name for f in dataclasses.fields(scenarios.Scenario)} - {"factors"}
    assert fields <= set(summary) and summary["params"].keys() == {"Csy"}
    assert summary == {**task.scenario(0), **{k: summary[k] for k in set(summary) - set(task.scenario(0))}}
    assert (summary["failed_actuator"] is None) != (summary["stuck_actuator"] is None)
    assert summary["start_kmh"] == 250.0 and summary["end_kmh"] == 600.0 and summary["accel_m_per_s2"] == 1.5
    assert summary["track_position_m"] == task.distance_m[0]
    assert summary["sensor_bias"] == dict(zip(SENSOR_NAMES, task.sensor_bias[0].tolist()))
    # the initial offsets and yaws rebuild the start state from the scenario bogie's equilibrium
    model = scenarios.scenario_model(task.base_params, task.scenarios[0], task.model)
    x = model.equilibrium(250.0 / 3.6)
    for name, value in {**summary["initial_offset_m"], **summary["initial_yaw_rad"]}.items():
        x[state_index(name)] += value
    assert np.array_equal(x, task.states[0])


def test_vector_env_reports_the_scenario_of_each_started_episode():
    vec = BogieHuntingVectorEnv(2, SHORT)
    _, info = vec.reset(seed=0)
    assert info["_scenario"].all() and [s["start_kmh"] for s in info["scenario"]] == [300.0, 300.0]
    mask = np.array([False, True])
    _, info = vec.reset(options={"reset_mask": mask, "start_kmh": 302.0})
    assert info["_scenario"].tolist() == [False, True] and info["scenario"][1]["start_kmh"] == 302.0
    seen = 0
    for _ in range(80):
        restarting = vec._autoreset.copy()
        _, _, _, _, info = vec.step(np.zeros((2, 4)))
        assert info.get("_scenario", np.zeros(2, bool)).tolist() == restarting.tolist()
        seen += int(restarting.sum())
    assert seen >= 2


# ---- one sensor-noise knob ----------------------------------------------------------------------
def _sensor_run(config, steps=30):
    task = v1_task({**FIXED, **config})
    reset(task, 5)
    obs = [task.obs.copy()]
    for _ in range(steps):
        task.step(np.zeros((1, 4)))
        obs.append(task.obs.copy())
    return task, np.array(obs)


def test_noise_and_bias_scale_equal_editing_every_channel():
    defaults = make_config(variant="v1")["sensors"]
    by_hand = {name: {"noise_density": 2.5 * defaults[name]["noise_density"], "bias": 0.5 * defaults[name]["bias"]}
               for name in SENSOR_NAMES}  # fmt: skip
    a, obs_a = _sensor_run({"sensors": {"noise_scale": 2.5, "bias_scale": 0.5}})
    b, obs_b = _sensor_run({"sensors": by_hand})
    assert np.array_equal(a.sensor_table, b.sensor_table)
    np.testing.assert_allclose(a.sensor_bias, b.sensor_bias, rtol=1e-12)
    np.testing.assert_allclose(obs_a, obs_b, rtol=0, atol=1e-6)
    nominal, obs_n = _sensor_run({})
    np.testing.assert_allclose(a.sensor_table[:, S_NOISE_RMS], 2.5 * nominal.sensor_table[:, S_NOISE_RMS], rtol=1e-12)
    assert not np.allclose(obs_a, obs_n)


def test_zero_scales_measure_the_clean_filtered_channels():
    off, obs_off = _sensor_run({"sensors": {"noise_scale": 0.0, "bias_scale": 0.0}})
    zero = {name: {"noise_density": 0.0, "bias": 0.0} for name in SENSOR_NAMES}
    _, obs_zero = _sensor_run({"sensors": zero})
    assert np.all(off.sensor_bias == 0.0) and np.array_equal(obs_off, obs_zero)


@pytest.mark.parametrize("key,value", [("noise_scale", -1.0), ("bias_scale", "big"), ("noise_scale", math.inf)])
def test_bad_scales_name_the_key(key, value):
    with pytest.raises(ConfigError, match=f"sensors.{key}"):
        make_config({"sensors": {key: value}}, variant="v1")


def test_the_lqg_design_sees_the_noise_scale():
    from bogie_agents.controllers.lqr import LQGController

    def errors(config):  # the filter's sensor errors, without designing the whole controller
        config = make_config(config, variant="v1")
        return LQGController.sensor_errors(SimpleNamespace(config=config, model=BogieModel(bogie_params(config))))

    (n0, b0), (n1, b1) = errors(None), errors({"sensors": {"noise_scale": 3.0, "bias_scale": 2.0}})
    np.testing.assert_allclose(n1, 3.0 * n0, rtol=1e-12)
    np.testing.assert_allclose(b1, 2.0 * b0, rtol=1e-12)


# ---- per-step criterion fields ------------------------------------------------------------------
def test_criterion_fields_agree_with_the_stability_protocol_and_the_wheel_forces():
    env = BogieHuntingEnv({**FIXED, **CRITERION, "large_perturbation_probability": 1.0}, variant="v1")  # on the flange
    _, info = env.reset(seed=2)
    task = env.unwrapped.task
    rng = np.random.default_rng(0)
    contact_steps = 0
    for k in range(60):
        if k:
            _, _, _, _, info = env.step(rng.uniform(-1, 1, 4))
        assert set(CRITERION_FIELDS) <= set(info)
        signals = np.zeros((1, 3))
        running_signals_rows(task.sim.rows, signals)
        assert np.array_equal(info["sum_y_n"], signals[0, :2])  # the protocol's ΣY, bit for bit
        assert np.array_equal(info["wheelset_lateral_rel_rail_m"], task.relative_lateral_m[0])
        assert bool(info["flange_contact"].any()) == bool(flange_touching(task)[0])
        assert np.array_equal(info["flange_contact"], info["wheel_flange_contact"].any(axis=1))
        # per wheelset, the rails' lateral force on it is Y_right - Y_left (each + outwards)
        q = 0.5 * task.P[0, P_WPA]
        np.testing.assert_allclose(q * (info["wheel_y_over_q"][:, 1] - info["wheel_y_over_q"][:, 0]), info["sum_y_n"],
                                   rtol=1e-9, atol=1e-6)  # fmt: skip
        assert info["y_over_q"] == info["wheel_y_over_q"].max()
        contact_steps += int(info["flange_contact"].any())
    assert contact_steps > 0


def test_flange_contact_flags_the_wheel_on_the_flange():
    task = v1_task()
    reset(task, 0)
    delta = task.delta(0)
    x = task.states.copy()
    track = task.sim.track_sample[0]
    x[0, Y1] = track[ALIGNMENT_WHEELSET1] + delta + 1e-3  # wheelset 1 on its left flange
    x[0, Y2] = track[ALIGNMENT_WHEELSET2] - delta - 1e-3  # wheelset 2 on its right flange
    task.set_states(x)
    q = task.criterion_quantities()
    assert q["wheel_flange_contact"][0].tolist() == [[True, False], [False, True]]
    assert q["flange_contact"][0].tolist() == [True, True]
    np.testing.assert_allclose(q["wheelset_lateral_rel_rail_m"][0], [delta + 1e-3, -delta - 1e-3])
    y_over_q = q["wheel_y_over_q"][0]
    # the flanging wheels push their rails outwards, more than the other wheel of their wheelset
    assert y_over_q[0, 0] > max(0.1, y_over_q[0, 1]) and y_over_q[1, 1] > max(0.1, y_over_q[1, 0])
    assert q["sum_y_n"][0, 0] < 0 < q["sum_y_n"][0, 1]  # the rails push the wheelsets back to the centre
    x[0, Y1] = track[ALIGNMENT_WHEELSET1] + 0.5 * delta
    x[0, Y2] = track[ALIGNMENT_WHEELSET2]
    task.set_states(x)
    assert not task.criterion_quantities()["wheel_flange_contact"].any()


def test_vector_env_criterion_fields_match_the_single_envs():
    n, seed = 3, 5
    vec = BogieHuntingVectorEnv(n, {**SHORT, **CRITERION})
    singles = [BogieHuntingEnv({**SHORT, **CRITERION}) for _ in range(n)]
    _, vinfo = vec.reset(seed=seed)
    infos = [e.reset(seed=seed + i)[1] for i, e in enumerate(singles)]
    for _ in range(10):
        for key in CRITERION_FIELDS:
            assert vinfo[f"_{key}"].all()
            for i in range(n):
                assert np.array_equal(vinfo[key][i], infos[i][key]), key
        actions = np.full((n, 4), 0.5)
        _, _, _, _, vinfo = vec.step(actions)
        infos = [e.step(actions[i])[4] for i, e in enumerate(singles)]


def test_criterion_fields_are_off_by_default_and_on_when_asked():
    for config, present in ((None, False), (CRITERION, True)):
        _, info = BogieHuntingEnv(config).reset(seed=0)
        _, vinfo = BogieHuntingVectorEnv(2, config).reset(seed=0)
        assert (set(CRITERION_FIELDS) <= set(info)) == present and (set(CRITERION_FIELDS) <= set(vinfo)) == present
        assert present or not set(CRITERION_FIELDS) & (set(info) | set(vinfo))
    with pytest.raises(ConfigError, match="'info.criterion' = 1"):
        make_config({"info": {"criterion": 1}})
    with pytest.raises(ConfigError, match="'info.criterion' = 1"):
        make_config({"info": {"criterion": 1}})


# ---- autoreset with the last options ------------------------------------------------------------
def _run_to_restart(vec, steps=60):
    """Step until every row has restarted at least once; returns the scenario of each row's
    first restart."""
    first: dict[int, dict] = {}
    for _ in range(steps):
        _, _, _, _, info = vec.step(np.zeros((vec.num_envs, 4)))
        for i in np.nonzero(info.get("_scenario", np.zeros(vec.num_envs, bool)))[0]:
            first.setdefault(int(i), info["scenario"][i])
        if len(first) == vec.num_envs:
            return first
    raise AssertionError(f"only rows {sorted(first)} restarted")


@pytest.mark.parametrize("reuse", [False, True])
def test_autoreset_reuses_each_rows_last_options_when_asked(reuse):
    config = {**SHORT, "autoreset": {"reuse_options": reuse}}
    vec = BogieHuntingVectorEnv(2, config)
    vec.reset(seed=0, options={"start_kmh": 303.0})
    vec.reset(options={"reset_mask": np.array([False, True]), "start_kmh": 304.0, "params": {"Csy": 0.8}})
    first = _run_to_restart(vec)
    if reuse:
        assert first[0]["start_kmh"] == 303.0 and first[0]["params"] == {}
        assert first[1]["start_kmh"] == 304.0 and first[1]["params"] == {"Csy": 0.8}
    else:
        assert first[0]["start_kmh"] == first[1]["start_kmh"] == 300.0 and first[1]["params"] == {}


def test_an_autoreset_row_restarts_like_a_row_reset_by_hand():
    options = {"start_kmh": 303.0, **scenarios.NO_FAULTS}
    config = {**SHORT, "randomize": ALWAYS_FAULTY["randomize"]}
    vec = BogieHuntingVectorEnv(1, {**config, "autoreset": {"reuse_options": True}}, variant="v1")
    vec.reset(seed=9, options=options)
    single = BogieHuntingEnv(config, variant="v1")
    single.reset(seed=9, options=options)
    while True:  # the single env's episode end, then its hand-made reset with the same options
        vobs, _, vterm, vtrunc, _ = vec.step(np.zeros((1, 4)))
        _, _, term, trunc, _ = single.step(np.zeros(4))
        if term or trunc:
            break
    vobs, _, _, _, vinfo = vec.step(np.zeros((1, 4)))  # NEXT_STEP: the reset
    obs, info = single.reset(options=options)
    assert np.array_equal(vobs[0], obs) and vinfo["scenario"][0] == info["scenario"]
    assert info["scenario"]["failed_actuator"] is None and info["scenario"]["stuck_actuator"] is None


def test_sb3_vec_env_reuses_the_last_options_when_asked():
    for reuse, expected in ((False, 300.0), (True, 303.0)):
        env = BogieHuntingSB3VecEnv(2, {**SHORT, "autoreset": {"reuse_options": reuse}}, seed=0)
        env.set_options({"start_kmh": 303.0})
        env.reset()
        assert [r["scenario"]["start_kmh"] for r in env.reset_infos] == [303.0, 303.0]
        for _ in range(40):
            env.step_async(np.zeros((2, 4)))
            _, _, dones, _ = env.step_wait()
            if dones.any():
                break
        assert dones.any()
        for i in np.nonzero(dones)[0]:
            assert env.reset_infos[i]["scenario"]["start_kmh"] == expected
            assert env.task.speed_kmh[i] == expected


# ---- the supported speed range ------------------------------------------------------------------
def test_supported_kmh_widens_the_speed_range_without_moving_the_default_ramp():
    narrow = BogieHuntingEnv(FIXED, variant="v1")
    with pytest.raises(ConfigError, match=r"start_kmh=40.*'speed.supported_kmh' widens it"):
        narrow.reset(seed=0, options={"start_kmh": 40.0})
    wide = BogieHuntingEnv({**FIXED, "speed": {**FIXED["speed"], "supported_kmh": [40.0, 600.0]}}, variant="v1")
    assert wide.unwrapped.task.speed_limits() == pytest.approx((40.0 / 3.6, 600.0 / 3.6))
    _, info = wide.reset(seed=0)
    assert info["speed_kmh"] == 300.0  # the default episode is unchanged
    _, info = wide.reset(seed=0, options={"start_kmh": 40.0, "end_kmh": 40.0})
    assert info["speed_kmh"] == 40.0 and info["scenario"]["start_kmh"] == 40.0
    with pytest.raises(ConfigError, match="speed.supported_kmh"):
        make_config({"speed": {"supported_kmh": [10.0, 600.0]}})


@pytest.mark.parametrize("variant", [None, "v1"])
def test_the_docstring_states_each_versions_speed_range(variant):
    speed = make_config(variant=variant)["speed"]
    text = " ".join(BogieHuntingEnv.__doc__.split())
    assert f"{speed['start_kmh']:g}-{speed['end_kmh']:g} km/h" in text
    assert "speed.supported_kmh" in text



def test_route_info_keeps_its_fields_and_agrees_with_the_criterion_fields():
    env = BogieHuntingEnv(CRITERION, variant="v1_route")
    _, info = env.reset(seed=1, options={"route": "s-curve"})
    rng = np.random.default_rng(1)
    for _ in range(30):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        q = env.unwrapped.task.criterion_quantities()
        assert np.array_equal(info["flange_contact"], q["flange_contact"][0])
        assert info["y_over_q"] == pytest.approx(q["y_over_q"][0], rel=1e-9)
        np.testing.assert_allclose(info["guiding_force_n"], -info["sum_y_n"], rtol=1e-9, atol=1e-6)


# ---- a reset's scenario bogie, and resets of many rows at once ----------------------------------
def _scenario_model_by_hand(base, s):
    """The documented chain, step by step: factors multiply (per parameter), the conicity
    replaces lam, the creep factor scales the creep coefficients of the bogie so changed."""
    factors = dict(s.factors)
    for name, key in (("primary_longitudinal_stiffness", "Kpx"), ("primary_lateral_stiffness", "Kpy"), ("axle_load", "Wpa")):
        factors[key] = factors.get(key, 1.0) * getattr(s, name)
    for key in ("Csx", "Csy"):
        factors[key] = factors.get(key, 1.0) * s.damper_factor
    params = base.scaled(**factors)
    if s.conicity is not None:
        params = params.replace(lam=s.conicity)
    creep = creep_coefficients(params)
    params = params.replace(**{k: getattr(creep, k) * s.creep_factor for k in ("f11", "f12", "f22", "f33")})
    return BogieModel(params)


V1_DRAWS = make_config(variant="v1")["randomize"]


@pytest.mark.parametrize("randomize", [V1_DRAWS, {**V1_DRAWS, "Kpz": [0.5, 2.0], "h1": [0.8, 1.2]},
                                       {"axle_load": [0.8, 1.2], "Wpa": [0.9, 1.1], "lam": [0.5, 4.0]}])  # fmt: skip
def test_a_resets_bogie_is_its_scenarios_model_bit_for_bit(randomize):
    cfg = make_config({"randomize": randomize}, variant="v1")
    base = bogie_params(cfg)
    nominal = BogieModel(base)
    rng = np.random.default_rng(0)
    for _ in range(40):
        s = scenarios.draw_scenario(cfg["randomize"], {}, rng, ["frame_lateral"])
        expected = _scenario_model_by_hand(base, s).coefficients
        assert np.array_equal(scenarios.scenario_coefficients(base, s, nominal), expected)
        assert np.array_equal(scenarios.scenario_model(base, s, nominal).coefficients, expected)
    assert scenarios.scenario_coefficients(base, scenarios.Scenario(), nominal) is nominal.coefficients


@pytest.mark.parametrize("randomize", [V1_DRAWS, {"axle_load": [0.8, 1.2]}, {"creep_factor": [0.5, 1.0], "conicity": [0.02, 0.4]},
                                       {**V1_DRAWS, "Kpz": [0.5, 2.0]}])  # fmt: skip
def test_a_batch_of_scenarios_is_each_scenarios_model_bit_for_bit(randomize):
    """The batched chain (v1's draws: all rows at once) against the documented chain by hand,
    row by row, with some rows at exactly 1 (nothing changed) and without a conicity."""
    cfg = make_config({"randomize": randomize}, variant="v1")
    base = bogie_params(cfg)
    nominal = BogieModel(base)
    rng = np.random.default_rng(2)
    drawn = [scenarios.draw_scenario(cfg["randomize"], {}, rng, ["frame_lateral"]) for _ in range(40)]
    drawn[3] = scenarios.Scenario()
    drawn[5].creep_factor = drawn[6].axle_load = 1.0
    drawn[7].conicity = None
    rows = scenarios.scenario_coefficient_rows(base, drawn, nominal)
    assert rows.shape == (40, nominal.coefficients.size)
    few = np.concatenate([scenarios.scenario_coefficient_rows(base, drawn[k : k + 3], nominal) for k in range(0, 40, 3)])
    for s, row, row_of_few in zip(drawn, rows, few):  # an autoreset's few rows take the scalar chain
        expected = _scenario_model_by_hand(base, s).coefficients
        assert np.array_equal(row, expected) and np.array_equal(row_of_few, expected)


def test_every_scenario_field_is_batched_or_health_only():
    """A new Scenario field that changes the bogie must be applied by scenario_params and by the
    batched scenario_coefficient_rows (docs/extending.md, "Add a randomised quantity")."""
    names = {f.name for f in dataclasses.fields(scenarios.Scenario)}
    assert names == set(scenarios.BATCHED_FIELDS) | set(scenarios.HEALTH_FIELDS)


@pytest.mark.parametrize("field, value", [("primary_longitudinal_stiffness", 1e12), ("axle_load", -0.5), ("damper_factor", math.nan), ("creep_factor", 1e40),
                                          ("conicity", 7.0)])  # fmt: skip
@pytest.mark.parametrize("batch", [3, scenarios.BATCH_MIN_ROWS])
def test_a_batch_raises_the_row_by_row_error(field, value, batch):
    """An out-of-range value in one row of a batch (of a few rows, or of many) raises the error
    the row alone raises."""
    cfg = make_config(variant="v1")
    base = bogie_params(cfg)
    nominal = BogieModel(base)
    rng = np.random.default_rng(3)
    drawn = [scenarios.draw_scenario(cfg["randomize"], {}, rng, ["frame_lateral"]) for _ in range(batch)]
    setattr(drawn[2], field, value)
    with pytest.raises(ConfigError) as alone:
        scenarios.scenario_coefficients(base, drawn[2], nominal)
    with pytest.raises(ConfigError) as batched:
        scenarios.scenario_coefficient_rows(base, drawn, nominal)
    assert str(batched.value) == str(alone.value)


@pytest.mark.parametrize("variant", ["v1", "v1_route"])
def test_many_rows_reset_at_once_as_each_alone(variant):
    config = {"randomize": {**V1_DRAWS, **ALWAYS_FAULTY["randomize"]}}
    if variant == "v1":
        config["speed"] = {"start_kmh_range": [200.0, 300.0], "end_kmh": 400.0, "accel": 1.0}
    n = 10  # at least FANCY_RESET_MIN_ROWS: set with one fancy index per array, against row by row
    together, alone = (HuntingTask(n, make_config(config, variant=variant)) for _ in range(2))
    rows = np.arange(n)
    together.seed_rows(rows, list(range(10, 10 + n)))
    together.reset_rows(rows)
    for i in rows:
        alone.seed_rows(np.array([i]), [10 + i])
        alone.reset_rows(np.array([i]))
    assert {together.scenarios[i].stuck_actuator is None for i in rows} == {True, False}  # both fault kinds
    for name in ("states", "obs", "health", "sensor_bias", "sensor_scale", "episode", "info", "route_slot"):
        a, b = getattr(together, name), getattr(alone, name)
        assert np.array_equal(a, b, equal_nan=True), name
    for name in ("coefficients", "lag", "delay", "motion"):
        assert np.array_equal(getattr(together.sim, name), getattr(alone.sim, name), equal_nan=True), name
    assert all(together.scenario_summary(i) == alone.scenario_summary(i) for i in rows)


def _row_snapshot(task, i):
    return (task.states[i].copy(), task.obs[i].copy(), task.health[i].copy(), task.sensor_bias[i].copy(),
            int(task.sensor_rng[i]), task.scenario_summary(i))  # fmt: skip


def _same_snapshot(a, b):
    return all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a[:4], b[:4])) and a[4:] == b[4:]


@pytest.mark.parametrize("fancy_min_rows", [FANCY_RESET_MIN_ROWS, 1])
def test_a_row_given_twice_keeps_its_last_draw_as_if_reset_twice(fancy_min_rows, monkeypatch):
    monkeypatch.setattr(task_module, "FANCY_RESET_MIN_ROWS", fancy_min_rows)
    config = {**FIXED, "randomize": {"actuator_failure_probability": 0.4, "actuator_stuck_probability": 0.4,
                                     "actuator_gain": [0.8, 1.25]}}  # fmt: skip
    twice, by_hand = v1_task(config, n=3), v1_task(config, n=3)
    for task in (twice, by_hand):
        task.seed_rows(np.arange(3), [5, 105, 205])
    twice.reset_rows(np.array([1, 1, 0]))
    for i in (1, 1, 0):
        by_hand.reset_rows(np.array([i]))
    first = v1_task(config, n=3)
    first.seed_rows(np.arange(3), [5, 105, 205])
    first.reset_rows(np.array([1]))
    assert first.scenarios[1].stuck_actuator is not None  # row 1's first draw is faulty
    assert {twice.scenarios[1].failed_actuator, twice.scenarios[1].stuck_actuator} == {None}  # its second is not
    for i in range(3):  # the episode; the first observation's noise is drawn once per mention
        a, b = _row_snapshot(twice, i), _row_snapshot(by_hand, i)
        assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in (0, 2, 3)) and a[5] == b[5], i
    assert np.array_equal(twice.sim.lag, by_hand.sim.lag) and np.array_equal(twice.sim.delay, by_hand.sim.delay)


def test_a_reset_that_raises_changes_no_rows_episode_and_no_rows_is_a_no_op():
    task = v1_task({"randomize": V1_DRAWS}, n=4)
    task.seed_rows(np.arange(4), [0, 1, 2, 3])
    task.reset_rows(np.arange(4))
    before = [_row_snapshot(task, i) for i in range(4)]
    # Wpa x 2.3 x the drawn axle load (0.8-1.2) is in range for some rows and not for others
    with pytest.raises(ConfigError, match="Wpa"):
        task.reset_rows(np.arange(4), {"params": {"Wpa": 2.3}})
    assert all(_same_snapshot(_row_snapshot(task, i), before[i]) for i in range(4))
    task.reset_rows(np.array([], dtype=np.int64))
    assert all(_same_snapshot(_row_snapshot(task, i), before[i]) for i in range(4))
    venv = BogieHuntingVectorEnv(2, variant="v1")
    venv.reset(seed=0)
    obs, _ = venv.reset(options={"reset_mask": np.zeros(2, dtype=bool)})
    assert obs.shape == (2, venv.single_observation_space.shape[0])


def test_a_factor_on_lam_is_checked_even_where_a_conicity_replaces_it():
    task = v1_task({"randomize": {"conicity": [0.1, 0.2]}})
    with pytest.raises(ConfigError, match="'lam'"):
        reset(task, 0, {"params": {"lam": 100.0}})
