"""The per-seed envelope of several controllers in one protocol column: what a selector that
picked, for every seed, the best of them (told which is best, so better than any real switch)
would score.

The protocol's column value is the lowest of its seeds. Controllers fail different seeds in
different ways (hunting, measured by the frame acceleration, or track-forced flange contact), so
the envelope asks whether switching between existing designs could reach a floor at all, or
whether a new design is needed. It reads the per-seed values of ``docs/results/v1/results.json``
and runs nothing.

    python studies/per_seed_envelope.py --column by_conicity/0.1 --policy lqg_rate --policy adaptive_lqg_rate --policy robust_steering
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from bogie_env.params import ConfigError

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results" / "v1" / "results.json"


def column_of(row: dict, column: str) -> dict:
    """The column ``column`` ("by_conicity/0.1", "worst_case", ...) of one policy's results."""
    value = row
    for key in column.split("/"):
        if not isinstance(value, dict) or key not in value:
            raise ConfigError(f"--column {column!r}: {row['policy']!r} has no {key!r}; allowed: a path such as by_conicity/0.1")
        value = value[key]
    if "per_seed_kmh" not in value:
        raise ConfigError(f"--column {column!r} is not a protocol column with per-seed values")
    return value


def envelope(results: dict, column: str, policies: list[str]) -> dict:
    """Per seed, the best of ``policies`` and which one it is; the envelope's column value."""
    rows = {row["policy"]: row for row in results["policies"]}
    unknown = [p for p in policies if p not in rows]
    if unknown:
        raise ConfigError(f"--policy {unknown}: not in the results; allowed: {', '.join(rows)}")
    columns = {p: column_of(rows[p], column) for p in policies}
    seeds = columns[policies[0]]["seeds"]
    if any(c["seeds"] != seeds for c in columns.values()):
        raise ConfigError(f"--column {column!r}: the policies were run on different seeds")
    best = [max(policies, key=lambda p: columns[p]["per_seed_kmh"][k]) for k in range(len(seeds))]
    per_seed = [columns[p]["per_seed_kmh"][k] for k, p in enumerate(best)]
    return {
        "column": column,
        "seeds": seeds,
        "policies": {p: {"kmh": c["kmh"], "per_seed_kmh": c["per_seed_kmh"], "worst_seed_fails_by": c.get("worst_seed_fails_by")}
                     for p, c in columns.items()},  # fmt: skip
        "envelope_per_seed_kmh": per_seed,
        "envelope_best_policy": best,
        "envelope_kmh": min(per_seed),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=Path, default=RESULTS, help="a results.json of `bogie results`")
    parser.add_argument("--column", default="by_conicity/0.1", help="the column, as a path in a policy's results")
    parser.add_argument("--policy", action="append", required=True, help="a policy of the results (repeat)")
    args = parser.parse_args()
    print(json.dumps(envelope(json.loads(args.results.read_text()), args.column, args.policy), indent=1))


if __name__ == "__main__":
    main()
