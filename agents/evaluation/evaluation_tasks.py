"""The evaluation protocol as independent tasks, for ``--backend ray`` (:mod:`bogie_env.distributed`).

One task is one (controller, part) pair, and robustness is one task per degraded bogie: the units
the protocol already computes independently (:func:`evaluate.evaluate_policy` with one part and,
for robustness, one variant). A task loads its controller by the name or path the user gave
(a path must be readable from every worker: the same machine or a shared file system), and the
merged result equals ``evaluate_policy`` with every part, bitwise: each unit runs the same code
on the same inputs, and its passive limit-cycle starts are keyed by the bogie variant, so no
unit depends on another's cache.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import sys
from pathlib import Path

from bogie_env.distributed import ChunkStore, map_chunks, source_digest

from ..controllers import lqr as controllers, policies
from . import evaluate
from .evaluate import PARTS, ProtocolSettings, evaluate_policy
from ..controllers.policies import PRETRAINED_DIR, SHIPPED, load_policy


def units(specs: list[str], parts: tuple[str, ...], settings: ProtocolSettings) -> list[list]:
    """``[spec, part, variant]`` per task, in the protocol's order."""
    out = []
    for spec in specs:
        for part in PARTS:
            if part not in parts:
                continue
            if part == "robustness":
                out.extend([spec, part, name] for name in settings.variants)
            else:
                out.append([spec, part, None])
    return out


def run_units(shared: tuple, chunk: list) -> list[dict]:
    """The scheduling unit: each ``[spec, part, variant]`` of the chunk, evaluated.
    ``shared``: ``(env_config, settings)`` or ``(env_config, settings, trusted)``."""
    env_config, settings, trusted = (*shared, False)[:3]
    results = []
    for spec, part, variant in chunk:
        unit_settings = copy.deepcopy(settings)
        if variant is not None:
            unit_settings.variants = {variant: settings.variants[variant]}
        results.append(evaluate_policy(load_policy(spec, env_config, trusted), env_config, unit_settings, (part,)))
    return results


def merge(unit_results: list[dict]) -> dict:
    """One controller's units back into ``evaluate_policy``'s result (same keys, same order)."""
    out: dict = {}
    for result in unit_results:
        for key, value in result.items():
            if key == "robustness":
                out.setdefault("robustness", {}).update(value)
            else:
                out[key] = value
    return out


def _fingerprint(spec: str) -> list:
    """What identifies a saved controller's files (size and time of change), for the store key."""
    path = PRETRAINED_DIR if spec in SHIPPED else Path(spec)
    files = sorted(path.rglob("*") if spec in SHIPPED else path.iterdir()) if path.is_dir() else \
        [path] if path.is_file() else []  # fmt: skip
    return [[str(f.relative_to(path)) if path.is_dir() else f.name, f.stat().st_size, f.stat().st_mtime_ns]
            for f in files if f.is_file()]  # fmt: skip


def definition(specs: list[str], env_config: dict, settings: ProtocolSettings) -> dict:
    import bogie_env

    return {
        "env_config": env_config,
        "settings": dataclasses.asdict(settings),
        "controllers": {spec: _fingerprint(spec) for spec in specs},
        "code": source_digest(bogie_env, evaluate, controllers, policies, sys.modules[__name__]),
    }


def evaluate_many(
    specs: list[str],
    env_config: dict,
    settings: ProtocolSettings,
    parts: tuple[str, ...] = PARTS,
    backend: str = "ray",
    address: str | None = None,
    workers: int | None = None,
    store_dir: str | os.PathLike | None = None,
    progress: bool = True,
    trusted: bool = False,
) -> list[dict]:
    """``evaluate_policy`` for every controller, as one batch of tasks; results in ``specs`` order.
    With ``store_dir``, finished tasks are kept and a rerun computes only the rest. ``trusted``
    allows policy paths, as for :func:`policies.load_policy`."""
    todo = units(specs, parts, settings)
    store = ChunkStore(store_dir, definition(specs, env_config, settings)) if store_dir is not None else None
    done = map_chunks(run_units, [[unit] for unit in todo], shared=(env_config, settings, trusted), backend=backend,
                      address=address, workers=workers, store=store, progress=progress, desc="evaluation tasks",
                      weight=lambda chunk: 1, unit="task")  # fmt: skip
    by_spec: dict[str, list] = {spec: [] for spec in specs}
    for unit, (result,) in zip(todo, done):
        by_spec[unit[0]].append(result)
    return [merge(by_spec[spec]) for spec in specs]


# ---- protocol v2 (the -v1 ids) ------------------------------------------------------------------
def run_units_v2(shared: tuple, chunk: list) -> list[dict]:
    """Protocol v2's unit: ``[spec, part]`` evaluated with :func:`stability_protocol.evaluate_policy_v2`.
    ``shared``: ``(env_config, settings, trusted)``."""
    from .stability_protocol import evaluate_policy_v2

    env_config, settings, trusted = shared
    unit_settings = copy.deepcopy(settings)
    unit_settings.progress = False  # a worker's stderr is not the user's terminal
    return [evaluate_policy_v2(spec, env_config, unit_settings, (part,), trusted=trusted) for spec, part in chunk]


def units_v2(specs: list[str], parts: tuple[str, ...]) -> list[list[str]]:
    """Protocol v2's tasks, ``[spec, part]``: every part of the first controller, then the next.
    A stored run's chunk ``i`` holds task ``i``."""
    return [[spec, part] for spec in specs for part in parts]


def code_digest_v2() -> str:
    """The code that protocol v2's stored tasks depend on (part of their store key)."""
    import bogie_env

    from . import stability_protocol

    return source_digest(bogie_env, controllers, policies, stability_protocol, sys.modules[__name__])


def evaluate_many_v2(specs: list[str], env_config: dict, settings, parts: tuple[str, ...], address: str | None = None,
                     workers: int | None = None, store_dir: str | os.PathLike | None = None, progress: bool = True,
                     trusted: bool = False) -> list[dict]:  # fmt: skip
    """Protocol v2 for every controller as Ray tasks, one per (controller, part); results in
    ``specs`` order, each equal to ``evaluate_policy_v2`` with all ``parts`` (parts are independent)."""
    todo = units_v2(specs, parts)
    key = {"env_config": env_config, "settings": dataclasses.asdict(settings), "parts": list(parts),
           "controllers": {spec: _fingerprint(spec) for spec in specs}, "code": code_digest_v2()}  # fmt: skip
    store = ChunkStore(store_dir, key) if store_dir is not None else None
    done = map_chunks(run_units_v2, [[unit] for unit in todo], shared=(env_config, settings, trusted), backend="ray",
                      address=address, workers=workers, store=store, progress=progress, desc="evaluation tasks",
                      weight=lambda chunk: 1, unit="task")  # fmt: skip
    out: dict[str, dict] = {spec: {} for spec in specs}
    for (spec, _), (result,) in zip(todo, done):
        out[spec].update(result)
    return [out[spec] for spec in specs]
