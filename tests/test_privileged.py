"""The privileged reference and the rate-aware LQG: their design model against independent
computations, and what the protocol tells the reference."""

from __future__ import annotations

import numpy as np
import pytest

from bogie_agents.evaluation import stability_protocol as sp
from bogie_agents.controllers.lqr import LQGController, RateAwareLQGController, add_rate_cost
from bogie_agents.controllers.privileged import PrivilegedController
from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.envs.config import make_config
from bogie_env.envs.scenario import Scenario
from bogie_env.envs import task as T
from bogie_env.envs.task import HuntingTask


@pytest.fixture(scope="module")
def v1() -> dict:
    return make_config(variant="v1")


@pytest.fixture(scope="module")
def reference(v1) -> PrivilegedController:
    return PrivilegedController(v1, step_kmh=100.0)


def test_rate_cost_is_the_squared_force_rate_of_the_plant(reference):
    """z'Qz + 2 z'S u + u'Ru of the added cost equals rate_weight * sum((dF/dt / limit)^2), the
    rate computed from the lag equation at the state and command (not from the cost's matrices)."""
    rng = np.random.default_rng(3)
    n_x, n_act = 16, reference.n_act
    for delays in ([1, 1, 1, 1], [0, 2, 1, 0]):
        n = n_x + n_act + sum(delays)
        limit = np.array([2e5, 4e5, np.inf, 4e5])
        held = reference.max_force * np.array([1.0, 0.8, 1.2, 0.0])
        q, s, r = add_rate_cost(np.zeros((n, n)), np.zeros((n_act, n_act)), n_x, delays, reference.bandwidth, held, limit, 7.0)
        z, u = rng.normal(size=n), rng.normal(size=n_act)
        force = z[n_x : n_x + n_act]
        pos, u_held = n_x + n_act, np.empty(n_act)
        for j, d in enumerate(delays):
            u_held[j] = u[j] if d == 0 else z[pos + d - 1]
            pos += d
        rate = reference.bandwidth * (held * u_held - force)
        expected = 7.0 * np.sum(np.where(np.isfinite(limit), (rate / np.where(np.isfinite(limit), limit, 1.0)) ** 2, 0.0))
        assert z @ q @ z + 2 * z @ s @ u + u @ r @ u == pytest.approx(expected, rel=1e-10)


def test_replicated_loop_state_follows_the_sampled_plant(v1, reference):
    """The forces and command registers the reference keeps from its own commands evolve as the
    design plant's states do, driven by the same commands (an independent time-domain check of
    the register order and the lag)."""
    told = reference.tell(Scenario(conicity=0.1, actuator_gain=np.array([1.1, 0.9, 1.0, 1.2])), v1)
    point = told.points[2]
    n_x = 16
    n_reg = sum(told.delays)
    rng = np.random.default_rng(0)
    told.reset(1)
    z = np.zeros(point.ad.shape[0])
    for _ in range(12):
        x = rng.normal(size=n_x) * 1e-3
        z[:n_x] = x
        u = np.clip(-point.gain @ z, -1, 1)
        # the controller's own view: state from the plant, loop states replicated
        np.testing.assert_allclose(told.force_state[0], z[n_x : n_x + told.n_act], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(told.registers()[0], z[n_x + told.n_act : n_x + told.n_act + n_reg], atol=1e-12)
        z = point.ad @ z + point.bd @ u
        told._advance(u[None, :])


def test_design_is_stable_where_passive_hunts(v1, reference):
    for conicity in (0.025, 0.1, 0.3):
        told = reference.tell(Scenario(conicity=conicity), v1)
        for v in (200.0, 400.0, 600.0):
            assert np.max(np.abs(told.closed_loop_eigenvalues(v))) < 1.0


def test_told_scenario_changes_the_design(v1, reference):
    nominal = reference.tell(Scenario(), v1)
    soft = reference.tell(Scenario(primary_longitudinal_stiffness=0.5), v1)
    failed = reference.tell(Scenario(failed_actuator="frame_yaw"), v1)
    assert soft.model.params.Kpx == pytest.approx(0.5 * nominal.model.params.Kpx)
    assert not np.allclose(soft.gains, nominal.gains)
    k = [CHANNEL_NAMES[c] for c in failed.active].index("frame_yaw")
    assert failed.channel_gain[k] == 0.0
    delayed = reference.tell(Scenario(), make_config({"actuators": {n: {"delay_steps": 2} for n in CHANNEL_NAMES}}, variant="v1"))
    assert delayed.delays == [2] * len(delayed.active)
    assert delayed.points[0].ad.shape[0] == nominal.points[0].ad.shape[0] + len(delayed.active)


def test_protocol_tells_each_row_its_scenario(v1):
    """The critical part's task groups a privileged controller's rows by their true scenario."""
    settings = sp.screening_settings(columns=("conicity:0.1", "degraded:Kpx-50%"), progress=False)
    ctx = sp.PartContext(sp.factory_for("privileged"), v1, settings, "state", sp.Progress("p", False), privileged=True)
    cases = [c for col in sp.columns(v1, settings).values() for c in col]
    task, groups = sp.Runner(ctx)._task(cases, np.full(len(cases), 200.0), "default")
    assert isinstance(task, HuntingTask)
    assert len(groups.groups) == 2
    by_rows = {tuple(rows): p for rows, p in groups.groups}
    lam_rows = tuple(i for i, c in enumerate(cases) if c.column == "conicity:0.1")
    assert by_rows[lam_rows].model.params.lam == pytest.approx(0.1)
    kpx_rows = tuple(i for i, c in enumerate(cases) if c.column == "degraded:Kpx-50%")
    assert by_rows[kpx_rows].model.params.Kpx == pytest.approx(0.5 * by_rows[lam_rows].model.params.Kpx)


def test_rate_aware_lqg_reduces_to_lqg(v1):
    plain = LQGController(v1, step_kmh=200.0)
    zero = RateAwareLQGController(v1, step_kmh=200.0, rate_weight=0.0)
    np.testing.assert_array_equal(plain.gains, zero.gains)
    rated = RateAwareLQGController(v1, step_kmh=200.0)
    assert rated.rate_weight > 0 and not np.allclose(rated.gains, plain.gains)
    with pytest.raises(ValueError, match="rate_weight"):
        RateAwareLQGController(v1, rate_weight=-1.0)
    with pytest.raises(ValueError, match="rate_weight"):
        PrivilegedController(v1, rate_weight=float("nan"))


def test_margins_model_matches_act(v1, reference):
    """The margins' linear controller model reproduces act() step by step (unclipped)."""
    from bogie_agents.design.margins import check_controller_model, controller_model

    told = reference.tell(Scenario(), v1)
    n_obs = 25
    y0 = np.zeros(n_obs)
    y0[T.speed_index("state")] = (350.0 - T.SPEED_CENTRE_KMH) / T.SPEED_SCALE_KMH
    ctrl = controller_model(told, n_obs, 350.0, y0)
    ctrl.check_shapes(n_obs, told.n_act)
    assert check_controller_model(told, ctrl, y0, np.zeros(told.n_act)) < 1e-3  # float32 rounding of act()
