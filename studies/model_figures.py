"""Print the model figures quoted in docs/model.md that no ``bogie`` subcommand prints.

    python studies/model_figures.py          # a few seconds; the sympy part about a minute

Sections: the nominal contact against the independent oracle (tests/oracles/contact_chain.py),
the equilibrium's spin-creep terms, the separable vertical pair, the fastest eigenvalue, the
two readings of Eq. (43)'s heights, ramps from tiny starts, and the cone-normal variant
(sympy oracle).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bogie_env import BogieModel  # noqa: E402
from bogie_env.contact import saturation_factor  # noqa: E402
from bogie_env.dynamics import COEFFICIENT_NAMES, LATERAL_STATES, state_index  # noqa: E402
from bogie_env.stability import critical_speed  # noqa: E402
from tests.oracles import contact_chain  # noqa: E402


def contact(model: BogieModel) -> None:
    p, c = model.params, model.creep
    ref = contact_chain.creep_coefficients(0.5 * p.Wpa, p.r0, p.Rrail, p.E, p.nu)
    print(f"Hertz ellipse: a = {c.contact.a * 1e3:.2f} mm, b = {c.contact.b * 1e3:.2f} mm, a/b = {c.contact.ratio:.3f}"
          f" (Carlson-form oracle: {ref['a'] * 1e3:.2f}, {ref['b'] * 1e3:.2f} mm)")  # fmt: skip
    for name in ("f11", "f12", "f22", "f33"):
        ours, table = getattr(c, name), ref[name]
        print(f"  {name}: fits (Eqs. 11-14) {ours:.4g}, Kalker's table {table:.4g}, difference {ours / table - 1:+.1%}")
    beta0 = c.f12 * p.lam / p.r0 / (p.mu * p.Wpa / 2)
    alpha0 = float(saturation_factor(beta0))
    print(f"alpha0 = {alpha0:.4f}; constant spin force alpha0 f12 lam / r0 = {alpha0 * c.f12 * p.lam / p.r0:.0f} N;"
          f" z0 = {model.equilibrium(100.0)[state_index('z1')]:.3e} m")  # fmt: skip
    print(f"gravitational yaw stiffness e lam W = {p.e * p.lam * p.Wpa:.0f} N m/rad;"
          f" primary 2 Kpx b1^2 = {2 * p.Kpx * p.b1**2:.3g} N m/rad")  # fmt: skip
    print(f"vertical pair: roots of mw s^2 + 2 Cpz s + 2 Kpz = {np.roots([p.mw, 2 * p.Cpz, 2 * p.Kpz])[0]:.3f}")
    v = 358.0 / 3.6
    eig = np.linalg.eigvals(model.jacobian(model.equilibrium(v), v))
    print(f"fastest eigenvalue at 358 km/h: {eig[np.argmax(np.abs(eig))]:.1f}")


def readings() -> None:
    print("Eq. (43) heights: reading -> critical speed, frequency, critical mode shape")
    for reading in ("table1", "printed"):
        model = BogieModel(BogieModel().params.replace(secondary_heights=reading))
        result = critical_speed(model)
        v = result.speed_kmh / 3.6
        eig, vec = np.linalg.eig(model.jacobian(model.equilibrium(v), v))
        mode = vec[:, np.argmax(eig.real)]
        amp = {n: abs(mode[state_index(n)]) for n in ("y1", "psi1", "phi1", "yb", "psib")}
        print(f"  {reading:8s}: {result.speed_kmh:.1f} km/h, {result.frequency_hz:.2f} Hz;"
              f" |phi1|/|psi1| = {amp['phi1'] / amp['psi1']:.3f}, r0|phi1|/|y1| = {0.46 * amp['phi1'] / amp['y1']:.3f},"
              f" |yb|/|y1| = {amp['yb'] / amp['y1']:.3f}")  # fmt: skip
        for kmh in (300.0, 320.0, 325.0, 330.0, 340.0, 355.0):
            v = kmh / 3.6
            jac = model.jacobian(model.equilibrium(v), v)[np.ix_(LATERAL_STATES, LATERAL_STATES)]
            lateral = sorted((e for e in np.linalg.eigvals(jac) if e.imag > 0.5), key=lambda e: -e.real)[:2]
            text = ", ".join(f"{e.real:+.2f} at {e.imag / (2 * math.pi):.2f} Hz" for e in lateral)
            print(f"      {kmh:.0f} km/h, two least-damped modes: {text}")


def cone_normal() -> None:
    from tests.oracles import linear_bogie_oracle as vector_oracle

    values = dict(zip(COEFFICIENT_NAMES, map(float, BogieModel().coefficients)))
    params = {k: values[k] for k in vector_oracle.PARAM_KEYS}
    paper = vector_oracle.critical_speed(params)[0]
    rotated = vector_oracle.critical_speed(params, {"normal_dir": "rotated"})[0]
    print(f"normal forces along the rotated cone normal (sympy oracle): {rotated:.2f} km/h against {paper:.2f} km/h")


def ramp_from_tiny_starts() -> None:
    from bogie_env.analysis.ramp import simulate

    model = BogieModel()
    print("ramp 350 km/h + 0.1 m/s^2, perfect track: start offset -> smallest |y1|, visible onset (|y1| > 4.5 mm)")
    for offset in (1e-7, 1e-9, 1e-12, 1e-15):
        x0 = model.equilibrium(350 / 3.6)
        x0[state_index("y1")] += offset
        run = simulate(model, x0, 350 / 3.6, 0.1, 250.0)
        y = np.abs(run.signal("y1"))
        onset = run.speed_kmh[np.argmax(y > 4.5e-3)] if np.any(y > 4.5e-3) else float("nan")
        print(f"  {offset:.0e} m: smallest {y.min():.1e} m, onset {onset:.1f} km/h")


if __name__ == "__main__":
    model = BogieModel()
    contact(model)
    readings()
    ramp_from_tiny_starts()
    cone_normal()
