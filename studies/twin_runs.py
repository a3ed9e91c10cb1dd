"""Twin runs: does a rough track entrain the hunting cycle? Each protocol row runs twice, the
second from the mirrored 12 mm start (same seed: same track section, sensor noise and biases).
A stable running state forgets its start, so the twins meet; a self-excited cycle keeps its own
phase unless the track's forcing synchronises it. The rms of the twins' difference in wheelset
displacement relative to the rail over the last 5 s of the 20 s run, over the flange clearance,
per seed (docs/studies/hunting_or_forced_contact.md, 'Why not twin runs').

    python studies/twin_runs.py --level alert --conicity 0.1 --speeds 120,220,12
    python studies/twin_runs.py --level alert --conicity 0.025 --speeds 340,460,20
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from bogie_agents.evaluation import stability_protocol as sp
from bogie_env.dynamics import state_index
from bogie_env.envs.config import make_config

LATERAL_AND_YAW = [state_index(k) for k in ("y1", "y2", "yb", "psi1", "psi2", "psib")]


def twin_difference(policy: str, level: str, conicity: float, speeds_kmh: np.ndarray, seeds: int = 10) -> dict:
    """Per speed, each seed's flange-contact time and the twins' rms difference / clearance."""
    env = make_config({"track": {"level": level}}, variant="v1")
    settings = sp.Settings(seeds=seeds, progress=False)
    ctx = sp.PartContext(sp.factory_for(policy), env, settings, "sensors", sp.Progress(policy, False))
    cases = sp.columns(env, settings)["nominal" if np.isclose(conicity, 0.025) else f"conicity:{conicity:g}"]
    rows = [c for _ in speeds_kmh for c in cases]
    n = len(rows)
    speeds = np.repeat(speeds_kmh, len(cases))
    task, controller = sp.Runner(ctx)._task(rows + rows, np.concatenate([speeds, speeds]), "default")
    # the straight track's equilibrium is centred, so the mirrored start is the negated lateral and yaw states
    task.sim.x[n:, LATERAL_AND_YAW] = -task.sim.x[:n, LATERAL_AND_YAW]
    dt = task.config["dt"]
    steps, first, last = int(round(settings.duration_s / dt)), int(round(settings.transient_s / dt)), int(round(5.0 / dt))
    contact = np.zeros(n)
    square = np.zeros(n)
    for k in range(steps):
        sp.step_guarded(task, controller.act(task.obs))
        if k >= first:
            contact += sp.flange_touching(task)[:n]
        if k >= steps - last:
            rel = task.relative_lateral_m / task.flange_clearance[:, None]
            square += ((rel[:n] - rel[n:]) ** 2).max(axis=1)
    out = {}
    for v in speeds_kmh:
        m = speeds == v
        out[f"{v:g}"] = {"flange_time": np.round(contact[m] / (steps - first), 3).tolist(),
                         "twin_rms_over_clearance": np.round(np.sqrt(square[m] / last), 3).tolist()}  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="passive")
    parser.add_argument("--level", default="alert")
    parser.add_argument("--conicity", type=float, default=0.1)
    parser.add_argument("--speeds", default="120,220,12", help="start,stop,step in km/h (numpy.arange)")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    speeds = np.arange(*[float(v) for v in args.speeds.split(",")])
    for speed, row in twin_difference(args.policy, args.level, args.conicity, speeds, args.seeds).items():
        print(json.dumps({"speed_kmh": float(speed), **row}))


if __name__ == "__main__":
    main()
