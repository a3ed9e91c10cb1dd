"""Stage 2 of robust_damping's design (bogie_agents.controllers.robust_track) against independent oracles.

- the track input: the same alignment under both wheelsets at a very long wavelength is a
  slow lateral shift of the track, which an uncontrolled stable bogie follows (relative
  displacement -> 0), while at 20 m it does not;
- the frequency response against a time-domain run of the same closed loop with a sinusoidal
  alignment (the rear wheelset's delayed by 2 L1 / V): the steady amplitude of y_i - y_t,i;
- the track input matrix and the frequency response without control against the nonlinear
  simulator on a sinusoidal alignment profile (its own track sampling under each wheelset,
  continuous in time; the design model holds the track over each 10 ms step);
- the lead check raises on a lead that destabilises the design loop.
"""

import math

import numpy as np
import pytest

from bogie_agents.controllers.robust import DesignModel, DesignSettings, closed_loop, filter_bank, load_gains
from bogie_agents.controllers.robust_track import TrackSettings, check_lead, forced_response, track_input
from bogie_env.dynamics import state_index
from bogie_env.envs.config import make_config, merge_config
from bogie_env.simulator import BatchSimulator
from bogie_env.stability import KMH
from bogie_env.track import TrackProfile
from bogie_agents.controllers.robust import LAT


@pytest.fixture(scope="module")
def setup():
    config = make_config({"randomize": {}}, variant="v1")
    model = DesignModel(config, 0.1)
    table = load_gains()
    bank = filter_bank(model.n_obs, config["dt"], float(table["washout_hz"]), float(table["leak_hz"]))
    return config, model, table, bank


def test_forced_response_against_time_domain(setup):
    config, model, table, bank = setup
    dt, v_kmh, lam = config["dt"], 180.0, 20.0
    k = list(table["speeds_kmh"]).index(v_kmh)
    gains = table["gains"][k]
    plant = model.plant(v_kmh)
    e_d = track_input(model, v_kmh)
    l1 = model.model.params.L1
    rel, _ = forced_response(plant, bank, gains, e_d, v_kmh, l1, dt, [lam])
    a_cl = closed_loop(plant, bank, gains)
    b = np.zeros((a_cl.shape[0], 2))
    b[: e_d.shape[0]] = e_d
    v = v_kmh / KMH
    w, lag = 2 * math.pi * v / lam, 2 * l1 / v
    x = np.zeros(a_cl.shape[0])
    i1, i2 = LAT.index(state_index("y1")), LAT.index(state_index("y2"))
    peak = 0.0
    n = 3000
    for step in range(n):
        t = step * dt
        track = np.array([math.sin(w * t), math.sin(w * (t - lag))])
        if step > n - 300:
            peak = max(peak, abs(x[i1] - track[0]), abs(x[i2] - track[1]))
        x = a_cl @ x + b @ track
    assert rel[0] > 0.3  # the 20 m alignment is not followed
    assert peak == pytest.approx(rel[0], rel=0.03)


@pytest.mark.parametrize("wavelength_m", [20.0, 30.0])
def test_uncontrolled_response_against_the_nonlinear_simulator(setup, wavelength_m):
    """Zero gains: the design model's steady |y_i - y_t,i| per unit alignment against the
    nonlinear bogie (conicity 0.1, 90 km/h, below its critical speed) on a 0.5 mm sinusoidal
    alignment profile. The tolerance (5 %) covers the design model's track hold over each step
    and the small amplitude's nonlinearity (about 3 % measured); a track input matrix 10 % off
    or the rear wheelset's track delay with the wrong sign fails it."""
    config, model, table, bank = setup
    v_kmh, amplitude = 90.0, 5e-4
    v, dt, l1 = v_kmh / KMH, config["dt"], model.model.params.L1
    zero = np.zeros_like(table["gains"][0])
    rel, _ = forced_response(model.plant(v_kmh), bank, zero, track_input(model, v_kmh), v_kmh, l1, dt, [wavelength_m])
    dx = wavelength_m / 400
    profile = TrackProfile(amplitude * np.sin(2 * math.pi * np.arange(4000) * dx / wavelength_m), dx)
    sim = BatchSimulator(model.model, 1, dt=dt, speed_range=(v, v), track=profile)
    sim.set_rows(slice(None), model.model.equilibrium(v), v)
    states, _ = sim.run(4000)
    distance = np.arange(states.shape[0]) * dt * v
    settled = slice(-1000, None)
    peak = max(np.abs(states[settled, 0, state_index(f"y{i + 1}")] - profile.at(distance[settled] + side * l1)).max()
               for i, side in enumerate((1.0, -1.0)))  # fmt: skip
    assert peak / amplitude == pytest.approx(rel[0], rel=0.05)


def test_long_wavelength_is_followed_without_control(setup):
    config, model, table, bank = setup
    v_kmh = 90.0  # below the passive critical speed at conicity 0.1: the passive loop is stable
    plant = model.plant(v_kmh)
    e_d = track_input(model, v_kmh)
    zero = np.zeros_like(table["gains"][0])
    rel, cmd = forced_response(plant, bank, zero, e_d, v_kmh, model.model.params.L1, config["dt"], [5000.0, 20.0])
    assert rel[0] < 0.02 and rel[1] > 0.2
    assert np.all(cmd == 0.0)


def test_lead_check_raises_on_a_destabilising_lead(setup):
    config, model, table, bank = setup
    design = DesignSettings()
    delayed = merge_config(config, {"actuators": {n: {"delay_steps": 2} for n in config["actuators"]}})
    speeds = [float(v) for v in table["speeds_kmh"]]
    nominal = {c: DesignModel(config, c) for c in (0.025, 0.05, 0.1)}
    late = {c: DesignModel(delayed, c) for c in (0.025, 0.05, 0.1)}
    design.conicities = (0.025, 0.05, 0.1)
    lead = np.array([0.01 if v == 240.0 else 0.0 for v in speeds])
    check_lead(table["gains"], lead, TrackSettings().lead_lowpass_hz, speeds, nominal, late, bank, design, config["dt"])
    with pytest.raises(ValueError, match="destabilises"):
        check_lead(table["gains"], 5 * lead, None, speeds, nominal, late, bank, design, config["dt"])


def test_track_weight_per_row():
    s = TrackSettings(speeds_kmh=(150.0, 240.0), w_track=(0.3, 0.1))
    assert s.track_weight(150.0) == 0.3 and s.track_weight(240.0) == 0.1
    assert TrackSettings(speeds_kmh=(150.0, 240.0), w_track=0.2).track_weight(240.0) == 0.2
    with pytest.raises(ValueError, match="w_track"):
        TrackSettings(speeds_kmh=(150.0, 240.0), w_track=(0.3, 0.1, 0.1)).track_weight(150.0)


@pytest.mark.slow  # 2.4-6 s warm: make test's 3 minutes on a clean clone
def test_retune_uses_each_rows_own_track_weight(setup):
    """Rows are tuned independently: a per-row weight gives, at each row, the row of a run with
    that weight for every row (a bug that uses one row's weight everywhere, or another row's,
    fails this)."""
    from bogie_agents.controllers.robust import load_gains, GAINS_FILE
    from bogie_agents.controllers.robust_track import retune_track

    config = setup[0]
    base = load_gains(GAINS_FILE.with_name("robust_gains_stage1.json"))
    speeds = (150.0, 240.0)
    short = {"speeds_kmh": speeds, "max_evaluations": 40}
    mixed = retune_track(config, base, TrackSettings(w_track=(2.0, 0.0), **short))["gains"]
    high = retune_track(config, base, TrackSettings(w_track=2.0, **short))["gains"]
    low = retune_track(config, base, TrackSettings(w_track=0.0, **short))["gains"]
    k150, k240 = (list(base["speeds_kmh"]).index(v) for v in speeds)
    assert np.array_equal(mixed[k150], high[k150]) and np.array_equal(mixed[k240], low[k240])
    assert not np.array_equal(high[k150], low[k150]) and not np.array_equal(high[k240], low[k240])
    with pytest.raises(ValueError, match="w_track"):
        retune_track(config, base, TrackSettings(w_track=(1.0,), **short))
