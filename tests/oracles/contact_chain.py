"""Independent oracles for the chain contact inputs -> creep coefficients -> critical speed.

Written without bogie_env (do not import it here: independence is the point).

- :func:`hertz_semi_axes` solves Hertz's problem through Carlson's symmetric integral R_D
  (bogie_env uses Legendre's K, E and a different unknown), Johnson, *Contact Mechanics* (1985),
  Sec. 4.2: with 1/E* = 2(1 - nu^2)/E for two identical steels,
  A = N R_D(0, b^2, a^2) / (2 pi E*) and B = N R_D(0, a^2, b^2) / (2 pi E*),
  where A, B are the relative curvatures (1/m) along the rolling (x, semi-axis a) and lateral
  (y, semi-axis b) directions.
- :func:`kalker_table_coefficients` interpolates Kalker's table (``tests/data/kalker_table.csv``;
  Kalker 1990, Table E3): linear in nu, cubic spline in b/a (for a >= b).
- :func:`creep_coefficients` gives f11 = G a b C22 (lateral), f12 = G (ab)^1.5 C23,
  f22 = G (ab)^2 C33, f33 = G a b C11 (longitudinal), in the paper's naming (Eqs. 7-10).
- :func:`roll_locked_bogie_matrix` is the textbook linear two-axle bogie in lateral and yaw
  (Wickens, *Fundamentals of Rail Vehicle Dynamics*, 2003, Ch. 4; Iwnicki (ed.), *Handbook of
  Railway Vehicle Dynamics*, 2006, Ch. 9), with each wheelset's roll held at zero, Kalker's linear
  creep with spin (f12, f22) scaled by the saturation factor at the equilibrium, the knife-edge
  normal forces' yaw moment e lam W psi, primary springs at x = +-L1 and dampers at +-L2, and a
  secondary suspension to a fixed car body. SI units throughout.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq, fsolve
from scipy.special import elliprd

KALKER_TABLE_PATH = Path(__file__).resolve().parent.parent / "data" / "kalker_table.csv"


def hertz_semi_axes(normal_load: float, A: float, B: float, E: float, nu: float) -> tuple[float, float]:
    """Semi-axes (a along x, b along y) in m of the Hertz ellipse, via Carlson's R_D."""
    e_star = E / (2.0 * (1.0 - nu * nu))
    k = normal_load / (2.0 * math.pi * e_star)

    def residual(log_ab):
        a, b = np.exp(log_ab)
        return [k * elliprd(0.0, b * b, a * a) / A - 1.0, k * elliprd(0.0, a * a, b * b) / B - 1.0]

    guess = math.log((3.0 * normal_load / (4.0 * e_star * (A + B))) ** (1.0 / 3.0))
    solution = fsolve(residual, [guess, guess], xtol=1e-13)
    if max(abs(r) for r in residual(solution)) > 1e-11:
        raise RuntimeError(f"hertz_semi_axes did not converge (A = {A}, B = {B})")
    a, b = np.exp(solution)
    return float(a), float(b)


def _kalker_rows() -> np.ndarray:
    lines = [ln for ln in KALKER_TABLE_PATH.read_text().splitlines() if ln and not ln.startswith("#")][1:]
    return np.array([[float(v) if v else np.nan for v in ln.split(",")] for ln in lines])


def kalker_table_coefficients(g: float, nu: float) -> tuple[float, float, float, float]:
    """(C11, C22, C23, C33) at a/b = g >= 1 and 0.25 <= nu <= 0.5, interpolated in Kalker's table."""
    if not (g >= 1.0 and 0.25 <= nu <= 0.5):
        raise ValueError(f"kalker_table_coefficients: g = {g}, nu = {nu} outside a/b >= 1, 0.25 <= nu <= 0.5")
    rows = _kalker_rows()
    weight = (nu - 0.25) / 0.25
    result = []
    for column in range(2, 6):
        at_nu = []
        for table_nu in (0.25, 0.5):
            sub = rows[(rows[:, 1] == table_nu) & (rows[:, 0] >= 1.0 - 1e-9)]
            q = 1.0 / sub[:, 0]
            order = np.argsort(q)
            at_nu.append(float(CubicSpline(q[order], sub[order, column])(1.0 / g)))
        result.append((1.0 - weight) * at_nu[0] + weight * at_nu[1])
    return tuple(result)


def creep_coefficients(wheel_load: float, r0: float, rail_radius: float, E: float, nu: float) -> dict:
    """Kalker's f11, f12, f22, f33 (paper naming) of a cone of radius r0 on a rail head of
    transverse radius rail_radius, under the normal load wheel_load (N)."""
    a, b = hertz_semi_axes(wheel_load, 0.5 / r0, 0.5 / rail_radius, E, nu)
    c11, c22, c23, c33 = kalker_table_coefficients(a / b, nu)
    shear = E / (2.0 * (1.0 + nu))
    ab = a * b
    return {"a": a, "b": b, "f11": shear * ab * c22, "f12": shear * ab**1.5 * c23,
            "f22": shear * ab**2 * c33, "f33": shear * ab * c11}  # fmt: skip


def saturation_at_rest(f12: float, lam: float, r0: float, mu: float, wheel_load: float) -> float:
    """Johnson-Vermeulen factor of the constant spin force f12 lam / r0 (Eq. 26, u < 3)."""
    u = f12 * lam / r0 / (mu * wheel_load)
    if u >= 3.0:
        return 1.0 / u
    return 1.0 - u / 3.0 + u * u / 27.0


ROLL_LOCKED_STATES = ("y1", "psi1", "y2", "psi2", "yb", "psib")


def roll_locked_bogie_matrix(p: dict, creep: dict, V: float, alpha: float) -> np.ndarray:
    """First-order matrix of the roll-locked bogie, state (q, dq/dt), q = ROLL_LOCKED_STATES.

    Per wheelset i (s = +1 front at x = +L1, -1 rear), both wheels summed, about the centred
    position: lateral creep force -2 f11 (dy/V - psi) - 2 f12 dpsi/V; yaw creep moment
    -2 f33 e (e dpsi/V + lam y / r0) + 2 f12 (dy/V - psi) - 2 f22 dpsi/V.
    """
    f11, f12, f22, f33 = (alpha * creep[k] for k in ("f11", "f12", "f22", "f33"))
    e, r0, lam, W = p["e"], p["r0"], p["lam"], p["Wpa"]
    M = np.diag([p["mw"], p["Iwz"], p["mw"], p["Iwz"], p["mb"], p["Ibz"]])
    K = np.zeros((6, 6))
    C = np.zeros((6, 6))
    for i, s in ((0, 1.0), (1, -1.0)):
        y, psi = 2 * i, 2 * i + 1
        C[y, y] += 2 * f11 / V
        K[y, psi] -= 2 * f11
        C[y, psi] += 2 * f12 / V
        C[psi, psi] += 2 * e * e * f33 / V + 2 * f22 / V
        K[psi, y] += 2 * e * f33 * lam / r0
        C[psi, y] -= 2 * f12 / V
        K[psi, psi] += 2 * f12 - e * lam * W
        for matrix, coefficient, arm in ((K, p["Kpy"], p["L1"]), (C, p["Cpy"], p["L2"])):
            d = np.zeros(6)
            d[y], d[4], d[5] = 1.0, -1.0, -s * arm  # lateral stretch of one side's element
            matrix += 2 * coefficient * np.outer(d, d)
        for matrix, coefficient in ((K, p["Kpx"]), (C, p["Cpx"])):
            d = np.zeros(6)
            d[psi], d[5] = 1.0, -1.0
            matrix += 2 * coefficient * p["b1"] ** 2 * np.outer(d, d)
    K[4, 4] += 2 * p["Ksy"]
    C[4, 4] += 2 * p["Csy"]
    K[5, 5] += 2 * p["Ksx"] * p["b2"] ** 2
    C[5, 5] += 2 * p["Csx"] * p["b3"] ** 2
    m_inv = np.linalg.inv(M)
    return np.block([[np.zeros((6, 6)), np.eye(6)], [-m_inv @ K, -m_inv @ C]])


def first_crossing(max_real_part, v_low: float, v_high: float, points: int = 45) -> float:
    """Lowest speed (m/s) in [v_low, v_high] where max_real_part(V) turns non-negative."""
    speeds = np.linspace(v_low, v_high, points)
    values = [max_real_part(v) for v in speeds]
    for k in range(points - 1):
        if values[k] < 0.0 <= values[k + 1]:
            return brentq(max_real_part, speeds[k], speeds[k + 1], xtol=1e-7)
    raise ValueError("no crossing in the window")
