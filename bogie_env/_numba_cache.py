"""numba's disk cache, keyed on all the source a compiled kernel depends on.

numba keys each cached kernel on the file that defines it, not on the files whose functions
and constants it compiles in: after an edit to ``dynamics.py``, a kernel of ``envs/kernel.py``
would load stale machine code. So, when the package is imported, a hash of every module that
uses numba, and of every package module those import, is compared with the hash stored beside
the cache; when they differ, the package's cached kernels (``*.nbi``, ``*.nbc``) are deleted
and numba compiles afresh. This uses no numba API and costs a few milliseconds per import (it reads
and hashes the sources; kept lean: it runs at every start, e.g. of ``bogie curving``).

Cache folders are those numba writes to: ``__pycache__`` beside each source folder, or
``$NUMBA_CACHE_DIR/<folder>_<sha1 of its path>`` when that variable is set. (When the source
folder is read-only, numba uses a per-user folder instead; that one is checked too.)
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
from pathlib import Path

STAMP_NAME = "bogie-source.sha256"
_USES_NUMBA = re.compile(rb"^(from numba\b|import numba\b)", re.MULTILINE)  # at module level
# "from .a import b, c" on one line, or "from .a import (b,\n c)" across lines: a one-line import must
# not run into the next line, or the import on that line would be missed.
_RELATIVE_IMPORT = re.compile(rb"^[ \t]*from (\.+)([\w.]*) import (?:\(([^)]*)\)|([\w \t,]+))", re.MULTILINE)
_WORD = re.compile(r"\w+")


def _module_file(sources: dict[str, bytes], current: str, dots: int, dotted: str) -> str | None:
    """The package file (a key of ``sources``) that ``from <dots><dotted> import ...`` in
    ``current`` names, or None (a module outside the package, or not a source file)."""
    base = os.path.dirname(current)
    for _ in range(dots - 1):
        base = os.path.dirname(base)
    target = os.path.join(base, *dotted.split(".")) if dotted else base
    for candidate in (target + ".py", os.path.join(target, "__init__.py")):
        if candidate in sources:
            return candidate
    return None


def tracked_sources(package_dir: Path) -> list[Path]:
    """The modules that import numba at module level and, transitively, the package modules
    they import. (Plain strings, not Path objects, inside: this runs on every ``import bogie_env``.)"""
    sources = {str(path): path.read_bytes() for path in Path(package_dir).rglob("*.py")}
    todo = [path for path, text in sources.items() if b"numba" in text and _USES_NUMBA.search(text)]  # substring test first: faster
    tracked: set[str] = set()
    while todo:
        path = todo.pop()
        if path in tracked:
            continue
        tracked.add(path)
        for dots, dotted, grouped, names in _RELATIVE_IMPORT.findall(sources[path]):
            module = dotted.decode()
            names = grouped or names
            found = [_module_file(sources, path, len(dots), module)]
            for name in _WORD.findall(names.decode()):  # "from . import kernel" names modules
                found.append(_module_file(sources, path, len(dots), f"{module}.{name}" if module else name))
            todo += [f for f in found if f is not None]
    return sorted(Path(path) for path in tracked)


def source_hash(package_dir: Path, tracked: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in tracked:
        digest.update(path.relative_to(package_dir).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def cache_dirs(tracked: list[Path]) -> list[Path]:
    """Where numba caches the kernels of each source folder of ``tracked``."""
    folders = sorted({path.parent for path in tracked})
    out = []
    for folder in folders:
        if os.environ.get("NUMBA_CACHE_DIR"):
            out.append(Path(os.environ["NUMBA_CACHE_DIR"]) / _cache_subpath(folder))
        elif _writable(folder / "__pycache__"):
            out.append(folder / "__pycache__")
        else:  # numba falls back to a per-user folder
            from numba.misc.appdirs import AppDirs

            out.append(Path(AppDirs(appname="numba", appauthor=False).user_cache_dir) / _cache_subpath(folder))
    return out


def _cache_subpath(folder: Path) -> str:
    """numba's name for a source folder inside a cache root (``_CacheLocator.get_suitable_cache_subpath``)."""
    path = os.path.abspath(folder)
    return f"{os.path.basename(path)}_{hashlib.sha1(path.encode()).hexdigest()}"


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def ensure_fresh_cache(package_dir: Path) -> list[Path]:
    """Delete the package's cached kernels if its source changed since they were written.
    Returns the files deleted. Safe to run from several processes at once."""
    package_dir = Path(package_dir).resolve()
    tracked = tracked_sources(package_dir)
    current = source_hash(package_dir, tracked)
    deleted: list[Path] = []
    for folder in cache_dirs(tracked):
        stamp = folder / STAMP_NAME
        try:
            if stamp.read_text().strip() == current:
                continue
        except OSError:
            pass
        if not _writable(folder):
            continue
        for pattern in ("*.nbi", "*.nbc"):
            for path in folder.glob(pattern):
                try:
                    path.unlink()
                    deleted.append(path)
                except FileNotFoundError:
                    pass
        with tempfile.NamedTemporaryFile("w", dir=folder, delete=False, suffix=".tmp") as handle:
            handle.write(current + "\n")
        os.replace(handle.name, stamp)
    return deleted
