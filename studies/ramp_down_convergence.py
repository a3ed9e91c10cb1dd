"""Protocol v2's ``ramp_down`` part at several integration steps and ramp rates: how far its
values move when the step or the deceleration is halved.

    python studies/ramp_down_convergence.py [--policy passive --policy pretrained] \
        [--n-sub 10,20] [--decel 0.25] [--conicities 0.025,0.05,0.1,0.2,0.3] [--seed 0] [--seeds 10] [--ideal] \
        [--stride-kmh 2]

``--ideal`` runs the part ``ramp_down_ideal`` instead: the same ramp-down on a perfect track
with noise-free sensors (``ramp_down.IDEAL_WORLD``); ``--stride-kmh`` sets how often a
judged window starts (the part's resolution; default 2 km/h).

Every (step, deceleration) pair runs the part (``agents/evaluation/stability_protocol.py``,
:func:`ramp_down_part`) on seeds ``--seed`` to ``--seed`` + ``--seeds`` - 1 (the nominal column
always runs beside the chosen conicities); v1's step is 10 substeps, the part's
deceleration 0.25 m/s^2. Prints JSON: per policy and pair, each conicity's value (lowest seed)
and the median over seeds; progress with the time left on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from bogie_env.envs.config import make_config
from bogie_env.params import ConfigError
from bogie_agents.evaluation.stability_protocol import Settings, evaluate_policy_v2


def floats(parser: argparse.ArgumentParser, name: str, text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        parser.error(f"{name} = {text!r}: allowed: comma-separated numbers")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", action="append", default=None)
    parser.add_argument("--n-sub", default="10,20", help="RK4 substeps per env step, comma-separated (v1: 10)")
    parser.add_argument("--decel", default="0.25", help="ramp-down decelerations (m/s^2), comma-separated")
    parser.add_argument("--conicities", default="0.025,0.05,0.1,0.2,0.3")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--ideal", action="store_true", help="the part ramp_down_ideal (perfect track, noise-free sensors)")
    parser.add_argument("--stride-kmh", type=float, default=2.0, help="a judged window starts every this many km/h")
    args = parser.parse_args()
    steps = [int(v) for v in floats(parser, "--n-sub", args.n_sub)]
    decels, conicities = floats(parser, "--decel", args.decel), tuple(floats(parser, "--conicities", args.conicities))
    if any(n < 1 for n in steps) or args.seeds < 1:
        parser.error(f"--n-sub = {args.n_sub!r} and --seeds = {args.seeds} must be >= 1")
    for decel in decels:  # every setting is checked before the first run
        try:
            Settings(seed=args.seed, seeds=args.seeds, conicities=conicities, ramp_down_decel=decel,
                     ramp_down_stride_kmh=args.stride_kmh).check()
        except ConfigError as error:
            parser.error(f"--decel or --stride-kmh: {error}")
    policies = args.policy or ["passive", "pretrained"]
    pairs = [(n, d) for n in steps for d in decels]
    total, done, t0 = len(policies) * len(pairs), 0, time.monotonic()
    out: dict[str, dict] = {}
    for policy in policies:
        for n_sub, decel in pairs:
            config = make_config({"integration": {"n_sub": n_sub}}, variant="v1")
            settings = Settings(seed=args.seed, seeds=args.seeds, conicities=conicities, ramp_down_decel=decel,
                                ramp_down_stride_kmh=args.stride_kmh, progress=False)
            name = "ramp_down_ideal" if args.ideal else "ramp_down"
            part = evaluate_policy_v2(policy, config, settings, (name,))[name]["by_conicity"]
            where = ", ideal track" if args.ideal else ""
            where += f", windows every {args.stride_kmh:g} km/h" if args.stride_kmh != 2.0 else ""
            out[f"{policy}, {n_sub} substeps, {decel:g} m/s^2{where}"] = {
                lam: {"kmh": e["kmh"], "bound": e["bound"], "median_kmh": e["spread_kmh"]["median"],
                      "per_seed_kmh": e["per_seed_kmh"]}
                for lam, e in part.items()
            }  # fmt: skip
            done += 1
            elapsed = time.monotonic() - t0
            print(f"[{done}/{total}: {policy}, {n_sub} substeps, {decel:g} m/s^2; {elapsed:.0f} s, "
                  f"about {elapsed / done * (total - done):.0f} s left]", file=sys.stderr, flush=True)  # fmt: skip
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
