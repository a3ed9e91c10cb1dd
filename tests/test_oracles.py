"""bogie_env's exact Jacobian against two independent formulations of the linearised model:
a sympy vector-mechanics derivation (cross products of 3-D position and force vectors,
Newton-Euler with the spinning wheelset's angular momentum) and the corrected condensed
Eqs. (47)-(52) typed by hand. Both were written separately from bogie_env."""

import numpy as np
import pytest

sympy = pytest.importorskip("sympy")

from bogie_env.dynamics import COEFFICIENT_NAMES, BogieModel  # noqa: E402
from bogie_env.stability import critical_speed  # noqa: E402

from .oracles import linear_bogie_oracle as vector_oracle  # noqa: E402
from .oracles.condensed_equations import condensed_jacobian  # noqa: E402

ORACLE_KEYS = ("mb Ibz mw Iwx Iwy Iwz L1 L2 b1 b2 b3 h1 h2 Wpa e r0 lam Kpx Kpy Kpz Cpx Cpy Cpz "
               "Ksx Ksy Csx Csy f11 f12 f22 f33 mu").split()  # fmt: skip


def oracle_params(model: BogieModel) -> dict:
    values = dict(zip(COEFFICIENT_NAMES, model.coefficients))
    return {key: float(values[key]) for key in ORACLE_KEYS}


VARIANTS = [
    {},
    {"Kpx": 0.6, "Kpy": 1.4, "Kpz": 2.0, "Csy": 0.5},
    {"Wpa": 0.7, "Ksx": 1.5, "Csx": 0.5, "Cpz": 1.5},
]


@pytest.fixture(scope="module", params=range(len(VARIANTS)), ids=lambda i: f"variant{i}")
def model(request, paper_params):
    params = paper_params.scaled(**VARIANTS[request.param])
    if request.param == 1:  # exercise the primary dampers the paper sets to zero
        params = params.replace(Cpx=2.0e4, Cpy=1.0e4, L2=1.3)
    return BogieModel(params)


@pytest.mark.parametrize("speed", [20.0, 90.0, 170.0])
def test_jacobian_matches_vector_mechanics_derivation(model, speed):
    reference = vector_oracle.jacobian(oracle_params(model), speed)
    ours = model.jacobian(model.equilibrium(speed), speed)
    assert np.max(np.abs(ours - reference)) <= 1e-12 * np.max(np.abs(reference))


@pytest.mark.parametrize("speed", [20.0, 90.0, 170.0])
def test_jacobian_matches_condensed_equations_47_to_52(model, speed):
    params = oracle_params(model)
    _, alpha = vector_oracle.jacobian(params, speed, return_alpha=True)
    reference = condensed_jacobian(params, speed, alpha)
    ours = model.jacobian(model.equilibrium(speed), speed)
    assert np.max(np.abs(ours - reference)) <= 1e-12 * np.max(np.abs(reference))


def test_equilibrium_matches_vector_mechanics_derivation(model):
    np.testing.assert_allclose(model.equilibrium(100.0), vector_oracle.equilibrium(oracle_params(model), 100.0),
                               rtol=1e-10, atol=1e-15)  # fmt: skip


def test_critical_speed_matches_the_oracle(paper_model):
    reference_kmh, reference_hz = vector_oracle.critical_speed(oracle_params(paper_model))
    ours = critical_speed(paper_model)
    assert ours.speed_kmh == pytest.approx(reference_kmh, abs=0.05)
    assert ours.frequency_hz == pytest.approx(reference_hz, rel=1e-3)
