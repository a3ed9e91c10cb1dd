"""The curving columns (``bogie_agents.curving_evaluation``): the route runs against the
steady-state solver, and the columns' bookkeeping."""

import math

import numpy as np
import pytest

from bogie_agents.curving_evaluation import CurvingSettings, _sliding, curving_columns, steady_state_check, sum_y_limits_n


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


def test_passive_columns_have_no_excess_over_themselves():
    settings = CurvingSettings(seeds=2, routes=("conventional-1500",), max_distance_m=250.0)
    result = curving_columns("passive", settings=settings, progress=False)
    route = result["routes"]["conventional-1500"]
    assert route["speed_kmh"] == pytest.approx(180.0)
    assert route["seeds"] == [0, 1] and route["blown_up"] == 0
    for column, excess in route["excess_over_passive"].items():
        assert excess["mean"] == 0.0 and route["no_worse_than_passive"][column]
    assert route["wear_number_n"] > 0 and math.isfinite(route["max_sum_y_rms_n"])
    assert route["sum_y_rms_limit_n"] == pytest.approx(30e3)


def test_curving_is_a_part_of_protocol_v2():
    from bogie_agents.stability_protocol import available_parts

    assert "curving" in available_parts()
