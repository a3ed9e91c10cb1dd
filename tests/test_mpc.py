"""The MPC reference (privileged_mpc): the LQR where no limit binds, the limits where they do."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("osqp")

from bogie_agents.controllers.mpc import MPCReference, condensed_qp  # noqa: E402
from bogie_agents.controllers.lqr import force_rate_rows, lqr_gain_cross  # noqa: E402
from bogie_env.envs.config import make_config  # noqa: E402
from bogie_env.envs.scenario import Scenario  # noqa: E402
from scipy.linalg import solve_discrete_are  # noqa: E402


@pytest.fixture(scope="module")
def mpc() -> MPCReference:
    v1 = make_config(variant="v1")
    return MPCReference(v1, step_kmh=100.0, v_range_kmh=(200.0, 400.0), horizon=15).tell(Scenario(conicity=0.1), v1)


def _z(mpc: MPCReference, size: float, seed: int = 0) -> np.ndarray:
    n = mpc.points[0].ad.shape[0]
    z = np.random.default_rng(seed).normal(size=n) * size
    z[16:] = 0.0  # the loop states at rest: the controller keeps them itself
    return z


def _solve(mpc: MPCReference, k: int, z: np.ndarray) -> np.ndarray:
    qp, solver = mpc.qp(k), mpc.solver(k)
    g = qp.offset @ z
    solver.update(q=qp.linear @ z, l=qp.lower - g, u=qp.upper - g)
    result = solver.solve(raise_error=False)
    assert result.info.status_val == 1
    return result.x


def test_without_active_limits_the_first_command_is_the_lqr(mpc):
    """With the Riccati solution as terminal cost, the finite-horizon problem without active
    constraints has the infinite-horizon LQR's first command (an independent closed form)."""
    k = 1
    a, b, q, s, r = mpc.loop_problem(mpc.points[k].speed)
    gain = lqr_gain_cross(a, b, q, r, s)
    z = _z(mpc, 1e-7)
    u = _solve(mpc, k, z)[: mpc.n_act]
    np.testing.assert_allclose(u, -gain @ z, rtol=1e-3, atol=1e-6 * np.max(np.abs(gain @ z)))


def test_the_predicted_commands_and_force_changes_keep_their_limits(mpc):
    """For a large state the LQR command saturates; the QP's plan keeps |u| <= 1 and, from each
    channel's delay on, the force's change over every step within the rate limit times the step
    (rate basis "step"), read from the plan stepped through the plant (not from the QP's matrices)."""
    k = 1
    a, b, *_ = mpc.loop_problem(mpc.points[k].speed)
    z0 = _z(mpc, 3e-2, seed=1)
    plan = _solve(mpc, k, z0).reshape(mpc.horizon, mpc.n_act)
    assert np.max(np.abs(plan)) <= 1.0 + 1e-4
    assert np.max(np.abs(mpc.points[k].gain @ z0)) > 1.0  # the LQR would saturate here
    n_x = a.shape[0] - mpc.n_act - sum(mpc.delays)
    z, binding = z0, 0.0
    for step, u in enumerate(plan):
        z_next = a @ z + b @ u
        change = (z_next[n_x : n_x + mpc.n_act] - z[n_x : n_x + mpc.n_act]) / mpc.dt
        for j, d in enumerate(mpc.delays):
            if step >= d and np.isfinite(mpc.rate_limit[j]):
                assert abs(change[j]) <= mpc.rate_limit[j] * (1 + 1e-3)
                binding = max(binding, abs(change[j]) / mpc.rate_limit[j])
        z = z_next
    assert binding > 0.99  # a rate limit binds: the constrained plan, not the LQR's


def test_condensed_cost_and_rates_are_the_stepped_plans():
    """The condensed Hessian and linear term give the cost of a plan summed stage by stage, and
    the constraint rows its commands and force rates (relative to their limits) stepped the same way."""
    rng = np.random.default_rng(2)
    n, m, horizon = 5, 2, 4
    a = rng.normal(size=(n, n)) * 0.4
    b = rng.normal(size=(n, m))
    q = np.diag(rng.uniform(1, 2, n))
    r = np.eye(m)
    s = rng.normal(size=(n, m)) * 0.1
    p = solve_discrete_are(a, b, q, r, s=s)
    delays, limits = [0, 1], np.array([2.0, 3.0])
    m_z, m_u = force_rate_rows(n, n - m - 1, delays, np.array([3.0, 5.0]), np.array([1.5, 0.7]))
    qp = condensed_qp(a, b, q, s, r, p, m_z, m_u, limits, delays, horizon)
    z0, plan = rng.normal(size=n), rng.normal(size=horizon * m)
    hessian = qp.hessian.toarray()
    hessian = hessian + np.triu(hessian, 1).T
    z, cost, rows = z0, 0.0, [plan]
    for k, u in enumerate(plan.reshape(horizon, m)):
        cost += z @ q @ z + 2 * z @ s @ u + u @ r @ u
        rows += [np.array([(m_z[j] @ z + m_u[j] @ u) / limits[j]]) for j in range(m) if k >= delays[j]]
        z = a @ z + b @ u
    np.testing.assert_allclose(qp.constraint @ plan + qp.offset @ z0, np.concatenate(rows), rtol=1e-10, atol=1e-12)
    cost += z @ p @ z
    z_only, zz = 0.0, z0.copy()  # the cost of the zero plan: the part without the commands
    for _ in range(horizon):
        z_only += zz @ q @ zz
        zz = a @ zz
    z_only += zz @ p @ zz
    assert 0.5 * plan @ hessian @ plan + (qp.linear @ z0) @ plan + z_only == pytest.approx(cost, rel=1e-9)


@pytest.mark.parametrize("field, value", [("horizon", 0), ("horizon", 2.5), ("rate_basis", "mean")])
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        MPCReference(make_config(variant="v1"), step_kmh=100.0, **{field: value})


def test_the_protocol_tells_it_and_it_acts_in_a_task(capfd):
    """By name, as the protocol builds it: told a scenario it stays an MPC reference with its
    horizon and the weights scheduled on the told conicity, and it commands a task's rows
    without OSQP's line per solve on stdout (osqp/osqp#785)."""
    from bogie_agents.evaluation import stability_protocol as sp
    from bogie_env.envs.task import HuntingTask

    v1 = make_config(variant="v1")
    settings = sp.screening_settings(columns=("conicity:0.3",), progress=False)
    ctx = sp.PartContext(sp.factory_for("privileged_mpc"), v1, settings, "state", sp.Progress("p", False), privileged=True)
    cases = [c for col in sp.columns(v1, settings).values() for c in col]
    task, groups = sp.Runner(ctx)._task(cases, np.full(len(cases), 150.0), "default")
    assert isinstance(task, HuntingTask)
    (rows, told), = groups.groups
    assert isinstance(told, MPCReference) and told.rate_weight == 0.0 and told.r == 10.0
    told.reset(len(rows))
    actions = told.act(task.obs[rows])
    assert actions.shape == (len(rows), told.n_act) and actions.dtype == np.float32
    assert np.all(np.abs(actions) <= 1.0) and told.fallbacks == 0
    told.act(np.zeros_like(task.obs[rows]))  # at rest: no active constraint, the case OSQP reports
    assert "Polishing" not in capfd.readouterr().out
