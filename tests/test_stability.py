"""Linear stability: the speed decomposition of the Jacobian, the separable vertical modes,
the critical-speed search, and agreement of eigenvalues with time-domain simulation."""

import numpy as np
import pytest

from bogie_env.dynamics import state_index
from bogie_env.integrate import stable_substep
from bogie_env.simulator import BatchSimulator
from bogie_env.stability import KMH, critical_speed


@pytest.mark.parametrize("speed", [12.0, 57.3, 111.1, 230.0])
def test_jacobian_speed_decomposition_is_exact(paper_model, paper_linearization, speed):
    direct = paper_model.jacobian(paper_model.equilibrium(speed), speed)
    np.testing.assert_allclose(paper_linearization.jacobian(speed), direct, rtol=1e-9, atol=1e-9)


def test_vertical_modes_are_the_analytic_pair(paper_params, paper_linearization):
    # m_w s^2 + 2 Cpz s + 2 Kpz = 0, twice; the rest is the lateral block's spectrum.
    p = paper_params
    roots = np.roots([p.mw, 2 * p.Cpz, 2 * p.Kpz])
    full = list(paper_linearization.eigenvalues(100.0))
    lateral = paper_linearization.eigenvalues(100.0, lateral_only=True)
    for value in np.concatenate([lateral, roots, roots]):  # multiset match
        k = int(np.argmin(np.abs(np.array(full) - value)))
        assert abs(full.pop(k) - value) < 1e-8 * max(1.0, abs(value))
    assert not full


def test_critical_speed_is_a_sign_change_to_0_1_kmh(paper_model, paper_linearization):
    result = critical_speed(paper_model)
    assert result.status == "crossing"
    below = paper_linearization.growth_rate(result.speed - 0.05 / KMH)
    above = paper_linearization.growth_rate(result.speed + 0.05 / KMH)
    assert below < 0 < above
    # nothing crosses lower down: stable over a fine grid below the critical speed
    grid = np.linspace(50 / KMH, result.speed - 0.1 / KMH, 400)
    assert np.all(paper_linearization.growth_rate(grid) < 0)
    assert 1.0 < result.frequency_hz < 5.0  # bogie hunting of a low-conicity bogie


def test_critical_speed_window_statuses(paper_model):
    nominal = critical_speed(paper_model).speed_kmh
    assert critical_speed(paper_model, v_max_kmh=nominal - 5).status == "stable"
    assert np.isnan(critical_speed(paper_model, v_max_kmh=nominal - 5).speed)
    assert critical_speed(paper_model, v_min_kmh=nominal + 5).status == "unstable"


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(v_min_kmh=500, v_max_kmh=400), "must be below"),
        (dict(v_min_kmh=-1), "v_min = .* not allowed"),
        (dict(v_max_kmh=float("nan")), "v_max = nan"),
        (dict(tol_kmh=0.0), "tol_kmh"),
    ],
)
def test_critical_speed_bad_input(paper_model, kwargs, message):
    with pytest.raises(ValueError, match=message):
        critical_speed(paper_model, **kwargs)


def _envelope_growth(model, speed, duration=24.0, amplitude=1e-7):
    """Fixed-speed RK4 run from a small lateral offset; log-envelope slope of y1 (1/s)."""
    choice = stable_substep(model, speed, speed, 0.01)
    x = model.equilibrium(speed)[None, :].copy()
    x[0, state_index("y1")] += amplitude
    n_steps = int(duration / 0.01)
    y1 = np.empty(n_steps)
    sim = BatchSimulator(model, 1, 0.01, (speed, speed), n_sub=choice.n_sub)
    sim.set_rows(0, x[0], speed)
    for k in range(n_steps):
        sim.step()
        y1[k] = sim.x[0, state_index("y1")]
    t = 0.01 * np.arange(1, n_steps + 1)
    # peak envelope over 1-s windows after the initial transient
    windows = np.arange(4, int(duration))
    peaks = np.array([np.max(np.abs(y1[(t >= w) & (t < w + 1)])) for w in windows])
    slope = np.polyfit(windows + 0.5, np.log(peaks), 1)[0]
    return slope, peaks


def test_eigenvalues_agree_with_time_simulation(paper_model, paper_linearization):
    """2 % below the critical speed a perturbation decays, 2 % above it grows, each at the
    rate the leading eigenvalue predicts."""
    vc = critical_speed(paper_model).speed
    for factor in (0.98, 1.02):
        speed = factor * vc
        predicted = float(paper_linearization.growth_rate(speed))
        measured, peaks = _envelope_growth(paper_model, speed)
        assert np.sign(measured) == np.sign(predicted) == (1 if factor > 1 else -1)
        assert measured == pytest.approx(predicted, rel=0.1)
        assert peaks.max() < 3e-3  # stayed clear of the flange (9 mm) and deep saturation
