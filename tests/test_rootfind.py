"""bogie_env.rootfind.brentq returns exactly (==) the float scipy.optimize.brentq returns.

The oracle is scipy itself, on random brackets of smooth functions with random tolerances: a
reordered operation or a changed branch in the port moves the last bits of some root and fails
here (checked by planting reordered products in the secant or the inverse-quadratic step: both fail).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq as scipy_brentq

from bogie_env.contact import _hertz_ratio
from bogie_env.rootfind import brentq

FUNCTIONS = {
    "cubic": lambda c: (lambda x: x**3 - c),
    "exp": lambda c: (lambda x: math.exp(x) - 1.0 - c),
    "tanh": lambda c: (lambda x: math.tanh(5.0 * (x - c))),
    "sin": lambda c: (lambda x: math.sin(x) - 0.5 * math.tanh(c)),
    "flat": lambda c: (lambda x: (x - c) ** 5 + 1e-3 * (x - c)),
    "atan": lambda c: (lambda x: math.atan(x - c) + 1e-9 * x),
}

finite = st.floats(-2.0, 2.0, allow_nan=False, allow_infinity=False)


def _outcome(solver, f, a: float, b: float, **kw):
    """The root, or the type of the error raised (scipy also fails to converge on some brackets)."""
    try:
        return solver(f, a, b, **kw)
    except (ValueError, RuntimeError) as err:
        return type(err)


def _same(f, a: float, b: float, **kw) -> None:
    expected = _outcome(scipy_brentq, f, a, b, **kw)
    assert _outcome(brentq, f, a, b, **kw) == expected


@settings(max_examples=300, deadline=None)
@given(name=st.sampled_from(sorted(FUNCTIONS)), c=finite, lo=st.floats(0.01, 3.0), hi=st.floats(0.01, 3.0),
       xtol=st.sampled_from([2e-12, 1e-15, 1e-8, 5e-324, 0.1]), rtol=st.sampled_from([8.881784197001252e-16, 1e-14, 1e-6]))  # fmt: skip
def test_equals_scipy_on_random_brackets(name: str, c: float, lo: float, hi: float, xtol: float, rtol: float) -> None:
    """Same root as scipy, bit for bit, for brackets around the root at various tolerances."""
    f = FUNCTIONS[name](c)
    root_guess = {"cubic": math.copysign(abs(c) ** (1 / 3), c), "exp": math.log1p(c) if c > -1 else None,
                  "sin": math.asin(0.5 * math.tanh(c))}.get(name, c)  # fmt: skip
    if root_guess is None:
        return
    a, b = root_guess - lo, root_guess + hi
    if f(a) * f(b) > 0:
        return
    _same(f, a, b, xtol=xtol, rtol=rtol)
    _same(f, b, a, xtol=xtol, rtol=rtol)


@settings(max_examples=100, deadline=None)
@given(ratio=st.floats(1.0 + 1e-9, 1e4))
def test_equals_scipy_on_the_hertz_equation(ratio: float) -> None:
    """The call of bogie_env.contact (B/A = ratio for m = e^2), over the whole range of shapes."""
    _same(lambda m: _hertz_ratio(m) - ratio, 1e-9, 1.0 - 1e-15, xtol=1e-15, rtol=1e-14)


def test_defaults_and_exact_endpoint_roots() -> None:
    """Defaults as scipy's; a root at an end of the bracket is returned as given."""
    _same(lambda x: x * x - 2.0, 0.0, 2.0)
    assert brentq(lambda x: x - 1.0, 1.0, 3.0) == 1.0
    assert brentq(lambda x: x - 3.0, 1.0, 3.0) == 3.0


def test_tiny_function_values() -> None:
    """Values whose products underflow to zero (scipy checks signs, not the sign of the product)."""
    _same(lambda x: math.atan(x - 7.5666148214268745e-295) + 1e-9 * x, -1.0, 1.0, xtol=5e-324)
    _same(lambda x: 1e-200 * (x - 0.3), 0.0, 1.0)


def test_errors_as_scipy() -> None:
    """No sign change, NaN, too few iterations and bad tolerances are errors, as in scipy."""
    with pytest.raises(ValueError, match="different signs"):
        brentq(lambda x: x * x + 1.0, -1.0, 1.0)
    with pytest.raises(ValueError, match="NaN"):
        brentq(lambda x: math.nan, -1.0, 1.0)
    with pytest.raises(RuntimeError, match="converge"):
        brentq(lambda x: math.exp(x) - 1.3, 0.0, 1.0, maxiter=2)
    with pytest.raises(ValueError, match="xtol"):
        brentq(lambda x: x, -1.0, 1.0, xtol=0.0)
    with pytest.raises(ValueError, match="rtol"):
        brentq(lambda x: x, -1.0, 1.0, rtol=1e-17)
