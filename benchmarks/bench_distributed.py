"""Scaling of the Ray backend against the local one, measured in one run, and a cluster projection.

    python benchmarks/bench_distributed.py sensitivity   # bogie sensitivity --all: local, Ray with 1 and 2 CPUs
    python benchmarks/bench_distributed.py evaluate      # bogie evaluate (a controller table): the same
    python benchmarks/bench_distributed.py overhead      # Ray's cost per task and the work per study point
    python benchmarks/bench_distributed.py project --overhead-json OVERHEAD.json   # a 64-node cluster, simulated
    python benchmarks/bench_distributed.py screening [--full pretrained]   # bogie evaluate --quick (and the full protocol), local

Each backend runs as the user runs it: one ``bogie`` command in a fresh process (Ray's start-up
included), timed from outside, with its output compared byte for byte against the local
backend's. The projection simulates a list schedule of chunks on P workers fed by one driver:
the driver hands out one task every ``driver_s`` seconds, each task costs ``task_s`` on its worker
on top of its work (points x ``point_s``), and the cluster's start-up ``init_s`` comes first.
"""

from __future__ import annotations

import argparse
import heapq
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
POINTS = 16065  # the full Section-5 study


def bogie(*args: str) -> tuple[float, str]:
    """Run one ``bogie`` command in a fresh process; wall time and stdout."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bogie_agents", *args], capture_output=True, text=True, cwd=ROOT)
    elapsed = time.perf_counter() - start
    if done.returncode:
        raise SystemExit(f"bogie {' '.join(args)} failed:\n{done.stderr[-3000:]}")
    return elapsed, done.stdout


BACKENDS = {"local": [], "ray, 1 CPU": ["--backend", "ray", "--workers", "1"], "ray, 2 CPUs": ["--backend", "ray", "--workers", "2"]}


def bench_sensitivity(args) -> dict:
    rows, reference = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for name, extra in BACKENDS.items():
            out = Path(tmp) / name.replace(" ", "").replace(",", "_")
            wall, stdout = bogie("sensitivity", "--all", "--json", "--out", str(out), *extra)
            study = (out / "sensitivity.json").read_bytes()
            reference = reference or study
            rows.append({"backend": name, "command": f"bogie sensitivity --all --json --out DIR {' '.join(extra)}".strip(),
                         "wall_s": round(wall, 2), "study_s": json.loads(stdout)["wall_time_s"],
                         "identical_to_local": study == reference})  # fmt: skip
    local = rows[0]["wall_s"]
    for row in rows:
        row["ratio_to_local"] = round(row["wall_s"] / local, 3)
    return {"benchmark": "sensitivity --all (16,065 critical speeds)", "cpus": os.cpu_count(), "load_before": os.getloadavg(), "rows": rows}


def bench_evaluate(args) -> dict:
    policies = [item for spec in args.policy for item in ("--policy", spec)]
    rows, reference = [], None
    for name, extra in BACKENDS.items():
        wall, stdout = bogie("evaluate", *policies, "--parts", args.parts, "--json", *extra)
        reference = reference or stdout
        rows.append({"backend": name, "command": f"bogie evaluate {' '.join(policies)} --parts {args.parts} --json {' '.join(extra)}".strip(),
                     "wall_s": round(wall, 2), "identical_to_local": stdout == reference})  # fmt: skip
    local = rows[0]["wall_s"]
    for row in rows:
        row["ratio_to_local"] = round(row["wall_s"] / local, 3)
    return {"benchmark": "evaluate", "cpus": os.cpu_count(), "load_before": os.getloadavg(), "rows": rows}


def _noop(_shared, chunk):
    return chunk


def bench_overhead(args) -> dict:
    from bogie_env import distributed as dist
    from bogie_env.analysis import sensitivity as sens
    from bogie_env.params import BogieParams

    params = BogieParams.paper()
    start = time.perf_counter()
    dist.init_ray(None, 2)
    init_s = time.perf_counter() - start
    dist.map_chunks(_noop, [[i] for i in range(50)], backend="ray", progress=False)  # workers up
    n = args.tasks
    start = time.perf_counter()
    dist.map_chunks(_noop, [[i] for i in range(n)], backend="ray", progress=False)
    per_task = (time.perf_counter() - start) / n
    tasks = [(params, {"Csy": 0.5 + i / args.points, "Kpz": 1.0}, False) for i in range(args.points)]
    sens.run_tasks(tasks[:8], workers=1, progress=False)  # compiled
    start = time.perf_counter()
    sens.run_tasks(tasks, workers=1, progress=False)
    per_point = (time.perf_counter() - start) / args.points
    return {"benchmark": "overhead", "ray_init_s": round(init_s, 2), "tasks": n,
            "ray_s_per_empty_task_2cpus": round(per_task, 5), "points": args.points,
            "s_per_point_one_core": round(per_point, 5), "load_before": os.getloadavg()}  # fmt: skip


def simulate(points: int, chunk: int, workers: int, point_s: float, task_s: float, driver_s: float, init_s: float) -> float:
    """Makespan of a greedy list schedule: chunks go to the first free worker, one dispatch per ``driver_s``."""
    sizes = [min(chunk, points - i) for i in range(0, points, chunk)]
    free = [0.0] * workers
    heapq.heapify(free)
    end = 0.0
    for k, size in enumerate(sizes):
        start = max(heapq.heappop(free), (k + 1) * driver_s)
        finish = start + task_s + size * point_s
        heapq.heappush(free, finish)
        end = max(end, finish)
    return init_s + end


def bench_project(args) -> dict:
    measured = json.loads(Path(args.overhead_json).read_text())
    point_s, task_s = measured["s_per_point_one_core"], measured["ray_s_per_empty_task_2cpus"] * 2  # a task's CPU time
    driver_s, init_s = measured["ray_s_per_empty_task_2cpus"], args.init_s
    out = {"benchmark": "projection", "workers": args.nodes * args.cpus_per_node, "nodes": args.nodes, "cpus_per_node": args.cpus_per_node, "point_s": point_s,
           "task_s": task_s, "driver_s": driver_s, "init_s": init_s, "studies": []}  # fmt: skip
    workers = args.nodes * args.cpus_per_node
    # overhead stops mattering once a chunk's work is >= 10 x task_s (< 10 % per task) and the
    # driver hands out tasks as fast as the workers finish them: chunk work >= workers x driver_s
    out["chunk_work_s_where_overhead_stops_mattering"] = round(max(10 * task_s, workers * driver_s), 3)
    for points in (POINTS, 21 * 21 * 36 * 16, 10**7):
        rows = []
        for chunk in (1, 4, 16, 64, 256, 1024, 4096, 16384):
            if chunk > points:
                continue
            makespan = simulate(points, chunk, workers, point_s, task_s, driver_s, init_s)
            ideal = points * point_s / workers  # perfect division of the work, no overhead
            rows.append({"chunk": chunk, "tasks": -(-points // chunk), "chunk_work_s": round(chunk * point_s, 4),
                         "makespan_s": round(makespan, 2), "compute_efficiency": round(ideal / (makespan - init_s), 3)})  # fmt: skip
        out["studies"].append({"points": points, "one_core_s": round(points * point_s, 1), "rows": rows})
    return out


def _timed(command: list[str]) -> dict:
    """Wall time of one command in a fresh process, with the load average before and after it."""
    before = os.getloadavg()[0]
    start = time.perf_counter()
    subprocess.run(command, capture_output=True, text=True, check=True)
    return {"command": " ".join(command[2:]), "seconds": round(time.perf_counter() - start, 1),
            "load_before": round(before, 2), "load_after": round(os.getloadavg()[0], 2), "cores": os.cpu_count()}  # fmt: skip


def bench_screening(args: argparse.Namespace) -> dict:
    """``bogie evaluate --quick --policy passive --policy pretrained`` (the screening run of
    protocol v3) and, with ``--full NAME``, the full protocol's default parts for one controller,
    on the local backend, as a user runs them (start-up, policy loading, cached kernels)."""
    bogie = [sys.executable, "-m", "bogie_agents"]
    out = {"screening": _timed(bogie + ["evaluate", "--quick", "--policy", "passive", "--policy", "pretrained", "--json"])}
    if args.full:
        out["full"] = _timed(bogie + ["evaluate", "--policy", args.full, "--json"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    sc = sub.add_parser("screening")
    sc.add_argument("--full", default=None, help="also time the full protocol (default parts) for this controller")
    sub.add_parser("sensitivity")
    ev = sub.add_parser("evaluate")
    ev.add_argument("--policy", action="append", default=None)
    ev.add_argument("--parts", default="critical,robustness")
    ov = sub.add_parser("overhead")
    ov.add_argument("--tasks", type=int, default=2000)
    ov.add_argument("--points", type=int, default=512)
    pr = sub.add_parser("project")
    pr.add_argument("--overhead-json", required=True)
    pr.add_argument("--nodes", type=int, default=64)
    pr.add_argument("--cpus-per-node", type=int, default=2)
    pr.add_argument("--init-s", type=float, default=10.0, help="cluster connection and worker start-up (s)")
    args = parser.parse_args()
    if args.what == "evaluate" and not args.policy:
        args.policy = ["passive", "skyhook", "lqr", "lqg"]
    result = {"sensitivity": bench_sensitivity, "evaluate": bench_evaluate, "overhead": bench_overhead,
              "project": bench_project, "screening": bench_screening}[args.what](args)  # fmt: skip
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
