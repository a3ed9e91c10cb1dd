"""How fast ``adaptive_lqg`` (``agents/adaptive.py``) finds the conicity it is not told, in protocol runs.

    python studies/conicity_estimation.py [--conicities 0.025,0.05,0.1,0.2,0.3] [--seeds 5] \
        [--speeds 0.025=150,250,350 --speeds 0.3=60,80,100] [--duration 20] [--json] \
        [--controller adaptive_lqg_rate] [--degraded Kpx-50%]

Each (conicity, speed, seed) row is one protocol run (``agents/stability_protocol.py``: the v1
env at a fixed speed, the 12 mm start, the alert-level track, sensor noise and bias, 10 ms loop
delay; seeds 0 to ``--seeds`` - 1, one batch per conicity) with the adaptive controller, whose
conicity estimate (``estimate_conicity``) is recorded every step. Per (conicity, speed), the
median over seeds of: ``t_1.25``, the time from which the estimate stays within a factor 1.25 of
the true conicity to the end of the run (the run's length if it never settles); the final
estimate's error ``estimate / true - 1``; the share of the run's steps at which the commanding
model is the bank model nearest the true conicity; and how many seeds pass the protocol's
criterion. Prints a Markdown table (or JSON with ``--json``); progress on stderr.
``--controller adaptive_lqg_rate`` records that variant instead; ``--degraded NAME`` runs every
row with one of the protocol's degraded bogies (``stability_protocol.DEGRADED``), which the
controller is not told either.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

import numpy as np

from bogie_env.envs.config import make_config
from bogie_agents.controllers.adaptive import AdaptiveLQGController, AdaptiveRateLQGController
from bogie_agents.evaluation.stability_protocol import DEGRADED, NOMINAL_OPTIONS, Case, PartContext, Progress, Runner, Settings

#: Default speeds per conicity (km/h): below each conicity's closed-loop critical speed of
#: adaptive_lqg under protocol v3 (docs/studies/conicity_estimation.md).
DEFAULT_SPEEDS: dict[float, tuple[float, ...]] = {0.025: (150.0, 250.0, 350.0), 0.05: (150.0, 250.0, 350.0),
                                                   0.1: (100.0, 150.0, 200.0), 0.2: (60.0, 90.0, 120.0),
                                                   0.3: (60.0, 80.0, 100.0)}  # fmt: skip
FACTOR = 1.25


class _Recorder:
    """Records an adaptive controller's conicity estimate and selected model after every step."""

    def reset(self, n_envs: int, rows: np.ndarray | None = None) -> None:
        super().reset(n_envs, rows)
        self.history, self.selection = [], []

    def act(self, obs: np.ndarray) -> np.ndarray:
        actions = super().act(obs)
        self.history.append(self.estimate_conicity.copy())
        self.selection.append(self.selected_conicity.copy())
        return actions


class Recording(_Recorder, AdaptiveLQGController):
    """``adaptive_lqg``, recording."""


class RecordingRate(_Recorder, AdaptiveRateLQGController):
    """``adaptive_lqg_rate``, recording."""


RECORDING = {"adaptive_lqg": Recording, "adaptive_lqg_rate": RecordingRate}


def settling_time(ratio: np.ndarray, dt: float, factor: float = FACTOR) -> np.ndarray:
    """Per row of ``ratio`` (rows, steps: estimate / true), the time from which it stays within
    ``[1/factor, factor]`` to the end; the run's length where it is outside at the end."""
    inside = np.abs(np.log(ratio)) <= np.log(factor)
    steps = ratio.shape[1]
    outside_any = ~inside
    last_out = np.where(outside_any.any(axis=1), steps - 1 - np.argmax(outside_any[:, ::-1], axis=1), -1)
    return (last_out + 1) * dt


def run_conicity(conicity: float, speeds: list[float], seeds: int, duration_s: float, name: str = "adaptive_lqg",
                 degraded: str | None = None, **controller: object) -> list[dict]:  # fmt: skip
    config = make_config(variant="v1")
    settings = Settings(progress=False, duration_s=duration_s)
    holder: dict[str, _Recorder] = {}

    def factory(cfg: dict) -> _Recorder:
        holder["policy"] = RECORDING[name](cfg, **controller)
        return holder["policy"]

    ctx = PartContext(factory, config, settings, "sensors", Progress(name, False))
    options = {**NOMINAL_OPTIONS, **(DEGRADED[degraded] if degraded else {}), "conicity": conicity}
    cases = [Case("fixed", seed, options, conicity) for _ in speeds for seed in range(seeds)]
    rows_kmh = np.repeat(np.asarray(speeds, dtype=float), seeds)
    result = Runner(ctx).run(cases, rows_kmh, f"conicity {conicity:g}", 0)
    policy = holder["policy"]
    dt = config["dt"]
    estimate = np.stack(policy.history, axis=1)  # (rows, steps)
    selected = np.stack(policy.selection, axis=1)
    nearest = policy.conicities[np.argmin(np.abs(np.log(policy.conicities / conicity)))]
    t_settle = settling_time(estimate / conicity, dt)
    out = []
    for k, v in enumerate(speeds):
        rows = slice(k * seeds, (k + 1) * seeds)
        out.append({
            "conicity": conicity, "speed_kmh": v, "seeds": seeds,
            "t_settle_s_median": round(float(np.median(t_settle[rows])), 2),
            "t_settle_s_max": round(float(np.max(t_settle[rows])), 2),
            "final_error_median": round(float(np.median(estimate[rows, -1] / conicity - 1.0)), 3),
            "final_error_max_abs": round(float(np.max(np.abs(estimate[rows, -1] / conicity - 1.0))), 3),
            "nearest_model_share_median": round(float(np.median(np.mean(np.isclose(selected[rows], nearest), axis=1))), 3),
            "passed": int(result.passed[rows].sum()),
        })  # fmt: skip
    return out


def parse_speed_overrides(items: list[str]) -> dict[float, tuple[float, ...]]:
    out = {}
    for item in items:
        try:
            lam, values = item.split("=")
            out[float(lam)] = tuple(float(v) for v in values.split(","))
        except ValueError as exc:
            raise ValueError(f"--speeds = {item!r}: allowed 'CONICITY=KMH,KMH,...'") from exc
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--conicities", default="0.025,0.05,0.1,0.2,0.3")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--speeds", action="append", default=[], help="CONICITY=KMH,KMH,... (repeatable)")
    parser.add_argument("--duration", type=float, default=20.0, help="run length, s (the protocol's: 20)")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--controller", default="adaptive_lqg", choices=sorted(RECORDING))
    parser.add_argument("--degraded", default=None, choices=sorted(DEGRADED), help="a degraded bogie (default: nominal)")
    args = parser.parse_args()
    lams = [float(v) for v in args.conicities.split(",")]
    try:
        speeds = {**DEFAULT_SPEEDS, **parse_speed_overrides(args.speeds)}
    except ValueError as exc:
        parser.error(str(exc))
    missing = [lam for lam in lams if lam not in speeds]
    if missing or args.seeds < 1 or args.duration <= 5.0:
        parser.error(f"--conicities {missing} have no speeds (give --speeds LAM=...); --seeds = {args.seeds} (>= 1); "
                     f"--duration = {args.duration} (> 5 s, the protocol's transient)")  # fmt: skip
    rows = []
    t0 = time.monotonic()
    for lam in lams:
        rows += run_conicity(lam, list(speeds[lam]), args.seeds, args.duration, args.controller, args.degraded)
        print(f"[conicity_estimation] conicity {lam:g} done, {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"| conicity | speed (km/h) | t_{FACTOR} median (max), s | final error median (max abs) | "
          "nearest model commanding (median share) | seeds passing |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['conicity']:g} | {r['speed_kmh']:g} | {r['t_settle_s_median']:.2f} ({r['t_settle_s_max']:.2f}) | "
              f"{r['final_error_median']:+.3f} ({r['final_error_max_abs']:.3f}) | {r['nearest_model_share_median']:.2f} | "
              f"{r['passed']}/{r['seeds']} |")  # fmt: skip


if __name__ == "__main__":
    main()
