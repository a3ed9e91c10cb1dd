"""A chunked map with two backends: local processes, or tasks on a Ray cluster.

    results = map_chunks(func, chunks, shared=params, backend="ray", store=ChunkStore(out, definition))

``func(shared, chunk)`` is a module-level function that returns a JSON value (numbers, strings,
lists, dicts with string keys). Each chunk is one unit of scheduling: one process-pool job
(``backend="local"``) or one Ray task (``backend="ray"``). The results come back in chunk order
and do not depend on the backend, the number of workers or the order in which chunks finish.

Resume: with a :class:`ChunkStore`, each finished chunk's result is written atomically to a JSON
file in a folder named by a hash of the study's definition (the caller's description, the
function and every chunk). A rerun of the same study reads the finished chunks and computes only
the rest; a different study gets a different folder. Every result passes through JSON whether it
was computed or read back, so a resumed study returns exactly what a fresh one does.

The Ray backend uses plain Ray tasks: ``ray.remote`` with ``max_retries`` (a task whose worker
dies is re-run), ``ray.wait`` for progress, and one CPU per task. Each task runs single-threaded
numba and BLAS, so N workers use N cores. ``address=None`` starts a local cluster (or joins the one
this process already started); ``address="auto"`` or ``"HOST:6379"`` joins a running cluster
(docs/distributed.md). Ray is an optional extra: ``pip install -e '.[distributed]'``.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any, Callable, Sequence

from .fileio import write_text_atomic
from .params import ConfigError

BACKENDS = ("local", "ray")
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
DEFAULT_MAX_RETRIES = 3


def check_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ConfigError(f"backend {backend!r} is not allowed; allowed: {', '.join(BACKENDS)}")
    return backend


def require_ray():
    """The ``ray`` module, or an error that says how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError("backend 'ray' needs the optional extra: pip install -e '.[distributed]' (Ray and Optuna)") from None
    return ray


def init_ray(address: str | None = None, num_cpus: int | None = None):
    """Connect to a cluster (``address``: ``"auto"`` or ``HOST:PORT``) or start a new local one
    with ``num_cpus`` CPUs (default: all).

    A connection this process already has is reused as it is."""
    ray = require_ray()
    if not ray.is_initialized():
        # workers' output stays in Ray's session logs; a task's exception still reaches ray.get
        kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": "ERROR", "log_to_driver": False}
        if address is None:  # a new private cluster, even if `ray start` runs one on this machine
            address, kwargs["num_cpus"] = "local", num_cpus
        ray.init(address=address, **kwargs)
    return ray


def chunked(items: Sequence, size: int) -> list[list]:
    """``items`` in consecutive chunks of ``size`` (the last one shorter)."""
    if size < 1:
        raise ConfigError(f"chunk size {size!r} is not allowed; it must be an integer >= 1")
    return [list(items[i : i + size]) for i in range(0, len(items), size)]


def _canonical(value: Any) -> Any:
    """The value as JSON gives it back (tuples become lists, numpy scalars Python numbers);
    NaN and infinities are kept."""
    return json.loads(json.dumps(value, default=_json_default))


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):  # numpy scalars and arrays
        return value.tolist()
    raise TypeError(f"a chunk's result must be JSON data; got {type(value).__name__}")


class ChunkStore:
    """Finished chunks of one study, as ``<root>/<key>/chunk_<i>.json`` written atomically.

    ``definition`` is anything JSON-serialisable that fixes the study's results (inputs,
    settings, code version); together with the function name and the chunks it gives the key."""

    def __init__(self, root: str | Path, definition: Any) -> None:
        self.root = Path(root)
        self.definition = definition
        self.key: str | None = None

    def bind(self, func: Callable, chunks: Sequence) -> Path:
        text = json.dumps({"func": f"{func.__module__}.{func.__qualname__}", "definition": self.definition,
                           "chunks": list(chunks)}, sort_keys=True, default=repr)  # fmt: skip
        self.key = hashlib.sha256(text.encode()).hexdigest()[:20]
        folder = self.folder
        folder.mkdir(parents=True, exist_ok=True)
        manifest = folder / "study.json"
        if not manifest.exists():
            _write_atomic(manifest, json.dumps({"func": f"{func.__module__}.{func.__qualname__}", "n_chunks": len(chunks),
                                                "definition": self.definition}, indent=1, default=repr))  # fmt: skip
        return folder

    @property
    def folder(self) -> Path:
        if self.key is None:
            raise RuntimeError("ChunkStore.bind() has not been called")
        return self.root / self.key

    def _path(self, index: int) -> Path:
        return self.folder / f"chunk_{index:06d}.json"

    def load(self, index: int) -> tuple[bool, Any]:
        """``(True, result)`` for a finished chunk; ``(False, None)`` if absent or unreadable."""
        path = self._path(index)
        try:
            return True, json.loads(path.read_text())["result"]
        except (OSError, ValueError, KeyError):
            return False, None

    def save(self, index: int, result: Any) -> None:
        _write_atomic(self._path(index), json.dumps({"index": index, "result": result}, default=_json_default))


def _write_atomic(path: Path, text: str) -> None:
    write_text_atomic(path, text)


# ---- the local backend: a process pool (or this process) -----------------------------------
_SHARED: Any = None


def _init_local_worker(shared: Any) -> None:
    global _SHARED
    _SHARED = shared


def _run_local_chunk(func: Callable, chunk: list) -> Any:
    return _canonical(func(_SHARED, chunk))


def _run_local(func, chunks, todo, shared, workers, on_done) -> None:
    if workers == 1 or len(todo) <= 1:
        for i in todo:
            on_done(i, _canonical(func(shared, chunks[i])))
        return
    previous = {k: os.environ.get(k) for k in THREAD_VARS}
    os.environ.update({k: "1" for k in THREAD_VARS})  # the spawned workers inherit one thread each
    try:
        pool = ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_local_worker, initargs=(shared,))  # fmt: skip
    finally:
        for k, v in previous.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    with pool:
        pending = {pool.submit(_run_local_chunk, func, chunks[i]): i for i in todo}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                on_done(pending.pop(future), future.result())


# ---- the Ray backend: one task per chunk ------------------------------------------------------
def _run_ray_chunk(func: Callable, shared: Any, chunk: list) -> Any:
    import numba

    numba.set_num_threads(1)  # one core per task (Ray sets OMP_NUM_THREADS=1 for BLAS likewise)
    return _canonical(func(shared, chunk))


def _run_ray(func, chunks, todo, shared, address, workers, max_retries, on_done) -> None:
    ray = init_ray(address, workers)
    remote = ray.remote(_run_ray_chunk).options(num_cpus=1, max_retries=max_retries, retry_exceptions=False)
    shared_ref = ray.put(shared)
    pending = {remote.remote(func, shared_ref, chunks[i]): i for i in todo}
    try:
        while pending:
            finished, _ = ray.wait(list(pending), num_returns=1)
            for ref in finished:
                on_done(pending.pop(ref), ray.get(ref))
    finally:
        for ref in pending:
            ray.cancel(ref)


def map_chunks(
    func: Callable[[Any, list], Any],
    chunks: Sequence[list],
    *,
    shared: Any = None,
    backend: str = "local",
    address: str | None = None,
    workers: int | None = None,
    store: ChunkStore | None = None,
    progress: bool = True,
    desc: str = "chunks",
    max_retries: int = DEFAULT_MAX_RETRIES,
    weight: Callable[[list], int] = len,
    unit: str = "pt",
) -> list:
    """``[func(shared, chunk) for chunk in chunks]`` on the chosen backend, resumable with a store.

    ``workers``: local processes (default: all cores; 1 runs in this process), or the CPUs of a
    local Ray cluster this call starts (ignored when joining a cluster by ``address``).
    ``weight(chunk)`` is the chunk's share of the progress bar (default: its length), counted in ``unit``."""
    check_backend(backend)
    if backend == "local" and address is not None:
        raise ConfigError(f"--address {address!r} is for --backend ray; the local backend runs on this machine")
    chunks = [list(chunk) for chunk in chunks]
    results: list = [None] * len(chunks)
    todo = list(range(len(chunks)))
    if store is not None:
        store.bind(func, chunks)
        todo = []
        for i in range(len(chunks)):
            found, value = store.load(i)
            if found:
                results[i] = value
            else:
                todo.append(i)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        total = sum(weight(chunk) for chunk in chunks)
        bar = tqdm(total=total, initial=total - sum(weight(chunks[i]) for i in todo), desc=desc, unit=unit,
                   leave=False, smoothing=0.1)  # fmt: skip

    def on_done(index: int, result: Any) -> None:
        results[index] = result
        if store is not None:
            store.save(index, result)
        if bar is not None:
            bar.update(weight(chunks[index]))

    try:
        if todo:
            if backend == "ray":
                _run_ray(func, chunks, todo, shared, address, workers, max_retries, on_done)
            else:
                workers = (os.cpu_count() or 1) if workers is None else max(1, int(workers))
                _run_local(func, chunks, todo, shared, workers, on_done)
    finally:
        if bar is not None:
            bar.close()
    return results


def source_digest(*modules) -> str:
    """A short hash of the modules' source files (a package: every ``.py`` file under it), part
    of a study's definition so that changed code does not reuse chunks stored by the old code."""
    digest = hashlib.sha256()
    for module in modules:
        root = Path(module.__file__)
        files = sorted(root.parent.rglob("*.py")) if hasattr(module, "__path__") else [root]
        for path in files:
            digest.update(path.name.encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]
