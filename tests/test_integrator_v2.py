"""The 10-stage Taylor integrator of Bogie/Hunting-v2 (docs/studies/integrator.md).

- the compiled kernel's wheelset-mode decay rate, measured by projecting a small perturbation
  on the mode, against the exact linear eigenvalue (v1's 10 % criterion) and against the
  method's own stability polynomial; RK4 at the same step fails the same check;
- convergence against RK4 at 160 substeps: second order at least;
- actuated runs: v2 follows v1 (RK4, 10 substeps) closely, power included;
- the env ids: v2 takes 2 substeps of the 10-stage method, v1 keeps RK4 at 10.
"""

from __future__ import annotations

import numpy as np
import pytest

from bogie_env.dynamics import BogieModel
from bogie_env.integrate import METHOD_STAGES, accurate_substep, taylor_effective_eigenvalue
from bogie_env.simulator import BatchSimulator

KMH = 3.6
DT = 0.01
STAGES = METHOD_STAGES["taylor10"]


def _run(model, x0, speed, n_sub, stages, n_steps):
    sim = BatchSimulator(model, 1, DT, (speed, speed), n_sub=n_sub, stages=stages)
    sim.set_rows(0, x0, speed, 0.0)
    states, _ = sim.run(n_steps, 1)
    return states[:, 0]


def _mode_decay(model, speed, n_sub, stages):
    """(measured decay rate, exact eigenvalue, predicted effective eigenvalue) of the least
    damped mode above 60 Hz (the wheelsets' yaw against the primary suspension, ~84 Hz), over
    the time in which it decays by e^-6 (far above the rounding floor)."""
    x_eq = model.equilibrium(speed)
    j = model.jacobian(x_eq, speed)
    lam, vec = np.linalg.eig(j)
    fast = np.nonzero(lam.imag > 2 * np.pi * 60)[0]
    k = fast[np.argmax(lam[fast].real)]
    n_steps = max(4, int(6.0 / abs(lam[k].real) / DT))
    left = np.linalg.inv(vec)[k]
    x0 = x_eq + 1e-7 * np.real(vec[:, k]) / np.max(np.abs(vec[:, k]))
    states = _run(model, x0, speed, n_sub, stages, n_steps)
    amplitude = np.abs((states - x_eq) @ left)
    measured = np.log(amplitude[-1] / amplitude[0]) / (n_steps * DT)
    predicted = taylor_effective_eigenvalue(np.array([lam[k]]), DT / n_sub, stages)[0] if stages else np.nan
    return measured, lam[k], predicted


@pytest.mark.parametrize("speed_kmh", [100.0, 350.0, 600.0])
def test_wheelset_mode_decay_rate_within_criterion(speed_kmh):
    assert_mode_decay(speed_kmh, 2, STAGES)


def assert_mode_decay(speed_kmh: float, n_sub: int, method) -> None:
    """The kernel's decay rate of the 84-Hz mode within 10 % of exact (v1's criterion) and, the
    kernel being the method, within 0.2 % of the stability polynomial's, to the linearisation."""
    measured, exact, predicted = _mode_decay(BogieModel(), speed_kmh / KMH, n_sub, method)
    assert abs(measured - exact.real) <= 0.1 * abs(exact.real), (measured, exact)
    assert abs(measured - predicted.real) <= 2e-3 * abs(exact.real), (measured, predicted)


def test_rk4_at_the_same_step_misses_the_mode_decay():
    """The check above can fail: RK4 at 2 substeps (v0's step) damps the 84-Hz mode several times over."""
    model = BogieModel()
    measured, exact, _ = _mode_decay(model, 600 / KMH, 2, 0)
    assert abs(measured - exact.real) > 0.5 * abs(exact.real), (measured, exact)


def test_second_order_convergence_against_rk4_reference():
    """A 3-mm start at 300 km/h on perfect track, 1 s: max error of y1 against RK4 at 160
    substeps, relative to its max, at 2 .. 32 substeps (measured: 4.9e-3, 7.5e-4, 2.5e-4,
    6.4e-5, 1.7e-5)."""
    errors = assert_second_order(STAGES, np.array([2, 4, 8, 16, 32]))
    assert errors[0] < 1e-2, errors


def assert_second_order(method, n_subs: np.ndarray) -> np.ndarray:
    """The relative errors of y1 at ``n_subs`` (a 3-mm start at 300 km/h, perfect track, 1 s,
    against RK4 at 160 substeps), checked to fall by at least 2.5 per halving of the step and
    at a fitted order of at least 1.8."""
    model = BogieModel()
    speed = 300 / KMH
    x0 = model.equilibrium(speed)
    x0[0] += 3e-3
    ref = _run(model, x0, speed, 160, 0, 100)
    errors = np.array([np.max(np.abs(_run(model, x0, speed, n, method, 100)[:, 0] - ref[:, 0])) for n in n_subs])
    errors /= np.max(np.abs(ref[:, 0]))
    assert np.all(errors[:-1] / errors[1:] >= 2.5), errors  # every halving
    slope = -np.polyfit(np.log(n_subs), np.log(errors), 1)[0]
    assert slope >= 1.8, (slope, errors)
    return errors


def test_criterion_picks_two_substeps_for_the_nominal_bogie():
    model = BogieModel()
    assert accurate_substep(model, 100 / KMH, 600 / KMH, DT, stages=STAGES).n_sub == 2
    assert accurate_substep(model, 100 / KMH, 600 / KMH, DT).n_sub > 2  # RK4


def actuated_runs(variants: tuple[str, ...], n: int = 4, steps: int = 200) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each variant's final states, actuator forces and per-step power under the same random
    actions (seed 5) from the same episodes (seeds 0 .. n-1)."""
    from bogie_env.envs.config import make_config
    from bogie_env.envs.task import HuntingTask

    runs = {}
    for variant in variants:
        task = HuntingTask(n, make_config(variant=variant))
        task.seed_rows(np.arange(n), list(range(n)))
        task.reset_rows(np.arange(n))
        rng = np.random.default_rng(5)
        power = []
        for _ in range(steps):
            task.step(rng.uniform(-1, 1, (n, task.action_dim)))
            power.append(task.sim.output[:, 1].copy())
        runs[variant] = (task.sim.x.copy(), task.sim.output[:, 0].copy(), np.array(power))
    return runs


def test_v2_follows_v1_with_actuators():
    """Random actions, 200 steps: v2's states, actuator forces and power against v1's."""
    assert_follows_v1("v2", lateral_share=1e-2)


def assert_follows_v1(variant: str, lateral_share: float) -> None:
    """``variant`` against v1 under :func:`actuated_runs`: lateral displacements within
    ``lateral_share`` of their range, actuator forces within 1 %, mean power within 5 %."""
    runs = actuated_runs(("v1", variant))
    (x1, f1, p1), (x2, f2, p2) = runs["v1"], runs[variant]
    lateral = [0, 8, 16]
    assert np.max(np.abs(x2[:, lateral] - x1[:, lateral])) <= lateral_share * np.max(np.abs(x1[:, lateral])) + 1e-6
    assert np.max(np.abs(f2 - f1)) <= 1e-2 * np.max(np.abs(f1)) + 1.0
    assert np.max(np.abs(np.mean(p2, axis=0) - np.mean(p1, axis=0))) <= 0.05 * np.max(np.abs(np.mean(p1, axis=0))) + 1.0


def test_env_ids():
    import gymnasium as gym

    import bogie_env  # noqa: F401  (registers the ids)

    v2 = gym.make("Bogie/Hunting-v2").unwrapped.task
    assert (v2.stages, v2.n_sub) == (STAGES, 2)
    v1 = gym.make("Bogie/Hunting-v1").unwrapped.task
    assert (v1.stages, v1.n_sub) == (0, 10)
