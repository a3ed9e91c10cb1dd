"""Choose a distilled student's iteration on validation seeds (not the protocol's).

    python studies/distill_select.py --run runs/distill_v1 [--seed 1000] [--first 4]
    python studies/distill_select.py --run runs/distill_residual_v1 --rule loop-bound

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="the distill run folder (bogie distill --out)")
    parser.add_argument("--seed", type=int, default=1000, help="first validation seed (the protocol uses 0-9)")
    parser.add_argument("--first", type=int, default=4, help="the first iteration to consider")
    parser.add_argument("--rule", choices=("screening", "loop-bound"), default="screening",
                        help="screening: best validation score no worse than passive; loop-bound: last iteration with every penalised loop bound <= the limit")
    args = parser.parse_args(argv)
    run = Path(args.run)
    if args.rule == "loop-bound":
        return select_by_loop_bound(run, args.first)
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
