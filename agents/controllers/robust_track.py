"""The second stage of ``robust_damping``'s design: the track-forced re-tune and the command lead.

:func:`bogie_agents.controllers.robust.tune` maximises the worst damping ratio over the conicity grid. At
conicity 0.1 and 120-270 km/h that design moves the bogie's kinematic (track-following) mode to
1.4-2.2 Hz, i.e. 20-32 m, inside the alert track's 3-25 m band, and the wheelsets stop
following 20-25 m alignment: on the alert track they touch the flange 1-3 % of the time
(protocol v2's limit: 1 %), and the wheelset-yaw channels saturate fighting the track-following
yaw (docs/studies/conicity_0.1.md).

Stage 2 (:func:`retune_track`) re-tunes the rows of ``TrackSettings.speeds_kmh`` from stage 1's
table (Nelder-Mead per row, warm-started from it) on

    w_track x max over ``wavelengths`` of max_i |y_i - y_t,i| / |y_t|      (conicity ``conicity``;
                                                   w_track per row: 0.3 at 90-180 km/h, 0.1 at 210-270)
  + w_yaw   x max over ``yaw_wavelengths`` of max |u_wheelset yaw| per mm of alignment
  + w_zeta  x (- least damping ratio of the nominal loop at ``conicity``)
  + 50 x max(0, stage 1's objective - (its stage-1 value + slack))   (stage 1's design set)

on the sampled design model (:func:`bogie_agents.controllers.robust.design_plant`'s model with the
alignment under each wheelset as input, the rear wheelset's delayed by 2 L1 / V, held over each
step). Rows outside ``speeds_kmh`` are kept. The track weight is larger on the rows up to
180 km/h, where the alert track forces flange contact at 150-200 km/h on some seeds; on the rows
from 210 km/h a larger weight lowers the damping that keeps the saturated limit cycle at
230-250 km/h away (weights and wavelengths chosen on the protocol's conicity-0.1 column over
seeds 20-79, docs/studies/floors_and_held_out_seeds.md).

Then it sets the command lead (:func:`bogie_agents.controllers.robust.lead_command`): ``lead_s`` at the
rows of ``lead_speeds_kmh``, zero elsewhere (interpolated linearly in speed, so it ramps in
from the row below and out by the row above). At conicity 0.1, 230-250 km/h, the 12 mm start
or the alert track drive the bogie into a 5 Hz limit cycle with every channel saturated; the
actuators' rate limits (frame lateral 200 kN/s: a 10 kN swing at 5 Hz needs 314 kN/s) turn
the saturated command into a triangle that lags it by about a quarter of its ramp time. The
lead (15 ms on the 4 Hz low-passed command change, rows 240-270 km/h) moves the reversals
earlier; it was chosen on robust_damping's conicity-0.1 column over seeds 0-79 among leads that
keep stage 1's gain factor 2 (:func:`check_lead`; docs/controllers.md, "Stage 2").
It is zero from 300 km/h, so the nominal conicity's margins (300-450 km/h) and stage 1's
high-speed rows are unchanged.

    python -m bogie_agents.design.robust_cli retune --base agents/controllers/robust_gains_stage1.json --out agents/controllers/robust_gains.json
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.dynamics import N_STATES, N_TRACK, state_index
from bogie_env.envs.config import merge_config
from bogie_env.sampled_plant import PlantModel, discretize
from bogie_env.stability import KMH

from .robust import (GAIN_SCALE, LAT, N_SIG, DesignModel, DesignSettings, FilterBank, closed_loop,
                     filter_bank, mode_score)  # fmt: skip


@dataclass
class TrackSettings:
    """What :func:`retune_track` asks of the rows it re-tunes, and the command lead it sets."""

    speeds_kmh: tuple[float, ...] = (90.0, 120.0, 150.0, 180.0, 210.0, 240.0, 270.0)
    conicity: float = 0.1
    wavelengths_m: tuple[float, ...] = (10.0, 14.0, 18.0, 22.0, 26.0, 30.0)
    yaw_wavelengths_m: tuple[float, ...] = (6.0, 10.0, 16.0, 24.0)
    #: one weight for every row, or one per row of ``speeds_kmh``: the low-speed rows (where the
    #: alert track forces flange contact at 150-200 km/h) weigh the track response more than the
    #: rows near the self-excited ceiling (230-250 km/h), where it costs damping
    w_track: float | tuple[float, ...] = (0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1)
    w_yaw: float = 0.05
    w_zeta: float = 1.0
    slack: float = 0.02  # how far stage 1's objective (minus its worst damping ratio) may rise
    max_evaluations: int = 3000
    lead_s: float = 0.015
    lead_lowpass_hz: float = 4.0
    lead_speeds_kmh: tuple[float, ...] = (240.0, 270.0)

    def track_weight(self, speed_kmh: float) -> float:
        """``w_track`` at the row ``speed_kmh`` (one of ``speeds_kmh``)."""
        if isinstance(self.w_track, (int, float)):
            return float(self.w_track)
        if len(self.w_track) != len(self.speeds_kmh):
            raise ValueError(f"TrackSettings: w_track = {self.w_track!r} has {len(self.w_track)} values; allowed: one number, "
                             f"or one per row of speeds_kmh ({len(self.speeds_kmh)})")  # fmt: skip
        return float(self.w_track[list(self.speeds_kmh).index(speed_kmh)])


def track_input(model: DesignModel, speed_kmh: float) -> np.ndarray:
    """(n_plant_lateral_and_actuator_states, 2): the sampled plant's input matrix from the track
    alignment under wheelset 1 and wheelset 2 (held over each step), by central differences of
    the bogie's equations about the straight-track equilibrium."""
    v = speed_kmh / KMH
    x_eq = model.model.equilibrium(v)
    e = np.zeros((N_STATES, 2))
    for i in range(2):
        yt = np.zeros(N_TRACK)
        yt[i] = 1e-6
        up = model.model.rhs(x_eq, v, None, yt)
        yt[i] = -1e-6
        down = model.model.rhs(x_eq, v, None, yt)
        e[:, i] = (up - down) / 2e-6
    a_c, _ = model.continuous(v)
    e_ext = np.zeros((a_c.shape[0], 2))
    e_ext[: len(LAT)] = e[list(LAT)]
    _, e_d = discretize(a_c, e_ext, model.dt)
    return e_d


def forced_response(plant: PlantModel, bank: FilterBank, gains: np.ndarray, e_d: np.ndarray, speed_kmh: float,
                    semi_wheelbase_m: float, dt: float, wavelengths_m) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Per wavelength of a sinusoidal alignment (unit amplitude, the rear wheelset's delayed by
    2 L1 / V): the larger of the wheelsets' |y_i - y_t,i| (per unit alignment) and the larger
    wheelset-yaw command (normalised, per metre of alignment), from the closed loop's steady
    state response."""
    a_cl = closed_loop(plant, bank, gains)
    n_all = a_cl.shape[0]
    b = np.zeros((n_all, 2))
    b[: e_d.shape[0]] = e_d
    u_row = np.hstack([(-gains @ bank.d) @ plant.c, -gains @ bank.c])
    iy1, iy2 = LAT.index(state_index("y1")), LAT.index(state_index("y2"))
    yaw = [CHANNEL_NAMES.index("wheelset1_yaw"), CHANNEL_NAMES.index("wheelset2_yaw")]
    v = speed_kmh / KMH
    rel, cmd = [], []
    for lam in wavelengths_m:
        w = 2 * math.pi * v / lam
        u_t = np.array([1.0, np.exp(-1j * w * 2 * semi_wheelbase_m / v)])
        x = np.linalg.solve(np.exp(1j * w * dt) * np.eye(n_all) - a_cl, b @ u_t)
        rel.append(max(abs(x[iy1] - u_t[0]), abs(x[iy2] - u_t[1])))
        cmd.append(float(np.max(np.abs((u_row @ x)[yaw]))))
    return np.array(rel), np.array(cmd)


def retune_track(env_config: dict, table: dict, settings: TrackSettings | None = None,
                 design: DesignSettings | None = None, progress=None) -> dict:  # fmt: skip
    """Stage 2 on stage 1's ``table`` (:func:`bogie_agents.controllers.robust.load_gains`'s dict, all four
    channels active): a new table with the rows of ``settings.speeds_kmh`` re-tuned, the command
    lead set, and a per-row log (``track_design``)."""
    from scipy.optimize import minimize

    settings = settings or TrackSettings()
    for v in settings.speeds_kmh:
        settings.track_weight(v)  # a wrong-length w_track fails before any row is tuned
    design = design or DesignSettings(washout_hz=float(table["washout_hz"]), leak_hz=float(table["leak_hz"]),
                                      washout_order=int(table.get("washout_order", 1)))  # fmt: skip
    dt = env_config["dt"]
    delayed = merge_config(env_config, {"actuators": {n: {"delay_steps": env_config["actuators"][n]["delay_steps"]
                                                          + design.extra_delay_steps} for n in CHANNEL_NAMES}})  # fmt: skip
    nominal = {c: DesignModel(env_config, c) for c in design.conicities}
    late = {c: DesignModel(delayed, c) for c in design.conicities}
    bank = filter_bank(nominal[design.conicities[0]].n_obs, dt, design.washout_hz, design.leak_hz, design.washout_order)
    target = DesignModel(env_config, settings.conicity)
    l1 = target.model.params.L1
    speeds = [float(v) for v in table["speeds_kmh"]]
    gains = np.array(table["gains"], dtype=float)
    log = []
    for v in settings.speeds_kmh:
        if v not in speeds:
            raise ValueError(f"retune_track: speed {v:g} km/h is not a row of the table ({speeds})")
        k = speeds.index(v)
        w_track = settings.track_weight(v)
        cs = [c for c in design.conicities if design.required(c, v)] or [min(design.conicities)]
        plants = [(nominal[c].plant(v), late[c].plant(v)) for c in cs]
        tp, e_d = target.plant(v), track_input(target, v)

        def stage1(g: np.ndarray) -> float:
            worst = -math.inf
            for p, p_late in plants:
                for a_cl in [closed_loop(p, bank, g, f) for f in design.gain_factors] + [closed_loop(p_late, bank, g)]:
                    worst = max(worst, mode_score(a_cl, dt, design.min_mode_hz, design.max_radius))
            return worst

        def terms(g: np.ndarray) -> tuple[float, float, float]:
            rel, _ = forced_response(tp, bank, g, e_d, v, l1, dt, settings.wavelengths_m)
            _, cmd = forced_response(tp, bank, g, e_d, v, l1, dt, settings.yaw_wavelengths_m)
            return float(rel.max()), float(cmd.max()), mode_score(closed_loop(tp, bank, g), dt, design.min_mode_hz, design.max_radius)

        base = stage1(gains[k])

        def objective(x: np.ndarray) -> float:
            g = x.reshape(len(CHANNEL_NAMES), N_SIG) * GAIN_SCALE
            score = stage1(g)
            if score > 0.5:  # unstable or far off: the forced response means nothing
                return 10.0 + score
            rel, cmd, zeta_score = terms(g)
            penalty = 50.0 * max(0.0, score - (base + settings.slack)) + settings.w_zeta * zeta_score
            return float(w_track * rel + settings.w_yaw * 1e-3 * cmd + penalty + 1e-5 * np.sum(x**2))

        x0 = (gains[k] / GAIN_SCALE).ravel()
        simplex = np.vstack([x0] + [x0 + 0.2 * e for e in np.eye(x0.size)])
        before = terms(gains[k])
        result = minimize(objective, x0, method="Nelder-Mead", options={"maxfev": settings.max_evaluations, "xatol": 1e-3,
                                                                         "fatol": 1e-6, "adaptive": True, "initial_simplex": simplex})  # fmt: skip
        gains[k] = result.x.reshape(len(CHANNEL_NAMES), N_SIG) * GAIN_SCALE
        after = terms(gains[k])
        row = {"speed_kmh": v, "conicities": cs, "stage1_worst_zeta": [round(-base, 4), round(-stage1(gains[k]), 4)],
               "track_rel_max": [round(before[0], 3), round(after[0], 3)], "ws_yaw_u_per_mm": [round(1e-3 * before[1], 3), round(1e-3 * after[1], 3)],
               f"least_zeta_at_{settings.conicity:g}": [round(-before[2], 4), round(-after[2], 4)], "evaluations": int(result.nfev)}  # fmt: skip
        log.append(row)
        if progress:
            progress(row)
    lead = np.array([settings.lead_s if v in settings.lead_speeds_kmh else 0.0 for v in speeds])
    check_lead(gains, lead, settings.lead_lowpass_hz, speeds, nominal, late, bank, design, dt)
    return {**table, "gains": gains, "lead_s": lead, "lead_lowpass_hz": settings.lead_lowpass_hz,
            "track_design": {"settings": {k: (list(val) if isinstance(val, tuple) else val) for k, val in vars(settings).items()},
                             "log": log}}  # fmt: skip


def check_lead(gains: np.ndarray, lead: np.ndarray, lowpass_hz: float, speeds: list[float], nominal: dict, late: dict,
               bank: FilterBank, design: DesignSettings, dt: float) -> None:  # fmt: skip
    """Raise if the lead destabilises stage 1's design set: at every row with a lead and at the
    midpoints to its neighbours (the lead and the gains are interpolated), every conicity the
    design requires there, nominal with each gain factor and with the extra loop delay."""
    rows = [i for i, x in enumerate(lead) if x > 0]
    checked = sorted({speeds[i] for i in rows} | {0.5 * (speeds[i] + speeds[j]) for i in rows for j in (i - 1, i + 1)
                                                  if 0 <= j < len(speeds)})  # fmt: skip
    for v in checked:
        g = np.array([[np.interp(v, speeds, gains[:, i, j]) for j in range(gains.shape[2])] for i in range(gains.shape[1])])
        tau = float(np.interp(v, speeds, lead))
        for c in [c for c in design.conicities if design.required(c, v)] or [min(design.conicities)]:
            loops = [(f, nominal[c].plant(v)) for f in design.gain_factors] + [(1.0, late[c].plant(v))]
            for f, p in loops:
                radius = float(np.max(np.abs(np.linalg.eigvals(closed_loop(p, bank, g, f, tau, dt, lowpass_hz)))))
                if radius >= 1.0:
                    raise ValueError(f"retune_track: the command lead ({tau:g} s, low-pass {lowpass_hz} Hz) destabilises the "
                                     f"design loop at {v:g} km/h, conicity {c:g}, gain factor {f:g} (spectral radius {radius:.4f})")
