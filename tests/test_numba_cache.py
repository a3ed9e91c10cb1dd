"""The compiled-cache trap is closed: after an edit to any source a cached kernel compiles in,
the next run uses the new source (bogie_env/_numba_cache.py)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import bogie_env
from bogie_env import _numba_cache

REPO = Path(bogie_env.__file__).resolve().parent.parent


def run(code: str, *paths: Path) -> str:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(map(str, paths))}
    env.pop("NUMBA_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=paths[0], timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


@pytest.mark.slow  # 2.4-6 s warm: make test's 3 minutes on a clean clone
def test_a_kernel_sees_an_edit_of_a_function_it_inlines_from_another_module(tmp_path):
    """numba keys b.g's cache on b.py only; without the guard the second run prints 2.0."""
    package = tmp_path / "minipkg"
    package.mkdir()
    (package / "__init__.py").write_text(
        "from pathlib import Path\n"
        "from bogie_env._numba_cache import ensure_fresh_cache\n"
        "ensure_fresh_cache(Path(__file__).parent)\n"
    )
    (package / "a.py").write_text("from numba import njit\n\n@njit(cache=True)\ndef f():\n    return 1.0\n")
    (package / "b.py").write_text(
        "from numba import njit\nfrom .a import f\n\n@njit(cache=True)\ndef g():\n    return f() + 1.0\n"
    )
    code = "from minipkg.b import g; print(g())"
    assert run(code, tmp_path, REPO) == "2.0"
    cached = sorted(p.name for p in (package / "__pycache__").glob("b.g-*.nbi"))
    assert cached
    assert run(code, tmp_path, REPO) == "2.0"  # unchanged source: the cache is kept
    assert sorted(p.name for p in (package / "__pycache__").glob("b.g-*.nbi")) == cached
    (package / "a.py").write_text("from numba import njit\n\n@njit(cache=True)\ndef f():\n    return 10.0\n")
    assert run(code, tmp_path, REPO) == "11.0"


def test_importing_bogie_env_drops_kernels_compiled_from_other_source(tmp_path):
    copy = tmp_path / "bogie_env"
    shutil.copytree(Path(bogie_env.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    sources = _numba_cache.tracked_sources(copy)
    tracked = {p.relative_to(copy).as_posix() for p in sources}
    assert {"contact.py", "dynamics.py", "integrate.py", "params.py"} <= tracked  # params: compiled-in constants
    uses_numba = {p.relative_to(copy).as_posix() for p in copy.rglob("*.py") if "\nfrom numba import" in p.read_text()}
    assert uses_numba and uses_numba <= tracked
    assert "cli.py" not in tracked and "envs/hunting_env.py" not in tracked

    def plant() -> list[Path]:
        files = [folder / "__pycache__" / f"kernel.step-{i}.py311.{suffix}"
                 for i, folder in enumerate(sorted({p.parent for p in sources})) for suffix in ("nbi", "nbc")]  # fmt: skip
        for path in files:
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(b"machine code")
        return files

    code = "import sys, bogie_env; assert 'numba' not in sys.modules"
    files = plant()
    run(code, tmp_path)  # no stamp yet: the cache's source is unknown
    assert not any(p.exists() for p in files)
    files = plant()
    run(code, tmp_path)  # same source: kept
    assert all(p.exists() for p in files)
    with (copy / "contact.py").open("a") as handle:  # a module the kernels compile in
        handle.write("\n# edited\n")
    run(code, tmp_path)
    assert not any(p.exists() for p in files)
    files = plant()
    with (copy / "cli.py").open("a") as handle:  # not compiled in: no recompilation
        handle.write("\n# edited\n")
    run(code, tmp_path)
    assert all(p.exists() for p in files)


def test_tracked_sources_follow_every_relative_import_form(tmp_path):
    """One-line imports on consecutive lines, a parenthesised import across lines with a comment,
    and ``from . import module``: each imported package module is tracked."""
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "kernel.py").write_text(
        "from numba import njit\n"
        "from .a import x\n"
        "from .b import y\n"
        "from .c import (\n    z,  # a comment\n    w,\n)\n"
        "from . import d\n"
        "from .sub import e\n"
    )
    for name in ("a", "b", "c", "d", "unused"):
        (package / f"{name}.py").write_text("x = y = z = w = 1\n")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "e.py").write_text("")
    tracked = {p.relative_to(package).as_posix() for p in _numba_cache.tracked_sources(package)}
    assert tracked == {"kernel.py", "a.py", "b.py", "c.py", "d.py", "sub/__init__.py", "sub/e.py"}
