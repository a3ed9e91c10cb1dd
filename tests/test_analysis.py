"""The analysis suite: root-locus tracking, ramps, nonlinear critical speed, sensitivity."""

import json
import subprocess
import sys

import numpy as np
import pytest

from bogie_env.analysis.bifurcation import nonlinear_critical_speed, ramp_down
from bogie_env.analysis.ramp import speed_ramp
from bogie_env.analysis.root_locus import root_locus, track_modes
from bogie_env.analysis.sensitivity import one_parameter, two_parameter
from bogie_env.cli import main as cli_main
from bogie_env.dynamics import N_TRACK, BogieModel
from bogie_env.stability import critical_speed


@pytest.fixture(scope="module")
def nonlinear(paper_model):
    return nonlinear_critical_speed(paper_model, rates_kmh_per_s=(2.0, 1.0, 0.5, 0.25, 0.125))


def test_tracked_hunting_mode_is_continuous_and_crosses_at_the_critical_speed(paper_model):
    locus = root_locus(paper_model, 300.0, 600.0, 301)
    h = locus.hunting
    step = np.abs(np.diff(h))
    # 1 km/h steps: the branch moves by at most a few percent of its size per step
    assert step.max() < 0.05 * np.abs(h).max()
    k = np.nonzero(h.real >= 0)[0][0]
    assert locus.speeds_kmh[k - 1] <= critical_speed(paper_model).speed_kmh <= locus.speeds_kmh[k]


def test_tracking_follows_modes_through_a_crossing():
    """Two modes whose real parts cross: tracking keeps each branch, sorting would swap them."""
    t = np.linspace(-1, 1, 41)
    mats = np.array([np.diag([-1 + s, -s - 1 + 0.5j]) for s in t]).astype(complex)
    tracked = track_modes(mats)
    np.testing.assert_allclose(tracked[:, 0], -1 + t, atol=1e-12)
    np.testing.assert_allclose(tracked[:, 1], -t - 1 + 0.5j, atol=1e-12)


def test_ramp_envelope_turns_at_the_linear_critical_speed(paper_model):
    """Time domain against eigenvalues: on a perfect track the envelope's minimum is where
    Re(lambda) = 0, whatever the initial offset."""
    linear = critical_speed(paper_model).speed_kmh
    for offset in (1e-3, 1e-6):
        result = speed_ramp(paper_model, 345.0, 420.0, 0.1, initial_offset=offset, track_rms=0.0, frozen_every_kmh=5.0)
        assert result.growth_start_kmh == pytest.approx(linear, abs=1.5)
        assert result.onset_kmh > linear
    # frozen eigenvalues along the trajectory cross where the equilibrium's do, until hunting sets in
    assert result.frozen_crossing_kmh == pytest.approx(linear, abs=5.0)


def test_smaller_perturbation_delays_the_visible_onset(paper_model):
    onsets = [speed_ramp(paper_model, 350.0, 450.0, 0.1, off, 0.0, frozen_every_kmh=50.0).onset_kmh
              for off in (1e-3, 1e-5, 1e-7)]  # fmt: skip
    assert onsets[0] < onsets[1] < onsets[2]


def test_nonlinear_critical_speed_at_or_below_linear(nonlinear):
    assert nonlinear.value_kmh <= nonlinear.linear_critical_speed_kmh
    assert nonlinear.fixed_speed_kmh <= nonlinear.linear_critical_speed_kmh + 0.5


def test_ramp_down_converges_as_the_ramp_slows(nonlinear):
    collapse = np.array(nonlinear.collapse_kmh)
    assert np.all(np.diff(collapse) > 0)  # slower ramps collapse later (higher speed)
    gaps = np.abs(collapse - nonlinear.fixed_speed_kmh)
    assert np.all(np.diff(gaps) < 0)  # and approach the fixed-speed fold
    assert gaps[-1] < 3.0
    # extrapolated to a vanishing rate (collapse delay ~ sqrt(rate) near a fold) they meet it
    assert nonlinear.extrapolated_kmh == pytest.approx(nonlinear.fixed_speed_kmh, abs=1.0)


def test_ramp_down_bad_input(paper_model):
    with pytest.raises(ValueError, match="rate_kmh_per_s"):
        ramp_down(paper_model, 0.0, 400.0, 300.0)
    with pytest.raises(ValueError, match="must be below"):
        ramp_down(paper_model, 1.0, 300.0, 400.0)


def test_sensitivity_points_equal_direct_critical_speed_calls(paper_params):
    curve = one_parameter(paper_params, "Csy", [0.5, 1.3])
    for scale, speed in zip(curve.scales, curve.critical_speed_kmh):
        direct = critical_speed(BogieModel(paper_params.replace(Csy=paper_params.Csy * scale))).speed_kmh
        assert speed == pytest.approx(direct, abs=1e-9)
    grid = two_parameter(paper_params, ("Wpa", "Kpz"), ([0.7], [1.8]))
    direct = critical_speed(BogieModel(paper_params.scaled(Wpa=0.7, Kpz=1.8))).speed_kmh
    assert grid.critical_speed_kmh[0, 0] == pytest.approx(direct, abs=1e-9)


def test_axle_load_recomputes_the_contact(paper_params):
    """A load change grows the contact ellipse; --fixed-contact holds the creep coefficients
    at their nominal values and gives a different curve."""
    grown = one_parameter(paper_params, "Wpa", [1.4])
    fixed = one_parameter(paper_params, "Wpa", [1.4], fixed_contact=True)
    assert abs(grown.critical_speed_kmh[0] - fixed.critical_speed_kmh[0]) > 0.5


def test_default_scan_step_misses_no_crossing(paper_params):
    """The 100 km/h scan of critical_speed finds the same crossing as a 5 km/h scan over
    the sensitivity study's extreme corners."""
    for factors in ({}, {"Kpz": 0.5}, {"Kpz": 2.5}, {"Wpa": 0.5}, {"Wpa": 1.5, "Kpz": 2.5}, {"Csy": 0.5, "Kpz": 0.5}):
        model = BogieModel(paper_params.scaled(**factors))
        coarse = critical_speed(model)
        fine = critical_speed(model, scan_step_kmh=5.0)
        assert coarse.speed_kmh == pytest.approx(fine.speed_kmh, abs=0.05), factors


@pytest.mark.parametrize(
    "argv, message",
    [
        (["sensitivity", "--param", "Foo"], "unknown parameter 'Foo'"),
        (["sensitivity", "--param", "Csy", "--scales", ""], "empty"),
        (["sensitivity", "--param", "Csy", "--scales=-0.5,1"], "--scales '-0.5,1': every entry must be a finite number > 0"),
        (["sensitivity", "--param", "Csy", "--param", "Csy"], "two different parameters"),
        (["ramp", "--v-start-kmh", "600", "--v-end-kmh", "300"], "inverted"),
        (["root-locus", "--v-min-kmh", "500", "--v-max-kmh", "400"], "inverted"),
        (["bifurcation", "--v-min-kmh", "500", "--v-max-kmh", "400"], "inverted"),
    ],
)
def test_cli_bad_input_is_a_clear_error(capsys, argv, message):
    assert cli_main(argv) == 2
    assert message in capsys.readouterr().err


def test_cli_sensitivity_json_contracts(capsys):
    assert cli_main(["sensitivity", "--param", "Csy", "--scales", "0.5,1,1.5", "--json"]) == 0
    one = json.loads(capsys.readouterr().out)
    assert one["param"] == "Csy" and [p["scale"] for p in one["points"]] == [0.5, 1.0, 1.5]
    assert {"scale", "value", "critical_speed_kmh"} <= set(one["points"][0])
    assert one["points"][1]["critical_speed_kmh"] == pytest.approx(critical_speed(BogieModel()).speed_kmh, abs=1e-3)
    assert cli_main(["sensitivity", "--param", "Csy", "--param", "Kpz", "--scales", "0.5,1", "--json"]) == 0
    two = json.loads(capsys.readouterr().out)
    assert two["params"] == ["Csy", "Kpz"] and len(two["points"]) == 4
    assert {"scales", "values", "critical_speed_kmh"} <= set(two["points"][0])


def test_cli_critical_speed_json(capsys):
    assert cli_main(["critical-speed", "--json", "--set", "Csy=45000"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert {"critical_speed_kmh", "hunting_frequency_hz", "equilibrium"} <= set(payload)
    assert payload["overrides"] == ["Csy=45000"]


@pytest.mark.slow
def test_cli_bifurcation_json_has_both_critical_speeds(capsys):
    assert cli_main(["bifurcation", "--json", "--n-speeds", "6", "--rates", "2,0.5"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["nonlinear_critical_speed_kmh"] <= payload["linear_critical_speed_kmh"]


@pytest.mark.slow
def test_reproduce_writes_every_figure_and_the_report(tmp_path):
    out = tmp_path / "repro"
    done = subprocess.run([sys.executable, "-m", "bogie_env.cli", "reproduce", "--out", str(out)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    for name in ("fig07_root_locus", "fig08_root_locus_zoom", "fig09_ramp_lateral", "fig10_real_parts",
                 "fig11_phase_portrait", "fig12_axle_load", "fig13_primary", "fig14_secondary",
                 "fig15_axle_load_pairs", "fig16_suspension_pairs", "bifurcation", "ramp_down_convergence"):  # fmt: skip
        assert (out / f"{name}.png").stat().st_size > 10_000
    report = (out / "report.md").read_text()
    assert "427 km/h" in report and "Table 2" in report


def test_en14363_quantities_limits_and_mirror_symmetry(paper_model):
    """ΣY's rms limit is half Prud'homme's (10 kN + P0/3), 30 kN for the 150-kN axle (EN 14363);
    the guiding forces change sign with the mirrored state; on the limit cycle both quantities
    are non-zero and below their limits (why the env uses its own criterion)."""
    import numpy as np

    from bogie_env.analysis.bifurcation import limit_cycle_state
    from bogie_env.analysis.en14363 import limit_cycle_quantities
    from bogie_env.dynamics import ANTISYMMETRIC_STATES, N_STATES, guiding_forces_kernel

    (row,) = limit_cycle_quantities(paper_model, np.array([400.0]), duration=2.0)
    assert row["sum_y_rms_limit_n"] == pytest.approx(30e3)
    assert 0 < row["sum_y_rms_n"] < row["sum_y_rms_limit_n"]
    assert 0 < row["frame_accel_rms_m_per_s2"] < row["frame_accel_limit_m_per_s2"]
    x = limit_cycle_state(paper_model, 400.0)[None]
    mirror = np.ones(N_STATES)
    mirror[list(ANTISYMMETRIC_STATES)] = -1.0
    direct, mirrored = np.empty((1, 2)), np.empty((1, 2))
    v = np.array([400.0 / 3.6])
    guiding_forces_kernel(x, v, np.zeros((1, N_TRACK)), paper_model.coefficients, direct)
    guiding_forces_kernel(x * mirror, v, np.zeros((1, N_TRACK)), paper_model.coefficients, mirrored)
    assert np.abs(direct).max() > 1e3
    np.testing.assert_allclose(mirrored, -direct, rtol=1e-12, atol=1e-9)
