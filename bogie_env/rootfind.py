"""Brent's bracketing root finder, bit-identical to :func:`scipy.optimize.brentq`.

Why not scipy's own: importing ``scipy.optimize`` costs about a third of a second, a third of the
start-up of ``bogie curving`` (``benchmarks/curving_startup.py``), and the Hertz solver of
:mod:`bogie_env.contact` needs nothing else from it. Why not another root finder: the Hertz
eccentricity feeds the creep coefficients, which ``tests/test_v0_golden.py`` pins bit for bit, so
the root must be the very same float scipy returns.

This is a port of scipy's C routine (``scipy/optimize/Zeros/brentq.c``, BSD-3-Clause, written by
Charles Harris; as of the tag v1.17.1, the installed version) with the same defaults, the same branches and the same
floating-point operations in the same order. Python floats are IEEE doubles and the C code is
compiled without contraction into fused multiply-adds on x86-64, so each step rounds as in scipy;
``tests/test_rootfind.py`` checks equality (``==``) against scipy on random brackets.
"""

from __future__ import annotations

import math
from typing import Callable

#: scipy's defaults (``scipy.optimize._zeros_py``): xtol, rtol = 4 * machine epsilon, maxiter.
XTOL = 2e-12
RTOL = 4 * 2.220446049250313e-16
MAXITER = 100


def _checked(f: Callable[[float], float], x: float) -> float:
    """f(x) as a float; NaN is an error (as in scipy >= 1.11), since the bracket logic cannot use it."""
    fx = float(f(x))
    if math.isnan(fx):
        raise ValueError(f"The function value at x={x} is NaN; solver cannot continue.")
    return fx


def _signbit(x: float) -> bool:
    """C's ``signbit``: True for negative numbers, -0.0 and NaNs with the sign bit set."""
    return math.copysign(1.0, x) < 0


def _div(num: float, den: float) -> float:
    """num / den with C's IEEE result for den == 0 (inf or NaN, so the step is rejected) instead of an exception."""
    try:
        return num / den
    except ZeroDivisionError:
        if num == 0 or math.isnan(num):
            return math.nan
        return math.copysign(math.inf, num) * math.copysign(1.0, den)


def brentq(f: Callable[[float], float], a: float, b: float, xtol: float = XTOL, rtol: float = RTOL,
           maxiter: int = MAXITER) -> float:  # fmt: skip
    """A root of ``f`` in the bracket [a, b] (f(a) and f(b) of opposite signs), as scipy's ``brentq``.

    Raises ValueError for a bad tolerance, a bracket without a sign change or a NaN value, and
    RuntimeError when ``maxiter`` iterations do not converge (scipy's ``disp=True``).
    """
    if xtol <= 0:
        raise ValueError(f"xtol too small ({xtol:g} <= 0)")
    if rtol < RTOL:
        raise ValueError(f"rtol too small ({rtol:g} < {RTOL:g})")
    maxiter = int(maxiter)
    if maxiter < 0:
        raise ValueError("maxiter must be >= 0")
    xpre, xcur = float(a), float(b)
    xblk = fblk = spre = scur = 0.0
    fpre = _checked(f, xpre)
    fcur = _checked(f, xcur)
    if fpre == 0:
        return xpre
    if fcur == 0:
        return xcur
    if _signbit(fpre) == _signbit(fcur):  # signs, not the product's, which underflows for tiny values
        raise ValueError("f(a) and f(b) must have different signs")
    for _ in range(maxiter):
        if fpre != 0 and fcur != 0 and _signbit(fpre) != _signbit(fcur):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        # The tolerance is 2 * delta.
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:  # interpolate (secant)
                stry = _div(-fcur * (xcur - xpre), fcur - fpre)
            else:  # extrapolate (inverse quadratic)
                dpre = _div(fpre - fcur, xpre - xcur)
                dblk = _div(fblk - fcur, xblk - xcur)
                stry = _div(-fcur * (fblk * dblk - fpre * dpre), dblk * dpre * (fblk - fpre))
            limit = abs(spre) if abs(spre) < 3 * abs(sbis) - delta else 3 * abs(sbis) - delta  # C's MIN macro
            if 2 * abs(stry) < limit:
                spre, scur = scur, stry  # good short step
            else:
                spre = scur = sbis  # bisect
        else:
            spre = scur = sbis  # bisect
        xpre, fpre = xcur, fcur
        if abs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = _checked(f, xcur)
    raise RuntimeError(f"Failed to converge after {maxiter} iterations.")
