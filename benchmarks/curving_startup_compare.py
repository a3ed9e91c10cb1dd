"""Warm wall and CPU time of ``bogie curving --radius 7000 --cant 0.15 --speed 350 --json`` in two trees.

    python benchmarks/curving_startup_compare.py BEFORE_TREE AFTER_TREE [RUNS]

Each tree is a plain checkout: the command runs with that tree's ``bogie_env`` and its ``agents/``
(linked as ``bogie_agents`` in a temporary folder) first on PYTHONPATH, ahead of any installed
copy, once in each tree to warm its kernel cache, then RUNS times (default 8)
alternating between the trees (and which goes first), so a busy host slows both alike. Prints the median and minimum
wall time and the child's user and system CPU (``getrusage``).
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMAND = ["-m", "bogie_agents", "curving", "--radius", "7000", "--cant", "0.15", "--speed", "350", "--json"]


def tree_path(tree: str, links: Path) -> str:
    """PYTHONPATH for ``tree``: the tree (``bogie_env``) and a folder holding ``bogie_agents`` -> its ``agents/``."""
    folder = links / str(abs(hash(tree)))
    folder.mkdir(exist_ok=True)
    if not (folder / "bogie_agents").exists():
        (folder / "bogie_agents").symlink_to(Path(tree).resolve() / "agents")
    return os.pathsep.join([str(Path(tree).resolve()), str(folder)])


def run(tree: str, path: str) -> tuple[float, float, float]:
    """Wall, user and system seconds of one run of the command with ``tree`` (``path``) on the path."""
    env = dict(os.environ, PYTHONPATH=path)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *COMMAND], env=env, stdout=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime


def main(argv: list[str]) -> None:
    """Warm both trees, time them interleaved, print one line per tree."""
    trees, runs = argv[:2], int(argv[2]) if len(argv) > 2 else 8
    with tempfile.TemporaryDirectory() as links:
        paths = {tree: tree_path(tree, Path(links)) for tree in trees}
        for tree in trees:
            run(tree, paths[tree])
        times: dict[str, list[tuple[float, float, float]]] = {tree: [] for tree in trees}
        for round_ in range(runs):
            for tree in trees if round_ % 2 == 0 else trees[::-1]:  # alternate which tree goes first
                times[tree].append(run(tree, paths[tree]))
    for tree in trees:
        wall, user, system = zip(*times[tree])
        print(f"{tree}: wall median {statistics.median(wall):.3f} min {min(wall):.3f} s | user median "
              f"{statistics.median(user):.3f} min {min(user):.3f} s | sys median {statistics.median(system):.3f} s (n={runs})")  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
