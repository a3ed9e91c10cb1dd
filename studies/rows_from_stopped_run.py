"""Merge the finished parts of a stopped ``bogie results --backend ray`` run into its results.json.

    python studies/rows_from_stopped_run.py --out DIR [--docs README.md --docs docs/results.md]

``bogie results --backend ray`` keeps every finished (controller, part) task in ``DIR/chunks``
and writes ``DIR/results.json`` only when every task has finished. A part that takes hours
(for example `mpc`'s ramp-down parts: one QP per row and step over a 620-s ramp) can hold back
the parts that did finish. This script adds the finished tasks' results to ``DIR/results.json``
as ``bogie results`` would (a row keeps what it had; a part that did not finish stays absent,
and the table shows its columns empty), then renders the table, the figure and ``--docs``.

It refuses chunks that the current code did not compute (the store's code digest, the same as
``bogie results``' own) and chunks of a run at another step, seed or protocol version than the
rows already in ``DIR/results.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bogie_env.fileio import write_text_atomic
from bogie_agents.evaluation.evaluation_tasks import code_digest_v2, units_v2
from bogie_agents.evaluation.results import _check_same_run, _ordered, _results_folder, _v2_payload
from bogie_agents.evaluation.scoreboard import render


def finished_units(store: Path) -> tuple[dict, list[tuple[str, str, dict]]]:
    """The store's definition and its finished ``(spec, part, result)`` tasks, in task order
    (``evaluate_many_v2``'s: every part of the first controller, then the next)."""
    definition = json.loads((store / "study.json").read_text())["definition"]
    code = code_digest_v2()
    if definition["code"] != code:
        raise SystemExit(f"{store}: computed by other code (digest {definition['code']}, now {code}); not merged")
    todo = units_v2(list(definition["controllers"]), tuple(definition["parts"]))
    found = []
    for index, (spec, part) in enumerate(todo):
        path = store / f"chunk_{index:06d}.json"
        if path.is_file():
            (result,) = json.loads(path.read_text())["result"]
            found.append((spec, part, result))
    return definition, found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="the stopped run's --out folder")
    parser.add_argument("--docs", action="append", default=[], help="docs whose generated blocks to re-render")
    args = parser.parse_args(argv)
    out = Path(args.out)
    json_path, rows = _results_folder(out, resume=True)
    stores = sorted(p.parent for p in (out / "chunks").glob("*/study.json"))
    if not stores:
        raise SystemExit(f"{out / 'chunks'}: no stored tasks")
    for store in stores:
        definition, found = finished_units(store)
        settings = definition["settings"]
        if json_path.is_file():
            _check_same_run(json_path, definition["env_config"]["integration"]["n_sub"], settings["seed"], settings["version"])
        for spec, part, result in found:
            rows[spec] = {**rows.get(spec, {}), **result, "policy": spec}
            print(f"{spec}: {part} merged from {store.name}", file=sys.stderr)
    write_text_atomic(json_path, _v2_payload(_ordered(rows, list(rows)), definition["env_config"]["integration"]["n_sub"],
                                             settings["seed"], settings["version"]))  # fmt: skip
    render(json_path, [Path(d) for d in args.docs])
    print((out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
