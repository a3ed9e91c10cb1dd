"""The ``bogie`` command: the library's commands (:mod:`bogie_env.cli`) plus the agents' ones.

    bogie train --algo ppo --config configs/agents/ppo.yaml --out runs/ppo
    bogie evaluate --policy passive --policy pretrained --json
    bogie results --policy passive --policy lqr --out results/table
    bogie results ... --backend ray [--address HOST:PORT]       (one Ray task per controller and part)
    bogie margins --policy lqr --policy pretrained --speeds 300,400,500
    bogie margins --env Bogie/Hunting-v1 --policy passive --policy lqg --conicity 0.05 --json
    bogie tune --algo ppo --trials 4 --out runs/tune_ppo          (needs the [distributed] extra)
    bogie distill --config configs/agents/distill_v1.yaml --out runs/distill_v1

The library stands alone (``python -m bogie_env.cli`` has the analysis commands); this module
adds train, distill, tune, evaluate, results and margins to the same parser. Training and SB3 policies need the
``[agents]`` extra; the classical controllers do not.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from bogie_env import cli as library_cli
from bogie_env.fileio import write_text_atomic
from bogie_env.cli import (SEED, argument, backend_options, bogie_options, bounded, check_backend_args, command,
                           env_config_from_args, json_option, print_json)  # fmt: skip
from bogie_env.params import ConfigError

from .controllers import POLICY_HELP

#: Modules of the ``[agents]`` extra: a missing one is reported with the install command.
AGENTS_EXTRA = ("stable_baselines3", "torch", "tensorboard", "tqdm", "rich")


# ---------------------------------------------------------------------------------
@command("train", "train an SB3 agent (PPO, SAC, TD3) on the native batched VecEnv; resumes if interrupted")
@argument("--no-progress", action="store_true", help="no progress bar")
@argument("--no-resume", action="store_true", help="start afresh: an earlier run in --out is moved to OUT/previous/<UTC time>/ (nothing is deleted)")
@argument("--seed", type=int, default=None, help="override the config's seed")
@argument("--timesteps", type=int, default=None, help="override the config's total_timesteps")
@argument("--out", required=True, help="run folder, e.g. runs/ppo")
@argument("--config", default=None, help="agent config YAML (default: configs/agents/ALGO.yaml)")
@argument("--algo", choices=("ppo", "sac", "td3", "recurrent_ppo"), default=None)
def cmd_train(args: argparse.Namespace) -> int:
    from .training.train import train_from_cli

    summary = train_from_cli(args.algo, args.config, args.out, args.timesteps, args.seed, not args.no_resume,
                             not args.no_progress)  # fmt: skip
    print_json(summary)
    return 0


@command("distill", "distil the privileged reference into a student that sees only the sensors (DAgger); writes OUT/student.npz")
@argument("--seed", type=int, default=None, help="override the config's seed")
@argument("--out", required=True, help="student folder, e.g. runs/distill_v1")
@argument("--config", default="configs/agents/distill_v1.yaml", help="distill config YAML (keys: bogie_agents.training.distill.default_config)")
def cmd_distill(args: argparse.Namespace) -> int:
    from .training.distill import distill, load_config

    cfg = load_config(args.config, {"seed": args.seed} if args.seed is not None else None)
    out = distill(cfg, args.out)
    print_json({"out": str(out), "progress": json.loads((out / "progress.json").read_text())})
    return 0


@command("tune", "hyperparameter search for an SB3 agent (Ray Tune with Optuna); resumable; writes the best config")
@argument("--n-envs", type=int, default=None, help="override the config's n_envs for the trials")
@argument("--seed", type=int, default=0, help="training and sampler seed")
@argument("--concurrent", type=int, default=None, help="trials at once (default: the cluster's CPUs)")
@argument("--address", default=None, help="Ray cluster to join (HOST:PORT or 'auto'); default: a local cluster")
@argument("--write-config", default=None, help="where to write the best config (default: configs/agents/ALGO_tuned.yaml)")
@argument("--episodes", type=int, default=4, help="evaluation episodes that score each trial")
@argument("--trial-time-s", type=float, default=300.0, help="wall-time cap of one trial's training (s)")
@argument("--timesteps", type=int, default=100_000, help="training steps per trial")
@argument("--trials", type=int, default=4, help="trials of a new experiment (a restored one keeps its own)")
@argument("--out", required=True, help="experiment folder, e.g. runs/tune_ppo (rerun to resume)")
@argument("--config", default=None, help="agent config YAML to start from (default: configs/agents/ALGO.yaml)")
@argument("--algo", choices=("ppo", "sac", "td3"), default="ppo")
def cmd_tune(args: argparse.Namespace) -> int:
    from .training.tune import tune_agent

    summary = tune_agent(args.algo, args.out, args.trials, args.timesteps, args.trial_time_s, args.episodes, args.config,
                         args.write_config, args.address, args.concurrent, args.seed, args.n_envs)  # fmt: skip
    print_json({key: summary[key] for key in ("algo", "env_id", "experiment", "restored", "trials_finished", "interrupted",
                                              "best", "config")})  # fmt: skip
    if summary["interrupted"]:
        print(f"bogie tune: interrupted; rerun the same command to resume {summary['experiment']}", file=sys.stderr)
        return 130
    return 0


def policy_options(func, required: bool = True):
    """--trust-policy, --policy (repeatable) and --workers: the controllers to run and where."""
    func = argument("--workers", type=int, default=None,
                    help="CPUs of the local Ray cluster that --backend ray starts (default: all)")(func)  # fmt: skip
    func = argument("--policy", action="append", required=required,
                    help=POLICY_HELP)(func)
    return argument("--trust-policy", action="store_true",
                    help="allow loading a policy PATH: an SB3 model file is code (it unpickles) and runs with your "
                         "rights; use only for files you made or trust (pretrained is checked against its SHA-256 "
                         "sums instead)")(func)  # fmt: skip


def _env_variant(env_id: str) -> str | None:
    """The config variant behind a registered env id (``--env``)."""
    from bogie_env.envs.registration import IDS

    if env_id not in IDS:
        raise ConfigError(f"--env {env_id!r} is not a bogie-env id; known ids: {', '.join(IDS)}")
    return IDS[env_id]


PROTOCOL_HELP = ("protocol version for the -v1 ids: 3 (default; flange contact counts only when sustained, so a rough "
                 "track's forced contacts do not fail a run) or 2 (every contact counts; docs/results.md, 'Protocol v3')")


@command("evaluate", "the evaluation protocol of the env's version: v1 (for -v0 ids) or v3/v2 (for -v1 ids)")
@json_option
@argument("--out", default=None, help="write the JSON result here as well (atomically)")
@argument("--parts", default=None,
          help="which parts of the protocol to run. Protocol v2 (-v1 ids): critical, cost, margins (default: these three; "
               "margins needs the [margins] extra), curving, "
               "ramp, ramp_down (closed-loop ramp-down from fully developed hunting), ramp_down_ideal (the same on a perfect "
               "track with noise-free sensors) and any registered part; protocol v1 (-v0 ids): critical, ramp, effort, robustness (default: all), margins")
@argument("--seed", type=SEED, default=0, help="seed of the protocol's random starts and tracks")
@argument("--protocol", type=int, choices=(2, 3), default=None, help=PROTOCOL_HELP)
@argument("--quick", action="store_true",
          help="-v1 ids: a screening run (3 seeds, 3 worst-case draws, bisection to 4 km/h; default part critical) for "
               "ranking candidates in about a minute; marked 'screening' in the JSON, never the protocol's table")
@argument("--n-sub", type=bounded(int, 1, 1000), default=None,
          help="RK4 substeps per env step for every run of the protocol (default: the env's own step; v1: 10). "
               "40 runs the v1 protocol with the integration converged (docs/results.md, 'Step convergence')")
@argument("--env-config", default=None, help="env config YAML (default: the env's default_config)")
@argument("--env", default="Bogie/Hunting-v1",
          help="env id whose task to evaluate on (its variant; --env-config merges into it); its version picks the "
               "protocol: -v1 ids protocol v2 (docs/results.md), -v0 ids protocol v1")
@policy_options
@backend_options
@bogie_options
def cmd_evaluate(args: argparse.Namespace) -> int:
    check_backend_args(args)
    _check_workers(args)
    env_config = with_substeps(env_config_from_args(args, _env_variant(args.env)), args.n_sub)
    env_version = args.env.rsplit("-", 1)[-1]
    if env_version == "v0":
        _refuse_protocol_for_v0(args)
        results, protocol_version = _evaluate_v1(args, env_config), 1
    else:
        results, protocol_version = _evaluate_v2(args, env_config), protocol_settings(args).version
    payload = {"env_id": args.env, "env_version": env_version, "protocol_version": protocol_version,
               "integration_n_sub": env_config["integration"]["n_sub"], "policies": results}  # fmt: skip
    if args.quick:
        payload = {"screening": results[0]["screening"], **payload}
    if protocol_version >= 2:
        from .evaluation.scoreboard import with_scores

        payload = with_scores(payload)  # the score against the passive row of this run (none without one)
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(payload, indent=2, default=float))
    if args.json:
        print_json(payload)
    elif protocol_version == 1:
        _print_v1(results)
    else:
        from .evaluation.results import v2_summary
        from .evaluation.scoreboard import score_text

        for r in payload["policies"]:
            print(v2_summary(r))
        if any(payload["scores"].values()):
            print("score (mean over the critical columns of the speed relative to passive's, docs/results.md): "
                  + ", ".join(f"{name} {score_text(s)}" for name, s in payload["scores"].items()))  # fmt: skip
    return 0


def protocol_settings(args: argparse.Namespace):
    """The -v1 ids' protocol settings of ``--protocol``, ``--seed`` and (bogie evaluate) ``--quick``."""
    from .evaluation.stability_protocol import PROTOCOL_VERSION, Settings, screening_settings

    make = screening_settings if getattr(args, "quick", False) else Settings
    return make(version=args.protocol or PROTOCOL_VERSION, seed=args.seed, progress=True)


def _refuse_protocol_for_v0(args: argparse.Namespace) -> None:
    if args.protocol is not None:
        raise ConfigError(f"--protocol {args.protocol} chooses the -v1 ids' protocol; -v0 ids run protocol v1")
    if getattr(args, "quick", False):
        raise ConfigError("--quick is a screening run of the -v1 ids' protocol; -v0 ids run protocol v1")


def with_substeps(env_config: dict, n_sub: int | None) -> dict:
    """``env_config`` with ``integration.n_sub`` set (None: unchanged, the env's own step)."""
    if n_sub is None:
        return env_config
    from bogie_env.envs.config import make_config, merge_config

    return make_config(merge_config(env_config, {"integration": {"n_sub": int(n_sub)}}))


def _requested_parts(args: argparse.Namespace, allowed: set[str], default: str) -> tuple[str, ...]:
    text = default if args.parts is None else args.parts
    requested = tuple(p.strip() for p in text.split(",") if p.strip())
    if not requested or set(requested) - allowed:
        raise ConfigError(f"--parts {text!r}: allowed parts are {', '.join(sorted(allowed))}")
    return requested


def _default_v2_parts() -> str:
    """critical, cost and margins; margins only where python-control (the [margins] extra) is installed."""
    import importlib.util

    if importlib.util.find_spec("control") is None:
        print("bogie evaluate: python-control is not installed, so the margins part is skipped "
              "(pip install 'bogie-env[margins]')", file=sys.stderr)  # fmt: skip
        return "critical,cost"
    return "critical,cost,margins"


def _evaluate_v2(args: argparse.Namespace, env_config: dict) -> list[dict]:
    """Protocol v2 (agents/evaluation/stability_protocol.py) for every --policy."""
    from .evaluation.results import evaluate_v2
    from .evaluation.stability_protocol import available_parts

    parts = _requested_parts(args, set(available_parts()), "critical" if args.quick else _default_v2_parts())
    store = Path(f"{args.out}.chunks") if args.out else None
    return evaluate_v2(args.policy, env_config, protocol_settings(args), parts, args.backend, args.address, args.workers,
                       store_dir=store, trusted=args.trust_policy)  # fmt: skip


def _evaluate_v1(args: argparse.Namespace, env_config: dict) -> list[dict]:
    """Protocol v1 (agents/evaluation/evaluate.py), unchanged, for the -v0 ids."""
    from .evaluation.results import evaluate_v1

    requested = _requested_parts(args, {"critical", "ramp", "effort", "robustness", "margins"}, "critical,ramp,effort,robustness")
    store = Path(f"{args.out}.chunks") if args.out else None
    return evaluate_v1(args.policy, env_config, requested, args.seed, args.backend, args.address, args.workers,
                       store_dir=store, progress=not args.json, trusted=args.trust_policy)  # fmt: skip


def _print_v1(results: list[dict]) -> None:
    from .evaluation.results import v1_summary

    for r in results:
        print(v1_summary(r))


@command("margins", "stability margins of a controller's loop (gain, phase, delay, disk) per speed and actuator")
@json_option
@argument("--out", default=None, help="write the JSON result here as well (atomically)")
@argument("--conicity", type=float, default=None,
          help="equivalent conicity lam of the plant (the v1 scenario's 'conicity'; default: the bogie's own, 0.025)")
@argument("--speeds", default="300,350,400,450,500", help="comma-separated speeds, km/h")
@argument("--env-config", default=None, help="env config YAML (default: the env's default_config)")
@argument("--env", default="Bogie/Hunting-v0",
          help="env id whose task the loop is (its variant; --env-config merges into it), e.g. Bogie/Hunting-v1: "
               "its sensor filters and loop delay enter the loop")
@argument("--trust-policy", action="store_true",
          help="allow loading a policy PATH: an SB3 model file is code (it unpickles) and runs with your rights")
@argument("--policy", action="append", required=True,
          help=POLICY_HELP)
@bogie_options
def cmd_margins(args: argparse.Namespace) -> int:
    try:
        import control  # noqa: F401
    except ModuleNotFoundError:
        print("bogie: error: python-control is not installed; it comes with the margins extra: "
              "pip install 'bogie-env[margins]'", file=sys.stderr)  # fmt: skip
        return 2
    from .design.margins import format_table, margins_table
    from .controllers.policies import load_policy

    from .design.margins import check_conicity

    env_config = env_config_from_args(args, _env_variant(args.env))
    try:
        check_conicity(args.conicity)
    except ConfigError as error:
        raise ConfigError(f"--conicity: {error}") from None
    try:
        speeds = [float(v) for v in args.speeds.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--speeds {args.speeds!r} must be comma-separated numbers (km/h)") from None
    from bogie_env.envs.config import MAX_SPEED_KMH, MIN_SPEED_KMH

    if not speeds or not all(MIN_SPEED_KMH <= v <= MAX_SPEED_KMH for v in speeds):  # False for NaN
        raise ConfigError(f"--speeds {args.speeds!r}: give one or more speeds in [{MIN_SPEED_KMH:g}, {MAX_SPEED_KMH:g}] km/h")
    from .evaluation.stability_protocol import policy_config

    # a controller told the conicity class is designed for --conicity, as the protocol tells it its column's
    policy_env = env_config if args.conicity is None else policy_config(env_config, env_config["observation"]["type"], args.conicity)
    results = []
    for spec in args.policy:
        policy = load_policy(spec, policy_env, args.trust_policy)
        results.append({"policy": spec, "margins": margins_table(policy, env_config, speeds, conicity=args.conicity)})
    payload = {"env_id": args.env, "env_version": args.env.rsplit("-", 1)[-1], "policies": results}
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(payload, indent=2, default=float))
    if args.json:
        print_json(payload)
    else:
        for r in results:
            print(f"{r['policy']}:")
            print(format_table(r["margins"]))
    return 0


@command("results", "evaluate several controllers; write results.json and table.md (v1 env: protocol v2; v0: plots too)")
@argument("--resume", action="store_true",
          help="keep controllers already in OUT/results.json (run at the same --n-sub); v1: run only the parts they lack")
@argument("--seed", type=SEED, default=0, help="seed of the protocol's random starts and tracks")
@argument("--protocol", type=int, choices=(2, 3), default=None, help=PROTOCOL_HELP + "; written into results.json")
@argument("--n-sub", type=bounded(int, 1, 1000), default=None,
          help="RK4 substeps per env step for every run (default: the env's own step; v1: 10); written into "
               "results.json (integration_n_sub) and below the table")
@argument("--env-config", default=None)
@argument("--env", default="Bogie/Hunting-v1",
          help="env id (its version picks the protocol: -v1 ids protocol v2 with critical, cost, margins, curving, "
               "ramp_down and ramp_down_ideal; -v0 ids protocol v1 with the ramp plots)")
@argument("--out", required=True, help="output folder, e.g. docs/results")
@argument("--docs", action="append", default=[], metavar="FILE",
          help="markdown file whose generated blocks (<!-- results:NAME OUT/results.json -->) to refresh from "
               "OUT/results.json; repeatable (v1 env)")
@argument("--render-only", action="store_true",
          help="run nothing: rewrite OUT/results.json's scores, table.md, table_full.md, the figure and the --docs "
               "blocks from the existing OUT/results.json (v1 env)")
@argument("--curves", action="append", default=[], metavar="NAME=GLOB",
          help="also draw OUT/learning_curves.png (and .json) from training runs' eval/evaluations.npz: per NAME the "
               "mean and min-max over its run folders (one per training seed), e.g. "
               "ppo_scratch_v1='runs/ppo_scratch_v1/seed_*'; repeatable; without --policy nothing else is run")
@(lambda func: policy_options(func, required=False))
@backend_options
@bogie_options
def cmd_results(args: argparse.Namespace) -> int:
    from .evaluation.results import run, run_v2

    if args.curves:
        from .training.learning_curves import write_curves

        print_json(write_curves(args.curves, Path(args.out)))
        if not args.policy and not args.render_only:
            return 0
    if args.render_only:
        from .evaluation.scoreboard import render

        if args.env.rsplit("-", 1)[-1] == "v0":
            raise ConfigError("--render-only renders protocol v2's results (the -v1 ids)")
        json_path = Path(args.out) / "results.json"
        if not json_path.is_file():
            raise ConfigError(f"--render-only: {str(json_path)!r} does not exist; run bogie results without it first")
        render(json_path, [Path(d) for d in args.docs])
        print((Path(args.out) / "table.md").read_text())
        return 0
    if not args.policy:
        raise ConfigError("bogie results: give at least one --policy (or --render-only)")
    check_backend_args(args)
    _check_workers(args)
    env_config = with_substeps(env_config_from_args(args, _env_variant(args.env)), args.n_sub)
    if args.env.rsplit("-", 1)[-1] == "v0":
        _refuse_protocol_for_v0(args)
        if args.n_sub is not None:
            raise ConfigError("--n-sub sets protocol v2's step (the -v1 ids); protocol v1 keeps the -v0 ids' own step")
        payload = run(args.policy, env_config, Path(args.out), args.resume, args.seed, trusted=args.trust_policy,
                      backend=args.backend, address=args.address, workers=args.workers)  # fmt: skip
    else:
        payload = run_v2(args.policy, env_config, Path(args.out), args.resume, args.seed, trusted=args.trust_policy,
                         backend=args.backend, address=args.address, workers=args.workers,
                         settings=protocol_settings(args), docs=tuple(Path(d) for d in args.docs))  # fmt: skip
    print((Path(args.out) / "table.md").read_text())
    return 0 if payload else 1


def _check_workers(args: argparse.Namespace) -> None:
    if args.workers is not None and (args.backend != "ray" or args.address is not None):
        raise ConfigError(f"--workers {args.workers} sizes the local Ray cluster of --backend ray (without --address); "
                          "the local backend evaluates in this process")  # fmt: skip
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers} must be >= 1")


def main(argv: Sequence[str] | None = None) -> int:
    """The ``bogie`` command line (the console script is :mod:`bogie_agents.__main__`)."""
    try:
        return library_cli.main(argv)
    except ModuleNotFoundError as error:
        if (error.name or "").split(".")[0] not in AGENTS_EXTRA:
            raise
        print(f"bogie: error: {error.name} is not installed; it comes with the agents extra: "
              f"pip install 'bogie-env[agents]'", file=sys.stderr)  # fmt: skip
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
