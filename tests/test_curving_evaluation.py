"""The curving columns (``bogie_agents.evaluation.curving_evaluation``): the route runs against the
steady-state solver, and the columns' bookkeeping."""

import math
from dataclasses import replace

import numpy as np
import pytest

from bogie_agents.evaluation import curving_evaluation
from bogie_agents.evaluation.curving_evaluation import CurvingSettings, _sliding, curving_columns, steady_state_check, sum_y_limits_n


def test_route_run_on_a_constant_curve_reaches_the_steady_state_of_bogie_curving():
    """Passive bogie, perfect track, 1.5 km of a constant curve: the env's curving quantities at
    the end of the curve match the steady-state solver within 1e-6 relative (30 s in the curve:
    the entry transient has decayed to rounding, measured 4e-15; docs/results.md)."""
    check = steady_state_check(radius_m=1500.0, cant_m=0.15, speed_kmh=180.0, direction="right")
    for name, difference in check["relative_difference"].items():
        assert difference < 1e-6, (name, check["route_run"][name], check["steady_state"][name])


def test_sliding_windows_against_direct_sums():
    values = np.random.default_rng(0).normal(size=(50, 2))
    rms = _sliding(values, 10, 5, "rms")
    direct = np.array([np.sqrt((values[s : s + 10] ** 2).mean(axis=0)) for s in range(0, 41, 5)])
    np.testing.assert_allclose(rms, direct, rtol=1e-12)
    mean = _sliding(values, 4, 1, "mean")
    np.testing.assert_allclose(mean[7], values[7:11].mean(axis=0), rtol=1e-12)
    assert sum_y_limits_n(150e3) == (30e3, 60e3)


def test_passive_columns_have_no_excess_over_themselves(monkeypatch):
    runs = []
    real_run_routes = curving_evaluation.run_routes
    monkeypatch.setattr(curving_evaluation, "_PASSIVE_CACHE", {})
    monkeypatch.setattr(curving_evaluation, "run_routes", lambda policy, *a, **k: runs.append(policy) or real_run_routes(policy, *a, **k))
    settings = CurvingSettings(seeds=2, routes=("conventional-1500",), max_distance_m=250.0)
    result = curving_columns("passive", settings=settings, progress=False)
    assert len(runs) == 1  # passive is its own reference: one run, not two identical ones
    route = result["routes"]["conventional-1500"]
    assert route["speed_kmh"] == pytest.approx(180.0)
    assert route["seeds"] == [0, 1] and route["blown_up"] == 0
    for column, excess in route["excess_over_passive"].items():
        assert excess["mean"] == 0.0 and route["no_worse_than_passive"][column]
    assert route["wear_number_n"] > 0 and math.isfinite(route["max_sum_y_rms_n"])
    assert route["sum_y_rms_limit_n"] == pytest.approx(30e3)


def test_protocol_v2_part_curving_runs_every_route_with_the_protocol_seed_and_label(monkeypatch):
    """``bogie evaluate --parts curving``: the part hands the controller (built for the routes),
    the protocol's seed and every shipped route to the curving columns, under the protocol's label."""
    from bogie_agents.evaluation.stability_protocol import Settings, evaluate_policy_v2
    from bogie_env.route import available_routes

    runs = []

    def fake_run_routes(policy, env_config, settings, progress=None):
        runs.append((policy.name, policy.observation_type, settings))
        per_seed = {column: [1.0] * settings.seeds for column in curving_evaluation.COMPARED}
        return {name: {"per_seed": per_seed, **{c: 1.0 for c in per_seed}} for name in settings.routes or available_routes()}

    monkeypatch.setattr(curving_evaluation, "_PASSIVE_CACHE", {})
    monkeypatch.setattr(curving_evaluation, "run_routes", fake_run_routes)
    result = evaluate_policy_v2("lqr", settings=Settings(seed=7, progress=False), parts=("curving",), label="my-lqr")
    columns = result["curving"]
    assert columns["policy"] == "my-lqr"
    assert sorted(columns["routes"]) == sorted(available_routes())
    assert columns["settings"]["seed"] == 7
    assert sorted((name, observation, settings.seed) for name, observation, settings in runs) == [
        ("lqr", "state", 7), ("passive", "sensors", 7)]


def test_each_controller_runs_once_and_passive_once_per_settings(monkeypatch):
    """The bookkeeping of :func:`curving_columns` with a stand-in for the route runs whose every
    call returns a different result: a policy's columns are its own run's, passive's are the one
    passive run's (never a second passive run, which would hide behind a zero excess)."""
    calls = []

    def fake_run_routes(policy, env_config, settings, progress=None):
        calls.append(getattr(policy, "name", policy))
        value = float(len(calls))
        per_seed = {column: [value, value + 1.0] for column in curving_evaluation.COMPARED}
        return {"conventional-1500": {"per_seed": per_seed, **{c: value + 0.5 for c in per_seed}}}

    monkeypatch.setattr(curving_evaluation, "_PASSIVE_CACHE", {})
    monkeypatch.setattr(curving_evaluation, "run_routes", fake_run_routes)
    settings = CurvingSettings(seeds=2, routes=("conventional-1500",))
    passive = curving_columns("passive", settings=settings, progress=False)["routes"]["conventional-1500"]
    assert len(calls) == 1
    assert all(e["mean"] == 0.0 for e in passive["excess_over_passive"].values())
    skyhook = curving_columns("skyhook", settings=settings, progress=False)["routes"]["conventional-1500"]
    assert len(calls) == 2  # passive comes from the cache
    column = curving_evaluation.COMPARED[0]
    assert skyhook["per_seed"][column] == [2.0, 3.0]
    assert skyhook["excess_over_passive"][column]["mean"] == pytest.approx(1.0)
    assert skyhook["excess_over_passive"][column]["passive"] == pytest.approx(1.5)
    given = {"conventional-1500": {"per_seed": {c: [10.0, 10.0] for c in curving_evaluation.COMPARED},
                                   **{c: 10.0 for c in curving_evaluation.COMPARED}}}  # fmt: skip
    lqr = curving_columns("lqr", settings=replace(settings, seed=5), progress=False, passive=given)["routes"]["conventional-1500"]
    assert len(calls) == 3  # a given passive is used, not run
    assert lqr["excess_over_passive"][column]["mean"] == pytest.approx(3.0 + 0.5 - 10.0)
