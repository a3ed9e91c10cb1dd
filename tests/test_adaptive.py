"""The adaptive LQG (``agents/adaptive.py``): its estimator on its own linear sampled plant, its
per-row state, and that it ignores the conicity it is told."""

from __future__ import annotations

import numpy as np
import pytest

from bogie_env.dynamics import state_index
from bogie_env.envs import task as T
from bogie_env.envs.config import make_config, merge_config
from bogie_agents.controllers.adaptive import AdaptiveLQGController
from bogie_agents.controllers.classical import CLASSICAL
from bogie_agents.controllers.lqr import LAT, LQGController

BANK = (0.05, 0.1, 0.2)
SPEED_KMH = 100.0  # every bank model's linear plant is stable here, so an open loop stays bounded
STEP_KMH = 100.0  # a coarse design grid keeps the bank's design to seconds
OBS_DIM = T.speed_index("sensors") + 1


@pytest.fixture(scope="module")
def config() -> dict:
    return make_config(variant="v1")


@pytest.fixture(scope="module")
def bank(config) -> AdaptiveLQGController:
    return AdaptiveLQGController(config, conicities=BANK, step_kmh=STEP_KMH, score="likelihood")


def observation(y: np.ndarray, speed_kmh: float) -> np.ndarray:
    obs = np.zeros((y.shape[0], OBS_DIM))
    obs[:, : y.shape[1]] = y
    obs[:, T.speed_index("sensors")] = (speed_kmh - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    return obs


def simulate(controller: AdaptiveLQGController, config: dict, true_lam: float, rows: int = 4, steps: int = 500,
             seed: int = 0) -> np.ndarray:  # fmt: skip
    """Closed loop of ``controller`` on the sampled plant of ``true_lam``, built independently of
    the bank (its own LQGController for that conicity), driven by the noise the filters assume:
    white lateral forcing of both wheelsets (0.05 m/s per step) and 0.01 per sensor. Returns each
    row's normalised innovation squared of the true model, averaged over the last half."""
    plant = LQGController(make_config(merge_config(config, {"bogie_overrides": {"lam": true_lam}})),
                          sensor_model=True, v_range_kmh=(SPEED_KMH, SPEED_KMH))  # fmt: skip
    a, b, c = plant.ads[0], plant.bds[0], plant.cds[0]
    noise, _ = plant.sensor_errors()
    noise = np.maximum(noise, 0.01)
    rng = np.random.default_rng(seed)
    controller.reset(rows)
    z = np.zeros((rows, a.shape[0]))
    z[:, LAT.index(state_index("y1"))] = 0.003
    u = np.zeros((rows, controller.n_act))
    forced = [LAT.index(state_index("dy1")), LAT.index(state_index("dy2"))]
    true = int(np.argmin(np.abs(np.log(controller.conicities / true_lam))))
    nis = []
    for k in range(steps):
        w = np.zeros_like(z)
        w[:, forced] = rng.normal(0.0, 0.05, (rows, 2))
        z = z @ a.T + u @ b.T + w
        y = z @ c.T + rng.normal(0.0, 1.0, (rows, c.shape[0])) * noise
        u = np.asarray(controller.act(observation(y, SPEED_KMH)), dtype=float)
        if k >= steps // 2:
            e = controller.innovation[:, true]
            nis.append(np.einsum("np,npq,nq->n", e, controller.rows_of["sinv"][:, true], e))
    return np.mean(nis, axis=0)


def failures(controller: AdaptiveLQGController, config: dict, true_lam: float, steps: int = 500) -> list[str]:
    """What goes wrong on the true conicity's plant: the selected model, the posterior's mode,
    the estimate (within a factor 1.25), the true model's innovation consistency."""
    nis = simulate(controller, config, true_lam, steps=steps)
    out = []
    if not np.all(controller.selected_conicity == true_lam):
        out.append(f"selected {controller.selected_conicity}")
    if not np.all(np.argmax(controller.posterior, axis=1) == list(controller.conicities).index(true_lam)):
        out.append(f"posterior {controller.posterior.round(3)}")
    if not np.all(np.abs(np.log(controller.estimate_conicity / true_lam)) < np.log(1.25)):
        out.append(f"estimate {controller.estimate_conicity}")
    # the true model's filter is consistent: its innovations have the covariance it assumes
    if not np.all((nis > 0.75 * len(T.SENSORS)) & (nis < 1.33 * len(T.SENSORS))):
        out.append(f"normalised innovation squared {nis}")
    return out


@pytest.mark.parametrize("true_lam", BANK)
def test_the_estimator_picks_the_true_model_on_its_linear_plant(bank, config, true_lam):
    assert failures(bank, config, true_lam) == []


def test_a_wrong_kalman_gain_is_detected(config):
    """Planted bug: the 0.05 model filters with the 0.2 model's Kalman gain; the test above
    then fails on the 0.05 plant (the 0.1 model's likelihood wins)."""
    broken = AdaptiveLQGController(config, conicities=BANK, step_kmh=STEP_KMH, score="likelihood")
    broken.k_stack[0] = broken.k_stack[2].copy()
    assert failures(broken, config, 0.05, steps=300) != []


def test_reset_clears_the_rows_state(bank, config):
    simulate(bank, config, 0.2, rows=3, steps=200)
    assert np.all(bank.selected_conicity == 0.2)
    before = bank.scores.copy()
    bank.reset(3, np.array([1]))
    assert np.all(bank.scores[1] == 0) and np.all(bank.estimates[1] == 0) and np.all(bank.last_action[1] == 0)
    assert bank.selected_conicity[1] == 0.1  # initial_conicity's model
    assert np.array_equal(bank.scores[[0, 2]], before[[0, 2]])
    bank.reset(5)
    assert bank.scores.shape == (5, len(BANK)) and np.all(bank.scores == 0)


def test_it_ignores_the_conicity_it_is_told(config):
    told = {lam: make_config(merge_config(config, {"bogie_overrides": {"lam": lam}})) for lam in (0.025, 0.3)}
    controllers = [AdaptiveLQGController(cfg, conicities=BANK, step_kmh=STEP_KMH) for cfg in told.values()]
    rng = np.random.default_rng(3)
    for c in controllers:
        c.reset(2)
    for _ in range(50):
        obs = observation(rng.normal(0.0, 0.1, (2, len(T.SENSORS))), 250.0)
        a0, a1 = (c.act(obs) for c in controllers)
        assert np.array_equal(a0, a1)
    assert np.any(a0 != 0)


def test_registered_and_refuses_bad_settings(config):
    assert CLASSICAL["adaptive_lqg"] is AdaptiveLQGController
    assert AdaptiveLQGController.observation_type == "sensors"
    with pytest.raises(ValueError, match="conicities"):
        AdaptiveLQGController(config, conicities=(0.1,))
    with pytest.raises(ValueError, match="score"):
        AdaptiveLQGController(config, conicities=BANK, step_kmh=STEP_KMH, score="innovation")
    with pytest.raises(ValueError, match="sensors.enabled"):
        AdaptiveLQGController(make_config(variant="active"))
