"""The right-hand side against independent oracles: symmetry, equilibrium, Jacobian by finite
differences, the single-wheelset closed forms (Wickens), Klingel's kinematic wavelength,
the rigid-bogie wavelength, and the power neutrality of the gyroscopic coupling."""

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from bogie_env.dynamics import (
    ANTISYMMETRIC_STATES,
    N_STATES,
    N_TRACK,
    P_IWY,
    P_KPX,
    P_KPY,
    jacobian_kernel,
    STATE_NAMES,
    BogieModel,
    frame_lateral_accel,
    rhs_single_kernel,
    solve_dense,
    state_index,
)
from bogie_env.contact import saturation_factor
from bogie_env.track import (
    ALIGNMENT_WHEELSET1,
    ALIGNMENT_WHEELSET2,
    CANT_FRAME,
    CANT_WHEELSET1,
    CANT_WHEELSET2,
    CURVATURE_FRAME,
    CURVATURE_WHEELSET1,
    CURVATURE_WHEELSET2,
)

Y1, DY1, PSI1, DPSI1 = (state_index(n) for n in ("y1", "dy1", "psi1", "dpsi1"))


def random_states(rng, n, scale=1.0):
    """Random states of realistic size: mm, mrad, and their rates; some in flange contact."""
    size = np.array([5e-3, 5e-2, 1e-4, 1e-3, 3e-3, 3e-2, 2e-3, 2e-2] * 2 + [5e-3, 5e-2, 3e-3, 3e-2])
    return scale * size * rng.standard_normal((n, N_STATES))


def test_shapes_and_bad_input(paper_model, rng):
    x = random_states(rng, 5)
    assert paper_model.rhs(x, 100.0).shape == (5, 20)
    assert paper_model.rhs(x[0], 100.0).shape == (20,)
    np.testing.assert_allclose(paper_model.rhs(x, np.full(5, 100.0)), paper_model.rhs(x, 100.0))
    with pytest.raises(ValueError, match=r"state has shape \(5, 19\)"):
        paper_model.rhs(x[:, :19], 100.0)
    bad = x.copy()
    bad[2, 3] = np.nan
    with pytest.raises(ValueError, match="state contains NaN"):
        paper_model.rhs(bad, 100.0)
    for speed in (0.0, -10.0, np.nan, np.inf, 300.0):
        with pytest.raises(ValueError, match="speed .* not allowed; allowed: finite, 1 to 250 m/s"):
            paper_model.rhs(x, speed)
    with pytest.raises(ValueError, match="inputs has shape"):
        paper_model.rhs(x, 100.0, inputs=np.zeros(3))
    with pytest.raises(ValueError, match="track contains NaN"):
        paper_model.rhs(x, 100.0, track=np.array([np.nan, 0.0]))


def test_mirror_symmetry(paper_model, rng):
    """Reflecting y -> -y maps solutions to solutions: f(Mx, -Q, -yt) = M f(x, Q, yt)."""
    mirror = np.ones(N_STATES)
    mirror[list(ANTISYMMETRIC_STATES)] = -1.0
    x = random_states(rng, 64, scale=2.0)  # includes flange contact and saturation
    q = 1e4 * rng.standard_normal((64, 4))
    yt = 2e-3 * rng.standard_normal((64, 2))
    direct = paper_model.rhs(x, 90.0, q, yt)
    mirrored = paper_model.rhs(x * mirror, 90.0, -q, -yt)
    np.testing.assert_allclose(mirrored, direct * mirror, rtol=1e-12, atol=1e-12)


def test_equilibrium_residual_and_closed_form_lift(paper_model, paper_params):
    x_eq = paper_model.equilibrium(100.0)
    assert np.max(np.abs(paper_model.rhs(x_eq, 100.0))) < 1e-12
    # Independent closed form: the constant spin creepage lam/r0 gives each wheel a lateral creep
    # force f12 lam/r0 along its inclined contact plane; the vertical components lift the
    # wheelset against 2 Kpz: z0 = alpha0 f12 lam^2 / (r0 Kpz), alpha0 from Eq. (26).
    p, c = paper_params, paper_model.creep
    beta0 = c.f12 * p.lam / p.r0 / (p.mu * p.Wpa / 2)
    z0 = float(saturation_factor(beta0)) * c.f12 * p.lam**2 / (p.r0 * p.Kpz)
    assert x_eq[state_index("z1")] == pytest.approx(z0, rel=1e-10)
    assert x_eq[state_index("z2")] == pytest.approx(z0, rel=1e-10)
    others = np.delete(x_eq, [state_index("z1"), state_index("z2")])
    assert np.max(np.abs(others)) < 1e-15
    # the equilibrium does not depend on speed
    np.testing.assert_allclose(paper_model.equilibrium(50.0), x_eq, rtol=1e-12, atol=1e-15)


def test_solve_dense_matches_lapack_and_flags_a_singular_matrix(rng):
    for n in (1, 4, 20):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b = rng.normal(size=n)
        np.testing.assert_allclose(solve_dense(a, b), np.linalg.solve(a, b), rtol=1e-12, atol=1e-14)
    a = np.array([[0.0, 2.0], [3.0, 1.0]])  # needs a row swap
    np.testing.assert_allclose(solve_dense(a, np.array([4.0, 5.0])), np.linalg.solve(a, [4.0, 5.0]), rtol=1e-15)
    assert np.all(np.isnan(solve_dense(np.array([[1.0, 2.0], [2.0, 4.0]]), np.array([1.0, 1.0]))))


@pytest.mark.skipif("avx2" not in Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else True,
                    reason="forces OpenBLAS's Haswell kernel, which needs AVX2")
def test_equilibrium_bits_do_not_depend_on_the_blas_kernel():
    """Every seeded episode starts from the equilibrium, so its bits must not follow the
    processor-specific kernel that OpenBLAS picks (with LAPACK's least squares they did)."""
    code = ("from bogie_env.dynamics import BogieModel; from bogie_env.params import BogieParams; "
            "m = BogieModel(BogieParams.paper()); "
            "print(''.join(m.equilibrium(v).tobytes().hex() for v in (50.0, 83.3, 150.0)))")  # fmt: skip
    outs = set()
    for kernel in ("Prescott", "Haswell"):
        env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
        outs.add(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout)
    assert len(outs) == 1


@pytest.mark.parametrize("scale", [0.0, 0.3, 2.0])
def test_complex_step_jacobian_matches_central_differences(paper_model, rng, scale):
    x = paper_model.equilibrium(100.0) + random_states(rng, 1, scale)[0]
    if scale:  # keep clear of the flange kink, where finite differences are not meaningful
        x[[0, 8]] = np.clip(x[[0, 8]], -8e-3, 8e-3)
    jac = paper_model.jacobian(x, 100.0)
    numeric = np.empty_like(jac)
    for j in range(N_STATES):
        h = 1e-7 * max(1e-3, abs(x[j]))
        up, down = x.copy(), x.copy()
        up[j] += h
        down[j] -= h
        numeric[:, j] = (paper_model.rhs(up, 100.0) - paper_model.rhs(down, 100.0)) / (2 * h)
    np.testing.assert_allclose(jac, numeric, rtol=2e-5, atol=1e-6 * np.max(np.abs(jac)))


def test_inputs_enter_as_generalised_forces(paper_model, rng):
    x = random_states(rng, 1)[0]
    q = np.array([3e3, -2e3, 1e3, 5e2])
    delta = paper_model.rhs(x, 80.0, q) - paper_model.rhs(x, 80.0)
    np.testing.assert_allclose(delta, paper_model.input_matrix() @ q, rtol=1e-10, atol=1e-12)
    p = paper_model.params
    assert delta[state_index("dyb")] == pytest.approx(3e3 / p.mb)
    assert delta[state_index("dpsi2")] == pytest.approx(5e2 / p.Iwz)


def test_track_enters_through_relative_displacement(paper_model, paper_params):
    """Moving wheelset 1 and the rail under it together changes only the suspension force."""
    x = paper_model.equilibrium(80.0)
    d = 2e-3
    shifted = x.copy()
    shifted[Y1] += d
    delta = paper_model.rhs(shifted, 80.0, track=[d, 0.0]) - paper_model.rhs(x, 80.0)
    p = paper_params
    expected = np.zeros(N_STATES)
    expected[DY1] = -2 * p.Kpy * d / p.mw
    expected[state_index("dyb")] = 2 * p.Kpy * d / p.mb
    expected[state_index("dpsib")] = 2 * p.Kpy * p.L1 * d / p.Ibz
    np.testing.assert_allclose(delta, expected, rtol=1e-9, atol=1e-9)


def test_frame_lateral_acceleration_alone_equals_the_full_right_hand_side(paper_model, rng):
    """The observation's frame acceleration (``frame_lateral_accel``, no wheel-rail contact) is
    bit for bit the frame's lateral equation of the full right-hand side, in curves with cant too."""
    out = np.empty(N_STATES)
    for scale in (0.3, 1.0, 3.0):
        for x in random_states(rng, 8, scale):
            q = rng.normal(scale=2e4, size=4)
            yt = np.zeros(N_TRACK)
            yt[[ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET2]] = rng.normal(scale=2e-3, size=2)
            if scale > 1.0:  # curvature (R about 10 km) and cant (about 0.1 rad) under the frame and each wheelset
                yt[[CURVATURE_WHEELSET1, CURVATURE_WHEELSET2, CURVATURE_FRAME]] = rng.normal(scale=1e-4, size=3)
                yt[[CANT_WHEELSET1, CANT_WHEELSET2, CANT_FRAME]] = rng.normal(scale=0.1, size=3)
            rhs_single_kernel(x, 83.0, q, yt, paper_model.coefficients, out)
            assert frame_lateral_accel(x, 83.0, q, yt, paper_model.coefficients) == out[state_index("dyb")]


def test_gyroscopic_coupling_is_power_neutral(paper_model, rng):
    """The Iwy terms of Eqs. (5)-(6) exchange power between yaw and roll but create none."""
    p_no_gyro = paper_model.coefficients.copy()
    p_no_gyro[P_IWY] = 0.0
    p_no_gyro.setflags(write=False)  # like the model's: the kernel's compiled signature, not a second one
    x = random_states(rng, 1)[0]
    q, yt = np.zeros(4), np.zeros(2)
    with_gyro, without = np.empty(N_STATES), np.empty(N_STATES)
    rhs_single_kernel(x, 90.0, q, yt, paper_model.coefficients, with_gyro)
    rhs_single_kernel(x, 90.0, q, yt, p_no_gyro, without)
    d = with_gyro - without
    prm = paper_model.params
    power = 0.0
    for w in range(2):
        o = 8 * w
        power += prm.Iwz * x[o + 5] * d[o + 5] + prm.Iwx * x[o + 7] * d[o + 7]
    scale = prm.Iwy * 90.0 / prm.r0 * np.max(np.abs(x)) ** 2
    assert abs(power) < 1e-12 * scale
    assert np.max(np.abs(d)) > 0  # the coupling is really there


# --- single wheelset oracles ----------------------------------------------------------------
def _wheelset_block(model, speed):
    """Linear dynamics of wheelset 1 in (y, dy, psi, dpsi) with frame, roll and the other
    wheelset clamped at equilibrium: the matching rows and columns of the exact Jacobian."""
    idx = [Y1, DY1, PSI1, DPSI1]
    jac = model.jacobian(model.equilibrium(speed), speed)
    return jac[np.ix_(idx, idx)]


def _wickens_model(paper_params, k_psi=2e6, f_lat=8e6, f_lon=9e6, mass=1500.0, inertia=700.0,
                   l0=0.75, r0=0.46, lam=0.15):
    b1 = paper_params.b1
    return BogieModel(paper_params.replace(
        mw=mass, Iwz=inertia, e=l0, r0=r0, lam=lam, Kpy=0.0, Cpy=0.0, Kpx=k_psi / (2 * b1**2), Cpx=0.0,
        f11=f_lat, f33=f_lon, f12=0.0, f22=0.0,
    ))


def test_single_wheelset_closed_form_formula_reproduces_the_oracle_example():
    # The closed form itself (oracles.md): m=1500, I=700, f_lat=8e6, f_lon=9e6, l0=0.75,
    # r0=0.46, lam=0.15, k_psi=2e6 gives V_c = 53.6 m/s.
    m, i, f_lat, f_lon, l0, r0, lam, k = 1500, 700, 8e6, 9e6, 0.75, 0.46, 0.15, 2e6
    a = m * f_lon * l0**2 + i * f_lat
    vc = math.sqrt(4 * f_lat * l0 * k * a / (4 * a**2 * lam / r0 - m**2 * l0 * k**2))
    assert vc == pytest.approx(53.6, abs=0.05)


def test_single_wheelset_critical_speed_closed_form_and_routh_hurwitz(paper_params):
    k_psi, f_lat, f_lon, m, inertia, l0, r0, lam = 2e6, 8e6, 9e6, 1500.0, 700.0, 0.75, 0.46, 0.15
    model = _wickens_model(paper_params, k_psi, f_lat, f_lon, m, inertia, l0, r0, lam)
    # The model's gravitational yaw stiffness e W lam (Eq. 49) softens the yaw spring.
    k_eff = k_psi - l0 * paper_params.Wpa * lam
    a = m * f_lon * l0**2 + inertia * f_lat
    vc_closed = math.sqrt(4 * f_lat * l0 * k_eff * a / (4 * a**2 * lam / r0 - m**2 * l0 * k_eff**2))

    def routh_hurwitz(v):
        cy, cpsi = 2 * f_lat / v, 2 * f_lon * l0**2 / v
        a4, a3, a2, a1, a0 = m * inertia, m * cpsi + inertia * cy, m * k_eff + cy * cpsi, cy * k_eff, \
            4 * f_lat * f_lon * lam * l0 / r0
        return a3 * a2 * a1 - a4 * a1**2 - a3**2 * a0

    vc_rh = brentq(routh_hurwitz, 5.0, 200.0, xtol=1e-10)
    vc_model = brentq(lambda v: np.linalg.eigvals(_wheelset_block(model, v)).real.max(), 5.0, 200.0, xtol=1e-8)
    assert vc_rh == pytest.approx(vc_closed, rel=1e-9)
    assert vc_model == pytest.approx(vc_closed, rel=1e-6)


def test_single_wheelset_stable_at_all_speeds_when_denominator_is_negative(paper_params):
    # Very stiff yaw restraint: 4 A^2 lam/r0 - m^2 l0 k^2 < 0, so no critical speed exists.
    model = _wickens_model(paper_params, k_psi=2e8)
    rates = [np.linalg.eigvals(_wheelset_block(model, v)).real.max() for v in (10.0, 60.0, 120.0, 240.0)]
    assert max(rates) < 0


@pytest.mark.parametrize("speed", [30.0, 80.0, 160.0])
def test_free_wheelset_approaches_klingel_frequency(paper_params, speed):
    """No suspension, very large creep coefficients: hunting at V / (2 pi sqrt(e r0 / lam))."""
    p = paper_params
    model = BogieModel(p.replace(Kpx=0.0, Kpy=0.0, f11=5e9, f33=5e9, f12=0.0, f22=0.0))
    eig = np.linalg.eigvals(_wheelset_block(model, speed))
    slow = eig[np.argmin(np.abs(eig))]
    klingel_hz = speed / (2 * math.pi * math.sqrt(p.e * p.r0 / p.lam))
    assert abs(slow.imag) / (2 * math.pi) == pytest.approx(klingel_hz, rel=2e-3)
    assert abs(slow.real) < 0.02 * abs(slow.imag)


@pytest.mark.parametrize("speed", [40.0, 100.0])
def test_rigid_bogie_kinematic_wavelength(paper_params, speed):
    """Rigid two-axle bogie, equal creep coefficients, free of the car body:
    L = 2 pi sqrt((r0 e / lam) (1 + L1^2 / e^2)). Exercises the frame and primary equations.
    "Rigid" is a mathematical limit (primary stiffness 1e12, beyond the plausible config range),
    so it is set on the kernel's coefficient vector."""
    p = paper_params
    model = BogieModel(p.replace(Ksx=0.0, Ksy=0.0, Csx=0.0, Csy=0.0, f11=1e8, f33=1e8, f12=0.0, f22=0.0))
    coefficients = model.coefficients.copy()
    coefficients[[P_KPX, P_KPY]] = 1e12
    coefficients.setflags(write=False)  # like the model's: the kernel's compiled signature, not a second one
    jac = np.empty((N_STATES, N_STATES))
    jacobian_kernel(np.zeros(N_STATES), speed, np.zeros(4), np.zeros(2), coefficients, jac)
    idx = [state_index(n) for n in ("y1", "dy1", "psi1", "dpsi1", "y2", "dy2", "psi2", "dpsi2",
                                    "yb", "dyb", "psib", "dpsib")]
    eig = np.linalg.eigvals(jac[np.ix_(idx, idx)])
    slow = eig[np.argmin(np.abs(eig))]
    wavelength = 2 * math.pi * math.sqrt(p.r0 * p.e / p.lam * (1 + p.L1**2 / p.e**2))
    assert abs(slow.imag) / (2 * math.pi) == pytest.approx(speed / wavelength, rel=1e-3)
    # and it is not the single wheelset's wavelength
    assert abs(slow.imag) / (2 * math.pi) < 0.5 * speed / (2 * math.pi * math.sqrt(p.r0 * p.e / p.lam))


def test_vertical_states_do_not_feed_back(paper_model, rng):
    """z and dz appear only in their own equations, so the lateral spectrum is separable."""
    jac = paper_model.jacobian(paper_model.equilibrium(100.0) + random_states(rng, 1, 0.3)[0], 100.0)
    vertical = [state_index(n) for n in ("z1", "dz1", "z2", "dz2")]
    others = [i for i in range(N_STATES) if i not in vertical]
    assert np.all(jac[np.ix_(others, vertical)] == 0.0)


def test_state_names_are_the_papers_order():
    assert STATE_NAMES[:8] == ("y1", "dy1", "z1", "dz1", "psi1", "dpsi1", "phi1", "dphi1")
    assert STATE_NAMES[16:] == ("yb", "dyb", "psib", "dpsib")
    with pytest.raises(KeyError, match="unknown state 'q'"):
        state_index("q")
