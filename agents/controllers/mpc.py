"""The privileged reference with hard limits: model-predictive control on the true scenario's loop.

:class:`MPCReference` (``privileged_mpc``) is the privileged reference
(:mod:`bogie_agents.controllers.privileged`) with the actuators' limits as **hard constraints**
instead of soft costs. Like it, it is told the true scenario, sees the full state, is not
buildable in service and is **not a baseline to beat**: it is a second, tighter estimate of the
headroom, since the soft-constrained LQR may waste what the limits allow.

**Design.** At each design speed (every ``step_kmh``), the sampled loop plant and the cost of
the privileged reference (``A, B, Q, S, R``: the scenario's lateral bogie, the lags, the zero-order
hold and the delay registers; the state weights, the command weight and the soft force-rate
term), with the discrete Riccati solution ``P`` as terminal cost. Every step, for every row, a
quadratic program over the next ``horizon`` commands (condensed: the commands are the only
unknowns) at the design speed nearest the row's speed:

- minimise ``sum_k z_k'Q z_k + 2 z_k'S u_k + u_k'R u_k + z_H'P z_H``;
- subject to ``|u_k| <= 1`` (each channel's force limit) and ``|rate_jk| <= rate_limit_j``, the
  force rate ``w_j (g_j F_max,j u_held - F_j)`` at every sample that the commands can still move
  (from the channel's delay on).

The condensed form is the standard one (Borrelli, Bemporad & Morari, *Predictive Control for
Linear and Hybrid Systems*, 2017, Sec. 8.2; Maciejowski, *Predictive Control with Constraints*,
2002, Ch. 3): ``z_k = A^k z0 + sum_{i<k} A^(k-1-i) B u_i`` stacked as ``Z = Phi z0 + Gamma U``,
so the cost is ``U'(Gamma'Qbar Gamma + Gamma'Sbar + Sbar'Gamma + Rbar) U + 2 z0'(Phi'Qbar Gamma +
Phi'Sbar) U`` plus terms without ``U``. Forces in N (N m for yaw), rates in N/s. The step basis
follows from the zero-order-held lag ``dF/dt = w (target - F)``: over a step of ``dt`` the force
moves by ``(1 - exp(-w dt)) (target - F)``, which is ``(1 - exp(-w dt)) / (w dt)`` times the
sample's rate ``w (target - F)`` times ``dt``. Without active constraints the first command is the
LQR's, so the reference can only gain by the limits. The QP is solved by OSQP (a well-kept first-order QP solver, warm-started from the
row's previous solution shifted by one step). Where OSQP does not report a solution, the row takes
the privileged LQR's clipped command for that step (:attr:`fallbacks` counts them).

:class:`SensorMPCReference` (``privileged_mpc_sensors``) is the reference seeing only the sensors
through a Kalman filter designed on the told scenario; :class:`SensorMPC` (``mpc``) is that
controller told only the conicity class: buildable, and a baseline.
"""

from __future__ import annotations

import contextlib
import io
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import sparse
from scipy.linalg import solve_discrete_are

from bogie_env.envs.scenario import Scenario

from .lqr import force_rate_rows
from .privileged import PrivilegedController, SensorFed

RATE_BASES = ("step", "sample")
#: ``(r, rate_weight)`` by true conicity (``(upper conicity, weights)``, as the privileged
#: reference's): the limits are constraints here, so no soft rate cost; ``r`` the best of
#: {0.3, 1, 3, 10} per conicity on the screening seeds (docs/studies/headroom.md, "Hard limits").
MPC_WEIGHTS_BY_CONICITY: tuple[tuple[float, tuple[float, float]], ...] = ((0.25, (1.0, 0.0)), (math.inf, (10.0, 0.0)))
DEFAULT_HORIZON = 20  # steps of the env (0.2 s at v1's 10 ms): more than one hunting cycle above 5 Hz


def quiet_osqp() -> contextlib.AbstractContextManager:
    """``sys.stdout`` swallowed while OSQP solves: OSQP 1.0 prints "Polishing not needed" through
    Python's stdout on every solve without an active constraint, even with ``verbose=False``
    (osqp/osqp#785). Another thread's prints during a solve are swallowed too."""
    return contextlib.redirect_stdout(io.StringIO())


@dataclass
class CondensedQP:
    """One design speed's QP in the commands ``U`` (``horizon`` x n_act, stacked by step):
    ``1/2 U'HU + (F z0)'U`` subject to ``lower - G z0 <= C U <= upper - G z0``."""

    hessian: sparse.csc_matrix
    linear: np.ndarray  # F (n_u, n_z)
    constraint: sparse.csc_matrix  # C (n_c, n_u)
    offset: np.ndarray  # G (n_c, n_z)
    lower: np.ndarray
    upper: np.ndarray


def condensed_qp(a: np.ndarray, b: np.ndarray, q: np.ndarray, s: np.ndarray, r: np.ndarray, p: np.ndarray,
                 m_z: np.ndarray, m_u: np.ndarray, rate_limit: np.ndarray, delays, horizon: int,
                 rate_factor: np.ndarray | None = None) -> CondensedQP:  # fmt: skip
    """The MPC problem of the module docstring at one design point, condensed on ``z0``; each
    channel's constrained rate is ``rate_factor`` (default 1) times its rate at the sample."""
    n, m = b.shape
    phi = np.zeros(((horizon + 1) * n, n))
    gamma = np.zeros(((horizon + 1) * n, horizon * m))
    power = np.eye(n)
    for k in range(horizon + 1):
        phi[k * n : (k + 1) * n] = power
        power = a @ power
    for k in range(1, horizon + 1):
        gamma[k * n : (k + 1) * n] = a @ gamma[(k - 1) * n : k * n]
        gamma[k * n : (k + 1) * n, (k - 1) * m : k * m] += b
    q_bar = sparse.block_diag([q] * horizon + [p]).toarray()
    s_bar = np.zeros(((horizon + 1) * n, horizon * m))
    for k in range(horizon):
        s_bar[k * n : (k + 1) * n, k * m : (k + 1) * m] = s
    r_bar = sparse.block_diag([r] * horizon).toarray()
    cross = gamma.T @ s_bar
    hessian = 2.0 * (gamma.T @ q_bar @ gamma + cross + cross.T + r_bar)
    hessian = 0.5 * (hessian + hessian.T)
    linear = 2.0 * (gamma.T @ q_bar @ phi + s_bar.T @ phi)
    rows_c, rows_g, limits = [np.eye(horizon * m)], [np.zeros((horizon * m, n))], [np.ones(horizon * m)]
    for k in range(horizon):
        z_rows = slice(k * n, (k + 1) * n)
        for j, d in enumerate(delays):
            if not np.isfinite(rate_limit[j]) or k < d:  # no limit, or a rate the commands can no longer move
                continue
            scale = (1.0 if rate_factor is None else rate_factor[j]) / rate_limit[j]  # relative to the limit: rows of comparable size
            c = m_z[j] @ gamma[z_rows] * scale
            c[k * m : (k + 1) * m] += m_u[j] * scale
            rows_c.append(c[None, :])
            rows_g.append((m_z[j] @ phi[z_rows] * scale)[None, :])
            limits.append(np.ones(1))
    c_all, g_all, bound = np.vstack(rows_c), np.vstack(rows_g), np.concatenate(limits)
    return CondensedQP(sparse.triu(sparse.csc_matrix(hessian), format="csc"), linear, sparse.csc_matrix(c_all), g_all,
                       -bound, bound)  # fmt: skip


class MPCReference(PrivilegedController):
    """The privileged reference with the force and rate limits as hard constraints: a QP per row
    and step (module docstring). Full-state observation, told the true scenario."""

    name = "privileged_mpc"
    knows = "true scenario"
    weights_by_conicity = MPC_WEIGHTS_BY_CONICITY

    def __init__(self, env_config: dict, r: float | None = None, rate_weight: float | None = None,
                 step_kmh: float = 10.0, scenario: Scenario | None = None, loop_config: Mapping[str, Any] | None = None,
                 v_range_kmh: tuple[float, float] | None = None, horizon: int = DEFAULT_HORIZON,
                 rate_basis: str = "step") -> None:  # fmt: skip
        if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
            raise ValueError(f"MPCReference: horizon = {horizon!r}; allowed: an integer >= 1 (env steps)")
        if rate_basis not in RATE_BASES:
            raise ValueError(f"MPCReference: rate_basis = {rate_basis!r}; allowed: {', '.join(RATE_BASES)}")
        self.horizon = int(horizon)
        self.rate_basis = rate_basis
        self._qps: dict[int, CondensedQP] = {}
        self._solvers: dict[int, Any] = {}
        self.fallbacks = 0
        super().__init__(env_config, r, rate_weight, step_kmh, scenario, loop_config, v_range_kmh)
        self._previous = np.zeros((0, self.horizon * self.n_act))

    def tell(self, scenario: Scenario, loop_config: Mapping[str, Any]) -> "MPCReference":
        """The reference designed for ``scenario`` in the loop of ``loop_config``, with this one's
        weights, horizon and rate basis."""
        step = float(self.speeds_kmh[1] - self.speeds_kmh[0]) if len(self.speeds_kmh) > 1 else 10.0
        return type(self)(self.config, *self.weights_given, step, scenario, loop_config, self._v_range, self.horizon, self.rate_basis)

    def qp(self, k: int) -> CondensedQP:
        """The condensed QP at design speed ``k`` (built on first use)."""
        if k not in self._qps:
            a, b, q, s, r = self.loop_problem(self.points[k].speed)
            p = solve_discrete_are(a, b, q, r, s=s)
            n_x = a.shape[0] - self.n_act - sum(self.delays)
            m_z, m_u = force_rate_rows(a.shape[0], n_x, self.delays, self.bandwidth, self.channel_gain * self.max_force)
            self._qps[k] = condensed_qp(a, b, q, s, r, p, m_z, m_u, self.rate_limit, self.delays, self.horizon, self.rate_factor)
        return self._qps[k]

    @property
    def rate_factor(self) -> np.ndarray:
        """Per channel, the constrained rate over the rate at the sample: 1 (``rate_basis``
        "sample") or the step's mean rate of the lag, ``(1 - exp(-w dt)) / (w dt)`` ("step")."""
        if self.rate_basis == "sample":
            return np.ones(self.n_act)
        wdt = self.bandwidth * self.dt
        return -np.expm1(-wdt) / wdt

    def solver(self, k: int) -> Any:
        """An OSQP instance set up for design speed ``k`` (one per speed, reused by every row)."""
        if k not in self._solvers:
            import osqp

            qp = self.qp(k)
            n_u = qp.linear.shape[0]
            solver = osqp.OSQP()
            solver.setup(P=qp.hessian, q=np.zeros(n_u), A=qp.constraint, l=qp.lower.copy(), u=qp.upper.copy(),
                         verbose=False, warm_starting=True, eps_abs=1e-6, eps_rel=1e-6, max_iter=4000, polishing=True)  # fmt: skip
            self._solvers[k] = solver
        return self._solvers[k]

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        super().reset(n_envs, rows)
        shape = (n_envs, self.horizon * self.n_act)
        if rows is None or self._previous.shape != shape:
            self._previous = np.zeros(shape)
        else:
            self._previous[rows] = 0.0

    def command(self, x_lat: np.ndarray, gains: np.ndarray) -> np.ndarray:
        raise NotImplementedError("MPCReference.command: a linear law with given gains is not this controller's; "
                                  "use planned_command(x_lat, speed_kmh)")

    def planned_command(self, x_lat: np.ndarray, speed_kmh: np.ndarray,
                        designs: Sequence["MPCReference"] | None = None) -> np.ndarray:  # fmt: skip
        """The first command of each row's plan for lateral states ``x_lat`` (n, 16) at
        ``speed_kmh`` (n,), the loop states as they stand (nothing advances: :meth:`advance` does);
        a row whose QP OSQP does not solve takes the privileged LQR's clipped command. ``designs``
        (one per row, default this one) gives each row's QPs: a bank of scenarios whose rows share
        this controller's loop states (``bogie_agents.training.distill.MPCTeacherBank``)."""
        z = np.concatenate([x_lat, self.force_state, self.registers()], axis=1)
        if self._previous.shape[0] != z.shape[0]:
            self._previous = np.zeros((z.shape[0], self.horizon * self.n_act))
        grid = float(self.speeds_kmh[1] - self.speeds_kmh[0]) if len(self.speeds_kmh) > 1 else 1.0
        nearest = np.clip(np.rint((speed_kmh - self.speeds_kmh[0]) / grid), 0, len(self.speeds_kmh) - 1).astype(int)
        out = np.empty((z.shape[0], self.n_act))
        with quiet_osqp():
            self._solve_rows(z, nearest, out, designs)
        return out

    def _solve_rows(self, z: np.ndarray, nearest: np.ndarray, out: np.ndarray,
                    designs: Sequence["MPCReference"] | None = None) -> None:  # fmt: skip
        """Each row's QP at its design speed ``nearest``; the first commands into ``out``."""
        for i, k in enumerate(nearest.tolist()):
            design = self if designs is None else designs[i]
            qp, solver = design.qp(k), design.solver(k)
            g = qp.offset @ z[i]
            solver.update(q=qp.linear @ z[i], l=qp.lower - g, u=qp.upper - g)
            solver.warm_start(x=np.concatenate([self._previous[i, self.n_act :], self._previous[i, -self.n_act :]]))
            result = solver.solve(raise_error=False)
            if result.info.status_val in (1, 2) and np.all(np.isfinite(result.x)):  # solved (or to lower accuracy)
                self._previous[i] = result.x
                out[i] = np.clip(result.x[: self.n_act], -1.0, 1.0)
            else:
                self.fallbacks += 1
                self._previous[i] = 0.0
                out[i] = np.clip(-design.points[k].gain @ z[i], -1.0, 1.0)


class SensorMPCReference(SensorFed, MPCReference):
    """``privileged_mpc`` seeing only the sensors: told the true scenario, its lateral states from
    a Kalman filter designed on that scenario (:class:`bogie_agents.controllers.privileged.SensorFed`).
    Against ``privileged_mpc`` it measures what the sensors cost the headroom; not a baseline."""

    name = "privileged_mpc_sensors"


class SensorMPC(SensorMPCReference):
    """A buildable MPC (``mpc``): ``privileged_mpc_sensors`` told only what ``lqg_rate`` is told,
    the conicity class (the config's conicity), and designed on the nominal bogie at that
    conicity with every channel working. Sensors only; a baseline like any classical row."""

    name = "mpc"
    privileged = False
    knows = "conicity class"


__all__ = ["CondensedQP", "DEFAULT_HORIZON", "MPCReference", "SensorMPC", "SensorMPCReference", "condensed_qp"]
