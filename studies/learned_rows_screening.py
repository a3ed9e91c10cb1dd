"""The screening table of the learned v1 rows (docs/studies/learned_rows_v1.md).

Reads the ``bogie evaluate --quick --json --out DIR/NAME.json`` results in ``--screen DIR``
(``passive.json`` is the reference of the score: the same seeds, so the score is the one a
screening with passive among its policies gives) and prints one markdown row per policy: the
score and the critical speed (km/h) per conicity, of two degraded parts, the worst failed
actuator, 20 ms extra delay and the worst case.

    python studies/learned_rows_screening.py --screen runs/screen --rows baselines,ppo_v1_curves,ppo_memory_v1
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bogie_agents.evaluation.scoreboard import score
from bogie_env.params import ConfigError


def table(screen: Path, rows: list[str]) -> str:
    if not (screen / "passive.json").is_file():
        raise ConfigError(f"{str(screen / 'passive.json')!r} is missing: screen passive first (bogie evaluate --quick "
                          f"--policy passive --json --out {screen}/passive.json)")  # fmt: skip
    passive = json.loads((screen / "passive.json").read_text())["policies"][0]
    lams = list(passive["by_conicity"])
    heads = ["row", "run", "score", *(f"λ {lam}" for lam in lams), "Kpx −50 %", "creep −50 %",
             "one actuator failed (worst)", "delay 20 ms", "worst case"]  # fmt: skip
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for name in ["passive", *rows]:
        path = screen / f"{name}.json"
        if not path.is_file():
            raise ConfigError(f"--rows {name!r}: {str(path)!r} does not exist")
        for r in json.loads(path.read_text())["policies"]:
            s = score(r, passive)
            cols = [r["by_conicity"][lam]["kmh"] for lam in lams]
            cols += [r["degraded"]["Kpx-50%"]["kmh"], r["degraded"]["creep-50%"]["kmh"],
                     min(e["kmh"] for e in r["actuator_failed"].values()), r["delay_20ms"]["kmh"], r["worst_case"]["kmh"]]  # fmt: skip
            named = not Path(r["policy"]).exists()  # a controller name, not a run folder
            value = "—" if s is None else f"{'≥ ' if s['at_least'] else ''}{s['value']:.3f}"
            lines.append(f"| {r['policy'] if named else name} | {'—' if named else r['policy']} | {value} | "
                         + " | ".join(f"{c:.0f}" for c in cols) + " |")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--screen", default="runs/screen", help="folder of the screening JSON files")
    parser.add_argument("--rows", required=True, help="comma-separated NAMEs of NAME.json files, in table order")
    args = parser.parse_args()
    print(table(Path(args.screen), [r for r in args.rows.split(",") if r]))


if __name__ == "__main__":
    main()
