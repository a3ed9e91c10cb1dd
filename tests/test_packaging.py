"""Packaging and layering: what each import pulls in, checked in fresh interpreters.

The library (``bogie_env``) stands alone: it never imports the application (``bogie_agents``)
or the agents' heavy dependencies (SB3, torch). Each check runs in a subprocess, because the
test process itself has imported everything by the time it runs.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

APPLICATION = ("bogie_agents", "stable_baselines3", "torch")


def fresh_interpreter_output(script: str, cwd=None) -> str:
    """The last line a fresh interpreter prints running ``script`` (which must succeed)."""
    done = subprocess.run([sys.executable, "-c", script], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-1]


def modules_after(code: str, tmp_path) -> set[str]:
    """Top-level module names loaded by a fresh interpreter after running ``code``."""
    script = code + "\nimport json, sys\nprint(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))\n"
    return set(json.loads(fresh_interpreter_output(script, tmp_path)))


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


@pytest.mark.slow  # compiles its own kernels cold (60-100 s on a clean clone): make test stays within 3 minutes
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


def test_importing_the_parameters_loads_neither_gymnasium_nor_numba_nor_the_env(tmp_path):
    loaded = modules_after("import bogie_env.params\nbogie_env.params.load_params()", tmp_path)
    assert not loaded & {"gymnasium", "numba", "scipy", "stable_baselines3", "torch"}


def test_ids_register_whichever_of_bogie_env_and_gymnasium_comes_first(tmp_path):
    check = (
        "ids = sorted(i for i in gym.registry if i.startswith('Bogie/'))\n"
        "from bogie_env.envs.registration import IDS\n"
        "assert ids == sorted(IDS), ids\n"
        "assert {'Bogie/Hunting-v0', 'Bogie/Hunting-v1', 'Bogie/HuntingPassive-v1', 'Bogie/HuntingRoute-v1'} <= set(ids)\n"
        "assert all(isinstance(gym.spec(i).entry_point, str) for i in ids)\n"
        "assert type(gym.__spec__.loader).__name__ == 'SourceFileLoader'\n"  # the hook left no trace
    )
    modules_after("import bogie_env\nimport gymnasium as gym\n" + check, tmp_path)
    modules_after("import gymnasium as gym\nimport bogie_env\n" + check, tmp_path)
    # a worker that only imports the package (Ray, RL Zoo's --gym-packages) and then makes by id
    loaded = modules_after("import bogie_env\nimport gymnasium as gym\ngym.make('Bogie/HuntingPassive-v0')", tmp_path)
    assert "bogie_env" in loaded


def test_a_users_config_merges_into_the_variant():
    import gymnasium as gym

    env = gym.make("bogie_env:Bogie/HuntingPassive-v0", config={"speed": {"accel": 0.1}})
    config = env.unwrapped.config
    assert config["speed"]["accel"] == 0.1
    assert {spec["mode"] for spec in config["actuators"].values()} == {"off"}
    assert env.unwrapped.channel_names == ()
    slow = gym.make("bogie_env:Bogie/HuntingSlowRamp-v0", config={"speed": {"end_kmh": 500.0}}).unwrapped.config
    assert slow["speed"]["accel"] == 0.1 and slow["speed"]["end_kmh"] == 500.0


def test_the_step_limit_follows_the_configured_ramp():
    import gymnasium as gym
    from gymnasium.wrappers import TimeLimit

    env = gym.make("bogie_env:Bogie/Hunting-v0", config={"speed": {"end_kmh": 850.0}})
    ramp_steps = (850.0 - 300.0) / 3.6 / 1.0 / 0.01
    assert env.unwrapped.max_episode_steps > ramp_steps
    wrapper = env
    while wrapper is not env.unwrapped:
        assert not isinstance(wrapper, TimeLimit) or wrapper._max_episode_steps > ramp_steps
        wrapper = wrapper.env
    # the env truncates itself at the end of a short ramp, and at an explicit TimeLimit
    short = gym.make("bogie_env:Bogie/Hunting-v0", config={"speed": {"start_kmh": 300.0, "end_kmh": 306.0, "accel": 5.0}})
    short.reset(seed=0)
    steps, truncated = 0, False
    while not truncated:
        _, _, terminated, truncated, info = short.step(short.action_space.sample() * 0)
        steps += 1
        assert not terminated and steps < 100
    assert abs(info["speed_kmh"] - 306.0) < 0.5 and abs(steps - 6.0 / 3.6 / 5.0 / 0.01) <= 2
    cut = gym.make("bogie_env:Bogie/Hunting-v0", max_episode_steps=5)
    cut.reset(seed=0)
    assert [cut.step(cut.action_space.sample() * 0)[3] for _ in range(5)] == [False] * 4 + [True]


def test_every_shipped_config_and_the_pretrained_policy_are_package_data():
    """A file under configs/ or agents/pretrained/ that no package-data pattern matches would be
    missing from a wheel (CI's non-editable smoke test checks the rest: .ci/run)."""
    from pathlib import Path

    import pytest

    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

    root = Path(__file__).resolve().parent.parent
    setup = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {package: Path(folder) for package, folder in setup["package-dir"].items()}

    def source_dir(package: str) -> Path:
        parts = package.split(".")
        for i in range(len(parts), 0, -1):
            if ".".join(parts[:i]) in folders:
                return root / folders[".".join(parts[:i])] / Path(*parts[i:])
        return root / Path(*parts)

    shipped = set()
    for package, patterns in setup["package-data"].items():
        assert package in setup["packages"], package
        for pattern in patterns:
            shipped |= {p for p in source_dir(package).glob(pattern) if p.is_file()}
    wanted = {p for folder in ("configs", "agents/pretrained") for p in (root / folder).rglob("*") if p.is_file()}
    wanted |= {root / "agents" / "controllers" / name for name in ("robust_gains.json", "robust_gains_stage1.json")}  # robust_damping's gain tables
    assert wanted and not wanted - shipped, sorted(str(p.relative_to(root)) for p in wanted - shipped)
    packaged = {package for package in setup["packages"]}
    for init in list((root / "bogie_env").rglob("__init__.py")) + list((root / "agents").rglob("__init__.py")):
        folder = init.parent.relative_to(root)
        name = ".".join(("bogie_agents",) + folder.parts[1:]) if folder.parts[0] == "agents" else ".".join(folder.parts)
        assert name in packaged, f"{name} ({folder}) is not in pyproject's packages"


def test_the_readme_lists_every_command_with_exactly_its_options():
    import argparse
    import re
    from pathlib import Path

    import bogie_agents.cli  # noqa: F401  (adds the agents' commands)
    from bogie_env import cli as library_cli

    parser = library_cli.build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    rows = dict(re.findall(r"^\| `([a-z-]+)` \| (.*) \|$", readme, re.MULTILINE))
    assert set(rows) == set(commands), sorted(set(rows) ^ set(commands))
    for name, sub in commands.items():
        options = {s for action in sub._actions for s in action.option_strings if s.startswith("--") and s != "--help"}
        assert set(re.findall(r"`(--[a-z-]+)`", rows[name])) == options, name


#: What the ``bogie curving`` steady state has no use for: the agents' stack, Gymnasium and the
#: env, plotting, the margins' and the distributed extras, and the scipy modules it no longer
#: imports (each costs a noticeable part of the command's start-up, docs/performance.md).
NOT_FOR_CURVING = ("stable_baselines3", "torch", "gymnasium", "matplotlib", "control", "ray", "optuna", "pandas",
                   "tensorboard", "tqdm", "rich", "scipy.optimize", "scipy.integrate", "bogie_env.envs.config",
                   "bogie_env.envs.hunting_env", "bogie_env.envs.task")  # fmt: skip


@pytest.mark.slow  # compiles its own kernels cold (60-100 s on a clean clone): make test stays within 3 minutes
def test_the_bogie_curving_command_imports_nothing_it_does_not_use(tmp_path):
    """The console script's steady-curving path (``bogie_agents.cli``, as ``bogie`` runs it)."""
    script = (
        "import contextlib, io, json, sys\n"
        "from bogie_agents.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    code = main(['curving', '--radius', '7000', '--cant', '0.15', '--speed', '350', '--json'])\n"
        "assert code == 0 and json.loads(out.getvalue())['stable']\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    loaded = set(json.loads(fresh_interpreter_output(script, tmp_path)))
    unwanted = sorted(name for name in NOT_FOR_CURVING if name in loaded or any(m.startswith(name + ".") for m in loaded))
    assert not unwanted, unwanted
    assert "bogie_env.analysis.curving" in loaded  # the check ran the command, not an import error


#: A fresh interpreter's prelude that records the GC threshold when numpy is first imported.
GC_SPY = (
    "import builtins, contextlib, gc, io, sys\n"
    "seen = {}\n"
    "original = builtins.__import__\n"
    "def spy(name, *args, **kwargs):\n"
    "    if name.split('.')[0] == 'numpy' and 'numpy' not in sys.modules:\n"
    "        seen.setdefault('numpy', gc.get_threshold()[0])\n"
    "    return original(name, *args, **kwargs)\n"
    "builtins.__import__ = spy\n"
)
CURVING_ARGS = "['curving', '--radius', '7000', '--cant', '0.15', '--speed', '350', '--json']"


def test_the_bogie_script_tunes_the_gc():
    """The console script (``bogie_agents.__main__``) sets the young-generation GC threshold
    before numpy (and numba, and the package) load, where the default cost 0.1-0.2 s of ``bogie
    curving``, and freezes the collector's objects on the way out (docs/performance.md)."""
    script = GC_SPY + (
        "import bogie_agents.__main__ as script\n"
        f"sys.argv = ['bogie'] + {CURVING_ARGS}\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    code = script.main()\n"
        "print(code, seen['numpy'], script.GC_YOUNG_THRESHOLD, gc.get_threshold()[0], gc.get_freeze_count())\n"
    )
    code, at_numpy, constant, threshold, frozen = (int(v) for v in fresh_interpreter_output(script).split())
    assert code == 0 and at_numpy == constant == threshold > 700 and frozen > 10_000


def test_the_library_import_of_the_command_line_leaves_the_gc_alone():
    """Importing and calling ``bogie_agents.cli`` (tests, other programs) keeps the caller's GC
    threshold and freezes nothing."""
    script = GC_SPY + (
        "gc.set_threshold(123, 5, 5)\n"
        "import bogie_agents.cli as cli\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = cli.main({CURVING_ARGS})\n"
        "print(code, seen['numpy'], gc.get_threshold()[0], gc.get_freeze_count())\n"
    )
    code, at_numpy, threshold, frozen = (int(v) for v in fresh_interpreter_output(script).split())
    assert code == 0 and at_numpy == threshold == 123 and frozen == 0
