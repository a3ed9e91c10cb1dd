"""The 14-stage designed integrator of Bogie/Hunting-v3 (docs/studies/integrator.md).

- its stability polynomial: second order, the divisors' product form, and the step criterion met
  at one 10-ms substep, where the Taylor polynomial of the same degree is unstable;
- the compiled kernel's wheelset-mode decay rate at one substep against the exact eigenvalue
  (v1's 10 % criterion) and against the method's own polynomial;
- convergence against RK4 at 160 substeps: second order at least;
- actuated runs: v3 follows v1 (RK4, 10 substeps), power included;
- the env ids, and bad stage divisors refused by name.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bogie_env.dynamics import BogieModel
from bogie_env.integrate import (
    METHOD_DIVISORS, METHOD_STAGES, accurate_substep, method_divisors, stable_substep, taylor_polynomial,
)  # fmt: skip
from tests.test_integrator_v2 import assert_follows_v1, assert_mode_decay, assert_second_order

KMH = 3.6
DT = 0.01
METHOD = "poly14"


def assert_second_order_divisors_product(method: str, stages: int) -> np.ndarray:
    """R(z) = 1 + z + z^2/2 + O(z^3), and its coefficients are the running products of 1/d_k
    (Jameson's form), recomputed here from the divisors in the opposite order. Returns c_0 .. c_S."""
    d = METHOD_DIVISORS[method]
    assert METHOD_STAGES[method] == len(d) == stages
    coefficients = np.cumprod([1.0] + [1.0 / x for x in d[::-1]])
    z = np.array([1e-3 + 2e-3j, -0.5 + 3.0j, -4.0 + 6.0j])
    expected = sum(c * z**k for k, c in enumerate(coefficients))
    assert np.allclose(taylor_polynomial(z, method), expected, rtol=1e-13)
    small = 1e-2 * np.exp(1j * np.linspace(0, np.pi, 5))
    err = taylor_polynomial(small, method) - np.exp(small)
    assert np.all(np.abs(err) <= 0.2 * np.abs(small) ** 3)  # third-order local error: second order
    assert coefficients[3] != pytest.approx(1 / 6, rel=1e-6) or coefficients[6] != pytest.approx(1 / 720, rel=1e-6)  # not Taylor
    return coefficients


def assert_one_substep_where_taylor_is_unstable(method: str, stages: int) -> None:
    """The accuracy criterion picks one 10-ms substep for ``method`` over 100-600 km/h, where
    exp's Taylor polynomial of the same degree needs at least two to be stable."""
    model = BogieModel()
    lo, hi = 100 / KMH, 600 / KMH
    assert accurate_substep(model, lo, hi, DT, stages=method).n_sub == 1
    assert stable_substep(model, lo, hi, DT, stages=stages).n_sub >= 2


def test_polynomial_is_second_order_and_the_divisors_product():
    assert_second_order_divisors_product(METHOD, 14)


def test_one_substep_meets_the_criterion_where_taylor_of_the_same_degree_does_not():
    assert_one_substep_where_taylor_is_unstable(METHOD, 14)


@pytest.mark.parametrize("speed_kmh", [100.0, 350.0, 600.0])
def test_wheelset_mode_decay_rate_within_criterion_at_one_substep(speed_kmh):
    assert_mode_decay(speed_kmh, 1, METHOD)


def test_second_order_convergence_against_rk4_reference():
    """A 3-mm start at 300 km/h on perfect track, 1 s: max error of y1 against RK4 at 160
    substeps, relative to its max, at 1 .. 16 substeps."""
    errors = assert_second_order(METHOD, np.array([1, 2, 4, 8, 16]))
    assert errors[0] < 3e-2, errors


def test_v3_follows_v1_with_actuators():
    """Random actions, 200 steps: v3's states, actuator forces and power against v1's. One 10-ms
    substep of a second-order method is less accurate on the time-dependent terms than v2's two
    (measured: lateral displacements 9.4e-5 m off against a range of 5.4e-3 m, 1.7 %; v2 0.3 %),
    so the bound is 3 % of the range where v2's is 1 %."""
    assert_follows_v1("v3", lateral_share=3e-2)


def test_env_ids():
    import gymnasium as gym

    import bogie_env  # noqa: F401  (registers the ids)

    v3 = gym.make("Bogie/Hunting-v3").unwrapped.task
    assert (v3.stages, v3.n_sub) == (14, 1)
    assert np.array_equal(v3.sim.divisors, METHOD_DIVISORS[METHOD])
    passive = gym.make("Bogie/HuntingPassive-v3").unwrapped.task
    assert (passive.stages, passive.n_sub) == (14, 1)


@pytest.mark.parametrize(
    "method, match",
    [
        ("poly13", "'poly13' is not known"),
        (1, "stages = 1 must be 0"),
        ((3.0, 2.0, 0.5), "ending in 2, 1"),
        ((3.0, math.nan, 2.0, 1.0), "finite positive"),
    ],
)
def test_bad_methods_are_refused_by_name(method, match):
    with pytest.raises(ValueError, match=match):
        method_divisors(method)
