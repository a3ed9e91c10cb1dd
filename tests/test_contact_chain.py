"""The chain from the contact inputs to the critical speed, against oracles that share no code
with bogie_env: Table 1 typed from the paper, a Carlson-integral Hertz solution, Kalker's table,
Klingel's wavelength, a roll-locked textbook bogie and the sympy vector-mechanics derivation.

Each test fails for at least one planted bug (``studies/planted_bugs.py``, docs/model.md
Section 10): a creep coefficient off by 10 %, a wrong conicity, mass or spring position, a
printed sign."""

import math

import numpy as np
import pytest

from bogie_env.contact import hertz_ellipse
from bogie_env.dynamics import COEFFICIENT_NAMES, BogieModel, state_index
from bogie_env.stability import critical_speed

from .oracles import contact_chain as oracle

# Table 1 of Bustos et al. (2022) in SI units, typed from the paper (Wpa as the force 1.5e5 N,
# Section 5), plus the assumptions A1, A2, A4, A5 of docs/model.md.
TABLE1 = dict(mb=1610.0, Ibz=2820.0, mw=1570.0, Iwx=693.0, Iwy=121.0, Iwz=693.0, L1=1.5, L2=1.5,
              b1=1.02, b2=1.04, b3=1.34, h1=0.42, h2=0.14, Wpa=1.5e5, e=0.7175, r0=0.46, lam=0.025,
              Kpx=5.8e7, Kpy=1.6e7, Kpz=5.4e5, Cpx=0.0, Cpy=0.0, Cpz=5.0e3, Ksx=1.0e5, Ksy=1.0e5,
              Csx=1.3e4, Csy=3.0e4, Kr=1.617e7, delta=0.009)  # fmt: skip
ASSUMED = dict(E=2.1e11, nu=0.3, mu=0.3, Rrail=0.30)
# Accuracy of the paper's fits, Eqs. (11)-(14), against Kalker's table for a >= b (docs/model.md A15)
FIT_TOLERANCE = {"f11": 0.025, "f12": 0.025, "f22": 0.05, "f33": 0.025}


@pytest.fixture(scope="module")
def independent_creep():
    return oracle.creep_coefficients(0.5 * TABLE1["Wpa"], TABLE1["r0"], ASSUMED["Rrail"], ASSUMED["E"], ASSUMED["nu"])


@pytest.fixture(scope="module")
def independent_alpha(independent_creep):
    return oracle.saturation_at_rest(independent_creep["f12"], TABLE1["lam"], TABLE1["r0"], ASSUMED["mu"],
                                     0.5 * TABLE1["Wpa"])  # fmt: skip


def kernel_values(model: BogieModel) -> dict:
    """The numbers the compiled right-hand side reads, by name."""
    return dict(zip(COEFFICIENT_NAMES, map(float, model.coefficients)))


@pytest.mark.parametrize("ratio", [1.0, 1.533, 4.0, 0.3])
def test_hertz_legendre_and_carlson_forms_agree(ratio):
    ours = hertz_ellipse(75e3, 1.087, 1.087 * ratio, 2.1e11, 0.3)
    a, b = oracle.hertz_semi_axes(75e3, 1.087, 1.087 * ratio, 2.1e11, 0.3)
    assert ours.a == pytest.approx(a, rel=1e-9) and ours.b == pytest.approx(b, rel=1e-9)


def test_kernel_creep_coefficients_match_hertz_and_kalker_table(paper_model, independent_creep):
    """The coefficients the kernels use, against Hertz + Kalker's table from Table 1 alone."""
    values = kernel_values(paper_model)
    for name, tolerance in FIT_TOLERANCE.items():
        assert values[name] == pytest.approx(independent_creep[name], rel=tolerance), name
    assert paper_model.creep.contact.a == pytest.approx(independent_creep["a"], rel=1e-9)
    assert paper_model.creep.contact.b == pytest.approx(independent_creep["b"], rel=1e-9)


@pytest.mark.parametrize("speed", [30.0, 100.0])
def test_jacobian_creep_terms_close_the_chain(paper_model, independent_creep, independent_alpha, speed):
    """Single creep terms of the exact Jacobian (Kalker's linear law with the wheelset's mass and
    inertia of Table 1) against the independent coefficients."""
    jac = paper_model.jacobian(paper_model.equilibrium(speed), speed)
    f = {k: independent_alpha * v for k, v in independent_creep.items() if k.startswith("f")}
    t = TABLE1
    y1, dy1, psi1, dpsi1 = (state_index(n) for n in ("y1", "dy1", "psi1", "dpsi1"))
    expected = {
        (dy1, dy1): -2 * f["f11"] / speed / t["mw"],  # lateral creep damping (Cpy = 0)
        (dy1, psi1): 2 * f["f11"] / t["mw"],  # lateral creep stiffness against yaw
        (dy1, dpsi1): -2 * f["f12"] / speed / t["mw"],  # spin creep
        (dpsi1, y1): -2 * t["e"] * f["f33"] * t["lam"] / t["r0"] / t["Iwz"],  # rolling-radius difference
    }
    tolerance = {(dy1, dy1): "f11", (dy1, psi1): "f11", (dy1, dpsi1): "f12", (dpsi1, y1): "f33"}
    for (row, col), value in expected.items():
        assert jac[row, col] == pytest.approx(value, rel=FIT_TOLERANCE[tolerance[row, col]]), (row, col)


def test_free_wheelset_hunts_at_klingel_frequency_with_real_contact(paper_params):
    """The paper's wheelset with its own contact chain, spin, gravitational terms and roll, free
    of the primary lateral and yaw suspension: at walking pace the creep forces dominate
    inertia and it hunts at Klingel's V / (2 pi sqrt(e r0 / lam)), Table 1's geometry."""
    model = BogieModel(paper_params.replace(Kpx=0.0, Kpy=0.0, Cpx=0.0, Cpy=0.0))
    speed = 5.0
    idx = [state_index(n) for n in ("y1", "dy1", "psi1", "dpsi1", "phi1", "dphi1")]
    eig = np.linalg.eigvals(model.jacobian(model.equilibrium(speed), speed)[np.ix_(idx, idx)])
    klingel_hz = speed / (2 * math.pi * math.sqrt(TABLE1["e"] * TABLE1["r0"] / TABLE1["lam"]))
    frequencies = np.abs(eig.imag) / (2 * math.pi)
    closest = frequencies[np.argmin(np.abs(frequencies - klingel_hz))]
    assert closest == pytest.approx(klingel_hz, rel=3e-3)


def _roll_locked_rate(model: BogieModel):
    names = oracle.ROLL_LOCKED_STATES
    idx = [state_index(n) for n in names] + [state_index("d" + n) for n in names]

    def rate(speed):
        jac = model.jacobian(model.equilibrium(speed), speed)
        return np.linalg.eigvals(jac[np.ix_(idx, idx)]).real.max()

    return rate


def test_roll_locked_bogie_matches_textbook_equations(paper_model, independent_creep, independent_alpha):
    """Roll held at zero, the package's bogie is the textbook two-axle bogie in lateral and yaw.
    With the kernel's own coefficients the two critical speeds agree to rounding; with the
    independent Hertz + Kalker-table coefficients they agree to the fits' accuracy."""
    ours = oracle.first_crossing(_roll_locked_rate(paper_model), 20.0, 240.0)
    kernel = kernel_values(paper_model)
    kernel_alpha = oracle.saturation_at_rest(kernel["f12"], TABLE1["lam"], TABLE1["r0"], ASSUMED["mu"],
                                             0.5 * TABLE1["Wpa"])  # fmt: skip

    def textbook_rate(creep, alpha):
        return lambda v: np.linalg.eigvals(oracle.roll_locked_bogie_matrix(TABLE1, creep, v, alpha)).real.max()

    same_inputs = oracle.first_crossing(textbook_rate(kernel, kernel_alpha), 20.0, 240.0)
    independent = oracle.first_crossing(textbook_rate(independent_creep, independent_alpha), 20.0, 240.0)
    assert ours == pytest.approx(same_inputs, rel=1e-6)
    assert ours * 3.6 == pytest.approx(independent * 3.6, abs=2.0)


def test_critical_speed_from_table1_and_independent_contact(paper_model, independent_creep, independent_alpha):
    """The full 10-DOF critical speed, end to end: Table 1 + Hertz + Kalker's table into the
    sympy vector-mechanics derivation, against ``critical_speed`` of the default preset."""
    pytest.importorskip("sympy")
    from .oracles import linear_bogie_oracle as vector_oracle

    params = {**TABLE1, "mu": ASSUMED["mu"], **{k: v for k, v in independent_creep.items() if k.startswith("f")}}
    reference_kmh, reference_hz = vector_oracle.critical_speed(params, step=5.0)  # 5 km/h scan, then brentq to 0.01 km/h
    ours = critical_speed(paper_model)
    assert ours.speed_kmh == pytest.approx(reference_kmh, abs=2.0)
    assert ours.frequency_hz == pytest.approx(reference_hz, rel=0.02)
