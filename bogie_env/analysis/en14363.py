"""EN 14363's running-stability quantities on the passive hunting limit cycle.

    python -m bogie_env.analysis.en14363 [--speeds-kmh 360,380,400,420] [--json]

Why the environment does not use them as its hunting criterion (docs/environment.md): on this
model's limit cycle the sum of guiding forces ΣY (the lateral wheel-rail force per wheelset)
and the frame's lateral acceleration stay far below EN 14363's limits, because the model has no
car body and a soft flange. The limits:

- ΣY rms limit (stability, sliding rms over 100 m): half of Prud'homme's 10 kN + 2 Q0 / 3, with
  Q0 the static wheel load: (10 kN + P0 / 3) / 2 for the axle load P0, 30 kN here;
- frame lateral acceleration rms limit (simplified method): (12 - m+ / 5) / 2 m/s² with m+ the
  bogie mass in t; 5.8 m/s² for this 1.6-t frame.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from numba import njit

from ..actuators import generalised_forces
from ..dynamics import N_INPUTS, N_STATES, N_TRACK, BogieModel, _guiding_forces_row, _rhs_row, guiding_forces_kernel, state_index
from ..integrate import OUT_FORCE
from ..simulator import M_SPEED, BatchSimulator
from ..stability import KMH
from .bifurcation import limit_cycle_state

FRAME_ACCEL_LIMIT = 5.8  # m/s^2, (12 - 1.6 / 5) / 2 rounded
_DYB = state_index("dyb")


@njit(cache=True)
def running_signals_rows(sim_rows, out):
    """EN 14363's running quantities of every row of a :class:`BatchSimulator` at the end of its
    last interval, each row with its own bogie coefficients, speed, track sample and actuator
    forces: ``out[n] = (ΣY wheelset 1, ΣY wheelset 2 (N), frame lateral acceleration (m/s²))``."""
    x, motion, coefficients, _, _, _, output, track_sample, _ = sim_rows
    q = np.empty(N_INPUTS)
    dx = np.empty(N_STATES)
    for n in range(x.shape[0]):
        v = motion[n, M_SPEED]
        _guiding_forces_row(x[n], v, track_sample[n], coefficients[n], out[n, :2])
        generalised_forces(output[n, OUT_FORCE], q)
        _rhs_row(x[n], v, q, track_sample[n], coefficients[n], dx)
        out[n, 2] = dx[_DYB]


def limit_cycle_quantities(model: BogieModel, speeds_kmh: np.ndarray, duration: float = 10.0, dt: float = 0.01) -> list[dict]:
    """rms and peak of ΣY (both wheelsets) and of the frame lateral acceleration over ``duration``
    seconds on the passive limit cycle at each speed."""
    out = []
    yb_dot = state_index("dyb")
    for v_kmh in speeds_kmh:
        v = float(v_kmh) / KMH
        sim = BatchSimulator(model, 1, dt, speed_range=(v, v))
        sim.set_rows(slice(None), limit_cycle_state(model, float(v_kmh))[None], np.array([v]))
        forces, accels = [], []
        guiding = np.empty((1, 2))
        for _ in range(int(round(duration / dt))):
            sim.step()
            guiding_forces_kernel(sim.x, np.array([v]), np.zeros((1, N_TRACK)), model.coefficients, guiding)
            forces.append(guiding[0].copy())
            accels.append(model.rhs(sim.x[0], v)[yb_dot])
        forces, accels = np.array(forces), np.array(accels)
        out.append({
            "speed_kmh": float(v_kmh),
            "sum_y_rms_n": float(np.sqrt((forces**2).mean(axis=0)).max()),
            "sum_y_peak_n": float(np.abs(forces).max()),
            "sum_y_rms_limit_n": 0.5 * (10e3 + model.params.Wpa / 3.0),
            "frame_accel_rms_m_per_s2": float(np.sqrt((accels**2).mean())),
            "frame_accel_peak_m_per_s2": float(np.abs(accels).max()),
            "frame_accel_limit_m_per_s2": FRAME_ACCEL_LIMIT,
        })  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speeds-kmh", default="360,380,400,420")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    rows = limit_cycle_quantities(BogieModel(), np.array([float(s) for s in args.speeds_kmh.split(",")]))
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        for r in rows:
            print(f"{r['speed_kmh']:.0f} km/h: sum Y rms {r['sum_y_rms_n'] / 1e3:.2f} kN (limit {r['sum_y_rms_limit_n'] / 1e3:.0f}), "
                  f"frame accel rms {r['frame_accel_rms_m_per_s2']:.2f} m/s^2 (limit {FRAME_ACCEL_LIMIT})")  # fmt: skip
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
