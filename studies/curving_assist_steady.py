"""The curving assist in a steady curve: time simulation in the v1 route world against the
steady-state solver with the same constant torques.

    python studies/curving_assist_steady.py [--radius 3000] [--cant 0.16] [--speed 250]

A left curve (50 m tangent, 250 m transition, 2 km of curve), perfect track, no initial
perturbation, the v1 sensors with seed 0's biases and noise, loop delay and rate limits;
passive, ``robust_damping`` and ``robust_steering``. Printed per controller: the mean over the
last 5 s of the curve of the wheelsets' lateral displacement (from the track centreline),
angles of attack, actuator forces, flange-contact fraction and wear numbers; then the
steady-state solver (:mod:`bogie_env.analysis.curving`'s Newton iteration) with those mean
forces held constant, which the time simulation must reach. The default is the S-curve's curve
(R 3000 m, 160 mm, 250 km/h, cant deficiency 86 mm).
"""

from __future__ import annotations

import argparse

import numpy as np

from bogie_agents.evaluation.curving_evaluation import constant_curve_run
from bogie_agents.controllers.policies import load_policy
from bogie_env.actuators import force_matrix
from bogie_env.analysis.curving import ACCELERATIONS, POSITIONS, _newton, curve_samples, signed_curve
from bogie_env.dynamics import N_STATES, jacobian_kernel, rhs_single_kernel, state_index
from bogie_env.envs.task import HuntingTask

NAMES = ("y1", "y2", "psi1", "psi2")


def time_simulation(spec: str, radius: float, cant: float, speed_kmh: float) -> tuple[dict, HuntingTask]:
    rows = []

    def record(task: HuntingTask) -> None:
        x = task.states[0]
        rows.append([x[state_index(n)] for n in NAMES] + list(task.actuator_force[0])
                    + [float(task.flange_contact[0].any())] + list(task.wear_number_n[0]))  # fmt: skip

    task, _, config = constant_curve_run(radius, cant, speed_kmh, 2000.0, "left", transition_m=250.0,
                                         policy_factory=lambda c: load_policy(spec, c), on_step=record)  # fmt: skip
    last = np.array(rows)[-int(round(5.0 / config["dt"])):].mean(axis=0)
    return {"state": dict(zip(NAMES, last[:4])), "forces": last[4:8], "flange": last[8], "wear": last[9:11]}, task


def steady_state(task: HuntingTask, forces: np.ndarray, radius: float, cant: float, speed_kmh: float) -> dict:
    model = task.model
    speed = speed_kmh / 3.6
    kappa, cant_m = signed_curve(radius, cant, "left")
    samples = np.ascontiguousarray(curve_samples(kappa, cant_m), dtype=float)
    q = force_matrix() @ forces
    x, f, jac = np.zeros(N_STATES), np.empty(N_STATES), np.empty((N_STATES, N_STATES))
    acc, pos = list(ACCELERATIONS), list(POSITIONS)

    def residual(p):
        x[pos] = p
        rhs_single_kernel(x, speed, q, samples, model.coefficients, f)
        jacobian_kernel(x, speed, q, samples, model.coefficients, jac)
        return f[acc].copy(), jac[np.ix_(acc, pos)].copy()

    solution, norm = _newton(residual, model.equilibrium(speed)[pos])
    x[pos] = solution
    return {"state": {n: x[state_index(n)] for n in NAMES}, "residual": norm}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radius", type=float, default=3000.0)
    parser.add_argument("--cant", type=float, default=0.16)
    parser.add_argument("--speed", type=float, default=250.0)
    args = parser.parse_args()
    for spec in ("passive", "robust_damping", "robust_steering"):
        run, task = time_simulation(spec, args.radius, args.cant, args.speed)
        steady = steady_state(task, run["forces"], args.radius, args.cant, args.speed)
        s, t = run["state"], steady["state"]
        print(f"{spec:16s} time simulation: y {1e3 * s['y1']:+.2f} / {1e3 * s['y2']:+.2f} mm, AoA {1e3 * s['psi1']:+.3f} / "
              f"{1e3 * s['psi2']:+.3f} mrad, forces {np.round(run['forces']).tolist()} N (m), flange {run['flange']:.2f}, "
              f"wear {run['wear'][0]:.2f} / {run['wear'][1]:.2f} N")  # fmt: skip
        print(f"{'':16s} steady state at those forces: y {1e3 * t['y1']:+.2f} / {1e3 * t['y2']:+.2f} mm, AoA "
              f"{1e3 * t['psi1']:+.3f} / {1e3 * t['psi2']:+.3f} mrad (residual {steady['residual']:.1e})")  # fmt: skip


if __name__ == "__main__":
    main()
