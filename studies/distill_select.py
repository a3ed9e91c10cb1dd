"""Choose a distilled student's iteration on validation seeds (not the protocol's).

    python studies/distill_select.py --run runs/distill_v1 [--seed 1000] [--first 4]
    python studies/distill_select.py --run runs/distill_residual_v1 --rule loop-bound
    python studies/distill_select.py --run runs/distill_residual_faults_v1 --rule margins

Students of neighbouring DAgger iterations can differ by hundreds of km/h in one column of the
protocol, so the student is chosen by evaluation, as an RL run keeps its best checkpoint. Every
iteration's student from ``--first`` on (``RUN/iterations/NNN``) runs the screening
(``bogie evaluate --quick``: 3 seeds, 3 worst-case draws, bisection to 4 km/h) with passive, on the
seeds from ``--seed`` (default 1000; the protocol's are 0-9). The chosen one has the highest
screening score among those no worse than passive in any column (when none is, the highest
score, and ``selection.json`` says ``eligible: false``); it is copied to ``RUN/selected``
and ``RUN/selection.json`` records every candidate's score and columns.

``--rule loop-bound`` (for a run trained with ``fit.loop_penalty``) evaluates nothing: it takes
the last iteration whose growth bound on every penalised loop (``progress.json``,
``growth_bound_max_per_s``) is at most the penalty's ``max_growth_per_s``, the iteration whose
linearised loops are certified to meet the margin floors. It costs seconds where the screening of
ten students costs about an hour on 2 cores.

``--rule margins`` takes the last iteration that meets issue 25's margin floors as ``bogie
margins`` computes them (exact, not a bound): every loop stable, gain margin at least
:data:`MIN_GAIN_MARGIN` and delay margin, of each loop and of all loops at once, at least
:data:`MIN_DELAY_MARGIN_S` beyond the v1 default, at 300-450 km/h on new wheels and 150-250 km/h
at conicity 0.1 (:data:`MARGIN_POINTS`); and, for a run trained with ``fault_points``, every
fault loop of the penalty (each actuator failed, half the creep) with a negative exact growth
rate. It checks the iterations from the last one back and stops at the first that passes, about
three minutes per iteration on 2 cores; ``RUN/selection.json`` records each checked
iteration's figures.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

from bogie_env.fileio import write_text_atomic


def columns(policy: dict) -> dict[str, float]:
    """Every critical column of a screening result, name -> km/h."""
    out = {f"lambda {k}": v["kmh"] for k, v in policy["by_conicity"].items()}
    for group in ("degraded", "actuator_failed"):
        out.update({f"{group} {k}": v["kmh"] for k, v in policy[group].items()})
    out.update({name: policy[name]["kmh"] for name in ("delay_20ms", "worst_case")})
    return out


def copy_selected(run: Path, iteration: int) -> Path:
    """Copy ``RUN/iterations/NNN`` to ``RUN/selected`` (replacing it) and return that folder."""
    target = run / "selected"
    if target.exists():
        shutil.rmtree(target)
    shutil.copytree(run / "iterations" / f"{iteration:03d}", target)
    return target


def select_by_loop_bound(run: Path, first: int) -> int:
    """Choose the last iteration from ``first`` on whose penalised loops' growth bounds are all within the limit."""
    progress = json.loads((run / "progress.json").read_text())["iterations"]
    config = json.loads((run / "student.json").read_text())["config"]
    penalty = config["fit"]["loop_penalty"]
    if penalty is None:
        raise SystemExit(f"{run}: trained without fit.loop_penalty; use --rule screening")
    from bogie_agents.training.loop_penalty import DEFAULTS

    limit = float({**DEFAULTS, **penalty}["max_growth_per_s"])
    rows = [{"iteration": r["iteration"] + 1, "growth_bound_max_per_s": r["growth_bound_max_per_s"]} for r in progress]
    for r in rows:
        print(f"iteration {r['iteration']:3d}: worst growth bound {r['growth_bound_max_per_s']:+.3f} 1/s")
    eligible = [r for r in rows if r["iteration"] >= first and r["growth_bound_max_per_s"] <= limit]
    if not eligible:
        raise SystemExit(f"{run}: no iteration from {first} on has every loop bound <= {limit} 1/s; none is selected")
    chosen = eligible[-1]["iteration"]
    target = copy_selected(run, chosen)
    write_text_atomic(run / "selection.json", json.dumps({"rule": "loop-bound", "limit_per_s": limit, "first": first, "chosen": chosen,
                                                        "candidates": rows}, indent=1) + "\n")  # fmt: skip
    print(f"chosen: iteration {chosen} -> {target}")
    return 0


#: issue 25's margin floors: where (conicity, km/h; None is the env's new wheels) and how much
MARGIN_POINTS = ((None, (300.0, 350.0, 400.0, 450.0)), (0.1, (150.0, 200.0, 250.0)))
MIN_GAIN_MARGIN = 2.0
MIN_DELAY_MARGIN_S = 0.010


def margin_figures(folder: Path) -> dict:
    """The figures the margins rule checks for one student folder, and whether it ``passes``."""
    from bogie_agents.controllers.distilled import load_student
    from bogie_agents.controllers.policies import load_policy
    from bogie_agents.design.margins import margins_table
    from bogie_agents.training.loop_penalty import LoopPenalty, check_penalty_config
    from bogie_env.envs.config import make_config

    env_config = make_config(variant="v1")
    policy = load_policy(str(folder), env_config)
    out: dict = {"points": [], "fault_growth_max_per_s": None}
    ok = True
    for conicity, speeds in MARGIN_POINTS:
        t = margins_table(policy, env_config, list(speeds), conicity=conicity)
        delays = [v for v in (t["delay_margin_s"], t["all_loops_delay_margin_s"]) if v is not None]  # None: no finite margin
        row = {"conicity": t["conicity"], "speeds_kmh": list(speeds), "unstable_at_kmh": t["unstable_at_kmh"],
               "gain_margin": t["gain_margin"], "delay_margin_s": t["delay_margin_s"],
               "all_loops_delay_margin_s": t["all_loops_delay_margin_s"]}  # fmt: skip
        ok &= not t["unstable_at_kmh"] and (t["gain_margin"] is None or t["gain_margin"] >= MIN_GAIN_MARGIN) \
            and all(v >= MIN_DELAY_MARGIN_S for v in delays)
        out["points"].append(row)
    student = load_student(folder)
    meta = json.loads((folder / "student.json").read_text())
    trained = meta["config"]["fit"].get("loop_penalty") or {}
    faults = trained.get("fault_points") or []
    if faults and student.residual:  # the run's own fault loops (its fault_points and fault_degraded)
        settings = check_penalty_config({**trained, "points": [faults[0]], "stable_points": []})
        penalty = LoopPenalty(student.frames, meta["residual"]["env_config"], settings)
        rates = penalty.growth_rates_of(student.network)
        worst = max(r for (_, _, kind, _), r in zip(penalty.named_rows(), rates) if kind == "faults")
        out["fault_growth_max_per_s"] = float(worst)
        ok &= worst < 0.0
    out["passes"] = bool(ok)
    return out


def _ms(seconds: float | None) -> str:
    return "none" if seconds is None else f"{1e3 * seconds:.1f} ms"


def describe_margins(row: dict) -> str:
    """One line of the figures :func:`margin_figures` found, per conicity, for the log."""
    parts = []
    for p in row["points"]:
        if p["unstable_at_kmh"]:
            parts.append(f"λ {p['conicity']}: unstable at {p['unstable_at_kmh']} km/h")
            continue
        gain = "none" if p["gain_margin"] is None else f"{p['gain_margin']:.2f}"
        parts.append(f"λ {p['conicity']}: gain {gain}, delay {_ms(p['delay_margin_s'])} / all loops {_ms(p['all_loops_delay_margin_s'])}")
    if row["fault_growth_max_per_s"] is not None:
        parts.append(f"fault loops' growth {row['fault_growth_max_per_s']:+.3f} 1/s")
    return "; ".join(parts)


def select_by_margins(run: Path, first: int, figures=margin_figures) -> int:
    """Choose the last iteration from ``first`` on that meets the margin floors (module docstring)."""
    iterations = sorted((int(p.name) for p in (run / "iterations").iterdir() if p.is_dir() and int(p.name) >= first), reverse=True)
    rows, chosen = [], None
    for k in iterations:
        row = {"iteration": k, **figures(run / "iterations" / f"{k:03d}")}
        rows.append(row)
        verdict = "meets the margin floors" if row["passes"] else "misses the margin floors"
        print(f"iteration {k:3d}: {verdict}; {describe_margins(row)}", flush=True)
        if row["passes"]:
            chosen = k
            break
    record = {"rule": "margins", "min_gain_margin": MIN_GAIN_MARGIN, "min_delay_margin_s": MIN_DELAY_MARGIN_S,
              "points": [[c, list(v)] for c, v in MARGIN_POINTS], "first": first, "chosen": chosen, "candidates": rows}  # fmt: skip
    write_text_atomic(run / "selection.json", json.dumps(record, indent=1, default=float) + "\n")
    if chosen is None:
        raise SystemExit(f"{run}: no iteration from {first} on meets the margin floors; none is selected")
    target = copy_selected(run, chosen)
    print(f"chosen: iteration {chosen} -> {target}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="the distill run folder (bogie distill --out)")
    parser.add_argument("--seed", type=int, default=1000, help="first validation seed (the protocol uses 0-9)")
    parser.add_argument("--first", type=int, default=4, help="the first iteration to consider")
    parser.add_argument("--rule", choices=("screening", "loop-bound", "margins"), default="screening",
                        help="screening: best validation score no worse than passive; loop-bound: last iteration with every "
                             "penalised loop bound <= the limit; margins: last iteration that meets the margin floors")
    args = parser.parse_args(argv)
    run = Path(args.run)
    if args.rule == "loop-bound":
        return select_by_loop_bound(run, args.first)
    if args.rule == "margins":
        return select_by_margins(run, args.first)
    candidates = sorted(p for p in (run / "iterations").iterdir() if p.is_dir() and int(p.name) >= args.first)
    if not candidates:
        raise SystemExit(f"{run / 'iterations'}: no iteration folder from {args.first} on")
    screen = run / "selection_screening.json"
    command = [sys.executable, "-m", "bogie_agents", "evaluate", "--quick", "--seed", str(args.seed), "--policy", "passive"]
    for c in candidates:
        command += ["--policy", str(c)]
    subprocess.run(command + ["--json", "--out", str(screen)], check=True, stdout=subprocess.DEVNULL)
    result = json.loads(screen.read_text())
    by_name = {p["policy"]: p for p in result["policies"]}
    passive = columns(by_name["passive"])
    rows = []
    for c in candidates:
        cols = columns(by_name[str(c)])
        below = [k for k, v in cols.items() if v < passive[k]]
        rows.append({"iteration": int(c.name), "score": result["scores"][str(c)]["value"], "below_passive": below, "columns_kmh": cols})
        print(f"iteration {int(c.name):3d}: score {rows[-1]['score']:.3f}, below passive in {below or 'no column'}")
    eligible = [r for r in rows if not r["below_passive"]]
    chosen = max(eligible or rows, key=lambda r: r["score"])
    target = copy_selected(run, chosen["iteration"])
    write_text_atomic(run / "selection.json", json.dumps({"rule": "screening", "command": " ".join(command), "seed": args.seed, "chosen": chosen["iteration"],
                                                        "eligible": bool(eligible), "candidates": rows, "passive_kmh": passive},
                                                       indent=1) + "\n")  # fmt: skip
    print(f"chosen: iteration {chosen['iteration']} -> {target}" + ("" if eligible else " (every candidate is below passive somewhere)"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
