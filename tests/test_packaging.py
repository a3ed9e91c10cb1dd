"""Packaging and layering: what each import pulls in, checked in fresh interpreters.

The library (``bogie_env``) stands alone: it never imports the application (``bogie_agents``)
or the agents' heavy dependencies (SB3, torch). Each check runs in a subprocess, because the
test process itself has imported everything by the time it runs.
"""

from __future__ import annotations

import json
import subprocess
import sys

APPLICATION = ("bogie_agents", "stable_baselines3", "torch")


def modules_after(code: str, tmp_path) -> set[str]:
    """Top-level module names loaded by a fresh interpreter after running ``code``."""
    script = code + "\nimport json, sys\nprint(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def test_library_modules_import_neither_the_agents_nor_sb3_nor_torch(tmp_path):
    code = (
        "import importlib, pkgutil, bogie_env\n"
        "names = [m.name for m in pkgutil.walk_packages(bogie_env.__path__, 'bogie_env.')]\n"
        "assert len(names) > 15, names\n"
        "for name in names:\n"
        "    importlib.import_module(name)\n"
    )
    loaded = modules_after(code, tmp_path)
    assert not loaded & set(APPLICATION), sorted(loaded & set(APPLICATION))


def test_make_vec_imports_neither_sb3_nor_torch(tmp_path):
    code = (
        "import gymnasium as gym\n"
        "envs = gym.make_vec('bogie_env:Bogie/Hunting-v0', num_envs=2, vectorization_mode='vector_entry_point')\n"
        "envs.reset(seed=0)\n"
        "envs.step(envs.action_space.sample())\n"
    )
    loaded = modules_after(code, tmp_path)
    assert not loaded & {"stable_baselines3", "torch"}, sorted(loaded & {"stable_baselines3", "torch"})


def test_the_library_cli_has_no_agent_commands_and_the_bogie_script_adds_them():
    from bogie_agents import cli as agents_cli
    from bogie_env import cli as library_cli

    assert {"critical-speed", "reproduce"} <= set(library_cli.COMMANDS)
    assert {"train", "evaluate", "results"} <= set(library_cli.COMMANDS)  # added by importing bogie_agents.cli
    done = subprocess.run([sys.executable, "-m", "bogie_env.cli", "evaluate", "--policy", "passive"],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 2 and "invalid choice: 'evaluate'" in done.stderr
    assert agents_cli.main is not library_cli.main
