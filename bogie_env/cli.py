"""The ``bogie`` command line. Each subcommand is a thin client of the library.

    bogie critical-speed [--config FILE] [--set NAME=VALUE ...] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Callable, Sequence

import numpy as np

from .params import ConfigError, load_params

COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], int], Callable[[argparse.ArgumentParser], None], str]] = {}


def command(name: str, help_text: str):
    """Register a subcommand: ``func(args) -> exit code`` plus an argument-adder."""

    def decorator(func):
        def add_arguments(parser: argparse.ArgumentParser) -> None:
            for args, kwargs in getattr(func, "_arguments", []):
                parser.add_argument(*args, **kwargs)

        COMMANDS[name] = (func, add_arguments, help_text)
        return func

    return decorator


def argument(*args, **kwargs):
    """Declare one argparse argument on a subcommand (outermost decorator last)."""

    def decorator(func):
        func._arguments = [(args, kwargs)] + getattr(func, "_arguments", [])
        return func

    return decorator


def bogie_options(func):
    """The --config/--set pair every command takes."""
    func = argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override one bogie parameter by its paper symbol, e.g. --set Csy=45000 (repeatable)",
    )(func)
    func = argument("--config", default=None, help="bogie preset YAML (default: configs/bogie/paper.yaml)")(func)
    return func


def json_option(func):
    return argument("--json", action="store_true", help="print one JSON object instead of text")(func)


def print_json(payload: dict) -> None:
    print(json.dumps(payload, indent=2, allow_nan=False, default=_json_default))


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value)}")


# ---------------------------------------------------------------------------------
@command("critical-speed", "linear critical speed (km/h), hunting frequency (Hz) and equilibrium")
@json_option
@argument("--v-max-kmh", type=float, default=900.0, help="top of the search window (km/h)")
@argument("--v-min-kmh", type=float, default=50.0, help="bottom of the search window (km/h)")
@bogie_options
def cmd_critical_speed(args: argparse.Namespace) -> int:
    from .dynamics import BogieModel
    from .stability import critical_speed

    params = load_params(args.config, args.overrides)
    model = BogieModel(params)
    result = critical_speed(model, v_min_kmh=args.v_min_kmh, v_max_kmh=args.v_max_kmh)
    payload = result.to_dict()
    payload["config"] = params.source
    payload["overrides"] = args.overrides
    payload["creep_coefficients"] = {
        "f11": model.creep.f11,
        "f12": model.creep.f12,
        "f22": model.creep.f22,
        "f33": model.creep.f33,
        "contact_a_m": model.creep.contact.a,
        "contact_b_m": model.creep.contact.b,
    }
    payload["paper_critical_speed_kmh"] = 427.0
    if args.json:
        print_json(payload)
        return 0
    if result.status == "crossing":
        print(f"linear critical speed : {result.speed_kmh:.1f} km/h  ({result.speed:.2f} m/s)")
        print(f"hunting frequency     : {result.frequency_hz:.3f} Hz")
    elif result.status == "stable":
        print(f"stable over the whole window {args.v_min_kmh:g}-{args.v_max_kmh:g} km/h: no critical speed")
    else:
        print(f"already unstable at the bottom of the window ({args.v_min_kmh:g} km/h)")
    print("paper (Bustos et al. 2022): 427 km/h; docs/model.md explains the difference")
    print("equilibrium (non-zero entries):")
    for name, value in payload["equilibrium"].items():
        if abs(value) > 1e-15:
            print(f"  {name:6s} = {value:.6e}")
    return 0


# ---------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="bogie", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (func, add_arguments, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        add_arguments(sp)
        sp.set_defaults(func=func)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, ValueError, FileNotFoundError) as error:
        print(f"bogie {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
