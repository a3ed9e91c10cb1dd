"""The repository's script folders: ``benchmarks/`` times things, ``studies/`` measures results.

``benchmarks/`` holds at most 12 scripts, each timing something; the one-off studies live in
``studies/`` with an index (studies/README.md). Every ``benchmarks/NAME.py`` or ``studies/NAME.py``
that a doc, a docstring or a test names must exist, so a move cannot leave a dead command behind.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MAX_BENCHMARKS = 12
#: a path as a command or a doc names it: ``benchmarks/NAME.py`` or ``studies/NAME.py`` (not ``docs/studies/``)
SCRIPT_REF = re.compile(r"(?<![\w/.-])(benchmarks|studies)/(\w+)\.py\b")
SKIP_DIRS = {".git", ".venv", ".shim", "__pycache__", "build", "dist", ".pytest_cache", ".hypothesis"}
TEXT_SUFFIXES = {".md", ".py", ".toml", ".yaml", ".yml", ".cfg", ".txt", ".rst"}


def scripts(folder: str) -> list[str]:
    return sorted(p.name for p in (ROOT / folder).glob("*.py"))


def text_files(root: Path):
    """The tree's text files (docs, sources, configs, Makefile, CI), without caches and venvs."""
    for path in root.iterdir():
        if path.is_dir():
            if path.name not in SKIP_DIRS and not path.name.endswith(".egg-info"):
                yield from text_files(path)
        elif path.suffix in TEXT_SUFFIXES or path.name == "Makefile" or path.parent.name == ".ci":
            yield path


def dead_script_references(root: Path) -> list[str]:
    """``file: folder/NAME.py`` for every named script that does not exist under ``root`` (an
    upper-case name such as ``NAME`` is a placeholder; this file's own examples are left out)."""
    dead = []
    for path in text_files(root):
        if path == root / "tests" / Path(__file__).name:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue
        for folder, name in sorted(set(SCRIPT_REF.findall(text))):
            if not name.isupper() and not (root / folder / f"{name}.py").is_file():
                dead.append(f"{path.relative_to(root)}: {folder}/{name}.py")
    return dead


def test_benchmarks_hold_at_most_12_scripts():
    names = scripts("benchmarks")
    assert len(names) <= MAX_BENCHMARKS, (
        f"benchmarks/ holds {len(names)} scripts (at most {MAX_BENCHMARKS}, each timing something; "
        f"studies go to studies/ with a line in studies/README.md): {names}"
    )


def test_every_named_benchmark_or_study_script_exists():
    assert dead_script_references(ROOT) == []


def test_the_dead_reference_check_sees_a_missing_script(tmp_path):
    """The check itself: a doc naming a script that is not there is reported, docs/studies/ is not a script."""
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "benchmarks" / "bench_here.py").write_text('"""python benchmarks/bench_here.py"""\n')
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "x.md").write_text(
        "`python benchmarks/bench_here.py`, `python studies/gone.py --seeds 8`, docs/studies/step_convergence.md, "
        "`python studies/NAME.py`\n"
    )
    assert dead_script_references(tmp_path) == ["docs/x.md: studies/gone.py"]


def test_the_studies_index_lists_every_study_with_its_command():
    index = (ROOT / "studies" / "README.md").read_text()
    for name in scripts("studies"):
        assert f"`{name}`" in index and f"python studies/{name}" in index, f"studies/README.md lacks {name}"


def test_no_script_imports_a_script_of_the_other_folder():
    """A script runs as ``python FOLDER/NAME.py``: only its own folder is on the path, so a helper
    it imports from a sibling must sit in the same folder (or in the library)."""
    folders = {folder: {Path(n).stem for n in scripts(folder)} for folder in ("benchmarks", "studies")}
    for folder, own in folders.items():
        others = set().union(*(names for other, names in folders.items() if other != folder)) - own
        for name in scripts(folder):
            tree = ast.parse((ROOT / folder / name).read_text())
            imported = {alias.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
            imported |= {node.module.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module and not node.level}
            assert not imported & others, f"{folder}/{name} imports {sorted(imported & others)} from the other folder"
