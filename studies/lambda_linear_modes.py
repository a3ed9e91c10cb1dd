"""The least-damped closed-loop modes of controllers at one conicity over a speed range, and each
loop's response to a sinusoidal track alignment (the wheelsets' displacement relative to the rail
per unit alignment), from the sampled linear loop of :mod:`bogie_agents.design.margins` (bogie, actuator
lags, loop delay, sensor filters, the controller's own linear model).

    python studies/lambda_linear_modes.py --policy passive --policy robust_damping \
        --policy lqr --conicity 0.1 --speeds 120:260:10 [--gains FILE] [--wavelengths 10,15,20,24,30,40]

Modes: eigenvalues z of the closed-loop matrix, s = ln z / dt; oscillatory lateral modes (the
vertical DOFs, which do not couple, are left out) between 0.3 and 15 Hz: the three least damped,
and the two least damped between 1 and 3 Hz, each with its frequency, damping ratio, kinematic wavelength V / f
and its shape (the largest entries of the eigenvector over y1, y2, yb, L1 psi1, L1 psi2, L1 psib,
in mm per mm of the largest).

Track response: the plant's input matrix for the alignment is taken by finite differences of
the bogie's right-hand side in the track samples (the alignment under each wheelset, delayed by
2 L1 / V for the rear one); the relative displacement y_i - y_track,i per unit alignment is
evaluated at the frequency V / wavelength (the discrete loop at the env step, the alignment held
over a step; the sensors see the wheelsets relative to the frame, so the track enters only
through the bogie). The time-domain side: ``studies/lambda_low_speed_diagnosis.py``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from bogie_env.dynamics import N_INPUTS, N_STATES, N_TRACK, state_index
from bogie_env.envs.config import make_config
from bogie_env.stability import KMH
from bogie_env.sampled_plant import discretize
from bogie_agents.design.margins import linear_loop, plant_bogie
from bogie_agents.evaluation.stability_protocol import Settings, factory_for, policy_config, told_conicity

SHAPE_STATES = ("y1", "y2", "yb", "psi1", "psi2", "psib")


def build(name: str, env_config: dict, conicity: float, gains: str | None):
    """The controller as protocol v2 builds it, told the conicity class."""
    told = told_conicity(conicity, Settings().conicities)
    if gains is not None:
        from bogie_agents.controllers.robust import RobustDampingController

        return RobustDampingController(policy_config(env_config, "sensors", told), gains=gains)
    probe = factory_for(name)(env_config)
    return factory_for(name)(policy_config(env_config, getattr(probe, "observation_type", "sensors"), told))


def modes(loop, speed_kmh: float, l1: float, count: int = 3, band_hz: tuple[float, float] | None = None) -> list[dict]:
    """The ``count`` least-damped oscillatory lateral modes (0.3-15 Hz, or ``band_hz``) with their shapes."""
    a = loop.closed_loop_matrix()
    z, vecs = np.linalg.eig(a)
    keep = np.abs(z) > 1e-9
    s = np.log(z[keep].astype(complex)) / loop.dt
    vecs = vecs[:, keep]
    f = np.abs(s.imag) / (2 * math.pi)
    vertical = [state_index(n) for n in ("z1", "dz1", "z2", "dz2")]
    lateral = [state_index(n) for n in SHAPE_STATES]
    vert_share = np.linalg.norm(vecs[vertical], axis=0) / np.maximum(np.linalg.norm(vecs[vertical + lateral], axis=0), 1e-300)
    # lateral bogie modes only: the vertical DOFs do not couple to the lateral ones (docs/model.md)
    osc = (f > 0.3) & (f < 15.0) & (s.imag > 0) & (vert_share < 0.5) & (np.linalg.norm(vecs[lateral], axis=0) > 1e-9)
    zeta = -s.real / np.abs(s)
    if band_hz is not None:
        osc &= (f >= band_hz[0]) & (f <= band_hz[1])
    out = []
    for k in np.argsort(np.where(osc, zeta, np.inf))[:count]:
        if not osc[k]:
            break
        v = vecs[:N_STATES, k]
        amp = {n: abs(v[state_index(n)]) * (l1 if n.startswith("psi") else 1.0) for n in SHAPE_STATES}
        top = max(amp.values()) or 1.0
        out.append({"f_hz": round(float(f[k]), 3), "zeta": round(float(zeta[k]), 4),
                    "wavelength_m": round(speed_kmh / KMH / float(f[k]), 1),
                    "shape": {n: round(amp[n] / top, 2) for n in SHAPE_STATES}})  # fmt: skip
    return out


def track_response(loop, model, speed_kmh: float, wavelengths_m: list[float]) -> dict[str, float]:
    """|y_i - y_track,i| / |y_track| (max over the two wheelsets) for a sinusoidal alignment of
    each wavelength, from the linear loop (rear wheelset's input delayed by 2 L1 / V)."""
    p = model.params
    v = speed_kmh / KMH
    x_eq = loop.plant.x_eq
    q = np.zeros(N_INPUTS)  # the inputs enter the right-hand side linearly: they do not change d(rhs)/d(track)
    # d(rhs)/d(alignment under wheelset i) by central differences on the bogie's right-hand side
    e = np.zeros((N_STATES, 2))
    for i in range(2):
        h = 1e-6
        yt = np.zeros(N_TRACK)
        yt[i] = h
        up = model.rhs(x_eq, v, q, yt)
        yt[i] = -h
        down = model.rhs(x_eq, v, q, yt)
        e[:, i] = (up - down) / (2 * h)
    a_cl = loop.closed_loop_matrix()
    n_all = a_cl.shape[0]
    # continuous-time input of the bogie block, sampled with the plant's ZOH: approximate the
    # track as held over a step (the alignment varies slowly against the 10 ms step)
    n_b = loop.plant.a_cont.shape[0]
    _, e_d = discretize(loop.plant.a_cont, np.vstack([e, np.zeros((n_b - N_STATES, 2))]), loop.dt)
    b_track = np.zeros((n_all, 2))
    b_track[:n_b] = e_d
    out = {}
    for lam_m in wavelengths_m:
        w = 2 * math.pi * v / lam_m
        zq = np.exp(1j * w * loop.dt)
        u = np.array([1.0, np.exp(-1j * w * 2 * p.L1 / v)])  # front, rear (the rear sees it 2 L1 / V later)
        x = np.linalg.solve(zq * np.eye(n_all) - a_cl, b_track @ u)
        rel = [x[state_index("y1")] - u[0], x[state_index("y2")] - u[1]]
        out[f"{lam_m:g}"] = round(float(max(abs(r) for r in rel)), 3)
    return out


def parse_speeds(text: str) -> list[float]:
    if ":" in text:
        a, b, step = (float(v) for v in text.split(":"))
        return [float(v) for v in np.arange(a, b + 1e-9, step)]
    return [float(v) for v in text.split(",")]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--policy", action="append", default=None)
    ap.add_argument("--gains", action="append", default=[], help="robust_damping gain tables (JSON) to add")
    ap.add_argument("--conicity", type=float, default=0.1)
    ap.add_argument("--speeds", default="120:260:10")
    ap.add_argument("--wavelengths", default="12,16,20,24,28,35")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    env_config = make_config(variant="v1")
    wavelengths = [float(w) for w in args.wavelengths.split(",")]
    specs = [(p, None) for p in (args.policy or ["passive", "robust_damping", "lqr"])] + [("gains:" + g, g) for g in args.gains]
    results = {}
    for label, gains in specs:
        policy = build(label, env_config, args.conicity, gains)
        model = plant_bogie(env_config, args.conicity)
        rows = []
        for v in parse_speeds(args.speeds):
            loop = linear_loop(policy, env_config, v, conicity=args.conicity)
            radius = float(np.max(np.abs(loop.eigenvalues())))
            row = {"speed_kmh": v, "stable": radius < 1.0, "modes": modes(loop, v, model.params.L1),
                   "modes_1_3hz": modes(loop, v, model.params.L1, count=2, band_hz=(1.0, 3.0)),
                   "track_response": track_response(loop, model, v, wavelengths)}  # fmt: skip
            rows.append(row)
            m = row["modes"]
            print(f"{label:16s} {v:5.0f} km/h {'stable  ' if row['stable'] else 'UNSTABLE'} "
                  + " | ".join(f"{x['f_hz']:5.2f} Hz ζ {x['zeta']:+.3f} ({x['wavelength_m']:.0f} m; "
                               + ",".join(f"{k}{x['shape'][k]:.1f}" for k in SHAPE_STATES if x['shape'][k] >= 0.3) + ")" for x in m)
                  + "  || 1-3 Hz: " + " ".join(f"{x['f_hz']:.2f} Hz ζ {x['zeta']:+.3f}" for x in row["modes_1_3hz"])
                  + "  |y-yt|/yt: " + " ".join(f"{k}m {val:.2f}" for k, val in row["track_response"].items()), flush=True)  # fmt: skip
        results[label] = rows
    if args.json:
        from pathlib import Path

        from bogie_env.fileio import write_text_atomic

        write_text_atomic(Path(args.json), json.dumps({"argv": sys.argv[1:], "results": results}, indent=1))


if __name__ == "__main__":
    main()
