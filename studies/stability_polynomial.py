"""The fewest stages per env step of any explicit Runge-Kutta method under the v2 step criterion.

An explicit S-stage Runge-Kutta method applied to ``x' = J x`` multiplies the state each substep
by a polynomial ``R(h J)`` of degree at most S. Second order on nonlinear terms needs
``R(z) = 1 + z + z^2/2 + c_3 z^3 + ... + c_S z^S``; the remaining coefficients are free (any of
them is reached, e.g. by ``y_k = x + a_k h f(y_{k-1})`` with ``a_k`` the ratios ``c_k / c_{k-1}``).
For each substep count and stage count this asks a linear program whether some choice of
``c_3 .. c_S`` meets the criterion the env's step choice uses (``HuntingTask.step_choice``):

- stability: ``|R(1.05 h lambda)| <= max(1, exp(g Re(1.05 h lambda)))`` at every eigenvalue of
  the criterion's Jacobians (``HuntingTask.criterion_models``: 15 bogies, 7 speeds, at the
  equilibrium and in flange contact). With the default ``--growth`` g = 1.1 this is *looser*
  than ``integrate.stable_substep``, which lets a growing mode grow no faster than exactly (here:
  up to 10 % faster, the accuracy tolerance), so an infeasible answer is stronger than the env's
  own rule needs; ``--growth 1.0`` is the env's rule itself (what v3's method was designed with);
- accuracy: every lightly damped mode's decay rate and frequency within 10 %, as in
  ``integrate.eigenvalue_errors``, linearised in ``(R - exp) / exp`` and scaled by a free factor
  ``t`` that the program minimises (``t`` <= 1 meets the criterion to first order; the exact
  errors of the polynomial found are printed beside it).

Stability is imposed through supporting half-planes ``Re(R(z) e^{-i theta}) <= bound``, each
implied by ``|R(z)| <= bound``: so the planes are a relaxation, and "infeasible" is a certificate
that no polynomial of that degree is stable on those eigenvalues (up to the solver's
tolerance). A feasible answer is checked exactly (within ``stable_substep``'s 1e-12) and cut
again (at ``theta = arg R(z)``) until it holds. Cuts converge only in the limit: a degree whose
cuts do not settle within the rounds is reported "unsettled", which proves nothing either way.

    python studies/stability_polynomial.py                       # v2's config, 1-6 substeps
    python studies/stability_polynomial.py --n-sub 1,2 --show     # and the coefficients
    python studies/stability_polynomial.py --growth 1.0 --n-sub 1 --show   # v3's method (poly14)

``--inner K`` replaces the cuts by an inner approximation: at each eigenvalue, K half-planes whose
polygon is inscribed in the circle ``|R| = bound``, turned so that a vertex points at ``exp(z)``
(where an accurate ``R`` must lie). A polygon inside the circle makes every solution exactly
stable, with no cuts; it gives up a sliver of the circle, so an infeasible answer proves nothing,
and the coefficient scaling by the spectral radius keeps the program well conditioned. With
``--growth 1.0 --n-sub 1 --inner 64`` it finds degree 12 (v4's method, poly12)::

    python studies/stability_polynomial.py --growth 1.0 --n-sub 1 --inner 64 --show   # v4's method (poly12)

``--show`` prints the coefficients ``c_k`` and the stage divisors ``d_k = c_{S-k-1} / c_{S-k}``
of Jameson's form (``integrate.METHOD_DIVISORS``).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import linprog

from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.integrate import spectrum

MARGIN = 1.05  # integrate.stable_substep's default
GROWTH = 1.1  # a growing mode may grow up to 10 % faster (looser than the env's rule)
EXACT_TOLERANCE = 1e-12  # integrate.stable_substep's own allowance


def criterion_eigenvalues(variant: str = "v2") -> tuple[np.ndarray, float]:
    """Every eigenvalue the step criterion looks at (1/s), and the env step dt (s)."""
    task = HuntingTask(1, make_config(variant=variant))
    lo, hi = task.speed_limits()
    speeds = np.linspace(lo, hi, 7)
    return np.concatenate([spectrum(m, speeds).ravel() for m in task.criterion_models()]), float(task.config["dt"])


def polynomial(c: np.ndarray, z: np.ndarray) -> np.ndarray:
    r = np.zeros_like(z, dtype=complex)
    for ck in c[::-1]:
        r = r * z + ck
    return r


def mode_errors(c: np.ndarray, h: float, light: np.ndarray) -> tuple[float, float]:
    """Exact worst relative decay-rate and frequency errors (``integrate.eigenvalue_errors``)."""
    lam_h = np.log(polynomial(c, h * light)) / h
    lam_h = lam_h + 2j * np.pi * np.round((light.imag - lam_h.imag) * h / (2 * np.pi)) / h
    decay = np.abs(lam_h.real - light.real) / np.maximum(np.abs(light.real), 0.01 * np.abs(light))
    return float(np.max(decay)), float(np.max(np.abs(lam_h.imag - light.imag) / np.abs(light.imag)))


def _fixed(z: np.ndarray) -> np.ndarray:
    """The part of R that second order fixes: 1 + z + z^2/2."""
    return 1 + z + z**2 / 2


def _program(eigenvalues: np.ndarray, h: float, stages: int, tolerance: float, growth: float, scale: np.ndarray):
    """What both searches share: the light modes, the scaled stability points ``zs`` with their
    bounds, the powers 3..S, and the accuracy rows (A, b) of the linear program in the unknowns
    ``c_k * scale_k`` (k = 3..S) and ``t``."""
    light = eigenvalues[(eigenvalues.imag > 0) & (-eigenvalues.real < 0.5 * np.abs(eigenvalues))]
    zs = MARGIN * h * eigenvalues
    zs = np.unique(np.round(zs[zs.imag >= 0], 12))
    bound = np.maximum(1.0, np.exp(growth * zs.real))
    powers = np.arange(3, stages + 1)
    rows, rhs = [], []
    zl = h * light
    back = np.exp(-zl)
    for part, size in ((np.real, np.maximum(np.abs(light.real), 0.01 * np.abs(light))), (np.imag, np.abs(light.imag))):
        cols = part(zl[:, None] ** powers / scale * back[:, None])
        const = part(_fixed(zl) * back - 1)
        for sign in (1, -1):
            rows.append(np.hstack([sign * cols, -tolerance * h * size[:, None]]))
            rhs.append(-sign * const)
    return light, zs, bound, powers, rows, rhs


def _solve(rows: list, rhs: list, n_free: int) -> np.ndarray | str:
    """The program's solution (the free coefficients, then ``t``), or its verdict."""
    cost = np.zeros(n_free + 1)
    cost[-1] = 1.0
    res = linprog(cost, A_ub=np.vstack(rows), b_ub=np.concatenate(rhs), bounds=[(None, None)] * n_free + [(0, None)],
                  method="highs")  # fmt: skip
    if res.status == 2:
        return "infeasible"
    return res.x if res.success else "unsettled"


def design(eigenvalues: np.ndarray, h: float, stages: int, tolerance: float = 0.1, rounds: int = 60,
           growth: float = GROWTH, inner: int = 0):
    """(c_0 .. c_S, t, (decay error, frequency error)) of the most accurate stable polynomial of
    degree ``stages``; ``"infeasible"`` when the relaxation has no solution (a certificate); or
    ``"unsettled"`` when the cuts did not reach an exactly stable polynomial in ``rounds`` (no
    conclusion either way). ``inner`` = K > 0: one program on inscribed K-gons instead of the cuts
    (module docstring); ``"infeasible"`` is then no certificate."""
    if inner:
        return _design_inner(eigenvalues, h, stages, tolerance, growth, inner)
    light, zs, bound, powers, rows, rhs = _program(eigenvalues, h, stages, tolerance, growth, np.ones(stages - 2))
    bound = bound + 1e-13

    def planes(idx: np.ndarray, theta: np.ndarray) -> None:
        rot = np.exp(-1j * theta)
        z = zs[idx]
        rows.append(np.hstack([np.real(z[:, None] ** powers * rot[:, None]), np.zeros((idx.size, 1))]))
        rhs.append(bound[idx] - np.real(_fixed(z) * rot))

    every = np.arange(zs.size)
    for shift in (0.0, 0.1, -0.1, 0.3, -0.3, 1.0, -1.0, 2.0, -2.0, np.pi):
        planes(every, zs.imag + shift)
    for _ in range(rounds):
        x = _solve(rows, rhs, powers.size)
        if isinstance(x, str):
            return x
        c = np.concatenate([[1.0, 1.0, 0.5], x[:-1]])
        r = polynomial(c, zs)
        bad = np.nonzero(np.abs(r) > bound + EXACT_TOLERANCE)[0]
        if bad.size == 0:
            return c, float(x[-1]), mode_errors(c, h, light)
        planes(bad, np.angle(r[bad]))
    return "unsettled"


def _polygon_rows(zs, bound, powers, scale, k_sides, offset, inscribed, rows, rhs) -> None:
    """K half-planes per point, normals at ``arg exp(z) + offset + 2 pi k / K``: inscribed in the
    circle ``|R| = bound`` (their polygon lies inside it) or circumscribed (implied by it)."""
    columns = zs[:, None] ** powers / scale
    reach = bound * np.cos(np.pi / k_sides) if inscribed else bound
    for side in range(k_sides):
        rot = np.exp(-1j * (np.angle(np.exp(zs)) + offset + 2 * np.pi * side / k_sides))
        rows.append(np.hstack([np.real(columns * rot[:, None]), np.zeros((zs.size, 1))]))
        rhs.append(reach - np.real(_fixed(zs) * rot))


def least_error_bound(eigenvalues: np.ndarray, h: float, stages: int, tolerance: float = 0.1, growth: float = GROWTH,
                      k_sides: int = 256) -> float | str:
    """A lower bound on the least linearised error ``t`` of any stable polynomial of degree
    ``stages``: the program on circumscribed K-gons, a relaxation of ``|R| <= bound``. Above 1, no
    polynomial of that degree meets the accuracy criterion (to first order)."""
    scale = np.max(np.abs(MARGIN * h * eigenvalues)) ** np.arange(3, stages + 1, dtype=float)
    _, zs, bound, powers, rows, rhs = _program(eigenvalues, h, stages, tolerance, growth, scale)
    _polygon_rows(zs, bound, powers, scale, k_sides, 0.0, False, rows, rhs)
    x = _solve(rows, rhs, powers.size)
    return x if isinstance(x, str) else float(x[-1])


def _design_inner(eigenvalues: np.ndarray, h: float, stages: int, tolerance: float, growth: float, k_sides: int):
    """:func:`design` on oriented inscribed polygons (``--inner``), in scaled coefficients
    ``c_k rho^k`` (rho the largest ``|z|``) so that every column is of order one."""
    rho = np.max(np.abs(MARGIN * h * eigenvalues))
    scale = rho ** np.arange(3, stages + 1, dtype=float)
    light, zs, bound, powers, rows, rhs = _program(eigenvalues, h, stages, tolerance, growth, scale)
    _polygon_rows(zs, bound, powers, scale, k_sides, np.pi / k_sides, True, rows, rhs)  # a vertex points at exp(z)
    x = _solve(rows, rhs, powers.size)
    if isinstance(x, str):
        return x
    c = np.concatenate([[1.0, 1.0, 0.5], x[:-1] / scale])
    if np.any(np.abs(polynomial(c, zs)) > bound + EXACT_TOLERANCE):
        return "unsettled"  # the solver's own tolerance, not the polygon
    return c, float(x[-1]), mode_errors(c, h, light)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="v2")
    parser.add_argument("--n-sub", default="1,2,3,4,5,6", help="substeps per env step to try")
    parser.add_argument("--max-stages", type=int, default=16)
    parser.add_argument("--show", action="store_true", help="print the coefficients and stage divisors found")
    parser.add_argument("--growth", type=float, default=GROWTH,
                        help="a growing mode may grow this many times faster (1.0: the env's own rule)")
    parser.add_argument("--inner", type=int, default=0, metavar="K",
                        help="inscribed K-gons instead of cuts (see the docstring); 0: cuts")
    args = parser.parse_args()
    eigenvalues, dt = criterion_eigenvalues(args.variant)
    print(f"{eigenvalues.size} eigenvalues, spectral radius {np.max(np.abs(eigenvalues)):.0f} 1/s, dt {dt * 1e3:g} ms")
    print("per substep count: each degree tried, from 3 up, until a polynomial meets the criterion exactly")
    for n_sub in map(int, args.n_sub.split(",")):
        h = dt / n_sub
        verdicts = []
        for stages in range(3, args.max_stages + 1):
            found = design(eigenvalues, h, stages, growth=args.growth, inner=args.inner)
            if isinstance(found, str):
                verdicts.append(f"{stages}: {found}")
                continue
            c, t, (decay, freq) = found
            if max(decay, freq) > 0.1:
                bound = f", every polynomial t >= {least_error_bound(eigenvalues, h, stages, growth=args.growth, k_sides=args.inner):.3f}" \
                    if args.inner else ""  # fmt: skip
                verdicts.append(f"{stages}: stable, inaccurate (decay {decay:.3f}, frequency {freq:.3f}, t {t:.3f}{bound})")
                continue
            print(f"{n_sub} substeps: {'; '.join(verdicts) or '-'}; found at S = {stages} ({n_sub * stages} stages per env "
                  f"step, decay error {decay:.4f}, frequency error {freq:.4f})", flush=True)  # fmt: skip
            if args.show:
                print("  c =", ", ".join(f"{x:.10g}" for x in c))
                print("  divisors =", ", ".join(f"{float(c[k - 1] / c[k])!r}" for k in range(stages, 0, -1)))
            break
        else:
            print(f"{n_sub} substeps: {'; '.join(verdicts)}; none found up to S = {args.max_stages}", flush=True)


if __name__ == "__main__":
    main()
