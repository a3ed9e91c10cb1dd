"""The cost of v1: env steps per second of Bogie/Hunting-v1 against -v0, at N=1 and N=4096, in one run.

Each case steps the task (``HuntingTask``, the compiled batch step both front-ends use) with
zero actions for at least ``--seconds`` after a warm-up, episodes reset in place when done.
v1 integrates with more substeps (accuracy criterion), adds the sensor model and the
scenario's actuator health; the ratio is the cost of those.

    python benchmarks/bench_v1.py
"""

from __future__ import annotations

import argparse

from bench_route import make_task, steps_per_second  # the same warm-up and stepping loop


def rate(variant: str | None, n: int, seconds: float) -> tuple[float, int]:
    """Env steps per second of ``variant`` at ``n`` rows, and its substeps per env step."""
    task = make_task(variant, n)
    return steps_per_second(task, seconds), task.n_sub


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 4096])
    args = parser.parse_args()
    print(f"{'N':>6} {'v0 steps/s':>12} {'v1 steps/s':>12} {'v0/v1':>6}  substeps v0, v1")
    for n in args.sizes:
        v0, sub0 = rate(None, n, args.seconds)
        v1, sub1 = rate("v1", n, args.seconds)
        print(f"{n:>6} {v0:>12.0f} {v1:>12.0f} {v0 / v1:>6.2f}  {sub0}, {sub1}", flush=True)


if __name__ == "__main__":
    main()
