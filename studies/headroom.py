"""The headroom and what binds it: the privileged reference's closed-loop critical speed per
conicity in the v1 loop, and with one limit of the loop relaxed at a time (docs/studies/headroom.md).

    python studies/headroom.py                          # screening (3 seeds), the five worlds, conicity 0.05-0.3
    python studies/headroom.py --full --world v1        # the protocol's 10 seeds, the v1 loop only
    python studies/headroom.py --policy robust_steering # any controller in the same worlds
    python studies/headroom.py --full --world v1 --weights 1,3,10 --rate-weights 10,30   # the reference's weights
    python studies/headroom.py --full --world v1 --policy privileged_mpc   # the reference with hard limits (MPC)
    python studies/headroom.py --full --world v1 --policy privileged_mpc --n-sub 20   # at half v1's step
    python studies/headroom.py --full --world v1 --policy privileged_mpc_sensors   # told everything, sees the sensors

Worlds (each relaxes one thing of the v1 loop; the protocol is unchanged):

- ``v1``: the loop as it is;
- ``force_x10``: every channel's force limit x10 (the rate limit unchanged);
- ``no_rate_limit``: no force-rate limit;
- ``no_delay``: no command delay (``delay_steps`` 0);
- ``perfect_track``: no track irregularity;
- ``no_sensor_noise``: no sensor noise (a full-state controller such as the reference sees no
  sensors, so this world only matters for sensor-based controllers).

The reference's linear prediction (the speed where its designed closed loop on the sampled
plant loses stability, no limits) is printed beside the nonlinear protocol's value.
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from typing import Any

import numpy as np

from bogie_agents.evaluation import stability_protocol as sp
from bogie_agents.controllers.mpc import MPCReference, SensorMPCReference
from bogie_agents.controllers.privileged import PrivilegedController, SensorPrivilegedController
from bogie_env.actuators import CHANNEL_NAMES
from bogie_env.envs.config import make_config
from bogie_env.envs.scenario import Scenario
from bogie_env.envs.sensors import SENSOR_NAMES


#: the privileged references, whose weights --weights and --rate-weights set
REFERENCES = {"privileged": PrivilegedController, "privileged_mpc": MPCReference,
              "privileged_sensors": SensorPrivilegedController, "privileged_mpc_sensors": SensorMPCReference}


def worlds(base: dict) -> dict[str, dict[str, Any]]:
    """The v1 loop and each single relaxation of it (config overlays)."""
    acts = base["actuators"]
    return {
        "v1": {},
        "force_x10": {"actuators": {n: {"max_force": acts[n]["max_force"] * 10} for n in CHANNEL_NAMES}},
        "no_rate_limit": {"actuators": {n: {"rate_limit": None} for n in CHANNEL_NAMES}},
        "no_delay": {"actuators": {n: {"delay_steps": 0} for n in CHANNEL_NAMES}},
        "perfect_track": {"track": {"level": None, "rms": 0.0}},
        "no_sensor_noise": {"sensors": {n: {"noise_density": 0.0} for n in SENSOR_NAMES}, "observation": {"noise": 0.0}},
    }


def linear_limit_kmh(controller: PrivilegedController, conicity: float, speeds_kmh: np.ndarray) -> float | None:
    """The lowest design speed at which the reference's own closed loop (sampled plant, no
    limits, no noise) is unstable for ``conicity`` (None: stable at every speed)."""
    told = controller.tell(Scenario(conicity=conicity), controller.config)
    for v in speeds_kmh:
        if np.max(np.abs(told.closed_loop_eigenvalues(float(v)))) >= 1.0:
            return float(v)
    return None


def run(policy: str, world: dict, conicities: list[float], full: bool, r: float | None, rate_weight: float | None,
        n_sub: int | None = None, mpc: dict[str, Any] | None = None) -> dict[str, float]:  # fmt: skip
    overlay = copy.deepcopy(world)
    if n_sub is not None:  # the step-convergence check: v1's RK4 at n_sub substeps
        overlay["integration"] = {"n_sub": n_sub}
    env = make_config(overlay, variant="v1")
    cols = tuple("nominal" if np.isclose(c, 0.025) else f"conicity:{c:g}" for c in conicities)
    settings = sp.Settings(columns=cols, progress=False) if full else sp.screening_settings(columns=cols, progress=False)
    source: Any = policy
    if policy in REFERENCES:
        extra = (mpc or {}) if issubclass(REFERENCES[policy], MPCReference) else {}
        source = lambda cfg: REFERENCES[policy](cfg, r=r, rate_weight=rate_weight, **extra)  # noqa: E731
    res = sp.evaluate_policy_v2(source, env, settings, parts=("critical",), label=policy)
    return {k: v["kmh"] for k, v in res["by_conicity"].items()}


def _weights(text: str) -> list[float | None]:
    """A comma-separated list of weights; ``scheduled``: [None] (the reference's own schedule)."""
    return [None] if text == "scheduled" else [float(x) for x in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", default="privileged")
    parser.add_argument("--world", action="append", help="world names (default: all)")
    parser.add_argument("--conicity", default="0.05,0.1,0.2,0.3")
    parser.add_argument("--full", action="store_true", help="the protocol's 10 seeds (default: screening, 3 seeds)")
    parser.add_argument("--weights", default="scheduled", help="a reference's command weights r, comma-separated "
                        "(default: scheduled on the true conicity, its weights_by_conicity)")
    parser.add_argument("--rate-weights", default="scheduled", help="its force-rate weights, comma-separated (default: scheduled)")
    parser.add_argument("--horizon", type=int, default=None, help="privileged_mpc: its horizon, env steps (default: mpc.DEFAULT_HORIZON)")
    parser.add_argument("--rate-basis", default=None, help="privileged_mpc: 'step' (default) or 'sample' (mpc.RATE_BASES)")
    parser.add_argument("--n-sub", type=int, default=None, help="RK4 substeps per env step (default: v1's; 20 halves its step)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    conicities = [float(c) for c in args.conicity.split(",")]
    all_worlds = worlds(make_config(variant="v1"))
    names = args.world or list(all_worlds)
    unknown = [n for n in names if n not in all_worlds]
    if unknown:
        raise SystemExit(f"--world {unknown}: unknown; allowed: {', '.join(all_worlds)}")
    rows = []
    for r in _weights(args.weights):
        for q in _weights(args.rate_weights):
            for name in names:
                start = time.monotonic()
                mpc = {k: v for k, v in (("horizon", args.horizon), ("rate_basis", args.rate_basis)) if v is not None}
                values = run(args.policy, all_worlds[name], conicities, args.full, r, q, args.n_sub, mpc)
                row = {"policy": args.policy, "world": name, "r": r, "rate_weight": q, "kmh": values,
                       "seconds": round(time.monotonic() - start)}  # fmt: skip
                rows.append(row)
                if not args.json:
                    cells = " ".join(f"{k}:{v:.1f}" for k, v in values.items())
                    weights = f" r={r} rate_weight={q}" if args.policy in REFERENCES else ""
                    print(f"{args.policy}{weights} {name:16s} {cells} ({row['seconds']} s)", flush=True)
    if args.policy == "privileged":
        reference = PrivilegedController(make_config(variant="v1"), r=_weights(args.weights)[0],
                                         rate_weight=_weights(args.rate_weights)[0])  # fmt: skip
        speeds = np.arange(100.0, 700.0 + 1e-9, 10.0)
        linear = {f"{c:g}": linear_limit_kmh(reference, c, speeds) for c in conicities}
        rows.append({"linear_unstable_from_kmh": linear})
        if not args.json:
            print("linear prediction (first unstable design speed, km/h):", json.dumps(linear))
    if args.json:
        print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
