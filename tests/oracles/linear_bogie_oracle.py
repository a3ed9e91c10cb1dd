# Independent oracle, written separately from bogie_env by a second engineer (vector mechanics in
# sympy), used only by the tests. Do not import bogie_env here: its independence is the point.
#!/usr/bin/env python3
"""Independent first-principles linearisation of the 10-DOF bogie model of
Bustos, Tomas-Rodriguez, Rubio & Castejon, "On the nonlinear hunting stability of a
high-speed train bogie", Nonlinear Dynamics (2022).

Derivation (sympy, vector mechanics)
------------------------------------
Track axes: x forward, y left, z up.  Left wheel at y=+e (side s=+1), right wheel at
y=-e (s=-1).  Wheelset i=1 at x=+L1 (front), i=2 at x=-L1 (rear).

For every wheel:
  * rolling radius  r_s = r0 + s*lam*y                          (Eq. 15)
  * creepages       xi_x  = (1 - r_s/r0) - s*e*dpsi/V
                    xi_y  = (dy + r_s*dphi)/V - psi
                    xi_sp = dpsi/V - s*lam/r0                   (after Eq. 30)
  * Kalker linear   Fxc = -a f33 xi_x ; Fyc = -a f11 xi_y - a f12 xi_sp ;
                    Mzc =  a f12 xi_y - a f22 xi_sp             (Eqs. 16-25, 29-30)
  * contact frame (paper transformation, Eqs. 16-25): contact-plane inclination
        gamma_s = lam + s*phi   (deltaL+phi, deltaR-phi)
    body-plane vectors  t_y0 = (0, 1, s*gamma_s),  n0 = (0, -s*gamma_s, 1)
    then first-order yaw rotation Rz(psi) = [[1,-psi,0],[psi,1,0],[0,0,1]]:
        t_x = (1, psi, 0), t_y = (-psi, 1, s*gamma), n = (s*gamma*psi, -s*gamma, 1)
    creep force  F = Fxc t_x + Fyc t_y ; spin moment M = Mzc n.
    (option contact_frame='rotated' uses the exact rotation Rz(psi)Rx(phi) of the
     body-fixed cone vectors (0,1,s*lam), (0,-s*lam,1) instead.)
  * contact position (Eqs. 31-36)  R_s = (-s e psi, s e + r_s phi, s e phi - r_s)
  * normal force (Eqs. 37-39)      N_s = (0, -s (W/2) gamma_s, W/2)
    (option normal_dir='rotated' puts N along the rotated normal n with N_z = W/2.)
Wheelset Newton-Euler:  m_w (ddy, ddz) = sum F (y,z comps) - Wpa*e_z + primary forces;
angular momentum H = Iwx dphi e_x + Iwz dpsi e_z + Iwy (V/r0) a,   a = R e_y (axle),
(Iwx ddphi, Iwz ddpsi) = (x,z comps of) [ sum R x F + sum Mspin + sum R x N
                                        + primary moments - Iwy (V/r0) da/dt ]
plus, in the roll equation, the secondary-suspension term of Eq. 43
   -2 Ksy h_K yb - 2 Csy h_C dyb   (h_K = h2 = spring height, h_C = h1 = damper height by
   default; option eq43_heights='printed' uses the printed Ksy*h1, Csy*h2).
Primary suspension: springs/dampers between axle-box points (0, +-b1, 0) of the wheelset
and frame points (+-L1 / +-L2, +-b1, 0) (small-angle rotations), component-wise
Kpx,Kpy,Kpz / Cpx,Cpy,Cpz.  Secondary: frame points (0, +-b2, 0) springs and
(0, +-b3, 0) dampers to a fixed car body (Ksx,Ksy / Csx,Csy).  Frame: mb ddyb = F_y,
Ibz ddpsib = M_z of the reactions.  Flange force (Eq. 46) is zero for |y| < 9 mm.

Saturation (Eqs. 26-28): beta_i = (beta_iL + beta_iR)/2, beta_ij = |F_lin|/(mu N),
N = Wpa/2;  alpha = 1 - beta/3 + beta^2/27 (beta<=3), alpha = 1/beta (beta>3).

The Jacobian is evaluated at the equilibrium (all zero except z_i = z0, produced by the
constant vertical creep force 2 a f12 lam^2/r0) with alpha frozen at alpha0 = alpha(beta0),
beta0 = f12*lam/(r0*mu*N).  (It is shown in REPORT.md / sanity_checks.py that
d(alpha)/dx = 0 at the equilibrium, so the frozen-alpha Jacobian is the exact one.)

State order: y1,dy1,z1,dz1,psi1,dpsi1,phi1,dphi1, y2,...,dphi2, yb,dyb,psib,dpsib.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import sympy as sp
from scipy.optimize import brentq, fsolve

PARAM_KEYS = ["mb", "Ibz", "mw", "Iwx", "Iwy", "Iwz", "L1", "L2", "b1", "b2", "b3",
              "h1", "h2", "Wpa", "e", "r0", "lam", "Kpx", "Kpy", "Kpz", "Cpx", "Cpy",
              "Cpz", "Ksx", "Ksy", "Csx", "Csy", "f11", "f12", "f22", "f33", "mu"]

# Table 1 values + placeholder creep coefficients of the brief
DEFAULT_PARAMS = dict(
    mb=1610.0, Ibz=2.82e3, mw=1570.0, Iwx=693.0, Iwy=121.0, Iwz=693.0,
    L1=1.5, L2=1.5, b1=1.02, b2=1.04, b3=1.34, h1=0.42, h2=0.14,
    Wpa=1.5e5, e=0.7175, r0=0.46, lam=0.025,
    Kpx=5.8e7, Kpy=1.6e7, Kpz=5.4e5, Cpx=0.0, Cpy=0.0, Cpz=5.0e3,
    Ksx=1.0e5, Ksy=1.0e5, Csx=1.3e4, Csy=3.0e4,
    f11=1.064e7, f12=2.687e4, f22=78.9, f33=1.183e7, mu=0.3,
)

STATE_NAMES = ["y1", "dy1", "z1", "dz1", "psi1", "dpsi1", "phi1", "dphi1",
               "y2", "dy2", "z2", "dz2", "psi2", "dpsi2", "phi2", "dphi2",
               "yb", "dyb", "psib", "dpsib"]

DEFAULT_OPTIONS = dict(contact_frame="paper",     # 'paper' (Eqs.16-25) | 'rotated'
                       normal_dir="paper",        # 'paper' (Eqs.37-39) | 'rotated'
                       eq43_heights="physical",   # 'physical' (Ksy*h2, Csy*h1) | 'printed'
                       eq43_coef=-2.0)            # M_x += coef*(Ksy*hK*yb + Csy*hC*dyb);
                                                  # -2 as printed in Eq. 43


def alpha_of_beta(beta):
    """Eq. 26 with the correct saturated branch (alpha = 1/beta for beta > 3)."""
    beta = float(beta)
    if beta <= 3.0:
        return 1.0 - beta / 3.0 + beta * beta / 27.0
    return 1.0 / beta


# ----------------------------------------------------------------------------------
# symbolic derivation
# ----------------------------------------------------------------------------------
def _vec(*c):
    return sp.Matrix(c)


def _skew_rot(theta):
    """first-order rotation matrix I + [theta]_x"""
    tx, ty, tz = theta
    return sp.Matrix([[1, -tz, ty], [tz, 1, -tx], [-ty, tx, 1]])


def _Rz(a):
    return sp.Matrix([[sp.cos(a), -sp.sin(a), 0], [sp.sin(a), sp.cos(a), 0], [0, 0, 1]])


def _Rx(a):
    return sp.Matrix([[1, 0, 0], [0, sp.cos(a), -sp.sin(a)], [0, sp.sin(a), sp.cos(a)]])


@functools.lru_cache(maxsize=None)
def _derive(options_key):
    opt = dict(options_key)
    P = {k: sp.Symbol(k, real=True) for k in PARAM_KEYS}
    V = sp.Symbol("V", positive=True)
    al = sp.symbols("alpha1 alpha2", positive=True)
    X = sp.symbols(" ".join(STATE_NAMES), real=True)
    S = dict(zip(STATE_NAMES, X))
    # time derivative operator on expressions in positions (positions -> velocities)
    pos_names = ["y1", "z1", "psi1", "phi1", "y2", "z2", "psi2", "phi2", "yb", "psib"]
    pos = [S[n] for n in pos_names]
    vel = [S["d" + n] for n in pos_names]

    def ddt(expr):
        if isinstance(expr, sp.MatrixBase):
            return expr.applyfunc(ddt)
        return sum((sp.diff(expr, q) * qd for q, qd in zip(pos, vel)), sp.S(0))

    mw, Iwx, Iwy, Iwz = P["mw"], P["Iwx"], P["Iwy"], P["Iwz"]
    e, r0, lam, W = P["e"], P["r0"], P["lam"], P["Wpa"]
    yb, psib = S["yb"], S["psib"]
    Om = V / r0

    rhs = {}
    betas = []
    # frame accumulators (reactions of the primary suspension)
    Fb = _vec(0, 0, 0)
    Mbz = sp.S(0)

    for i, sgn_i in ((1, 1), (2, -1)):
        y, z, psi, phi = S[f"y{i}"], S[f"z{i}"], S[f"psi{i}"], S[f"phi{i}"]
        dy, dz, dpsi, dphi = S[f"dy{i}"], S[f"dz{i}"], S[f"dpsi{i}"], S[f"dphi{i}"]
        a = al[i - 1]
        Ftot = _vec(0, 0, 0)
        Mtot = _vec(0, 0, 0)
        beta_i = 0
        for s in (1, -1):                       # s=+1 left, s=-1 right
            rs = r0 + s * lam * y
            gam = lam + s * phi                 # deltaL+phi / deltaR-phi
            xi_x = (1 - rs / r0) - s * e * dpsi / V
            xi_y = (dy + rs * dphi) / V - psi
            xi_sp = dpsi / V - s * lam / r0
            Fx_lin = -P["f33"] * xi_x
            Fy_lin = -P["f11"] * xi_y - P["f12"] * xi_sp
            Mz_lin = P["f12"] * xi_y - P["f22"] * xi_sp
            beta_i += sp.sqrt(Fx_lin ** 2 + Fy_lin ** 2) / (P["mu"] * W / 2) / 2
            Fxc, Fyc, Mzc = a * Fx_lin, a * Fy_lin, a * Mz_lin
            if opt["contact_frame"] == "paper":
                Ryaw = _skew_rot((0, 0, psi))
                tx = Ryaw * _vec(1, 0, 0)
                ty = Ryaw * _vec(0, 1, s * gam)
                n = Ryaw * _vec(0, -s * gam, 1)
            elif opt["contact_frame"] == "rotated":
                R = _Rz(psi) * _Rx(phi)
                tx = R * _vec(1, 0, 0)
                ty = R * _vec(0, 1, s * lam)
                n = R * _vec(0, -s * lam, 1)
            else:
                raise ValueError(opt["contact_frame"])
            Fc = Fxc * tx + Fyc * ty            # creep force, track axes
            Msp = Mzc * n                       # spin moment about the contact normal
            Rc = _vec(-s * e * psi, s * e + rs * phi, s * e * phi - rs)   # Eqs. 31-36
            if opt["normal_dir"] == "paper":
                N = _vec(0, -s * (W / 2) * gam, W / 2)                   # Eqs. 37-39
            elif opt["normal_dir"] == "rotated":
                nn = _skew_rot((phi, 0, psi)) * _vec(0, -s * lam, 1)
                N = (W / 2) * nn / nn[2]
            else:
                raise ValueError(opt["normal_dir"])
            Ftot += Fc + N
            Mtot += Rc.cross(Fc) + Msp + Rc.cross(N)
        betas.append(beta_i)

        # primary suspension: box points (0, j b1, 0) on wheelset, frame points
        # (sgn_i*L1 | sgn_i*L2, j b1, 0); small-angle rotations
        Rw = _skew_rot((phi, 0, psi))
        Rb = _skew_rot((0, 0, psib))
        rw = _vec(sgn_i * P["L1"], y, z)        # wheelset CG (x fixed)
        rb = _vec(0, yb, 0)                     # frame CG
        for j in (1, -1):
            pw = _vec(0, j * P["b1"], 0)
            box = rw + Rw * pw
            # springs
            fk = rb + Rb * _vec(sgn_i * P["L1"], j * P["b1"], 0)
            dk = box - fk
            Fk = -sp.Matrix([P["Kpx"] * dk[0], P["Kpy"] * dk[1], P["Kpz"] * dk[2]])
            # dampers (lateral ones at L2 on the frame)
            fc = rb + Rb * _vec(sgn_i * P["L2"], j * P["b1"], 0)
            vc = ddt(box - fc)
            Fcd = -sp.Matrix([P["Cpx"] * vc[0], P["Cpy"] * vc[1], P["Cpz"] * vc[2]])
            Fs = Fk + Fcd
            Ftot += Fs
            Mtot += (Rw * pw).cross(Fs)
            # reactions on the frame (applied at the frame attachment points)
            Fb += -Fs
            Mbz += ((Rb * _vec(sgn_i * P["L1"], j * P["b1"], 0)).cross(-Fk))[2]
            Mbz += ((Rb * _vec(sgn_i * P["L2"], j * P["b1"], 0)).cross(-Fcd))[2]

        # weight / axle load (cancels against sum of N_z = Wpa)
        Ftot += _vec(0, 0, -W)
        # gyroscopic: H = Iwx dphi ex + Iwz dpsi ez + Iwy Om a, a = axle direction
        if opt["contact_frame"] == "rotated":
            axle = _Rz(psi) * _Rx(phi) * _vec(0, 1, 0)
        else:
            axle = _skew_rot((phi, 0, psi)) * _vec(0, 1, 0)
        Mgyro = -Iwy * Om * ddt(axle)
        Mtot += Mgyro
        # Eq. 43 secondary-suspension roll term (as modelled by the paper)
        if opt["eq43_heights"] == "physical":
            hK, hC = P["h2"], P["h1"]
        elif opt["eq43_heights"] == "printed":
            hK, hC = P["h1"], P["h2"]
        else:
            raise ValueError(opt["eq43_heights"])
        cf = sp.nsimplify(opt["eq43_coef"])
        Mtot[0] += cf * (P["Ksy"] * hK * yb + P["Csy"] * hC * S["dyb"])

        rhs[f"y{i}"] = Ftot[1] / mw
        rhs[f"z{i}"] = Ftot[2] / mw
        rhs[f"psi{i}"] = Mtot[2] / Iwz
        rhs[f"phi{i}"] = Mtot[0] / Iwx

    # secondary suspension: frame to fixed car body
    Rb = _skew_rot((0, 0, psib))
    rb = _vec(0, yb, 0)
    for j in (1, -1):
        pk = _vec(0, j * P["b2"], 0)
        dk = rb + Rb * pk - pk
        Fk = -sp.Matrix([P["Ksx"] * dk[0], P["Ksy"] * dk[1], 0])
        pc = _vec(0, j * P["b3"], 0)
        vc = ddt(rb + Rb * pc - pc)
        Fcd = -sp.Matrix([P["Csx"] * vc[0], P["Csy"] * vc[1], 0])
        Fb += Fk + Fcd
        Mbz += ((Rb * pk).cross(Fk))[2] + ((Rb * pc).cross(Fcd))[2]
    rhs["yb"] = Fb[1] / P["mb"]
    rhs["psib"] = Mbz / P["Ibz"]

    f = []
    order = ["y1", "z1", "psi1", "phi1", "y2", "z2", "psi2", "phi2", "yb", "psib"]
    for q in order:
        f.append(S["d" + q])
        f.append(sp.expand(rhs[q]))
    fvec = sp.Matrix(f)
    Xv = sp.Matrix(X)
    Jsym = fvec.jacobian(Xv)
    args = [X, [P[k] for k in PARAM_KEYS], V, al]
    out = dict(
        f=sp.lambdify(args, fvec, modules="numpy", cse=True),
        J=sp.lambdify(args, Jsym, modules="numpy", cse=True),
        beta=sp.lambdify([X, [P[k] for k in PARAM_KEYS], V], sp.Matrix(betas),
                         modules="numpy", cse=True),
        sym=dict(f=fvec, J=Jsym, X=X, P=P, V=V, alpha=al, beta=betas),
    )
    return out


def _key(options):
    o = dict(DEFAULT_OPTIONS)
    if options:
        o.update(options)
    return tuple(sorted(o.items()))


def _pvec(params):
    return [float(params[k]) for k in PARAM_KEYS]


# ----------------------------------------------------------------------------------
# numeric API
# ----------------------------------------------------------------------------------
def alphas_at(x, params, V, options=None):
    d = _derive(_key(options))
    b = np.asarray(d["beta"](np.asarray(x, float), _pvec(params), float(V)), float).ravel()
    return np.array([alpha_of_beta(bi) for bi in b]), b


def rhs(x, params, V, options=None, alpha=None):
    """Full nonlinear right-hand side dx/dt = f(x) (flange force zero). If alpha is
    None it is computed from the state (Eqs. 26-30); else the given pair is used."""
    d = _derive(_key(options))
    if alpha is None:
        alpha, _ = alphas_at(x, params, V, options)
    return np.asarray(d["f"](np.asarray(x, float), _pvec(params), float(V), list(alpha)),
                      float).ravel()


def equilibrium(params, V, options=None):
    """20-vector equilibrium of the nonlinear model (alpha computed from the state)."""
    p = dict(params)
    x0 = np.zeros(20)
    # analytic first guess: z_i = alpha0 f12 lam^2 / (r0 Kpz)
    a0, _ = alphas_at(x0, p, V, options)
    if p["Kpz"] != 0:
        x0[2] = a0[0] * p["f12"] * p["lam"] ** 2 / (p["r0"] * p["Kpz"])
        x0[10] = a0[1] * p["f12"] * p["lam"] ** 2 / (p["r0"] * p["Kpz"])
    sol, info, ier, msg = fsolve(lambda x: rhs(x, p, V, options), x0, full_output=True,
                                 xtol=1e-14)
    res = np.max(np.abs(rhs(sol, p, V, options)))
    if ier != 1 and res > 1e-8:
        raise RuntimeError(f"equilibrium not found: {msg} (residual {res})")
    return sol


def jacobian(params, V, options=None, return_alpha=False):
    """20x20 Jacobian at the equilibrium, alpha frozen at alpha0 (V in m/s)."""
    d = _derive(_key(options))
    x0 = equilibrium(params, V, options)
    a0, _ = alphas_at(x0, params, V, options)
    J = np.asarray(d["J"](x0, _pvec(params), float(V), list(a0)), float)
    return (J, a0) if return_alpha else J


def max_real_part(params, V_kmh, options=None):
    ev = np.linalg.eigvals(jacobian(params, V_kmh / 3.6, options))
    return float(np.max(ev.real))


def critical_speed(params, options=None, vmin=50.0, vmax=900.0, step=1.0):
    """Lowest speed (km/h) where max Re(eig) crosses zero, and the frequency (Hz) of the
    crossing mode.  Scan vmin..vmax then brentq to 0.01 km/h.  (nan, nan) if none."""
    Vs = np.arange(vmin, vmax + 1e-9, step)
    g = [max_real_part(params, v, options) for v in Vs]
    for k in range(1, len(Vs)):
        if g[k - 1] < 0.0 <= g[k]:
            vc = brentq(lambda v: max_real_part(params, v, options), Vs[k - 1], Vs[k],
                        xtol=0.01)
            ev = np.linalg.eigvals(jacobian(params, vc / 3.6, options))
            k0 = np.argmax(ev.real)
            return float(vc), float(abs(ev[k0].imag) / (2 * math.pi))
    return float("nan"), float("nan")


def symbolic(options=None):
    """Access to the symbolic objects (f, J, X, P, V, alpha, beta)."""
    return _derive(_key(options))["sym"]


if __name__ == "__main__":
    import time
    t0 = time.time()
    p = dict(DEFAULT_PARAMS)
    J, a0 = jacobian(p, 300 / 3.6, return_alpha=True)
    print(f"derivation+first Jacobian: {time.time() - t0:.2f} s")
    x0 = equilibrium(p, 300 / 3.6)
    print(f"alpha0 = {a0}, z0 = {x0[2]:.4e} m")
    vc, fc = critical_speed(p)
    print(f"Critical speed (Table 1, f11={p['f11']:.4g}, f12={p['f12']:.4g}, "
          f"f22={p['f22']:.4g}, f33={p['f33']:.4g}, mu={p['mu']}): "
          f"V_crit = {vc:.2f} km/h, f = {fc:.3f} Hz")
    q = dict(p, f12=0.0, f22=0.0)
    vc0, fc0 = critical_speed(q)
    print(f"Critical speed with f12 = f22 = 0: V_crit = {vc0:.2f} km/h, f = {fc0:.3f} Hz")
