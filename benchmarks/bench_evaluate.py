"""Wall time of a screening run and of the full protocol for one controller, with the host load.

    python benchmarks/bench_evaluate.py                  # bogie evaluate --quick --policy passive --policy pretrained
    python benchmarks/bench_evaluate.py --full pretrained  # also the full protocol v3 for one controller

Each command runs as a fresh process (start-up, policy loading and numba's cached kernels
included), as a user runs it. The load average before and after is printed beside each time,
because the machines are shared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time


def timed(command: list[str]) -> dict:
    before = os.getloadavg()[0]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    seconds = time.perf_counter() - start
    return {"command": " ".join(command[2:]), "seconds": round(seconds, 1), "load_before": round(before, 2),
            "load_after": round(os.getloadavg()[0], 2), "cores": os.cpu_count(), "stdout_chars": len(done.stdout)}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", default=None, help="also time the full protocol (default parts) for this controller")
    args = parser.parse_args()
    bogie = [sys.executable, "-m", "bogie_agents"]
    quick = timed(bogie + ["evaluate", "--quick", "--policy", "passive", "--policy", "pretrained", "--json"])
    print(json.dumps(quick))
    if args.full:
        print(json.dumps(timed(bogie + ["evaluate", "--policy", args.full, "--json"])))


if __name__ == "__main__":
    main()
