"""bogie_env.elliptic.ellipk/ellipe return exactly (==) the floats scipy.special.ellipk/ellipe return.

The oracle is scipy itself, over the whole parameter range and its edges (the Hertz solver of
bogie_env.contact uses 0 <= m < 1): a changed coefficient or a reordered operation in the port
moves the last bits of some value and fails here (checked by planting each of: ellpe's
``log(x) * (x * Q)`` reassociated as ``(log(x) * x) * Q``, a truncated coefficient, every Horner
coefficient one ulp off: 2, 6 and 11 tests fail). A second oracle, independent of Cephes' fits:
the arithmetic-geometric mean (Abramowitz & Stegun 17.6), to 4 ulp.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ellipe as scipy_ellipe
from scipy.special import ellipk as scipy_ellipk

from bogie_env.contact import creep_coefficients, hertz_ellipse
from bogie_env.elliptic import ellipe, ellipk


def _same(ours: float, theirs) -> bool:
    theirs = float(theirs)
    return ours == theirs or (math.isnan(ours) and math.isnan(theirs))


def _agm(m: float) -> tuple[float, float]:
    """K(m) and E(m) by the arithmetic-geometric mean, A&S 17.6.3-17.6.4 (0 <= m < 1)."""
    a, b, c2_sum, power = 1.0, math.sqrt(1.0 - m), m, 1.0  # c2_sum = sum of 2**n c_n**2, c_0**2 = m
    for _ in range(12):  # quadratic convergence: a few steps reach a == b to rounding for m < 1 - 1e-6
        c = 0.5 * (a - b)
        a, b = 0.5 * (a + b), math.sqrt(a * b)
        power *= 2.0
        c2_sum += power * c * c
    k = math.pi / (2.0 * a)
    return k, k * (1.0 - 0.5 * c2_sum)


@settings(max_examples=500, deadline=None)
@given(m=st.floats(0.0, 1.0, exclude_max=True))
def test_equals_scipy_on_the_unit_interval(m: float) -> None:
    assert _same(ellipk(m), scipy_ellipk(m)) and _same(ellipe(m), scipy_ellipe(m))


@settings(max_examples=200, deadline=None)
@given(exponent=st.floats(-20.0, 0.0))
def test_equals_scipy_near_both_ends(exponent: float) -> None:
    """m -> 0 and m -> 1 (K's logarithmic singularity, and its branch at 1 - m <= 2**-53)."""
    for m in (10.0**exponent, 1.0 - 10.0**exponent):
        assert _same(ellipk(m), scipy_ellipk(m)) and _same(ellipe(m), scipy_ellipe(m)), m


@pytest.mark.parametrize("m", [0.0, -0.0, 1.0, 1.0 - 2.0**-53, 5e-324, 1e-300, 0.5, -1.0, -1e300, 2.0, 1e300,
                               math.inf, -math.inf, math.nan])  # fmt: skip
def test_equals_scipy_at_special_values(m: float) -> None:
    """Edges, negative m (the reciprocal-modulus branches), m > 1 and m = 1 (NaN / inf as scipy)."""
    assert _same(ellipk(m), scipy_ellipk(m)) and _same(ellipe(m), scipy_ellipe(m))


def test_equals_scipy_on_a_dense_grid() -> None:
    rng = np.random.default_rng(0)
    ms = np.concatenate([rng.random(20_000), 1.0 - 10.0 ** rng.uniform(-17, 0, 5_000), -(10.0 ** rng.uniform(-5, 5, 2_000))])
    k, e = scipy_ellipk(ms), scipy_ellipe(ms)
    assert all(ellipk(m) == kk for m, kk in zip(ms.tolist(), k.tolist()))
    assert all(ellipe(m) == ee for m, ee in zip(ms.tolist(), e.tolist()))


@pytest.mark.parametrize("m", [0.0, 1e-9, 0.1, 0.5, 0.9, 0.99, 0.999999])
def test_agrees_with_the_arithmetic_geometric_mean(m: float) -> None:
    k, e = _agm(m)
    assert ellipk(m) == pytest.approx(k, rel=4 * 2.2e-16) and ellipe(m) == pytest.approx(e, rel=4 * 2.2e-16)


def test_the_hertz_ellipse_and_creep_coefficients_are_scipy_s(monkeypatch) -> None:
    """Downstream: the contact ellipse and the creep coefficients, bit for bit, with scipy's functions swapped in."""
    import bogie_env.contact as contact
    from bogie_env.params import load_params

    cases = [(1e3 * (1 + i), 0.5 / (1 + 0.3 * i), 0.5 + 7.0 * i, 2.1e11, 0.3) for i in range(20)]
    params = load_params()

    def run():
        contact._eccentricity_squared.cache_clear()
        ellipses = [(h.a, h.b) for h in (hertz_ellipse(*case) for case in cases)]
        c = creep_coefficients(params)
        return ellipses, (c.f11, c.f12, c.f22, c.f33)

    ours = run()
    monkeypatch.setattr(contact, "ellipk", scipy_ellipk)
    monkeypatch.setattr(contact, "ellipe", scipy_ellipe)
    theirs = run()
    contact._eccentricity_squared.cache_clear()
    assert ours == theirs
