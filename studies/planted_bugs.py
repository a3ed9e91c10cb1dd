"""Plant deliberate physics bugs and record which tests catch each (docs/model.md, Section 10).

Each bug is one textual edit of a copy of the package in a temporary folder; the repository
itself is never touched. For each bug the script reports the critical speed and hunting
frequency the bugged code gives (``bogie critical-speed --json``) and, unless
``--no-tests``, which of the physics tests fail::

    python studies/planted_bugs.py                      # every bug, the physics tests
    python studies/planted_bugs.py --bug eq6_gyro_sign --no-tests   # one bug, speed only
    python studies/planted_bugs.py --list

Slow (a cold numba compile and the physics tests per bug, minutes each); not part of the test
suite. Output: a markdown table on stdout and ``--json PATH`` if given.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PHYSICS_TESTS = ("tests/test_params.py", "tests/test_contact.py", "tests/test_dynamics.py", "tests/test_oracles.py",
                 "tests/test_stability.py", "tests/test_contact_chain.py")  # fmt: skip
SLOW_PHYSICS_TESTS = ("tests/test_analysis.py", "tests/test_integrate.py")


@dataclass(frozen=True)
class Bug:
    name: str
    description: str
    path: str
    old: str
    new: str


BUGS = (
    Bug("hertz_one_body_modulus", "Hertz contact modulus of one body, E/(1 - nu^2), for two", "bogie_env/contact.py",
        "e_star = E / (2.0 * (1.0 - nu * nu))", "e_star = E / (1.0 - nu * nu)"),
    Bug("f11_x1.5", "lateral creep coefficient f11 x 1.5", "bogie_env/contact.py",
        '"f11": area * shear_modulus * c22,', '"f11": 1.5 * area * shear_modulus * c22,'),
    Bug("f11_x1.1", "lateral creep coefficient f11 x 1.1", "bogie_env/contact.py",
        '"f11": area * shear_modulus * c22,', '"f11": 1.1 * area * shear_modulus * c22,'),
    Bug("f22_x0.9", "spin creep coefficient f22 x 0.9", "bogie_env/contact.py",
        '"f22": area**2 * shear_modulus * c33,', '"f22": 0.9 * area**2 * shear_modulus * c33,'),
    Bug("f33_x0.9", "longitudinal creep coefficient f33 x 0.9", "bogie_env/contact.py",
        '"f33": area * shear_modulus * c11,', '"f33": 0.9 * area * shear_modulus * c11,'),
    Bug("f12_sign", "lateral/spin coefficient f12 (Kalker c23) with the wrong sign", "bogie_env/contact.py",
        '"f12": area**1.5 * shear_modulus * c23,', '"f12": -(area**1.5) * shear_modulus * c23,'),
    Bug("eq12_printed", "Eq. (12) as printed (bare 1.163 instead of 1.163 nu g)", "bogie_env/contact.py",
        "1.163 * v * g", "1.163"),
    Bug("conicity_x1.1", "conicity 10 % too large in the right-hand side", "bogie_env/dynamics.py",
        "    lam = p[P_LAM]\n", "    lam = 1.1 * p[P_LAM]\n"),
    Bug("wheelset_mass_x1.1", "wheelset mass 10 % too large in its equations", "bogie_env/dynamics.py",
        "    mw = p[P_MW]\n", "    mw = 1.1 * p[P_MW]\n"),
    Bug("ksx_at_b3", "secondary yaw spring at the damper arm b3 instead of b2", "bogie_env/dynamics.py",
        "2.0 * p[P_KSX] * p[P_B2] * p[P_B2]", "2.0 * p[P_KSX] * p[P_B3] * p[P_B3]"),
    Bug("no_gravitational_stiffness", "normal forces' lateral components (gravitational stiffness) lost",
        "bogie_env/dynamics.py", "lateral = Fy_l + Fy_r + Ny_l + Ny_r - flange", "lateral = Fy_l + Fy_r - flange"),
    Bug("eq6_gyro_sign", "Eq. (6) gyroscopic term with its printed sign", "bogie_env/dynamics.py",
        "            gyro * dpsi\n", "            -gyro * dpsi\n"),
    Bug("eq40_printed", "Eq. (40) as printed (Kpy L1 psib without the factor 2)", "bogie_env/dynamics.py",
        "spring_y = Kpy2 * (x[o] - yb - side * L1 * psib)", "spring_y = Kpy2 * (x[o] - yb) - p[P_KPY] * side * L1 * psib"),
    Bug("eq51_printed", "Eq. (51) as printed (Kpy, Cpy where Ksy, Csy belong)", "bogie_env/dynamics.py",
        "(frame_force - 2.0 * p[P_KSY] * yb - 2.0 * p[P_CSY] * dyb", "(frame_force - 2.0 * p[P_KPY] * yb - 2.0 * p[P_CPY] * dyb"),
    Bug("eq26_printed", "Eq. (26) saturated branch as printed (alpha = beta)", "bogie_env/contact.py",
        "    return 1.0 / beta\n", "    return beta\n"),
)  # fmt: skip


def plant(bug: Bug, into: Path) -> None:
    """Copy the package, tests and configs into ``into`` and apply the bug's edit."""
    for name in ("bogie_env", "tests", "configs", "agents"):
        if (ROOT / name).exists():
            shutil.copytree(ROOT / name, into / name, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    shutil.copy(ROOT / "pyproject.toml", into / "pyproject.toml")
    target = into / bug.path
    text = target.read_text()
    if text.count(bug.old) != 1:
        raise SystemExit(f"bug {bug.name}: the text to replace occurs {text.count(bug.old)} times in {bug.path}")
    target.write_text(text.replace(bug.old, bug.new))


def _env(tree: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    env["NUMBA_CACHE_DIR"] = str(tree / ".numba_cache")
    return env


def critical_speed(tree: Path) -> dict:
    run = subprocess.run([sys.executable, "-m", "bogie_env.cli", "critical-speed", "--json"], cwd=tree,
                         env=_env(tree), capture_output=True, text=True)  # fmt: skip
    if run.returncode != 0:
        return {"error": (run.stderr or run.stdout).strip().splitlines()[-1:]}
    data = json.loads(run.stdout)
    return {"critical_speed_kmh": data.get("critical_speed_kmh"), "frequency_hz": data.get("hunting_frequency_hz"),
            "status": data.get("status")}  # fmt: skip


def failing_tests(tree: Path, files: tuple[str, ...]) -> tuple[list[str], int]:
    report = tree / "junit.xml"
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={report}", *files],
                   cwd=tree, env=_env(tree), capture_output=True, text=True)  # fmt: skip
    failed, total = [], 0
    for case in ET.parse(report).getroot().iter("testcase"):
        if case.find("skipped") is not None:
            continue
        total += 1
        if case.find("failure") is not None or case.find("error") is not None:
            failed.append(f"{case.get('classname').split('.')[-1]}::{case.get('name')}")
    return failed, total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bug", action="append", help="run only this bug (repeatable); see --list")
    parser.add_argument("--list", action="store_true", help="list the bugs and exit")
    parser.add_argument("--no-tests", action="store_true", help="only the critical speed of each bugged model")
    parser.add_argument("--with-slow-files", action="store_true", help="also run test_analysis and test_integrate")
    parser.add_argument("--json", default=None, help="write the results to this JSON file")
    args = parser.parse_args(argv)
    if args.list:
        for bug in BUGS:
            print(f"{bug.name:28s} {bug.description}")
        return 0
    chosen = [b for b in BUGS if not args.bug or b.name in args.bug]
    unknown = set(args.bug or ()) - {b.name for b in BUGS}
    if unknown:
        parser.error(f"unknown --bug {', '.join(sorted(unknown))}; known: {', '.join(b.name for b in BUGS)}")
    files = PHYSICS_TESTS + (SLOW_PHYSICS_TESTS if args.with_slow_files else ())
    results = []
    start = time.monotonic()
    for k, bug in enumerate(chosen):
        with tempfile.TemporaryDirectory(prefix="planted_") as folder:
            tree = Path(folder)
            plant(bug, tree)
            row = {"bug": bug.name, "description": bug.description, **critical_speed(tree)}
            if not args.no_tests:
                row["failed"], row["tests_run"] = failing_tests(tree, files)
        results.append(row)
        if args.json:  # after every bug, so a long run that is stopped keeps what it measured
            Path(args.json).write_text(json.dumps({"test_files": list(files), "results": results}, indent=2))
        elapsed = time.monotonic() - start
        left = elapsed / (k + 1) * (len(chosen) - k - 1)
        print(f"[{k + 1}/{len(chosen)}] {bug.name}: {row.get('critical_speed_kmh')} km/h, "
              f"{len(row.get('failed', []))} failed; about {left / 60:.0f} min left", file=sys.stderr, flush=True)  # fmt: skip
    print("| bug | critical speed (km/h) | frequency (Hz) | tests that fail |")
    print("|---|---|---|---|")
    for row in results:
        speed = row.get("critical_speed_kmh")
        speed_text = f"{speed:.1f}" if isinstance(speed, (int, float)) else str(row.get("status") or row.get("error"))
        freq = row.get("frequency_hz")
        freq_text = f"{freq:.2f}" if isinstance(freq, (int, float)) else "-"
        caught = ", ".join(f"`{name}`" for name in row.get("failed", [])) or ("not run" if args.no_tests else "**none**")
        print(f"| {row['description']} (`{row['bug']}`) | {speed_text} | {freq_text} | {caught} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
