"""The fixed-step integrator: convergence order, agreement with scipy, the spectrum-based
step choice, batching, actuator lag and NaN detection."""

import math

import numpy as np
import pytest

from bogie_env.actuators import CH_DECAY_RATE, DAMPING, FORCE, N_CHANNELS, channel_table
from bogie_env.dynamics import state_index
from bogie_env.integrate import STATUS_NONFINITE, STATUS_OK, reference_solution, rk4_amplification, stable_substep
from bogie_env.simulator import BatchSimulator

from .oracles.rk4 import rk4_interval


def per_channel(values):
    """Values for the four original channels, zero for any channel added since."""
    return np.concatenate([values, np.zeros(N_CHANNELS - len(values))])


def run_fixed(model, x0, speed, t_end, dt, n_sub, accel=0.0, n_rows=1, f_start=None, f_target=None,
              c_start=None, c_target=None, decay=None):
    """Through the simulator's driver; returns x, speed, distance, channel outputs, power, status."""
    channels = channel_table()
    if decay is not None:
        channels[:, CH_DECAY_RATE] = decay
    final = speed + accel * t_end
    sim = BatchSimulator(model, n_rows, dt, (min(speed, final), max(speed, final)), channels=channels, n_sub=n_sub)
    sim.set_rows(slice(None), np.repeat(np.asarray(x0, float)[None, :], n_rows, axis=0), speed, accel)
    if f_start is not None:
        sim.lag[:, FORCE] = f_start
    if c_start is not None:
        sim.lag[:, DAMPING] = c_start
    for _ in range(int(round(t_end / dt))):
        sim.step(f_target, c_target)
    return sim.x, sim.speed, sim.distance, sim.channel_output, sim.channel_power, sim.status


def perturbed(model, speed):
    x0 = model.equilibrium(speed)
    x0[state_index("y1")] += 2e-3
    x0[state_index("psi2")] += 1e-3
    return x0


def test_rk4_fourth_order_convergence(paper_model):
    """Small perturbation, so each wheel's creep-force vector stays near its equilibrium value
    (the constant spin force): far from |F| = 0, where the norm in Eq. (28) has a kink that
    would cap any method's order."""
    speed, t_end = 90.0, 0.4
    x0 = paper_model.equilibrium(speed)
    x0[state_index("y1")] += 2e-6
    x0[state_index("psi2")] += 1e-6
    ref = reference_solution(paper_model, x0, speed, (0.0, t_end), rtol=1e-13, atol=1e-18).y[:, -1]
    errors = []
    steps = [0.002, 0.001, 0.0005, 0.00025]  # asymptotic range: h |lambda|max <= 1.1
    for h in steps:
        x = run_fixed(paper_model, x0, speed, t_end, 0.02, int(round(0.02 / h)))[0][0]
        errors.append(np.max(np.abs(x - ref)))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 3.6) and np.all(orders < 4.4), (errors, orders)


def test_fixed_step_matches_scipy_with_speed_ramp(paper_model):
    speed, accel, t_end = 85.0, 0.5, 3.0
    x0 = perturbed(paper_model, speed)
    ref = reference_solution(paper_model, x0, speed, (0.0, t_end), accel=accel, rtol=1e-11, atol=1e-14)
    choice = stable_substep(paper_model, speed, speed + accel * t_end, 0.01)
    x, v, s, *_ = run_fixed(paper_model, x0, speed, t_end, 0.01, choice.n_sub, accel=accel)
    assert v[0] == pytest.approx(speed + accel * t_end, rel=1e-12)
    assert s[0] == pytest.approx(speed * t_end + 0.5 * accel * t_end**2, rel=1e-12)
    scale = np.max(np.abs(ref.y), axis=1) + 1e-12
    assert np.max(np.abs(x[0] - ref.y[:, -1]) / scale) < 1e-3


def test_step_choice_is_justified_by_the_spectrum(paper_model):
    """The step chosen from the spectrum integrates stably; one far beyond it does not."""
    speed = 300 / 3.6
    choice = stable_substep(paper_model, speed, 600 / 3.6, 0.01)
    assert 300 < choice.spectral_radius < 800  # |lambda| ~ 530 1/s (wheelset yaw/roll)
    assert choice.substep * choice.spectral_radius < 2.83  # inside RK4's stability boundary
    x0 = perturbed(paper_model, speed)
    good = run_fixed(paper_model, x0, speed, 2.0, 0.01, choice.n_sub)[0]
    assert np.all(np.isfinite(good)) and np.max(np.abs(good[0, [0, 8, 16]])) < 3e-3
    h_bad = 2.0 * 2.83 / choice.spectral_radius  # twice the boundary step
    bad = run_fixed(paper_model, x0, speed, 2.0, 0.01 * round(h_bad / 0.01 + 0.5), 1)
    assert bad[5][0] == STATUS_NONFINITE or np.max(np.abs(bad[0])) > 1.0


def test_rk4_amplification_polynomial():
    assert rk4_amplification(0.0) == pytest.approx(1.0)
    assert rk4_amplification(-2.785) == pytest.approx(1.0, abs=1e-3)  # real-axis boundary
    assert rk4_amplification(2.8284j) == pytest.approx(1.0, abs=1e-3)  # imaginary-axis boundary


@pytest.mark.slow  # 5-10 s warm: make test stays within 3 minutes from a clean clone
def test_batch_rows_are_independent_and_bitwise_reproducible(paper_model):
    """The same row on the calling thread (1 row) and on the thread pool (300 rows, 64 chunks)."""
    x0 = perturbed(paper_model, 100.0)
    one = run_fixed(paper_model, x0, 100.0, 0.5, 0.01, 3, n_rows=1)[0]
    many = run_fixed(paper_model, x0, 100.0, 0.5, 0.01, 3, n_rows=300)[0]
    assert np.array_equal(many, np.repeat(one, 300, axis=0))


def test_actuator_lag_is_exact_first_order(paper_model):
    """Force channels follow F(t) = F* + (F0 - F*) exp(-t/tau) exactly."""
    tau = 1 / (2 * math.pi * 10.0)
    x0 = paper_model.equilibrium(100.0)
    target = per_channel([5e3, 0.0, 0.0, 0.0])[None, :]
    dt = 0.01
    *_, u, power, status = run_fixed(paper_model, x0, 100.0, dt, dt, 3, f_target=target,
                                     decay=np.full(N_CHANNELS, 1 / tau))
    assert status[0] == STATUS_OK
    assert u[0, 0] == pytest.approx(5e3 * (1 - math.exp(-dt / tau)), rel=1e-12)


def test_semi_active_damper_only_dissipates(paper_model):
    x0 = perturbed(paper_model, 100.0)
    x0[state_index("dyb")] = 0.05
    x0[state_index("dpsi1")] = 0.05
    damping = per_channel([2e4, 1e4, 5e3, 5e3])[None, :]
    for _ in range(3):
        x, *_, u, power, status = run_fixed(paper_model, x0, 100.0, 0.01, 0.01, 3, c_start=damping,
                                            c_target=damping)
        assert np.all(power <= 1e-12)
        x0 = x[0]


def test_nonfinite_state_is_flagged(paper_model):
    x0 = paper_model.equilibrium(100.0)
    x0[3] = np.nan
    status = run_fixed(paper_model, x0, 100.0, 0.01, 0.01, 2)[5]
    assert status[0] == STATUS_NONFINITE


@pytest.mark.parametrize("accel, end", [(2.0, 101.0), (-2.0, 99.0)])
def test_speed_ramps_stop_exactly_at_the_end_speed(paper_model, accel, end):
    """Up or down, the speed follows V0 + a t until it reaches the end speed, then holds."""
    sim = BatchSimulator(paper_model, 1, 0.01, (98.0, 102.0), n_sub=2)
    sim.set_rows(0, paper_model.equilibrium(100.0), 100.0, accel, end_speed=end)
    speeds = []
    for _ in range(100):
        sim.step()
        speeds.append(sim.speed[0])
    assert speeds[10] == pytest.approx(100.0 + accel * 0.11, rel=1e-12)
    assert speeds[-1] == pytest.approx(end, abs=1e-12) and speeds[-1] == speeds[-40]


def test_one_interval_equals_a_python_rk4_with_track_and_actuators(paper_model):
    """An independent formulation of one interval: RK4 in numpy over model.rhs, with the speed
    ramp, the track under each wheelset at s(t) +- L1 and a lagged force channel mapped by the
    actuator matrices. Checks the driver's bookkeeping (distance, track input, channels)."""
    from bogie_env.actuators import force_matrix
    from bogie_env.track import TrackInput, alignment_profile

    track = TrackInput(alignment_profile(2e-3, 3.0, 80.0, seed=4))
    tau, dt, n_sub, v0, accel, s0 = 0.02, 0.01, 2, 95.0, 1.5, 1234.5
    target = per_channel([3e3, -2e3, 1e3, 4e3])
    sim = BatchSimulator(paper_model, 1, dt, (90.0, 100.0), track=track, lag_tau=tau, n_sub=n_sub)
    x0 = perturbed(paper_model, v0)
    sim.set_rows(0, x0, v0, accel, distance=s0)
    sim.step(target[None, :])
    L1 = paper_model.params.L1

    def f(t, x):
        s = s0 + v0 * t + 0.5 * accel * t * t
        u = target * (1 - math.exp(-t / tau))
        yt = np.array([track.alignment.at(s + L1), track.alignment.at(s - L1)])
        return paper_model.rhs(x, v0 + accel * t, inputs=force_matrix() @ u, track=yt)

    x = rk4_interval(f, x0, dt, n_sub)
    scale = np.abs(x - x0) + 1e-12
    assert np.max(np.abs(sim.x[0] - x) / scale) < 1e-6
    assert sim.distance[0] == pytest.approx(s0 + v0 * dt + 0.5 * accel * dt * dt, rel=1e-14)
    assert np.allclose(sim.track_sample[0], track.under_wheelsets(sim.distance[0], L1), rtol=0, atol=1e-15)
    assert np.allclose(sim.channel_output[0], target * (1 - math.exp(-dt / tau)), rtol=1e-12)


def test_rows_in_simd_lanes_get_the_bits_they_get_alone(paper_model):
    """Lane blocks (bogie_env.lanes): each row's interval gives the same bits whichever lane of a
    block of LANES rows it takes, or in a block of one (the rows that do not fill a block). 13
    rows, each with its own coefficients, speed, ramp and place on the s-curve route (tangents,
    transitions, curves, cant, both directions), rate-limited lagged channels with delays, and a
    non-finite row among them; the same rows in reverse order (other lanes, others alone) and a
    row by itself."""
    from bogie_env.actuators import CH_DELAY_STEPS, CH_RATE_LIMIT
    from bogie_env.lanes import LANES
    from bogie_env.route import load_route
    from bogie_env.track import CANT_WHEELSET1, TrackInput, alignment_profile

    n = 13
    assert n > LANES and n % LANES
    route = load_route("s-curve")
    track = TrackInput(alignment_profile(2e-3, seed=3), route)
    channels = channel_table()
    channels[:, CH_DECAY_RATE] = 2 * math.pi * 10.0
    channels[:, CH_RATE_LIMIT] = np.resize([5e4, np.inf], N_CHANNELS)
    channels[:, CH_DELAY_STEPS] = np.resize([0, 1, 2], N_CHANNELS)
    rng = np.random.default_rng(5)
    x0 = paper_model.equilibrium(80.0) + rng.normal(scale=1e-3, size=(n, 20))
    x0[6, 3] = np.nan
    speed, accel = rng.uniform(70.0, 90.0, n), rng.uniform(-2.0, 2.0, n)
    distance = np.linspace(150.0, 2450.0, n)
    coefficients = paper_model.coefficients * (1.0 + 0.05 * rng.uniform(-1.0, 1.0, (n, paper_model.coefficients.size)))
    forces = rng.normal(scale=1e4, size=(12, n, N_CHANNELS))

    def run(order):
        sim = BatchSimulator(paper_model, len(order), 0.01, (60.0, 100.0), track=track, channels=channels, n_sub=2)
        sim.set_rows(slice(None), x0[order], speed[order], accel[order], distance[order], coefficients=coefficients[order])
        for f in forces:
            sim.step(f[order])
        return sim

    rows = np.arange(n)
    batch, reverse, alone = run(rows), run(rows[::-1]), run(rows[3:4])
    for name in ("x", "motion", "lag", "output", "track_sample", "status"):
        assert getattr(batch, name).tobytes() == getattr(reverse, name)[::-1].tobytes(), name
        assert getattr(batch, name)[3:4].tobytes() == getattr(alone, name).tobytes(), name
    assert np.count_nonzero(batch.track_sample[:, CANT_WHEELSET1]) >= n - 4  # most rows on canted track
    assert list(batch.status) == [STATUS_NONFINITE if i == 6 else STATUS_OK for i in range(n)]
