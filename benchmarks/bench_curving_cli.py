"""Warm wall and CPU time of ``bogie curving --radius 7000 --cant 0.15 --speed 350 --json``, beside
the floor any numba program pays on the same host.

    python benchmarks/bench_curving_cli.py [--runs 7] [--json] [--no-bytecode-cache]
    python benchmarks/bench_curving_cli.py --trees BEFORE_TREE AFTER_TREE [--runs 8]

The command runs as the ``bogie`` console script does (``python -m bogie_agents``, the installed
package: ``make`` installs this tree editable into .venv), once to warm the kernel cache, then
``--runs`` times. Warm includes Python's bytecode cache, as an installed package has it (pip
compiles it at install): both programs run with ``PYTHONDONTWRITEBYTECODE`` removed from their
environment, so the warm-up writes the tree's ``__pycache__/*.pyc`` (ignored by git, beside the
kernel cache). ``--no-bytecode-cache`` keeps the caller's environment instead: where
``PYTHONDONTWRITEBYTECODE`` is set and no ``.pyc`` exists yet, every run compiles the package's
sources again (about 0.05 s of this command); the output counts the ``.pyc`` files in
``bogie_env``. The floor is a fresh interpreter that imports numpy and numba and calls one trivial
cached ``@njit`` function: python, numpy, numba and numba's target set-up on its first
cached kernel (which imports ``scipy.linalg``), none of which the package can avoid. The two
alternate, so a busy host slows both alike; the ratio command / floor is the figure that carries
across hosts. Prints the median and minimum wall time, the child's user + system CPU
(``getrusage``) and the load average before and after.

``--trees BEFORE_TREE AFTER_TREE`` times the same command in two trees instead of against the
floor. Each tree is a plain checkout: the command runs with that tree's ``bogie_env`` and its
``agents/`` (linked as ``bogie_agents`` in a temporary folder) first on PYTHONPATH, ahead of any
installed copy, once in each tree to warm its kernel cache, then ``--runs`` times (default 8 here)
alternating between the trees (and which goes first), so a busy host slows both alike. Prints the
median and minimum wall time and the child's user and system CPU (``getrusage``) per tree.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TREE = Path(__file__).resolve().parent.parent
COMMAND = ["-m", "bogie_agents", "curving", "--radius", "7000", "--cant", "0.15", "--speed", "350", "--json"]
FLOOR_MODULE = "from numba import njit\n\n\n@njit(cache=True)\ndef one_more(x):\n    return x + 1.0\n"
FLOOR_CODE = ["-c", "import numpy\nfrom floor_kernel import one_more\none_more(1.0)\n"]


def run(args: list[str], env: dict[str, str], cwd: Path) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one ``python ARGS`` in a fresh interpreter."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], env=env, cwd=cwd, stdout=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def summary(times: list[tuple[float, float]]) -> dict:
    wall, cpu = zip(*times)
    return {"wall_median_s": round(statistics.median(wall), 3), "wall_min_s": round(min(wall), 3),
            "cpu_median_s": round(statistics.median(cpu), 3), "cpu_min_s": round(min(cpu), 3)}  # fmt: skip


def measure(runs: int, bytecode_cache: bool = True) -> dict:
    """Warm both, then time them alternately ``runs`` times each."""
    base_env = {k: v for k, v in os.environ.items() if not (bytecode_cache and k == "PYTHONDONTWRITEBYTECODE")}
    command_env = dict(base_env)
    with tempfile.TemporaryDirectory() as folder:
        floor_dir = Path(folder)
        (floor_dir / "floor_kernel.py").write_text(FLOOR_MODULE)
        floor_env = {k: v for k, v in base_env.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
        floor_env["PYTHONPATH"] = str(floor_dir)
        load_before = os.getloadavg()
        done = subprocess.run([sys.executable, *COMMAND], env=command_env, cwd=TREE, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"bench_curving_cli: the command failed:\n{done.stderr}")
        json.loads(done.stdout)  # warm-up run; its output must be one JSON object
        run(FLOOR_CODE, floor_env, floor_dir)  # compiles the trivial kernel once
        command, floor = [], []
        for i in range(runs):
            pair = [(command, COMMAND, command_env, TREE), (floor, FLOOR_CODE, floor_env, floor_dir)]
            for times, args, env, cwd in pair if i % 2 == 0 else pair[::-1]:
                times.append(run(args, env, cwd))
            print(f"bench_curving_cli: {i + 1}/{runs} runs of each", file=sys.stderr, end="\r")
        print(file=sys.stderr)
        load_after = os.getloadavg()
    result = {"command": "bogie " + " ".join(COMMAND[2:]), "runs": runs, "cpus": os.cpu_count(),
              "package_pyc_files": sum(1 for _ in (TREE / "bogie_env").rglob("__pycache__/*.pyc")),
              "load_average_1min": [round(load_before[0], 2), round(load_after[0], 2)],
              "command_s": summary(command), "numba_floor_s": summary(floor)}  # fmt: skip
    result["wall_median_ratio"] = round(result["command_s"]["wall_median_s"] / result["numba_floor_s"]["wall_median_s"], 3)
    result["cpu_median_ratio"] = round(result["command_s"]["cpu_median_s"] / result["numba_floor_s"]["cpu_median_s"], 3)
    return result


def tree_path(tree: str, links: Path) -> str:
    """PYTHONPATH for ``tree``: the tree (``bogie_env``) and a folder holding ``bogie_agents`` -> its ``agents/``."""
    folder = links / str(abs(hash(tree)))
    folder.mkdir(exist_ok=True)
    if not (folder / "bogie_agents").exists():
        (folder / "bogie_agents").symlink_to(Path(tree).resolve() / "agents")
    return os.pathsep.join([str(Path(tree).resolve()), str(folder)])


def run_in_tree(path: str) -> tuple[float, float, float]:
    """Wall, user and system seconds of one run of the command with one tree (``path``) on the path."""
    env = dict(os.environ, PYTHONPATH=path)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *COMMAND], env=env, stdout=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime


def compare_trees(trees: list[str], runs: int) -> None:
    """Warm both trees, time them interleaved, print one line per tree."""
    with tempfile.TemporaryDirectory() as links:
        paths = {tree: tree_path(tree, Path(links)) for tree in trees}
        for tree in trees:
            run_in_tree(paths[tree])
        times: dict[str, list[tuple[float, float, float]]] = {tree: [] for tree in trees}
        for round_ in range(runs):
            for tree in trees if round_ % 2 == 0 else trees[::-1]:  # alternate which tree goes first
                times[tree].append(run_in_tree(paths[tree]))
    for tree in trees:
        wall, user, system = zip(*times[tree])
        print(f"{tree}: wall median {statistics.median(wall):.3f} min {min(wall):.3f} s | user median "
              f"{statistics.median(user):.3f} min {min(user):.3f} s | sys median {statistics.median(system):.3f} s (n={runs})")  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=None, help="timed runs of each (after one warm-up; default 7, 8 with --trees)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--no-bytecode-cache", action="store_true",
                        help="keep the caller's PYTHONDONTWRITEBYTECODE (default: removed, so the warm-up writes .pyc files)")
    parser.add_argument("--trees", nargs=2, metavar=("BEFORE_TREE", "AFTER_TREE"),
                        help="time the command in two checkouts against each other instead of against the floor")
    args = parser.parse_args(argv)
    if args.runs is None:
        args.runs = 8 if args.trees else 7
    if args.runs < 1:
        parser.error(f"--runs {args.runs} must be >= 1")
    if args.trees:
        compare_trees(args.trees, args.runs)
        return
    result = measure(args.runs, bytecode_cache=not args.no_bytecode_cache)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    for label, key in (("command", "command_s"), ("numba floor", "numba_floor_s")):
        s = result[key]
        print(f"{label:12s} wall median {s['wall_median_s']:.3f} s (min {s['wall_min_s']:.3f}), "
              f"CPU median {s['cpu_median_s']:.3f} s (min {s['cpu_min_s']:.3f})")  # fmt: skip
    print(f"command / floor: wall {result['wall_median_ratio']:.2f}, CPU {result['cpu_median_ratio']:.2f}; "
          f"load average {result['load_average_1min'][0]} -> {result['load_average_1min'][1]} on {result['cpus']} CPUs; "
          f"{result['package_pyc_files']} .pyc files in bogie_env")  # fmt: skip


if __name__ == "__main__":
    main()
