"""The bogie command line: critical speeds, analyses and, with bogie_agents, controllers.

Each subcommand is a thin client of the library.

    bogie critical-speed [--config FILE] [--set NAME=VALUE ...] [--json]
    bogie curving --radius M --cant M --speed-kmh KMH [--direction left|right] [--out DIR] [--json]
    bogie curving --route NAME [--speed-kmh KMH] [--out DIR] [--json]

The ``bogie`` console script (:mod:`bogie_agents.__main__`) runs :mod:`bogie_agents.cli`, which adds the agents' commands
(train, tune, evaluate, results) to this parser; ``python -m bogie_env.cli`` has the library's alone.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Callable, Sequence

import numpy as np

from .params import ConfigError, load_params, parse_assignments

COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], int], Callable[[argparse.ArgumentParser], None], str]] = {}


def bounded(kind: type, low: float, high: float, unit: str = "", low_open: bool = False):
    """An argparse ``type`` that accepts an int or float in [low, high] (``(low, high]`` if
    ``low_open``); argparse then reports ``argument --NAME: ...`` with what is allowed."""

    def convert(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        ok = np.isfinite(value) and (value > low if low_open else value >= low) and value <= high
        if not ok:
            what, lo, hi = ("an integer", f"{low}", f"{high}") if kind is int else ("a number", f"{low:g}", f"{high:g}")
            raise argparse.ArgumentTypeError(
                f"{text!r} is not allowed; allowed: {what} in {'(' if low_open else '['}{lo}, {hi}]{' ' + unit if unit else ''}"
            )
        return value

    convert.__name__ = kind.__name__  # argparse names the type in some messages
    return convert


SPEED_KMH = bounded(float, 0.0, 1000.0, "km/h", low_open=True)
SEED = bounded(int, 0, 2**32 - 1)
WORKERS = bounded(int, 1, 1024)


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


def backend_options(func):
    """--backend/--address: where the work runs (docs/distributed.md)."""
    func = argument("--address", default=None,
                    help="Ray cluster to join (HOST:PORT or 'auto'); default: start a local cluster "
                         "(--backend ray only)")(func)  # fmt: skip
    func = argument("--backend", choices=("local", "ray"), default="local",
                    help="local processes (default) or Ray tasks (needs pip install -e '.[distributed]')")(func)  # fmt: skip
    return func


def check_backend_args(args: argparse.Namespace) -> None:
    if args.address is not None and args.backend != "ray":
        raise ConfigError(f"--address {args.address!r} needs --backend ray (the local backend runs on this machine)")


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


def env_config_from_args(args: argparse.Namespace, variant: str | None = None) -> dict:
    """The env config (``--env-config``, merged into ``variant``'s) with the bogie preset and
    ``--set`` overrides folded in."""
    from .envs.config import bogie_params, make_config

    env_config = make_config(args.env_config, variant=variant)
    if args.config is None and not args.overrides:
        return env_config
    if args.config is not None:
        env_config["bogie"] = args.config
    env_config["bogie_overrides"] = {**env_config["bogie_overrides"], **parse_assignments(args.overrides)}
    bogie_params(env_config)  # the preset loads and takes the overrides
    return make_config(env_config)


# ---------------------------------------------------------------------------------
@command("critical-speed", "linear critical speed (km/h), hunting frequency (Hz) and equilibrium")
@json_option
@argument("--v-max-kmh", type=SPEED_KMH, default=900.0, help="top of the search window (km/h)")
@argument("--v-min-kmh", type=SPEED_KMH, default=50.0, help="bottom of the search window (km/h)")
@bogie_options
def cmd_critical_speed(args: argparse.Namespace) -> int:
    from .dynamics import BogieModel
    from .stability import critical_speed

    check_range("critical-speed", args.v_min_kmh, args.v_max_kmh)
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
def parse_scales(text: str, option: str = "--scales") -> list[float]:
    """'0.5,1,1.5' -> [0.5, 1.0, 1.5]; an empty list, a bad number or one <= 0 is an error naming ``option``."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise ConfigError(f"{option} {text!r} is empty; give comma-separated numbers > 0, e.g. 0.5,1,1.5")
    try:
        values = [float(item) for item in items]
    except ValueError:
        raise ConfigError(f"{option} {text!r}: every entry must be a number, e.g. 0.5,1,1.5") from None
    if not all(np.isfinite(v) and v > 0 for v in values):
        raise ConfigError(f"{option} {text!r}: every entry must be a finite number > 0")
    return values


def _kmh(value, digits: int = 1) -> str:
    return "none found" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def check_range(name: str, low: float, high: float) -> None:
    if not (np.isfinite(low) and np.isfinite(high) and low < high):
        raise ConfigError(f"{name}: speed range {low:g}-{high:g} km/h is inverted or empty; the first must be below the second")


def _model(args):
    from .dynamics import BogieModel

    return BogieModel(load_params(args.config, args.overrides))


@command("root-locus", "eigenvalues against speed with the hunting mode tracked (Figs. 7, 8, 10)")
@json_option
@argument("--out", default=None, help="write the root-locus figures with this file prefix (PNG)")
@argument("--n-speeds", type=bounded(int, 2, 100_000), default=301, help="speeds in the window")
@argument("--v-max-kmh", type=SPEED_KMH, default=600.0)
@argument("--v-min-kmh", type=SPEED_KMH, default=300.0)
@bogie_options
def cmd_root_locus(args: argparse.Namespace) -> int:
    from .analysis.root_locus import root_locus

    check_range("root-locus", args.v_min_kmh, args.v_max_kmh)
    locus = root_locus(_model(args), args.v_min_kmh, args.v_max_kmh, args.n_speeds)
    if args.out:
        from .analysis import plots

        plots.root_locus_figure(locus, f"{args.out}_root_locus.png")
        plots.root_locus_figure(locus, f"{args.out}_root_locus_zoom.png", zoom=True)
        plots.real_parts_figure(locus, f"{args.out}_real_parts.png")
    if args.json:
        print_json(locus.to_dict())
    else:
        c = locus.critical
        print(f"hunting mode crosses the imaginary axis at {c.speed_kmh:.1f} km/h, {c.frequency_hz:.3f} Hz")
        for v, ev in list(zip(locus.speeds_kmh, locus.hunting))[:: max(1, len(locus.speeds) // 10)]:
            print(f"  {v:7.1f} km/h  {ev.real:+9.4f} {ev.imag:+9.4f}j")
    return 0


@command("ramp", "the paper's speed-ramp simulation with frozen eigenvalues (Figs. 9, 11)")
@json_option
@argument("--out", default=None, help="folder for the figures")
@argument("--track-seed", type=SEED, default=0, help="seed of the track irregularity")
@argument("--track-rms", type=bounded(float, 0.0, 0.01, "m"), default=1e-6, help="alignment irregularity rms (m): the noise floor")
@argument("--offset", type=bounded(float, -0.03, 0.03, "m"), default=1e-3,
          help="initial lateral offset of wheelset 1 (m); the flange clearance is 9 mm")
@argument("--accel", type=bounded(float, 0.0, 10.0, "m/s^2", low_open=True), default=0.1, help="ramp rate (m/s^2)")
@argument("--v-end-kmh", type=SPEED_KMH, default=600.0)
@argument("--v-start-kmh", type=SPEED_KMH, default=300.0)
@bogie_options
def cmd_ramp(args: argparse.Namespace) -> int:
    import time

    from .analysis.ramp import speed_ramp

    check_range("ramp", args.v_start_kmh, args.v_end_kmh)
    model = _model(args)
    start = time.perf_counter()
    result = speed_ramp(model, args.v_start_kmh, args.v_end_kmh, args.accel, args.offset, args.track_rms, args.track_seed)
    payload = result.to_dict()
    payload["wall_time_s"] = round(time.perf_counter() - start, 3)
    if args.out:
        from pathlib import Path

        from .analysis import plots

        out = Path(args.out)
        plots.ramp_figure(result, out / "ramp_lateral.png")
        plots.ramp_eigenvalue_figure(result, out / "ramp_frozen_eigenvalues.png")
        plots.phase_portrait_figure(result, out / "phase_portrait.png")
    if args.json:
        print_json(payload)
    else:
        for key, value in payload.items():
            print(f"{key:34s} {value}")
    return 0


@command("bifurcation", "limit cycles, bifurcation diagram and the nonlinear critical speed (ramp-down)")
@json_option
@argument("--out", default=None, help="folder for the figures")
@argument("--rates", default="5,2,1,0.5,0.2,0.1", help="ramp-down rates, km/h per s")
@argument("--n-speeds", type=bounded(int, 2, 10_000), default=51, help="speeds in the window")
@argument("--v-max-kmh", type=SPEED_KMH, default=550.0)
@argument("--v-min-kmh", type=SPEED_KMH, default=300.0)
@bogie_options
def cmd_bifurcation(args: argparse.Namespace) -> int:
    from .analysis.bifurcation import bifurcation_diagram, nonlinear_critical_speed

    check_range("bifurcation", args.v_min_kmh, args.v_max_kmh)
    model = _model(args)
    rates = tuple(parse_scales(args.rates, "--rates"))
    nonlinear = nonlinear_critical_speed(model, rates)
    diagram = bifurcation_diagram(model, args.v_min_kmh, args.v_max_kmh, args.n_speeds)
    payload = nonlinear.to_dict()
    payload["bifurcation"] = diagram.to_dict()
    if args.out:
        from pathlib import Path

        from .analysis import plots

        plots.bifurcation_figure(diagram, nonlinear, Path(args.out) / "bifurcation.png")
        plots.ramp_down_figure(nonlinear, Path(args.out) / "ramp_down_convergence.png")
    if args.json:
        print_json(payload)
    else:
        print(f"linear critical speed      : {nonlinear.linear_critical_speed_kmh:.1f} km/h")
        print(f"nonlinear (fixed-speed fold): {_kmh(nonlinear.fixed_speed_kmh)} km/h "
              f"(grid {_kmh(nonlinear.fixed_speed_step_kmh, 2)} km/h)")
        print(f"ramp-down extrapolated to 0: {nonlinear.extrapolated_kmh:.2f} km/h")
        for r, c in zip(nonlinear.rates_kmh_per_s, nonlinear.collapse_kmh):
            print(f"  ramp-down {r:5g} km/h/s -> collapse at {c if c is None else round(c, 2)} km/h")
    return 0


@command("sensitivity", "critical speed against one or two parameters, or the whole Section-5 study")
@json_option
@argument("--fixed-contact", action="store_true", help="hold the creep coefficients at their nominal values while a parameter varies (the paper does not say which it did; docs/model.md)")
@argument("--chunk-size", type=bounded(int, 1, 10**6), default=None, help="points per task (default 256)")
@argument("--workers", type=WORKERS, default=None,
          help="local processes, or the CPUs of a local Ray cluster (default: all cores)")
@argument("--out", default=None,
          help="folder for CSV/JSON/figures (with --all); finished chunks are kept in OUT/chunks, so a rerun resumes")
@backend_options
@argument("--all", action="store_true", help="the full study: 9 curves and 36 pair grids")
@argument("--scales", action="append", default=[], help="comma-separated scale factors (once per --param)")
@argument("--param", action="append", default=[], help="parameter to vary (give twice for a 2-D grid)")
@bogie_options
def cmd_sensitivity(args: argparse.Namespace) -> int:
    import time

    from .analysis import sensitivity as sens

    params = load_params(args.config, args.overrides)
    check_backend_args(args)
    progress = not args.json
    distribute = {"backend": args.backend, "address": args.address,
                  "chunk_size": sens.DEFAULT_CHUNK_SIZE if args.chunk_size is None else args.chunk_size}  # fmt: skip
    if args.all:
        from pathlib import Path

        if args.out:
            distribute["store_dir"] = Path(args.out) / "chunks"
        start = time.perf_counter()
        study = sens.full_study(params, fixed_contact=args.fixed_contact, workers=args.workers, progress=progress,
                                **distribute)  # fmt: skip
        elapsed = time.perf_counter() - start
        payload = {"n_critical_speeds": study.n_points, "wall_time_s": round(elapsed, 3), "backend": args.backend,
                   "nominal_critical_speed_kmh": study.nominal_kmh, "table2": study.table2()}  # fmt: skip
        if args.out:
            from .analysis import plots
            from .analysis.report import _curves_csv, _grids_csv, write_text_atomic

            out = Path(args.out)
            write_text_atomic(out / "sensitivity.json", json.dumps(study.to_dict(), default=float))
            write_text_atomic(out / "sensitivity_curves.csv", _curves_csv(study.curves))
            write_text_atomic(out / "sensitivity_grids.csv", _grids_csv(study.grids))
            plots.curves_figure(study.curves, study.nominal_kmh, out / "sensitivity_curves.png")
        if args.json:
            print_json(payload)
        else:
            print(f"{study.n_points} critical speeds in {elapsed:.2f} s")
            for row in study.table2():
                print(f"  {row['params'][0]:>4s} x {row['params'][1]:<4s} max {row['critical_speed_kmh']} km/h at {row['values']}")
        return 0
    if not args.param or len(args.param) > 2:
        raise ConfigError("give --param NAME once (curve) or twice (2-D grid), or --all")
    if len(args.scales) > len(args.param):
        raise ConfigError(f"{len(args.scales)} --scales for {len(args.param)} --param; give at most one per --param")
    scales = [parse_scales(text) for text in args.scales]
    if len(args.param) == 1:
        curve = sens.one_parameter(params, args.param[0], scales[0] if scales else None, args.fixed_contact, args.workers,
                                   **distribute)  # fmt: skip
        payload = curve.to_dict()
    else:
        if len(scales) == 1:
            scales = scales * 2
        pair = (scales[0], scales[1]) if scales else (None, None)
        grid = sens.two_parameter(params, tuple(args.param), pair, args.fixed_contact, args.workers, **distribute)
        payload = grid.to_dict()
    if args.json:
        print_json(payload)
    else:
        for point in payload["points"]:
            key = point.get("scale", point.get("scales"))
            print(f"  scale {key}: {point['critical_speed_kmh']} km/h")
    return 0


@command("reproduce", "regenerate every Section 4-5 figure and a markdown report")
@argument("--workers", type=WORKERS, default=None, help="processes (default: all cores)")
@argument("--out", required=True, help="output folder")
@bogie_options
def cmd_reproduce(args: argparse.Namespace) -> int:
    from .analysis.report import reproduce

    results = reproduce(args.out, load_params(args.config, args.overrides), workers=args.workers)
    print(f"wrote {args.out}/report.md and figures; timings (s): {results['timings_s']}")
    return 0


# ---------------------------------------------------------------------------------
@command("curving", "steady-state curving at a radius, cant and speed; or dynamic curve negotiation on a route")
@json_option
@argument("--out", default=None, help="folder for the figures: against radius and cant deficiency (steady), "
                                      "or time histories (--route)")
@argument("--route", default=None, help="a shipped route name (configs/routes) or a route YAML file: run along it")
@argument("--direction", choices=("left", "right"), default="left", help="curve direction (steady state)")
@argument("--speed-kmh", "--speed", dest="speed_kmh", type=float, default=None,
          help="speed (km/h); with --route the route's design speed by default")
@argument("--cant", type=float, default=0.0, help="cant (m): height of the outer rail above the inner one")
@argument("--radius", type=float, default=None, help="curve radius (m)")
@bogie_options
def cmd_curving(args: argparse.Namespace) -> int:
    from .analysis import curving

    model = _model(args)
    if args.route is not None:
        return _curving_route(args, model)
    if args.radius is None or args.speed_kmh is None:
        raise ConfigError("curving: give --radius (m) and --speed-kmh (km/h) for a steady state, or --route NAME")
    result = curving.steady_curving(model, args.radius, args.cant, args.speed_kmh, args.direction)
    payload = result.to_dict()
    payload["config"] = model.params.source
    payload["overrides"] = args.overrides
    if args.out:
        payload["figures"] = curving.write_sweep_figures(model, args.radius, args.cant, args.speed_kmh, args.direction, args.out)
    if args.json:
        print_json(payload)
        return 0
    print(f"R {args.radius:g} m {args.direction}, cant {1e3 * args.cant:g} mm, {args.speed_kmh:g} km/h: cant deficiency "
          f"{1e3 * payload['cant_deficiency_m']:.1f} mm ({payload['unbalanced_acceleration_m_per_s2']:.3f} m/s^2), "
          f"steady state by {payload['method']}, {'stable' if payload['stable'] else 'UNSTABLE'}")
    for i, name in enumerate(("front", "rear")):
        print(f"  {name:5s} y {1e3 * payload['lateral_displacement_m'][i]:+7.2f} mm  "
              f"AoA {1e3 * payload['angle_of_attack_rad'][i]:+7.3f} mrad  "
              f"SumY {1e-3 * payload['guiding_force_n'][i]:+7.2f} kN  "
              f"Y/Q {payload['y_over_q'][i][0]:+.3f} / {payload['y_over_q'][i][1]:+.3f}  "
              f"Tgamma {payload['wear_number_n'][i]:7.1f} N  flange {'yes' if payload['flange_contact'][i] else 'no'}")
    return 0


def _curving_route(args: argparse.Namespace, model) -> int:
    from pathlib import Path

    from .analysis import curving
    from .route import load_route

    route = load_route(args.route)
    speed = args.speed_kmh if args.speed_kmh is not None else route.design_speed_kmh
    if speed is None:
        raise ConfigError(f"curving: route {route.name!r} has no design_speed_kmh; give --speed-kmh")
    run = curving.route_run(model, route, speed)
    payload = run.summary(flange_time_dt=0.01)
    if args.out:
        figure = curving.route_figure(run, Path(args.out) / f"route_{route.name}.png")
        payload["figures"] = {"time_histories": str(figure)}
    if args.json:
        print_json(payload)
    else:
        for key, value in payload.items():
            print(f"{key:30s} {value}")
    return 0


# ---------------------------------------------------------------------------------
class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """--help shows every default ("(default: ...)"), except for flags and unset options."""

    def _get_help_string(self, action):
        default = action.default
        if default is None or default is False or default == [] or default is argparse.SUPPRESS:
            return action.help
        if action.help is None:
            return "(default: %(default)s)"
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    from . import __version__

    parser = argparse.ArgumentParser(prog="bogie", description=__doc__.splitlines()[0].replace("``", ""))
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (func, add_arguments, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text, formatter_class=HelpFormatter)
        add_arguments(sp)
        sp.set_defaults(func=func)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ConfigError, ValueError, OSError) as error:  # OSError: an --out path that is a file, no permission, ...
        print(f"bogie {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
