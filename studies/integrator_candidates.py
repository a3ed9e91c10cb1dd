"""Integrators for fewer right-hand-side evaluations: exponential, Rosenbrock-W and splitting
candidates against classic RK4, measured with v1's accuracy criterion.

Every candidate freezes a matrix ``A``: the Jacobian of the right-hand side at the straight-track
equilibrium of the *nominal* bogie at the current speed (what a table over speed, shared by all
rows, can hold; ``--own-jacobian`` uses each bogie's own). Exponential candidates integrate
``x' = A x`` exactly and the remainder ``N(x) = f(x) - A x`` explicitly; Rosenbrock-W candidates
solve with ``W = I - gamma h A``. Candidates (one 10-ms env step = ``n_sub`` substeps of h):

- ``rk4``: classic RK4 (v1: 10 substeps);
- ``etd2rk``: Cox-Matthews exponential RK2 (``a = x + h phi1 f(x)``, ``x+ = a + h phi2 (N(a) - N(x))``);
- ``etdrk4``: Cox-Matthews exponential RK4;
- ``strang``: Strang splitting, ``exp(hA/2)``, an RK2 (midpoint) step on ``x' = N(x)``, ``exp(hA/2)``;
- ``ros2``: the two-stage Rosenbrock-W method of Verwer et al. (gamma = 1 + 1/sqrt(2), L-stable);
- ``ros3p``: Lang and Verwer's ROS3P (third order with the exact Jacobian, A-stable);
- ``tayS`` (S = 8, 10, 12, 16): an explicit S-stage method whose stability polynomial is the
  degree-S Taylor polynomial of exp (Jameson's form, ``y_k = x + h / (S + 1 - k) f(y_{k-1})``):
  order S on linear problems, order 2 on nonlinear ones, no frozen matrix;
- ``poly14``, ``poly12``: v3's 14-stage and v4's 12-stage methods in the same form with the stage divisors of
  ``bogie_env.integrate.METHOD_DIVISORS`` (a stability polynomial designed for this spectrum,
  ``studies/stability_polynomial.py``): order 2.

Parts:

1. ``spectral``: v1's criterion (``bogie_env.integrate.accurate_substep``) applied to each
   candidate. For every Jacobian J the criterion looks at (equilibrium and flange contact, 7
   speeds over 100-600 km/h, the nominal bogie and the ends of v1's randomised ranges), the
   candidate's one-step map of ``d' = J d`` is formed as a matrix; its eigenvalues ``mu`` give
   the modes the candidate reproduces, ``log(mu) / h``. Worst relative decay-rate and frequency
   errors over the lightly damped modes (damping ratio < 0.5), as in ``eigenvalue_errors``; and
   the largest growth factor per step beyond the exact one (stability).
2. ``critical``: the linear critical speed each candidate's step map gives (where its spectral
   radius at the equilibrium crosses 1), against the exact one.
3. ``nonlinear``: time-domain runs of the passive nominal bogie against RK4 at 160 substeps:
   a 2-s transient from a 3-mm start on v1's alert-level track at 300 and 500 km/h (the max
   error of y1 at the env steps over the reference's max |y1|), the limit-cycle amplitude at
   450 km/h on perfect track, and the onset speed of a 1 m/s^2 ramp from 300 km/h on a 0.5 mm
   rms track (``studies/step_accuracy.py``'s ramp).
4. ``env``: the v1 ramp's hunting onset in the env (``studies/step_convergence.py``'s measured
   table: passive, and the gain-scheduled LQR with one and two steps of delay) with RK4 at 10
   and 20 substeps and with the 10-stage Taylor method (``integration.method: taylor10``, v2)
   at 2 and 4, against RK4 at 40; ``--env-method poly14`` (poly12): v3's (v4's) method at 1 and 2 instead.
5. ``cost``: right-hand sides, matrix-vector products (20 x 20) and their flops per env step, and
   the measured time of a compiled single-row step of each (``--part cost``).

    python studies/integrator_candidates.py --part spectral
    python studies/integrator_candidates.py --part critical
    python studies/integrator_candidates.py --part nonlinear
    python studies/integrator_candidates.py --part env
    python studies/integrator_candidates.py --part cost
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit
from scipy.linalg import expm

from bogie_env.integrate import METHOD_DIVISORS
from bogie_env.dynamics import N_STATES, P_DELTA, P_L1, BogieModel, rhs_row_call
from bogie_env.envs import scenario as scenarios
from bogie_env.envs.config import V1_RANDOMIZE
from bogie_env.params import BogieParams
from bogie_env.stability import critical_speed
from bogie_env.track import TrackInput, alignment_profile, alignment_profile_at_level, sample_track

KMH = 3.6
DT = 0.01
METHODS = ("rk4", "etd2rk", "etdrk4", "strang", "ros2", "ros3p", "tay8", "tay9", "tay10", "tay11", "tay12", "tay16", "poly14", "poly12")
GAMMA_ROS2 = 1.0 + 1.0 / np.sqrt(2.0)
# ROS3P (Lang & Verwer 2001), Hairer-Wanner form: (I/(gamma h) - A) k_i = f(x + sum a_ij k_j) + sum c_ij k_j / h
ROS3P = dict(gamma=0.7886751345948129, a21=1.267949192431123, a31=1.267949192431123, a32=0.0,
             c21=-1.607695154586736, c31=-3.464101615137755, c32=-1.732050807568877,
             m=(2.0, 0.5773502691896258, 0.4226497308103742))  # fmt: skip
#: per substep: (right-hand sides, 20 x 20 matrix-vector products); LU solves are products with a
#: precomputed inverse W^-1 (frozen W per speed, tabulated like the phi-functions)
COUNTS = {"rk4": (4, 0), "etd2rk": (2, 3), "etdrk4": (4, 13), "strang": (2, 4), "ros2": (2, 2), "ros3p": (3, 3),
          "tay8": (8, 0), "tay9": (9, 0), "tay10": (10, 0), "tay11": (11, 0), "tay12": (12, 0), "tay16": (16, 0), "poly14": (14, 0), "poly12": (12, 0)}


# ---------------------------------------------------------------------------------
# Matrix functions of the frozen A
# ---------------------------------------------------------------------------------


def phi_functions(a: np.ndarray, h: float, order: int) -> list[np.ndarray]:
    """[exp(hA), phi1(hA), ..., phi_order(hA)] from one expm of an augmented matrix."""
    n = a.shape[0]
    big = np.zeros((n + order * n, n + order * n))
    big[:n, :n] = h * a
    for k in range(order):
        big[n * k : n * (k + 1), n * (k + 1) : n * (k + 2)] = np.eye(n) if k else np.eye(n)
    e = expm(big)
    return [e[:n, :n]] + [e[:n, n * k : n * (k + 1)] for k in range(1, order + 1)]


class Frozen:
    """The matrices a candidate needs for one substep h with the frozen A."""

    def __init__(self, method: str, a: np.ndarray, h: float) -> None:
        self.method, self.a, self.h = method, a, h
        n = a.shape[0]
        eye = np.eye(n)
        if method == "etd2rk":
            _, self.phi1, self.phi2 = phi_functions(a, h, 2)
        elif method in ("etdrk4", "strang"):
            self.e2, self.phi1_2 = phi_functions(a, h / 2, 1)
            if method == "etdrk4":
                self.e, p1, p2, p3 = phi_functions(a, h, 3)
                self.f1 = p1 - 3 * p2 + 4 * p3
                self.f2 = p2 - 2 * p3
                self.f3 = -p2 + 4 * p3
        elif method == "ros2":
            self.winv = np.linalg.inv(eye - GAMMA_ROS2 * h * a)
        elif method == "ros3p":
            self.minv = np.linalg.inv(eye / (ROS3P["gamma"] * h) - a)


def substep(fr: Frozen, f, x: np.ndarray, t: float) -> np.ndarray:
    """One substep of fr.method from x at time t; f(x, t) the right-hand side. Works for a state
    (20,) and for a matrix of states (20, k) (the linear one-step map)."""
    h, a, m = fr.h, fr.a, fr.method
    if m == "rk4":
        k1 = f(x, t)
        k2 = f(x + 0.5 * h * k1, t + 0.5 * h)
        k3 = f(x + 0.5 * h * k2, t + 0.5 * h)
        k4 = f(x + h * k3, t + h)
        return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    if m == "etd2rk":
        fx = f(x, t)
        d = h * (fr.phi1 @ fx)
        ax = x + d
        return ax + fr.phi2 @ (h * (f(ax, t + h) - fx) - h * (a @ d))
    if m == "etdrk4":
        def nl(y, s):
            return f(y, s) - a @ y

        q = 0.5 * h * fr.phi1_2
        nx = nl(x, t)
        ex = fr.e2 @ x
        ya = ex + q @ nx
        na = nl(ya, t + 0.5 * h)
        yb = ex + q @ na
        nb = nl(yb, t + 0.5 * h)
        yc = fr.e2 @ ya + q @ (2 * nb - nx)
        nc = nl(yc, t + h)
        return fr.e @ x + h * (fr.f1 @ nx + 2 * fr.f2 @ (na + nb) + fr.f3 @ nc)
    if m == "strang":
        y = fr.e2 @ x
        ym = y + 0.5 * h * (f(y, t) - a @ y)
        y = y + h * (f(ym, t + 0.5 * h) - a @ ym)
        return fr.e2 @ y
    if m == "ros2":
        k1 = fr.winv @ f(x, t)
        k2 = fr.winv @ (f(x + h * k1, t + h) - 2 * k1)
        return x + 1.5 * h * k1 + 0.5 * h * k2
    if m == "ros3p":
        c = ROS3P
        k1 = fr.minv @ f(x, t)
        k2 = fr.minv @ (f(x + c["a21"] * k1, t + h) + c["c21"] * k1 / h)
        k3 = fr.minv @ (f(x + c["a31"] * k1 + c["a32"] * k2, t + h) + (c["c31"] * k1 + c["c32"] * k2) / h)
        m1, m2, m3 = c["m"]
        return x + m1 * k1 + m2 * k2 + m3 * k3
    if _jameson(m):  # y_{k+1} = x + h / d_k f(y_k), d_k = S - k for tayS
        divisors = METHOD_DIVISORS[m] if m in METHOD_DIVISORS else [float(int(m[3:]) - k) for k in range(int(m[3:]))]
        y, c = x, 0.0
        for d in divisors:
            alpha = 1.0 / d
            y = x + alpha * h * f(y, t + c * h)
            c = alpha
        return y
    raise ValueError(m)


def _jameson(method: str) -> bool:
    """An explicit method in Jameson's form (no frozen matrix): tayS or a name of METHOD_DIVISORS."""
    return method.startswith("tay") or (method in METHOD_DIVISORS and method != "rk4")


def substep_map(method: str, j: np.ndarray, a: np.ndarray, h: float) -> np.ndarray:
    """The one-substep map of d' = J d with the frozen A (20 x 20)."""
    return substep(Frozen(method, a, h), lambda y, s: j @ y, np.eye(j.shape[0]), 0.0)


# ---------------------------------------------------------------------------------
# Part 1-2: the spectral criterion and the linear critical speed
# ---------------------------------------------------------------------------------


def criterion_models() -> list[tuple[str, BogieModel]]:
    """The bogies v1's criterion checks: nominal, all ranges at each end, each range alone at each end."""
    base = BogieParams.paper()
    nominal = BogieModel(base)
    ranges = {k: v for k, v in V1_RANDOMIZE.items() if k in scenarios.RANGES and k != "actuator_gain"}
    out = [("nominal", nominal)]
    for end in (0, 1):
        out.append((f"all {'low' if end == 0 else 'high'}", scenarios.scenario_model(base, scenarios.Scenario(**{k: v[end] for k, v in ranges.items()}), nominal)))
        for k, v in ranges.items():
            out.append((f"{k}={v[end]:g}", scenarios.scenario_model(base, scenarios.Scenario(**{k: v[end]}), nominal)))
    return out


def jacobians(model: BogieModel, speed: float, x_ref_speed: float) -> list[tuple[str, np.ndarray]]:
    """The criterion's Jacobians at one speed: equilibrium (at the range's top speed, as in
    ``bogie_env.integrate.spectrum``) and both wheelsets on the flange."""
    x_eq = model.equilibrium(x_ref_speed)
    engaged = x_eq.copy()
    engaged[[0, 8, 16]] = model.coefficients[P_DELTA] + 1e-3
    return [("equilibrium", model.jacobian(x_eq, speed)), ("flange", model.jacobian(engaged, speed))]


def mode_errors(j: np.ndarray, smap: np.ndarray, h: float, zeta_max: float = 0.5) -> tuple[float, float, float]:
    """(decay error, frequency error, excess growth per env step) of the substep map ``smap``
    (step h) against exp(h J), over J's lightly damped modes (as ``eigenvalue_errors``), each
    matched to the nearest reproduced mode ``log(mu) / h``."""
    lam = np.linalg.eigvals(j)
    mu = np.linalg.eigvals(smap).astype(complex)
    with np.errstate(divide="ignore"):
        lam_h = np.log(mu) / h  # principal branch: |Im| up to pi / h is unambiguous ...
    # ... beyond it (only at h = 10 ms: pi / h = 314 rad/s) each reproduced mode is unwrapped to
    # the branch nearest the exact mode it is compared with
    light = lam[(np.abs(lam.imag) > 0) & (-lam.real < zeta_max * np.abs(lam))]
    decay = freq = 0.0
    for lm in light:
        k_branch = np.round((lm.imag - lam_h.imag) * h / (2 * np.pi))
        cand = lam_h + 2j * np.pi * k_branch / h
        best = cand[np.argmin(np.abs(cand - lm))]
        decay = max(decay, abs(best.real - lm.real) / max(abs(lm.real), 0.01 * abs(lm)))
        freq = max(freq, abs(best.imag - lm.imag) / abs(lm.imag))
    n_sub = round(DT / h)
    exact_growth = np.max(np.abs(np.exp(DT * lam)))
    growth = max(0.0, float(np.max(np.abs(mu)) ** n_sub / max(exact_growth, 1.0) - 1.0))
    return decay, freq, growth


def spectral_part(n_subs: list[int], methods: list[str], own: bool, quick: bool) -> None:
    speeds = np.linspace(100 / KMH, 600 / KMH, 4 if quick else 7)
    models = criterion_models()[: 3 if quick else None]
    nominal = models[0][1]
    x_nom = nominal.equilibrium(float(speeds[-1]))
    a_tab = {float(v): nominal.jacobian(x_nom, float(v)) for v in speeds}
    print(f"v1's criterion per candidate: worst over {len(models)} bogies x {len(speeds)} speeds x (equilibrium, flange);"
          f" frozen A = {'each bogie' if own else 'the nominal bogie'}'s equilibrium Jacobian at the speed")
    print("cells: decay error / frequency error / excess growth per 10-ms step; criterion: decay and frequency <= 0.1, no excess growth")
    worst_where: dict = {}
    print(f"{'method':<8} " + " ".join(f"{'n_sub=' + str(n):>24}" for n in n_subs))
    for method in methods:
        cells = []
        for n in n_subs:
            d_max = f_max = g_max = 0.0
            where = ""
            for name, model in models:
                x_ref = float(speeds[-1])
                for v in speeds:
                    a = model.jacobian(model.equilibrium(x_ref), float(v)) if own else a_tab[float(v)]
                    for state, j in jacobians(model, float(v), x_ref):
                        d, f, g = mode_errors(j, substep_map(method, j, a, DT / n), DT / n)
                        if max(d, f) > max(d_max, f_max):
                            where = f"{name}, {v * KMH:.0f} km/h, {state}"
                        d_max, f_max, g_max = max(d_max, d), max(f_max, f), max(g_max, g)
            worst_where[(method, n)] = where
            cells.append(f"{min(d_max, 99):6.3f} / {min(f_max, 99):6.3f} / {min(g_max, 99):5.2g}")
        print(f"{method:<8} " + " ".join(f"{c:>24}" for c in cells), flush=True)
    print("worst case of each cell:")
    for (method, n), where in worst_where.items():
        print(f"  {method} n_sub={n}: {where}")


def critical_part(n_subs: list[int], methods: list[str]) -> None:
    model = BogieModel()
    exact = critical_speed(model).speed_kmh
    print(f"linear critical speed of the nominal bogie (km/h): exact {exact:.2f}")
    print(f"{'method':<8} " + " ".join(f"{'n_sub=' + str(n):>10}" for n in n_subs))

    def radius(method, n, v_kmh):
        v = v_kmh / KMH
        x_eq = model.equilibrium(v)
        j = model.jacobian(x_eq, v)
        return np.max(np.abs(np.linalg.eigvals(substep_map(method, j, j, DT / n)))) - 1.0

    for method in methods:
        row = []
        for n in n_subs:
            lo, hi = exact - 60.0, exact + 60.0
            if radius(method, n, lo) >= 0 or radius(method, n, hi) <= 0:
                row.append("n/a")
                continue
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if radius(method, n, mid) < 0 else (lo, mid)
            row.append(f"{0.5 * (lo + hi):.2f}")
        print(f"{method:<8} " + " ".join(f"{c:>10}" for c in row), flush=True)


def closed_loop_part(n_subs: list[int], methods: list[str], gains: list[float]) -> None:
    """The least-damped mode of a sampled loop with one step of delay: u_k = -g K x_{k-1}, held over
    the env step; K the LQR gain of the nominal bogie at each speed. Exact: M = exp(DT J), G =
    DT phi1(DT J) B; each candidate: its one-step maps of x' = J x + B u."""
    from scipy.linalg import solve_continuous_are

    model = BogieModel()
    b = model.input_matrix()
    names = ("y1", "psi1", "y2", "psi2", "yb", "psib")
    q = np.zeros(N_STATES)
    for name, scale in zip(names, (1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3)):
        from bogie_env.dynamics import state_index

        q[state_index(name)] = 1.0 / scale**2
    q[q == 0] = 1e-2
    r = np.eye(4) / 5e3**2
    speeds = np.linspace(100 / KMH, 600 / KMH, 11)
    x_eq = model.equilibrium(float(speeds[-1]))

    def loop(m, g_in, k):
        big = np.zeros((N_STATES + 4, N_STATES + 4))
        big[:N_STATES, :N_STATES] = m
        big[:N_STATES, N_STATES:] = g_in
        big[N_STATES:, :N_STATES] = -k
        return np.linalg.eigvals(big)

    def errors(mu_m, mu_e):
        """Worst relative decay-rate error over the exact loop's lightly damped modes (damping
        ratio < 0.5 from log(mu) / DT), each matched to the candidate's nearest eigenvalue."""
        worst = 0.0
        for me in mu_e:
            lam = np.log(me + 0j) / DT
            if abs(me) < 1e-12 or lam.imag == 0 or -lam.real >= 0.5 * abs(lam):
                continue
            mm = mu_m[np.argmin(np.abs(mu_m - me))]
            worst = max(worst, abs(np.log(abs(mm)) - np.log(abs(me))) / DT / max(abs(lam.real), 0.01 * abs(lam)))
        return worst

    def maps(method, j, n):
        if method == "exact":
            e, p1 = phi_functions(j, DT, 1)
            return e, DT * p1 @ b
        fr = Frozen(method, j, DT / n)
        aug = np.zeros((N_STATES + 4, N_STATES + 4))  # u as 4 constant states
        aug[:N_STATES, :N_STATES] = j
        aug[:N_STATES, N_STATES:] = b
        fr_aug = Frozen(method, aug, DT / n) if method != "rk4" and not _jameson(method) else None
        x = np.eye(N_STATES + 4)
        for _ in range(n):
            x = substep(fr_aug if fr_aug is not None else fr, lambda y, s_: aug @ y, x, 0.0)
        return x[:N_STATES, :N_STATES], x[:N_STATES, N_STATES:]

    print("sampled loop with one step of delay, LQR gain g K, 11 speeds 100-600 km/h: worst relative decay-rate error of the"
          " closed loop's lightly damped modes (damping ratio < 0.5) against the exact sampled loop; criterion 0.1")
    for g in gains:
        exact, gains_k, jacs = [], [], []
        for v in speeds:
            j = model.jacobian(x_eq, float(v))
            p_are = solve_continuous_are(j, b, np.diag(q), r)
            k = g * np.linalg.solve(r, b.T @ p_are)
            gains_k.append(k)
            jacs.append(j)
            exact.append(loop(*maps("exact", j, 1), k))
        radius = [float(np.max(np.abs(e))) for e in exact]
        print(f"gain factor {g:g}: exact loop's spectral radius per speed " + " ".join(f"{x:.4f}" for x in radius))
        for method in methods:
            cells = []
            for n in n_subs:
                err = max(errors(loop(*maps(method, j, n), k), e) for j, k, e in zip(jacs, gains_k, exact))
                cells.append(f"n_sub={n}: {min(err, 99):7.3f}")
            print(f"  {method:<8} " + " ".join(cells), flush=True)


# ---------------------------------------------------------------------------------
# Part 3: nonlinear time-domain runs
# ---------------------------------------------------------------------------------


@njit(cache=True)
def _rhs_track(x, v, s, track, p, q, yt, out):
    sample_track(track, s, p[P_L1], yt)
    rhs_row_call(x, v, q, yt, p, out)


class Plant:
    """The passive nominal bogie on a track, speed v0 + accel t, distance v0 t + accel t^2 / 2."""

    def __init__(self, model: BogieModel, track, v0: float, accel: float) -> None:
        self.track_profile = track
        self.p = model.coefficients
        self.track = TrackInput(track).compiled()
        self.v0, self.accel = v0, accel
        self.q = np.zeros(4)
        self.yt = np.zeros(8)

    def f(self, x: np.ndarray, t: float) -> np.ndarray:
        out = np.empty(N_STATES)
        _rhs_track(x, self.v0 + self.accel * t, self.v0 * t + 0.5 * self.accel * t * t, self.track, self.p, self.q, self.yt, out)
        return out


class Stepper:
    """Env steps of a candidate with A tabulated on a speed grid (nearest grid speed, 0.25 m/s)."""

    def __init__(self, method: str, n_sub: int, model: BogieModel, grid_step: float = 0.25) -> None:
        self.method, self.n_sub, self.model, self.grid_step = method, n_sub, model, grid_step
        self.cache: dict[int, Frozen] = {}
        self.x_eq = model.equilibrium(100.0)

    def frozen(self, v: float) -> Frozen:
        key = int(round(v / self.grid_step))
        if key not in self.cache:
            a = self.model.jacobian(self.x_eq, key * self.grid_step) if self.method != "rk4" else np.zeros((N_STATES, N_STATES))
            self.cache[key] = Frozen(self.method, a, DT / self.n_sub)
        return self.cache[key]

    def run(self, plant: Plant, x0: np.ndarray, n_steps: int) -> np.ndarray:
        x = x0.copy()
        out = np.empty((n_steps + 1, N_STATES))
        out[0] = x
        h = DT / self.n_sub
        for k in range(n_steps):
            t0 = k * DT
            fr = self.frozen(plant.v0 + plant.accel * (t0 + 0.5 * DT))
            for j in range(self.n_sub):
                x = substep(fr, plant.f, x, t0 + j * h)
            out[k + 1] = x
            if not np.all(np.isfinite(x)):
                out[k + 1 :] = np.nan
                break
        return out


def reference(model: BogieModel, plant: Plant, x0: np.ndarray, n_steps: int, n_sub: int = 160) -> np.ndarray:
    """RK4 at n_sub substeps, through the project's compiled simulator (the same physics)."""
    from bogie_env.simulator import BatchSimulator

    sim = BatchSimulator(model, 1, DT, (min(plant.v0, plant.v0 + plant.accel * n_steps * DT), max(plant.v0, plant.v0 + plant.accel * n_steps * DT)),
                         TrackInput(plant.track_profile), n_sub=n_sub)  # fmt: skip
    sim.set_rows(0, x0, plant.v0, plant.accel, end_speed=plant.v0 + plant.accel * n_steps * DT + (1e-9 if plant.accel >= 0 else -1e-9))
    states, _ = sim.run(n_steps, 1)
    return states[:, 0]


def onset_kmh(states: np.ndarray, v0: float, accel: float, threshold: float = 4.5e-3) -> float:
    y1 = np.abs(states[:, 0])
    n_win = int(round(1.0 / DT))
    for w in range(len(y1) // n_win):
        if np.nanmax(y1[w * n_win : (w + 1) * n_win + 1]) > threshold or not np.all(np.isfinite(y1[w * n_win : (w + 1) * n_win + 1])):
            return (v0 + accel * (w + 1) * 1.0) * KMH
    return float("nan")


def _print_runs(methods, n_subs, model, plant, start, n_steps, cell) -> None:
    """One line per method: ``cell(run)`` of its run at each substep count."""
    for method in methods:
        cells = [f"n_sub={n}: {cell(Stepper(method, n, model).run(plant, start, n_steps))}" for n in n_subs]
        print(f"  {method:<8} " + " ".join(cells), flush=True)


def nonlinear_part(n_subs: list[int], methods: list[str], quick: bool) -> None:
    model = BogieModel()
    alert = alignment_profile_at_level("alert")
    cases = []
    for v_kmh, seconds in ((300.0, 2.0), (500.0, 0.5)):  # above the critical speed runs diverge after ~1 s
        v = v_kmh / KMH
        x0 = model.equilibrium(v)
        x0[0] += 3e-3
        cases.append((f"transient {v_kmh:g} km/h, alert track, {seconds:g} s", alert, v, 0.0, x0, int(round(seconds / DT))))
    results: dict = {}
    print("max |y1 - y1_ref| over the env steps / max |y1_ref| (reference RK4 at 160 substeps)")
    for label, track, v, accel, x0, n_steps in cases:
        plant = Plant(model, track, v, accel)
        ref = reference(model, plant, x0, n_steps)
        scale = np.max(np.abs(ref[:, 0]))
        row = []
        for method in methods:
            for n in n_subs:
                run = Stepper(method, n, model).run(plant, x0, n_steps)
                err = float(np.max(np.abs(run[:, 0] - ref[:, 0])) / scale) if np.all(np.isfinite(run)) else float("inf")
                results[(label, method, n)] = err
                row.append(err)
        print(label)
        for i, method in enumerate(methods):
            print(f"  {method:<8} " + " ".join(f"n_sub={n}: {results[(label, method, n)]:9.2e}" for n in n_subs), flush=True)
    # limit cycle at 450 km/h, perfect track
    from bogie_env.analysis.bifurcation import limit_cycle_state
    from bogie_env.track import perfect_track

    v = 450.0 / KMH
    start = limit_cycle_state(model, 450.0)
    plant = Plant(model, perfect_track(), v, 0.0)
    n_steps = 500 if quick else 1000
    ref = reference(model, plant, start, n_steps)
    amp_ref = np.max(np.abs(ref[-200:, 0])) * 1e3
    print(f"limit cycle at 450 km/h, perfect track: y1 amplitude over the last 2 s of {n_steps * DT:g} s (mm); reference {amp_ref:.4f}")
    _print_runs(methods, n_subs, model, plant, start, n_steps, lambda run: f"{np.max(np.abs(run[-200:, 0])) * 1e3:8.4f}")
    if quick:
        return
    # ramp onset (studies/step_accuracy.py's ramp)
    track = alignment_profile(5e-4)
    x0 = model.equilibrium(300 / KMH)
    x0[0] += 1e-3
    plant = Plant(model, track, 300 / KMH, 1.0)
    n_steps = 8000
    ref = reference(model, plant, x0, n_steps, n_sub=80)
    print(f"ramp 300 km/h + 1 m/s^2, 0.5 mm rms track: onset (1-s peak of |y1| > 4.5 mm), km/h; reference (RK4, 80 substeps) {onset_kmh(ref, 300 / KMH, 1.0):.1f}")
    _print_runs(methods, n_subs, model, plant, x0, n_steps, lambda run: f"{onset_kmh(run, 300 / KMH, 1.0):6.1f}")


# ---------------------------------------------------------------------------------
# Part 5: the env's closed loop (studies/step_convergence.py's measured table, per method)
# ---------------------------------------------------------------------------------


def env_onsets(controller: str, conicity: float, method: str, n_sub: int, delay_steps: int, seeds: list[int]) -> np.ndarray:
    """Hunting onset (km/h) of each seed on the v1 ramp (``studies/step_convergence.py``'s
    set-up: passive bogie, or the gain-scheduled LQR on the full state) with ``method``."""
    from step_convergence import onset_speeds  # the sibling study script (studies/ is on sys.path)

    return onset_speeds(controller, conicity, n_sub, delay_steps, seeds, method)


def env_part(quick: bool, method: str = "taylor10") -> None:
    """Onsets with RK4 at 10 (v1) and 20 substeps, the env ``method`` at the substeps its env
    version picks (taylor10: 2, v2; poly14: 1, v3; poly12: 1, v4) and at twice that, RK4 at 40 (reference)."""
    from bogie_env.envs.config import make_config
    from bogie_env.envs.task import HuntingTask

    conicities = [0.025, 0.1] if quick else [0.025, 0.05, 0.1, 0.2, 0.3]
    seeds = [0, 1] if quick else [0, 1, 2, 3]
    n = HuntingTask(1, make_config({"integration": {"method": method}}, variant="v1")).n_sub
    steps = (("rk4", 10), ("rk4", 20), (method, n), (method, 2 * n), ("rk4", 40))
    print(f"hunting onset on the v1 ramp, mean over seeds {seeds} (km/h): RK4 at 10 (v1) and 20 substeps, {method}"
          f" at {n} (its env version) and {2 * n}, RK4 at 40 (reference)")  # fmt: skip
    print(f"{'controller':<10} {'conicity':>8} {'delay':>5}  " + "  ".join(f"{m}x{k:<3d}" for m, k in steps)
          + "  |env - env half| |env - ref| |v1 - ref|")  # fmt: skip
    for controller, delays in (("passive", [1]), ("lqr", [1, 2])):
        for lam in conicities:
            for delay in delays:
                t0 = time.perf_counter()
                means = [float(np.mean(env_onsets(controller, lam, m, k, delay, seeds))) for m, k in steps]
                print(f"{controller:<10} {lam:>8g} {delay * 10:>3d}ms  " + "  ".join(f"{x:11.1f}" for x in means)
                      + f"  {abs(means[2] - means[3]):16.2f} {abs(means[2] - means[4]):11.2f} {abs(means[0] - means[4]):10.2f}"
                      + f"   ({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip


# ---------------------------------------------------------------------------------
# Part 4: cost
# ---------------------------------------------------------------------------------


@njit(cache=True)
def _time_rhs(x, v, q, yt, p, out, reps):
    acc = 0.0
    for r in range(reps):
        x[0] = 1e-3 + 1e-12 * r
        rhs_row_call(x, v, q, yt, p, out)
        acc += out[1]
    return acc


@njit(cache=True)
def _time_matvec(m, x, out, reps):
    n = x.shape[0]
    acc = 0.0
    for r in range(reps):
        x[0] = 1e-3 + 1e-12 * r
        for i in range(n):
            s = 0.0
            for k in range(n):
                s += m[i, k] * x[k]
            out[i] = s
        acc += out[1]
    return acc


def cost_part() -> None:
    model = BogieModel()
    p = model.coefficients
    x = model.equilibrium(100.0)
    out = np.empty(N_STATES)
    q = np.zeros(4)
    yt = np.zeros(8)
    m = np.random.default_rng(0).random((N_STATES, N_STATES))
    reps = 200_000
    _time_rhs(x, 100.0, q, yt, p, out, 10)
    _time_matvec(m, x.copy(), out, 10)
    best_rhs = best_mv = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        _time_rhs(x, 100.0, q, yt, p, out, reps)
        best_rhs = min(best_rhs, (time.perf_counter() - t0) / reps)
        t0 = time.perf_counter()
        _time_matvec(m, x.copy(), out, reps)
        best_mv = min(best_mv, (time.perf_counter() - t0) / reps)
    ratio = best_mv / best_rhs
    print(f"compiled, one row, scalar: right-hand side {best_rhs * 1e9:.0f} ns, 20 x 20 matrix-vector product {best_mv * 1e9:.0f} ns"
          f" (= {ratio:.2f} right-hand sides)")
    print("cost per 10-ms env step, in right-hand-side equivalents (rhs + ratio x matvec), against RK4 x 10 (40 rhs):")
    print(f"{'method':<8} {'rhs/sub':>7} {'mv/sub':>6} " + " ".join(f"{'n_sub=' + str(n):>9}" for n in (1, 2, 5, 10)))
    for method in METHODS:
        r, mv = COUNTS[method]
        cells = [f"{n * (r + ratio * mv):9.1f}" for n in (1, 2, 5, 10)]
        print(f"{method:<8} {r:>7} {mv:>6} " + " ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("spectral", "critical", "closed-loop", "nonlinear", "env", "cost"), required=True)
    parser.add_argument("--gains", default="1,3", help="closed-loop: factors on the LQR gain")
    parser.add_argument("--n-sub", default="1,2,5,10", help="substeps per 10-ms env step, comma-separated")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--own-jacobian", action="store_true", help="spectral: A from each bogie's own Jacobian (per-row tables)")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--env-method", default="taylor10", help="env: the env's integration.method to check (poly14: v3, poly12: v4)")
    args = parser.parse_args()
    n_subs = [int(s) for s in args.n_sub.split(",")]
    methods = args.methods.split(",")
    if args.part == "spectral":
        spectral_part(n_subs, methods, args.own_jacobian, args.quick)
    elif args.part == "critical":
        critical_part(n_subs, methods)
    elif args.part == "closed-loop":
        closed_loop_part(n_subs, methods, [float(g) for g in args.gains.split(",")])
    elif args.part == "nonlinear":
        nonlinear_part(n_subs, methods, args.quick)
    elif args.part == "env":
        env_part(args.quick, args.env_method)
    else:
        cost_part()


if __name__ == "__main__":
    main()
