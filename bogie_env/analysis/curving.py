"""Curving: the steady state in a circular curve, sweeps over radius and cant deficiency, and
dynamic curve negotiation on a route (docs/model.md Section 11).

- :func:`steady_curving`: the steady state at a radius, cant and speed. The root of the
  right-hand side with all rates zero (Newton's method, exact complex-step Jacobian), started
  from the linear guess (one Newton step from the straight-track equilibrium); if the root
  finder fails, or finds an unstable steady state (largest real eigenvalue >= 0: the bogie
  does not stay there), a long time simulation entering the curve from the straight-track
  equilibrium (the simulator's one driver) and the root finder again from its end state: the
  steady state the bogie settles at.
- what a curving assessment reads at any state (lateral displacement, angle of attack, creep
  forces, Y/Q per wheel, the sum of guiding forces ΣY and the wear number Tγ per wheelset,
  flange contact) comes from :func:`bogie_env.wheel_rail.wheel_rail_quantities`.
- :func:`route_run`: a bogie at constant speed along a route (:mod:`bogie_env.route`), with the
  same quantities as time histories.

Sign conventions (model axes: x forward, y left): lateral displacement from the local track
centreline, + left; angle of attack = the wheelset's yaw from the local track tangent, + nose
left (in a left curve a wheelset pointing to the outer rail has a negative angle); creep
forces of the rail on the wheel in contact axes, longitudinal + forward, lateral + left;
Y of each wheel = the lateral force the wheel puts on its rail, + towards the outside of the
track for that rail (the derailment sign), Q = the model's wheel load Wpa/2; ΣY = the lateral
force of the wheelset on the track, + left; Tγ = -(Fx ξx + Fy ξy) per wheel, the creep work per
metre rolled (N), summed per wheelset.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..dynamics import N_INPUTS, N_STATES, N_TRACK, BogieModel, check_speed, jacobian_kernel, rhs_single_kernel
from ..route import GRAVITY, Route, cant_angle, constant_curve, equilibrium_cant_m, unbalanced_acceleration
from ..track import (
    ALIGNMENT_WHEELSET1, CANT_FRAME, CANT_WHEELSET1, CANT_WHEELSET2, CURVATURE_FRAME, CURVATURE_WHEELSET1,
    CURVATURE_WHEELSET2, TrackInput, TrackProfile,
)  # fmt: skip
from ..wheel_rail import wheel_rail_quantities

KMH = 3.6
#: EN 14363: Y/Q limit in curves of radius >= 250 m; ΣY limit 10 kN + 2 Q0 / 3 (Prud'homme,
#: alpha = 1), Q0 the static wheel force. Quoted as commonly cited; check against the standard.
Y_OVER_Q_LIMIT = 0.8
POSITIONS = tuple(range(0, N_STATES, 2))  # y1, z1, psi1, phi1, y2, z2, psi2, phi2, yb, psib
ACCELERATIONS = tuple(range(1, N_STATES, 2))


def curve_samples(curvature: float, cant_m: float) -> np.ndarray:
    """Track samples of a circular curve: the same curvature (1/m, + left) and cant (m, signed
    like the curvature) under both wheelsets and the frame, no alignment irregularity."""
    yt = np.zeros(N_TRACK)
    theta = cant_angle(cant_m)
    yt[[CURVATURE_WHEELSET1, CURVATURE_WHEELSET2, CURVATURE_FRAME]] = curvature
    yt[[CANT_WHEELSET1, CANT_WHEELSET2, CANT_FRAME]] = theta
    return yt


def signed_curve(radius_m: float, cant_m: float, direction: str) -> tuple[float, float]:
    """(curvature, signed cant) of a curve of radius (m) and cant (m, >= 0) towards direction."""
    if direction not in ("left", "right"):
        raise ValueError(f"direction = {direction!r} is not allowed; allowed: left, right")
    if not (math.isfinite(radius_m) and radius_m > 0):
        raise ValueError(f"radius = {radius_m!r} m is not allowed; allowed: finite, > 0 (m)")
    if not (math.isfinite(cant_m) and abs(cant_m) < 1.5):
        raise ValueError(f"cant = {cant_m!r} m is not allowed; allowed: finite, |cant| < 1.5 m (the cant base)")
    sign = 1.0 if direction == "left" else -1.0
    return sign / radius_m, sign * cant_m


# ---- steady state -------------------------------------------------------------------------------
def _residual_and_jacobian(model: BogieModel, speed: float, samples: np.ndarray):
    p = model.coefficients
    q = np.zeros(N_INPUTS)
    x = np.zeros(N_STATES)
    f = np.empty(N_STATES)
    jac = np.empty((N_STATES, N_STATES))
    acc = np.array(ACCELERATIONS)
    pos = np.array(POSITIONS)

    def residual(positions):
        x[pos] = positions
        rhs_single_kernel(x, speed, q, samples, p, f)
        jacobian_kernel(x, speed, q, samples, p, jac)
        return f[acc].copy(), jac[np.ix_(acc, pos)].copy()

    return residual


def _newton(residual, guess: np.ndarray, max_iterations: int = 60) -> tuple[np.ndarray, float]:
    """Newton's method with the exact Jacobian, halving the step until the largest residual
    falls; it stops when the residual no longer falls. Returns (solution, largest residual).
    (Not scipy's root: importing scipy.optimize costs about a third of the command's start.)"""
    x = np.array(guess, dtype=float)
    f, jac = residual(x)
    norm = float(np.max(np.abs(f)))
    for _ in range(max_iterations):
        if not np.isfinite(norm) or norm == 0.0:
            break
        try:
            step = np.linalg.solve(jac, -f)
        except np.linalg.LinAlgError:
            step = np.linalg.lstsq(jac, -f, rcond=None)[0]
        scale = 1.0
        while scale >= 2.0**-20:
            trial = x + scale * step
            f_trial, jac_trial = residual(trial)
            norm_trial = float(np.max(np.abs(f_trial)))
            if norm_trial < norm:
                break
            scale *= 0.5
        else:
            break  # no step lowers the residual: converged to rounding (or stuck)
        x, f, jac, norm = trial, f_trial, jac_trial, norm_trial
    return x, norm


def solve_steady_state(model: BogieModel, speed: float, samples: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, str, float]:
    """A steady state (20,) at speed (m/s) on constant track samples, rates zero.

    Returns (state, method, residual). Method "root" (Newton's method with the exact Jacobian
    from the linear guess) or "time-simulation" (a 60 s run on the curve, then the root finder
    from its end state). Raises RuntimeError if neither converges to ``tol`` (m/s^2 and rad/s^2).
    """
    speed = float(check_speed(speed))
    samples = np.ascontiguousarray(samples, dtype=np.float64)
    residual = _residual_and_jacobian(model, speed, samples)
    start = model.equilibrium(speed)[list(POSITIONS)]
    f0, j0 = residual(start)
    guess = start - np.linalg.solve(j0, f0)  # the linear guess
    solution, best = _newton(residual, guess)
    method = "root"
    if not (np.all(np.isfinite(solution)) and best < tol):
        return _steady_state_from_simulation(model, speed, samples, tol)
    state = np.zeros(N_STATES)
    state[list(POSITIONS)] = solution
    return state, method, best


def _steady_state_from_simulation(model: BogieModel, speed: float, samples: np.ndarray, tol: float) -> tuple[np.ndarray, str, float]:
    """The steady state the bogie settles at: 60 s on the curve from the straight-track
    equilibrium (entering the curve), then the root finder from the end state."""
    residual = _residual_and_jacobian(model, speed, samples)
    end = _simulated_end_state(model, speed, samples)
    solution, best = _newton(residual, end[list(POSITIONS)])
    if not (np.all(np.isfinite(solution)) and best < tol):
        raise RuntimeError(f"steady curving: no steady state found at {speed * KMH:.1f} km/h (residual {best:.3g})")
    state = np.zeros(N_STATES)
    state[list(POSITIONS)] = solution
    return state, "time-simulation", best


def _simulated_end_state(model: BogieModel, speed: float, samples: np.ndarray, duration: float = 60.0) -> np.ndarray:
    """The state after ``duration`` seconds on a constant curve with these samples (passive)."""
    from ..simulator import BatchSimulator

    curvature = float(samples[CURVATURE_FRAME])
    cant = 1.5 * math.sin(float(samples[CANT_FRAME]))
    route = _curve_route(curvature, cant)
    sim = BatchSimulator(model, 1, 0.01, (speed, speed), track=TrackInput(route=route))
    sim.set_rows(slice(None), model.equilibrium(speed)[None], speed)
    sim.run(int(round(duration / 0.01)), record_every=10**9)
    return sim.x[0].copy()


def _curve_route(curvature: float, cant_m: float, length_m: float = 1.0e6) -> Route:
    if curvature == 0.0:
        from ..route import route_from_dict

        return route_from_dict({"name": "tangent", "segments": [{"type": "tangent", "length": length_m}]})
    direction = "left" if curvature > 0 else "right"
    return constant_curve(1.0 / abs(curvature), abs(cant_m), direction, length_m)


@dataclass
class CurvingResult:
    """Steady curving at one radius, cant and speed; arrays per wheelset (and per wheel: [left, right])."""

    radius_m: float
    cant_m: float
    direction: str
    speed_kmh: float
    cant_deficiency_m: float
    unbalanced_acceleration_m_per_s2: float
    equilibrium_speed_kmh: float
    method: str
    residual: float
    max_real_eigenvalue: float
    state: np.ndarray
    quantities: dict = field(default_factory=dict)
    guiding_force_limit_n: float = 0.0
    #: When the root finder's steady state was unstable and the bogie settles elsewhere: that
    #: first root's lateral displacements and largest real eigenvalue (else None).
    unstable_root: dict | None = None

    def to_dict(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k not in ("state", "quantities")}
        out["stable"] = bool(self.max_real_eigenvalue < 0.0)
        for name, value in self.quantities.items():
            out[name] = np.asarray(value)[0].tolist()
        out["flange_contact_any"] = bool(np.any(self.quantities["flange_contact"]))
        out["guiding_force_sum_n"] = float(np.sum(self.quantities["guiding_force_n"][0]))
        out["y_over_q_max"] = float(np.max(self.quantities["y_over_q"][0]))
        out["y_over_q_limit"] = Y_OVER_Q_LIMIT
        out["state"] = {name: float(v) for name, v in zip(BogieModel.state_names, self.state)}
        return out


def steady_curving(model: BogieModel, radius_m: float, cant_m: float, speed_kmh: float, direction: str = "left") -> CurvingResult:
    """Steady-state curving at radius (m), cant (m, >= 0 raises the outer rail) and speed (km/h)."""
    curvature, cant = signed_curve(radius_m, cant_m, direction)
    v = float(check_speed(speed_kmh / KMH, "speed"))
    samples = curve_samples(curvature, cant)
    state, method, res = solve_steady_state(model, v, samples)
    growth = _max_real_eigenvalue(model, state, v, samples)
    unstable = None
    if growth >= 0.0 and method == "root":
        # An unstable steady state (e.g. a saddle with one wheelset just on its flange): the
        # bogie does not stay there. Report the one it settles at after entering the curve.
        settled, settled_method, settled_res = _steady_state_from_simulation(model, v, samples, 1e-9)
        settled_growth = _max_real_eigenvalue(model, settled, v, samples)
        if settled_growth < 0.0:
            unstable = {"lateral_displacement_m": (state[[0, 8]] - samples[[ALIGNMENT_WHEELSET1, ALIGNMENT_WHEELSET1 + 1]]).tolist(),
                        "max_real_eigenvalue": growth}  # fmt: skip
            state, method, res, growth = settled, settled_method, settled_res, settled_growth
    accel = unbalanced_acceleration(speed_kmh, curvature, cant)
    q0_kn = 0.5 * model.params.Wpa / 1e3
    return CurvingResult(
        radius_m=float(radius_m),
        cant_m=float(cant_m),
        direction=direction,
        speed_kmh=float(speed_kmh),
        cant_deficiency_m=equilibrium_cant_m(speed_kmh, radius_m) - float(cant_m),
        unbalanced_acceleration_m_per_s2=abs(accel),
        equilibrium_speed_kmh=math.sqrt(GRAVITY * math.tan(cant_angle(cant_m)) * radius_m) * KMH,
        method=method,
        residual=res,
        max_real_eigenvalue=growth,
        state=state,
        quantities=wheel_rail_quantities(model, state[None], np.array([v]), samples[None]),
        guiding_force_limit_n=1e3 * (10.0 + 2.0 * q0_kn / 3.0),
        unstable_root=unstable,
    )


def _max_real_eigenvalue(model: BogieModel, state: np.ndarray, speed: float, samples: np.ndarray) -> float:
    return float(np.max(np.linalg.eigvals(model.jacobian(state, speed, track=samples)).real))


# ---- sweeps and figures ---------------------------------------------------------------------------
def radius_sweep(model: BogieModel, radii_m: np.ndarray, cant_m: float, speed_kmh: float, direction: str = "left") -> list[CurvingResult]:
    return [steady_curving(model, float(r), cant_m, speed_kmh, direction) for r in radii_m]


def cant_deficiency_sweep(
    model: BogieModel, radius_m: float, deficiencies_m: np.ndarray, speed_kmh: float, direction: str = "left"
) -> list[CurvingResult]:
    """Steady curving at one radius and speed, the cant set to give each cant deficiency (m)."""
    d_eq = equilibrium_cant_m(speed_kmh, radius_m)
    return [steady_curving(model, radius_m, d_eq - float(d), speed_kmh, direction) for d in deficiencies_m]


def _panel_series(results: list[CurvingResult]) -> dict[str, np.ndarray]:
    q = [r.quantities for r in results]
    return {
        "lateral displacement (mm)": np.array([1e3 * x["lateral_displacement_m"][0] for x in q]),
        "angle of attack (mrad)": np.array([1e3 * x["angle_of_attack_rad"][0] for x in q]),
        "guiding force ΣY (kN)": np.array([1e-3 * x["guiding_force_n"][0] for x in q]),
        "max Y/Q per wheelset (-)": np.array([x["y_over_q"][0].max(axis=-1) for x in q]),
        "wear number Tγ (N)": np.array([x["wear_number_n"][0] for x in q]),
        "flange force (kN)": np.array([1e-3 * np.abs(x["flange_force_n"][0]) for x in q]),
    }


def sweep_figure(results: list[CurvingResult], xvalues: np.ndarray, xlabel: str, title: str, path, logx: bool = False):
    from . import plots

    fig, axes = plots.plt.subplots(2, 3, figsize=(13, 7), sharex=True)
    for ax, (label, series) in zip(axes.ravel(), _panel_series(results).items()):
        for i, name in enumerate(("front wheelset", "rear wheelset")):
            ax.plot(xvalues, series[:, i], marker="o", ms=3, label=name)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        if logx:
            ax.set_xscale("log")
    for ax in axes[1]:
        ax.set_xlabel(xlabel)
    axes[0, 0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    return plots.save(fig, path)


# ---- dynamic curve negotiation -----------------------------------------------------------------
@dataclass
class RouteRun:
    """A bogie along a route at constant speed: time histories (records every ``dt``)."""

    route: Route
    speed_kmh: float
    time_s: np.ndarray
    distance_m: np.ndarray
    states: np.ndarray
    samples: np.ndarray
    quantities: dict
    completed: bool

    def summary(self, flange_time_dt: float) -> dict:
        q = self.quantities
        return {
            "route": self.route.name,
            "route_length_m": self.route.length,
            "speed_kmh": self.speed_kmh,
            "completed": self.completed,
            "duration_s": float(self.time_s[-1]),
            "peak_lateral_displacement_m": np.abs(q["lateral_displacement_m"]).max(axis=0).tolist(),
            "peak_angle_of_attack_rad": np.abs(q["angle_of_attack_rad"]).max(axis=0).tolist(),
            "peak_guiding_force_n": np.abs(q["guiding_force_n"]).max(axis=0).tolist(),
            "peak_y_over_q": q["y_over_q"].max(axis=(0, 2)).tolist(),
            "mean_wear_number_n": q["wear_number_n"].mean(axis=0).tolist(),
            "flange_contact_time_s": (q["flange_contact"].sum(axis=0) * flange_time_dt).tolist(),
        }


def route_run(
    model: BogieModel,
    route: Route,
    speed_kmh: float,
    dt: float = 0.01,
    alignment: TrackProfile | None = None,
    start_distance_m: float = 0.0,
) -> RouteRun:
    """Run one passive bogie along the route at constant speed from the straight equilibrium,
    through the simulator's one driver; records every interval."""
    from ..simulator import BatchSimulator

    v = float(check_speed(speed_kmh / KMH, "speed"))
    track = TrackInput(alignment=alignment, route=route) if alignment is not None else TrackInput(route=route)
    sim = BatchSimulator(model, 1, dt, (v, v), track=track)
    sim.set_rows(slice(None), model.equilibrium(v)[None], v, distance=start_distance_m)
    n_steps = int(math.ceil((route.length - start_distance_m) / (v * dt)))
    states, speeds = sim.run(n_steps, record_every=1)
    time = np.arange(states.shape[0]) * dt
    distance = start_distance_m + v * time
    samples = track.under_wheelsets(distance, model.params.L1)
    quantities = wheel_rail_quantities(model, states[:, 0], speeds[:, 0], samples)
    return RouteRun(route, float(speed_kmh), time, distance, states[:, 0], samples, quantities,
                    completed=bool(states.shape[0] == n_steps + 1))  # fmt: skip


def route_figure(run: RouteRun, path):
    """Time histories along the route: geometry, displacements, angles of attack, ΣY, Y/Q, wear."""
    from . import plots

    q = run.quantities
    s = run.distance_m
    fig, axes = plots.plt.subplots(6, 1, figsize=(11, 13), sharex=True)
    ax = axes[0]
    ax.plot(s, 1e3 * run.samples[:, CURVATURE_FRAME], color="k", label="curvature (1/km)")
    ax.set_ylabel("curvature (1/km)")
    twin = ax.twinx()
    twin.plot(s, 1e3 * 1.5 * np.sin(run.samples[:, CANT_FRAME]), color="tab:red", ls="--")
    twin.set_ylabel("cant (mm)", color="tab:red")
    panels = (
        (1e3 * q["lateral_displacement_m"], "lateral displacement (mm)"),
        (1e3 * q["angle_of_attack_rad"], "angle of attack (mrad)"),
        (1e-3 * q["guiding_force_n"], "guiding force ΣY (kN)"),
        (q["y_over_q"].max(axis=-1), "max Y/Q of the wheelset (-)"),
        (q["wear_number_n"], "wear number Tγ (N)"),
    )
    for ax, (series, label) in zip(axes[1:], panels):
        for i, name in enumerate(("front wheelset", "rear wheelset")):
            ax.plot(s, series[:, i], lw=1, label=name)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[1].legend(loc="best")
    axes[-1].set_xlabel("distance along the route (m)")
    fig.suptitle(f"route {run.route.name} at {run.speed_kmh:g} km/h")
    fig.tight_layout()
    return plots.save(fig, path)


def write_sweep_figures(model: BogieModel, radius_m: float, cant_m: float, speed_kmh: float, direction: str, out: Path) -> dict:
    """Quantities against radius (cant and speed fixed) and against cant deficiency (radius and
    speed fixed, cant varied); returns the figure paths."""
    out = Path(out)
    radii = np.geomspace(max(500.0, radius_m / 5.0), radius_m * 4.0, 15)
    by_radius = radius_sweep(model, radii, cant_m, speed_kmh, direction)
    deficiencies = np.linspace(-0.1, 0.2, 16)
    by_deficiency = cant_deficiency_sweep(model, radius_m, deficiencies, speed_kmh, direction)
    return {
        "against_radius": str(sweep_figure(by_radius, radii, "curve radius (m)",
                                           f"steady curving at {speed_kmh:g} km/h, cant {1e3 * cant_m:g} mm",
                                           out / "curving_vs_radius.png", logx=True)),
        "against_cant_deficiency": str(sweep_figure(by_deficiency, 1e3 * deficiencies, "cant deficiency (mm)",
                                                    f"steady curving at {speed_kmh:g} km/h, R {radius_m:g} m",
                                                    out / "curving_vs_cant_deficiency.png")),
    }  # fmt: skip
