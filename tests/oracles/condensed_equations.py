"""The corrected condensed Eqs. (47)-(52), linearised about the equilibrium, written out by hand.

These are the equations of docs/model.md, Section "Condensed equations", typed term by term
from the derivation (independently of bogie_env's code). The paper's printed versions contain
the typos listed there; ``tests/test_oracles.py`` checks that bogie_env's exact Jacobian equals
this matrix.
"""

import numpy as np


def condensed_jacobian(p, V, alpha, secondary_heights="table1"):
    """Jacobian of Eqs. (47)-(52). ``secondary_heights``: "table1" puts Ksy at h2 and Csy at
    h1 in Eq. (50) (Table 1's spring and damper heights), "printed" Ksy at h1 and Csy at h2."""
    h_ksy, h_csy = {"table1": ("h2", "h1"), "printed": ("h1", "h2")}[secondary_heights]
    mw, Iwx, Iwy, Iwz = p["mw"], p["Iwx"], p["Iwy"], p["Iwz"]
    e, r0, lam, W = p["e"], p["r0"], p["lam"], p["Wpa"]
    f11, f12, f22, f33 = p["f11"], p["f12"], p["f22"], p["f33"]
    J = np.zeros((20, 20))
    for k in range(10):
        J[2 * k, 2 * k + 1] = 1.0
    yb, dyb, psb, dpsb = 16, 17, 18, 19
    for i, si in ((0, 1.0), (1, -1.0)):
        a = alpha[i]
        o = 8 * i
        y, dy, z, dz, ps, dps, ph, dph = range(o, o + 8)
        # lateral (Eq. 47 corrected)
        row = np.zeros(20)
        row[dy] = -2 * a * f11 / V - 2 * p["Cpy"]
        row[ps] = 2 * a * f11
        row[dps] = -2 * a * f12 / V
        row[ph] = -W
        row[dph] = -2 * a * f11 * r0 / V
        row[y] += -2 * p["Kpy"]
        row[yb] += 2 * p["Kpy"]; row[dyb] += 2 * p["Cpy"]
        row[psb] += si * 2 * p["Kpy"] * p["L1"]; row[dpsb] += si * 2 * p["Cpy"] * p["L2"]
        J[dy] = row / mw
        # vertical (Eq. 48): linear part only spring/damper
        row = np.zeros(20)
        row[z] = -2 * p["Kpz"]; row[dz] = -2 * p["Cpz"]
        J[dz] = row / mw
        # yaw (Eq. 49)
        row = np.zeros(20)
        row[y] = -2 * a * e * f33 * lam / r0
        row[dy] = 2 * a * f12 / V
        row[ps] = e * W * lam - 2 * a * f12 - 2 * p["Kpx"] * p["b1"] ** 2
        row[dps] = -(2 * a * e ** 2 * f33 + 2 * a * f22) / V - 2 * p["Cpx"] * p["b1"] ** 2
        row[dph] = -Iwy * V / r0 + 2 * a * f12 * r0 / V
        row[psb] = 2 * p["Kpx"] * p["b1"] ** 2; row[dpsb] = 2 * p["Cpx"] * p["b1"] ** 2
        J[dps] = row / Iwz
        # roll (Eq. 50)
        row = np.zeros(20)
        row[y] = 2 * a * f12 * lam ** 2 / r0 - W * lam ** 2
        row[dy] = -2 * a * f11 * (r0 + e * lam) / V
        row[ps] = 2 * a * f11 * (r0 + e * lam) + 2 * a * f22 * lam ** 2 / r0
        row[dps] = Iwy * V / r0 - 2 * a * f12 * (r0 + e * lam) / V
        row[ph] = 2 * a * f12 * lam ** 2 + e * lam * W - 2 * p["Kpz"] * p["b1"] ** 2
        row[dph] = -2 * a * f11 * r0 * (r0 + e * lam) / V - 2 * p["Cpz"] * p["b1"] ** 2
        row[yb] = -2 * p["Ksy"] * p[h_ksy]; row[dyb] = -2 * p["Csy"] * p[h_csy]
        J[dph] = row / Iwx
    # frame (Eqs. 51, 52 corrected)
    row = np.zeros(20)
    row[[0, 8]] = 2 * p["Kpy"]; row[[1, 9]] = 2 * p["Cpy"]
    row[yb] = -4 * p["Kpy"] - 2 * p["Ksy"]; row[dyb] = -4 * p["Cpy"] - 2 * p["Csy"]
    J[dyb] = row / p["mb"]
    row = np.zeros(20)
    row[0] = 2 * p["Kpy"] * p["L1"]; row[1] = 2 * p["Cpy"] * p["L2"]
    row[8] = -2 * p["Kpy"] * p["L1"]; row[9] = -2 * p["Cpy"] * p["L2"]
    row[[4, 12]] = 2 * p["Kpx"] * p["b1"] ** 2; row[[5, 13]] = 2 * p["Cpx"] * p["b1"] ** 2
    row[psb] = -(4 * p["Kpy"] * p["L1"] ** 2 + 4 * p["Kpx"] * p["b1"] ** 2 + 2 * p["Ksx"] * p["b2"] ** 2)
    row[dpsb] = -(4 * p["Cpy"] * p["L2"] ** 2 + 4 * p["Cpx"] * p["b1"] ** 2 + 2 * p["Csx"] * p["b3"] ** 2)
    J[dpsb] = row / p["Ibz"]
    return J
