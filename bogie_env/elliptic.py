"""Complete elliptic integrals K(m) and E(m), bit-identical to :func:`scipy.special.ellipk` and ``ellipe``.

Why not scipy's own: ``scipy.special`` was the one scipy module of ``bogie curving`` that numba
does not import anyway (numba's first kernel load imports ``scipy.linalg``, with scipy's shared
modules); beyond those it costs 0.04-0.06 CPU-s (0.23-0.29 s imported alone) of a start-up of
about 1 s (``docs/performance.md``), and :mod:`bogie_env.contact` needs nothing else from it. Why not another method (the arithmetic-geometric mean, say): the
Hertz eccentricity and the creep coefficients come from these values, and
``tests/test_v0_golden.py`` pins them bit for bit, so each must be the very float scipy returns.

This is a port of the Cephes routines scipy evaluates (``ellpk`` and ``ellpe`` with ``polevl``,
Cephes Math Library by Stephen L. Moshier, in scipy's ``xsf`` headers ``xsf/cephes/ellpk.h`` and
``ellpe.h``, BSD-3-Clause; scipy 1.17.1, the installed version): the same coefficients, branches and
floating-point operations in the same order; ``scipy.special.ellipk(m)`` is ``ellpk(1 - m)``.
Python floats are IEEE doubles, ``math.log`` and ``math.sqrt`` are the C library's, and the C code
is compiled without contraction into fused multiply-adds on x86-64, so each step rounds as in
scipy; ``tests/test_elliptic.py`` checks equality (``==``) against scipy.
"""

from __future__ import annotations

import math

#: Cephes ``MACHEP``: 2**-53.
MACHEP = 1.11022302462515654042e-16

# fmt: off
_ELLPK_P = (1.37982864606273237150e-4, 2.28025724005875567385e-3, 7.97404013220415179367e-3,
            9.85821379021226008714e-3, 6.87489687449949877925e-3, 6.18901033637687613229e-3,
            8.79078273952743772254e-3, 1.49380448916805252718e-2, 3.08851465246711995998e-2,
            9.65735902811690126535e-2, 1.38629436111989062502e0)
_ELLPK_Q = (2.94078955048598507511e-5, 9.14184723865917226571e-4, 5.94058303753167793257e-3,
            1.54850516649762399335e-2, 2.39089602715924892727e-2, 3.01204715227604046988e-2,
            3.73774314173823228969e-2, 4.88280347570998239232e-2, 7.03124996963957469739e-2,
            1.24999999999870820058e-1, 4.99999999999999999821e-1)
_ELLPK_C1 = 1.3862943611198906188e0  # log(4)
_ELLPE_P = (1.53552577301013293365e-4, 2.50888492163602060990e-3, 8.68786816565889628429e-3,
            1.07350949056076193403e-2, 7.77395492516787092951e-3, 7.58395289413514708519e-3,
            1.15688436810574127319e-2, 2.18317996015557253103e-2, 5.68051945617860553470e-2,
            4.43147180560990850618e-1, 1.00000000000000000299e0)
_ELLPE_Q = (3.27954898576485872656e-5, 1.00962792679356715133e-3, 6.50609489976927491433e-3,
            1.68862163993311317300e-2, 2.61769742454493659583e-2, 3.34833904888224918614e-2,
            4.27180926518931511717e-2, 5.85936634471101055642e-2, 9.37499997197644278445e-2,
            2.49999999999888314361e-1)
# fmt: on


def _polevl(x: float, coef: tuple[float, ...]) -> float:
    """Cephes ``polevl``: Horner's rule from the highest coefficient, one multiply and one add a step."""
    ans = coef[0]
    for c in coef[1:]:
        ans = ans * x + c
    return ans


def _log(x: float) -> float:
    """C's ``log`` for x >= 0 (``-inf`` at 0, where Python raises)."""
    return math.log(x) if x > 0.0 else -math.inf


def _ellpk(x: float) -> float:
    """Cephes ``ellpk(x)``: K at the complementary parameter ``x = 1 - m``."""
    if math.isnan(x):
        return math.nan
    if x < 0.0:
        return math.nan  # domain error
    if x > 1.0:
        if math.isinf(x):
            return 0.0
        return _ellpk(1 / x) / math.sqrt(x)
    if x > MACHEP:
        return _polevl(x, _ELLPK_P) - _log(x) * _polevl(x, _ELLPK_Q)
    if x == 0.0:
        return math.inf  # singular
    return _ELLPK_C1 - 0.5 * _log(x)


def _ellpe(x: float) -> float:
    """Cephes ``ellpe(m)``: E at the parameter ``m``, evaluated in ``1 - m``."""
    if math.isnan(x):
        return math.nan
    x = 1.0 - x
    if x <= 0.0:
        if x == 0.0:
            return 1.0
        return math.nan  # domain error
    if x > 1.0:
        return _ellpe(1.0 - 1 / x) * math.sqrt(x)
    return _polevl(x, _ELLPE_P) - _log(x) * (x * _polevl(x, _ELLPE_Q))


def ellipk(m: float) -> float:
    """Complete elliptic integral of the first kind K(m), parameter ``m = k**2``, as ``scipy.special.ellipk``."""
    return _ellpk(1.0 - float(m))


def ellipe(m: float) -> float:
    """Complete elliptic integral of the second kind E(m), parameter ``m = k**2``, as ``scipy.special.ellipe``."""
    return _ellpe(float(m))
