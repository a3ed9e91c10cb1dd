"""A distilled student's learning curve in the protocol: each DAgger iteration's closed-loop
critical speed per column, over training seeds (mean and range), beside its loop-penalty bound.

    python studies/distill_protocol_curve.py --run runs/A --run runs/B --run runs/C \\
        --columns conicity:0.1,conicity:0.2 --out runs/curve

Each ``--run`` is a ``bogie distill`` run folder (one per training seed); every iteration in its
``iterations/`` is run through the protocol's critical-speed part on seeds S..S+N-1 (``--seed``,
``--seeds``; default the protocol's 0-9). Writes ``OUT/protocol_curve.json`` (atomically, after
each iteration, merged under a lock so that calls with different ``--run`` can share one
``--out`` side by side; a second call resumes) and ``OUT/protocol_curve.png``, which draws the
iterations evaluated for every run (of ``--iterations`` when given).
The DAgger loss and the penalty's growth bound per iteration come from each run's
``progress.json``.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from bogie_env.envs.config import make_config
from bogie_env.fileio import write_text_atomic
from bogie_agents.evaluation.stability_protocol import Settings, columns_by_conicity, evaluate_policy_v2

DATA = "protocol_curve.json"
FIGURE = "protocol_curve.png"


def iterations_of(run: Path) -> list[Path]:
    folders = sorted(p for p in (run / "iterations").iterdir() if p.is_dir()) if (run / "iterations").is_dir() else []
    if not folders:
        raise SystemExit(f"--run {str(run)!r}: no iterations/NNN folders; allowed: a `bogie distill` run folder")
    return folders


def bound_per_iteration(run: Path) -> dict[int, float]:
    """The loop penalty's largest growth bound (1/s) after each iteration (``progress.json``)."""
    progress = json.loads((run / "progress.json").read_text())
    return {int(r["iteration"]) + 1: r["growth_bound_max_per_s"] for r in progress["iterations"]
            if r.get("growth_bound_max_per_s") is not None}  # fmt: skip


def locked_update(path: Path, change: Callable[[dict], None]) -> dict:
    """Apply ``change`` to the JSON at ``path`` (``{}`` when there is none) under a lock, since other
    calls may be writing other runs to it, write it atomically and return it."""
    folder = os.open(path.parent, os.O_RDONLY)  # the lock is on the folder: the file itself is replaced
    try:
        fcntl.flock(folder, fcntl.LOCK_EX)
        data = json.loads(path.read_text()) if path.exists() else {}
        change(data)
        write_text_atomic(path, json.dumps(data, indent=1))
    finally:
        os.close(folder)
    return data


def draw(data: dict, path: Path, wanted: set[int] | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = data["columns"]
    common = set.intersection(*(set(map(int, r["iterations"])) for r in data["runs"].values()))
    common = common if wanted is None else common & wanted
    fig, axes = plt.subplots(1, len(columns), figsize=(4.2 * len(columns), 3.4), squeeze=False)
    for ax, column in zip(axes[0], columns):
        table: dict[int, list[float]] = {}
        for run in data["runs"].values():
            for it, values in run["iterations"].items():
                if int(it) in common:
                    table.setdefault(int(it), []).append(values[column])
        its = sorted(table)
        v = [np.array(table[i]) for i in its]
        ax.fill_between(its, [x.min() for x in v], [x.max() for x in v], alpha=0.25, label=f"range, {len(data['runs'])} seeds")
        ax.plot(its, [x.mean() for x in v], "o-", label="mean")
        for name, reference in data.get("references", {}).items():
            if column in reference:
                ax.axhline(reference[column], ls="--" if name == "floor" else ":", lw=1, color="k" if name == "floor" else "gray",
                           label=name)  # fmt: skip
        ax.set_title(f"conicity {column}")
        ax.set_xticks(its)
        ax.set_xlabel("DAgger iteration")
        ax.set_ylabel("critical speed (km/h)")
        ax.grid(alpha=0.3)
    axes[0][-1].legend(fontsize=7, loc="lower right")
    fig.suptitle(f"Protocol critical speed per DAgger iteration (seeds {data['seed']}-{data['seed'] + data['seeds'] - 1})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, help="a `bogie distill` run folder (repeat: one per training seed)")
    parser.add_argument("--columns", default="conicity:0.1,conicity:0.2,conicity:0.3")
    parser.add_argument("--seed", type=int, default=0, help="first protocol seed (default 0: the protocol's seeds)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--iterations", default=None, help="comma-separated iteration numbers (default: all)")
    parser.add_argument("--reference", action="append", default=[], metavar="NAME=V,V,...",
                        help="a horizontal line per column, e.g. mpc=258.0,166.9,145.0 (drawn, not run)")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    columns = tuple(args.columns.split(","))
    labels = [c.split(":", 1)[1] if ":" in c else "0.025" for c in columns]
    wanted = None if args.iterations is None else {int(i) for i in args.iterations.split(",")}
    data_path = out / DATA
    references = {}
    for spec in args.reference:
        name, _, values = spec.partition("=")
        numbers = [float(v) for v in values.split(",")]
        if len(numbers) != len(labels):
            raise SystemExit(f"--reference {spec!r}: {len(numbers)} values for {len(labels)} columns; allowed: one per column")
        references[name] = dict(zip(labels, numbers))

    def start(data: dict) -> None:
        if data and (data["columns"] != labels or data["seed"] != args.seed or data["seeds"] != args.seeds):
            raise SystemExit(f"{data_path} holds columns {data['columns']} on seeds {data['seed']}+{data['seeds']}; "
                             f"allowed: the same arguments (resume) or another --out")  # fmt: skip
        for key, value in (("columns", labels), ("seed", args.seed), ("seeds", args.seeds), ("runs", {})):
            data.setdefault(key, value)
        data["references"] = references or data.get("references", {})

    data = locked_update(data_path, start)
    config = make_config(variant="v1")
    settings = Settings(seed=args.seed, seeds=args.seeds, columns=columns, progress=False)
    todo = [(Path(r), f) for r in args.run for f in iterations_of(Path(r)) if wanted is None or int(f.name) in wanted]
    todo = [(r, f) for r, f in todo if str(int(f.name)) not in data["runs"].get(str(r), {}).get("iterations", {})]
    t0 = time.monotonic()
    for k, (run, folder) in enumerate(todo):
        result = columns_by_conicity(evaluate_policy_v2(str(folder), config, settings, ("critical",)))
        values = {lam: result[lam]["kmh"] for lam in labels}

        def add(data: dict, run: Path = run, iteration: int = int(folder.name), values: dict = values) -> None:
            entry = data["runs"].setdefault(str(run), {"iterations": {}, "growth_bound_max_per_s": {}})
            entry["iterations"][str(iteration)] = values
            entry["growth_bound_max_per_s"] = {str(i): b for i, b in bound_per_iteration(run).items()}

        locked_update(data_path, add)
        elapsed = time.monotonic() - t0
        left = elapsed / (k + 1) * (len(todo) - k - 1)
        print(f"[{k + 1}/{len(todo)}] {folder}: {values} "
              f"({elapsed:.0f} s, about {left:.0f} s left)", file=sys.stderr, flush=True)  # fmt: skip
    command = " ".join(["python studies/distill_protocol_curve.py"] + sys.argv[1:])
    data = locked_update(data_path, lambda data: data.update(command=command))
    draw(data, out / FIGURE, wanted)
    print(json.dumps(data))


if __name__ == "__main__":
    main()
