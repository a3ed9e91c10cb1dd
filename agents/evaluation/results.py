"""``bogie results``: evaluate several controllers and write the table and plots of docs/results.md.

    bogie results --policy passive --policy skyhook --policy lqr --policy lqg \
                  --policy runs/ppo --policy runs/sac --policy pretrained --out docs/results

Writes ``results.json`` (every number of the protocol), ``table.md`` (the headline table) and
``ramp_<name>.png`` (lateral wheelset displacement against speed on the env's default ramp,
passive against the controller). Files are written atomically, and ``results.json`` after each
controller, so an interruption keeps what was done; ``--resume`` skips controllers already in it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from bogie_env.analysis.plots import EN14363_KMH, plt, save
from bogie_env.analysis.report import write_text_atomic
from bogie_env.envs.config import MAX_SPEED_KMH, merge_config
from bogie_env.envs.task import HuntingTask
from bogie_env.params import ConfigError

from .tables import RAMP_DOWN_COLUMNS, RAMP_DOWN_PARTS, _at_ceiling, _fmt, v2_columns, v2_speed, v2_table  # noqa: F401 (re-exported)

from .evaluate import PARTS, ProtocolSettings, _policy_config, evaluate_policy
from ..controllers.policies import SHIPPED, load_policy, shipped_dir


def slug(spec: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", spec).strip("_") or "policy"


def ramp_trace(policy, env_config: dict, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Speed (km/h) and wheelset-1 displacement relative to the rail (mm) on the default ramp."""
    task = HuntingTask(1, _policy_config(env_config, policy))
    task.seed_rows(np.array([0]), [seed])
    task.reset_rows(np.array([0]))
    policy.reset(1)
    speeds, lateral = [], []
    while True:
        task.step(policy.act(task.obs))
        speeds.append(float(task.speed_kmh[0]))
        lateral.append(1e3 * float(task.relative_lateral_m[0, 0]))
        if task.done[0]:
            break
    return np.array(speeds), np.array(lateral)


def ramp_figure(name: str, passive: tuple, controlled: tuple, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(passive[0], passive[1], lw=0.5, color="tab:red", label="passive")
    ax.plot(controlled[0], controlled[1], lw=0.5, color="tab:blue", label=name)
    ax.axvline(EN14363_KMH, color="tab:green", ls=":", lw=1, label="330 km/h (EN 14363)")
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("y1 relative to the rail (mm)")
    ax.set_title(f"Default ramp (1 m/s^2, 0.5 mm track), seed 0: passive vs {name}")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    save(fig, path)


EXTENDED_RAMP_END_KMH = MAX_SPEED_KMH


def extended_ramp_figure(traces: dict, path: Path) -> None:
    """Every controller on one ramp to the env's top speed: where each one starts to hunt."""
    fig, axes = plt.subplots(len(traces), 1, figsize=(9, 1.6 * len(traces) + 0.6), sharex=True, squeeze=False)
    for ax, (name, (speeds, lateral)) in zip(axes[:, 0], traces.items()):
        ax.plot(speeds, lateral, lw=0.4, color="tab:red" if name == "passive" else "tab:blue")
        ax.axvline(EN14363_KMH, color="tab:green", ls=":", lw=1)
        ax.set_ylabel("y1 (mm)")
        ax.set_ylim(-12, 12)
        ax.text(0.01, 0.8, f"{name}: reached {speeds[-1]:.0f} km/h", transform=ax.transAxes, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("speed (km/h)")
    axes[0, 0].set_title(f"Ramp 300 -> {EXTENDED_RAMP_END_KMH:.0f} km/h at 1 m/s^2, 0.5 mm track, seed 0")
    fig.tight_layout()
    save(fig, path)


def speed_text(entry: dict) -> str:
    """A critical speed with its bound: "≥" at the top of the search range, "≤" at the bottom."""
    bounds = entry.get("bounds", {}).values()
    prefix = "≥ " if bounds and all("at least" in b for b in bounds) else ("≤ " if any("at most" in b for b in bounds) else "")
    return prefix + _fmt(entry.get("closed_loop_critical_speed_kmh"))


def _gain_text(gain: float | None, entry: dict) -> str:
    if gain is None:
        return "-"
    at_least = speed_text(entry).startswith("≥")
    return ("≥ " if at_least else "") + _fmt(gain)


def _channels(values: dict, scale: float, digits: int) -> str:
    return " / ".join(f"{v / scale:.{digits}f}" for v in values.values()) if values else "-"


def table(results: list[dict], passive_kmh: float | None) -> str:
    """Two markdown tables: critical speeds (nominal and degraded), then ramp and effort."""
    lines = [
        "| controller | observations | closed-loop critical speed (km/h) | from small perturbation | from passive limit cycle "
        "| gain over passive | Csy -50 % | Kpz -50 % | Wpa -50 % | Wpa +50 % |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        bounds = r.get("bounds", {})

        def start(key, kind):
            return ("≥ " if "at least" in bounds.get(kind, "") else "") + _fmt(r.get(key))

        value = r.get("closed_loop_critical_speed_kmh")
        gain = (value - passive_kmh) if passive_kmh is not None and value is not None else None
        robust = r.get("robustness", {})
        degraded = [(speed_text(robust[name]) if name in robust else "-") for name in ("Csy-50%", "Kpz-50%", "Wpa-50%", "Wpa+50%")]
        lines.append(
            f"| {r['policy']} | {r['observation_type']} | {speed_text(r)} | "
            f"{start('from_small_perturbation_kmh', 'small')} | {start('from_passive_limit_cycle_kmh', 'limit_cycle')} | "
            f"{_gain_text(gain, r)} | " + " | ".join(degraded) + " |"
        )
    lines += [
        "",
        "Channels in the order frame lateral (kN) / frame yaw / wheelset 1 yaw / wheelset 2 yaw (kN m).",
        "",
        "| controller | ramp: mean speed reached (km/h) / seeds hunted | rms force at 400 km/h | peak force at 400 km/h "
        f"| rms force rate (kN/s, kN m/s) | within limits | ramp to {EXTENDED_RAMP_END_KMH:g} km/h (seed 0): reached |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ramp, effort = r.get("ramp", {}), r.get("effort", {})
        ramp_text = f"{ramp['mean_reached_kmh']} / {ramp['hunted']} of {len(ramp['seeds'])}" if ramp else "-"
        lines.append(
            f"| {r['policy']} | {ramp_text} | {_channels(effort.get('rms_force', {}), 1e3, 2)} | "
            f"{_channels(effort.get('peak_force', {}), 1e3, 1)} | {_channels(effort.get('rms_force_rate', {}), 1e3, 0)} | "
            f"{'yes' if effort.get('within_limits') else ('no' if effort else '-')} | "
            f"{r['extended_ramp']['reached_kmh'] if 'extended_ramp' in r else '-'} |"
        )
    return "\n".join(lines) + "\n"


def _results_folder(out: Path, resume: bool) -> tuple[Path, dict[str, dict]]:
    """``out/results.json`` and, with ``resume``, the controllers already in it (by policy spec)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {str(out)!r} is an existing file; give a folder")
    out.mkdir(parents=True, exist_ok=True)
    json_path = out / "results.json"
    done: dict[str, dict] = {}
    if resume and json_path.is_file():
        try:
            done = {r["policy"]: r for r in json.loads(json_path.read_text()).get("policies", [])}
        except (json.JSONDecodeError, AttributeError, KeyError, TypeError) as error:
            raise ConfigError(f"--resume: {str(json_path)!r} is not a results file ({error}); move it away") from None
    return json_path, done


def run(policies: list[str], env_config: dict, out: Path, resume: bool = False, seed: int = 0,
        settings: ProtocolSettings | None = None, parts: tuple[str, ...] = PARTS, trusted: bool = False,
        backend: str = "local", address: str | None = None, workers: int | None = None) -> dict:  # fmt: skip
    """Evaluate ``policies`` into ``out``; ``trusted`` allows policy paths (an SB3 model file is code).
    ``backend="ray"`` evaluates every controller and part as Ray tasks first (finished tasks kept in
    ``out/chunks``, so a rerun resumes); the figures and the table are made here as locally."""
    json_path, done = _results_folder(out, resume)
    settings = settings or ProtocolSettings(seed=seed)
    distributed: dict[str, dict] = {}
    if backend != "local":
        from .evaluation_tasks import evaluate_many

        todo = [spec for spec in dict.fromkeys(policies) if spec not in done]
        for spec in todo:
            load_policy(spec, env_config, trusted)  # a bad name or path fails before any task starts
        distributed = dict(zip(todo, evaluate_many(todo, env_config, settings, parts, backend, address, workers,
                                                   store_dir=out / "chunks", trusted=trusted)))  # fmt: skip
    passive_trace = ramp_trace(load_policy("passive", env_config), env_config, seed)
    results = []
    for spec in policies:
        if spec in done:
            results.append(done[spec])
            continue
        result = distributed[spec] if spec in distributed else \
            evaluate_policy(load_policy(spec, env_config, trusted), env_config, settings, parts)  # fmt: skip
        result["policy"] = spec
        folder = shipped_dir(spec, env_config) if spec in SHIPPED else Path(spec)
        progress = folder / "progress.json" if folder.is_dir() else None
        if progress is not None and progress.is_file():
            result["training"] = json.loads(progress.read_text())
        results.append(result)
        if spec != "passive":
            ramp_figure(spec, passive_trace, ramp_trace(load_policy(spec, env_config, trusted), env_config, seed),
                        out / f"ramp_{slug(spec)}.png")  # fmt: skip
        write_text_atomic(json_path, json.dumps({"policies": results}, indent=2, default=float))
    extended = merge_config(env_config, {"speed": {"end_kmh": EXTENDED_RAMP_END_KMH}})
    traces = {spec: ramp_trace(load_policy(spec, env_config, trusted), extended, seed) for spec in policies}
    for result in results:
        speeds = traces[result["policy"]][0]
        result["extended_ramp"] = {"end_kmh": EXTENDED_RAMP_END_KMH, "reached_kmh": round(float(speeds[-1]), 1),
                                   "hunted": bool(speeds[-1] < EXTENDED_RAMP_END_KMH - 0.5), "seed": seed}  # fmt: skip
    extended_ramp_figure(traces, out / "ramp_extended.png")
    write_text_atomic(json_path, json.dumps({"policies": results}, indent=2, default=float))
    passive = next((r for r in results if r["policy"] == "passive"), None)
    write_text_atomic(out / "table.md", table(results, passive.get("closed_loop_critical_speed_kmh") if passive else None))
    return {"policies": results}


# ---- protocol v2 (the -v1 ids) ------------------------------------------------------------------
#: Protocol v2's parts in ``bogie results``, and the key of a result that says a part has run
#: (``--resume`` runs the parts a kept row lacks).
V2_RESULTS_PARTS = ("critical", "cost", "margins", "curving", "ramp_down", "ramp_down_ideal")
V2_PART_KEYS = {"critical": "search"}


def v2_summary(result: dict) -> str:
    """One line per controller for ``bogie evaluate`` without ``--json``."""
    line = f"{result['policy']:>12s}:"
    if "nominal" in result:
        s = result["search"]
        line += (f" closed-loop critical speed {v2_speed(result['nominal'])} km/h (search {s['floor_kmh']:g}-"
                 f"{s['ceiling_kmh']:g} km/h, {s['seeds']} seeds); by conicity "
                 + ", ".join(f"{lam}: {v2_speed(e)}" for lam, e in result.get("by_conicity", {}).items()))  # fmt: skip
        if "worst_case" in result:
            line += f"; worst case {v2_speed(result['worst_case'])}"
    if "margins" in result:
        m = result["margins"]
        line += f"; gain margin {m.get('gain_margin')}, delay margin {m.get('delay_margin_s')} s"
    for part, where in (("ramp_down", ""), ("ramp_down_ideal", " on the ideal track")):
        if part in result:
            line += f"; hunting ends on the ramp-down{where} at " + ", ".join(
                f"{lam}: {v2_speed(e)}" for lam, e in result[part]["by_conicity"].items())
    return line


def run_v2(policies: list[str], env_config: dict, out: Path, resume: bool = False, seed: int = 0,
           parts: tuple[str, ...] = V2_RESULTS_PARTS, trusted: bool = False, backend: str = "local",
           address: str | None = None, workers: int | None = None, settings=None, docs: tuple = ()) -> dict:  # fmt: skip
    """Protocol v2 for ``policies`` into ``out``: ``results.json`` (rewritten atomically after
    each controller; ``resume`` keeps those already in it and runs only the ``parts`` they lack),
    then :func:`scoreboard.render`: the scores, ``table.md`` (the headline table), ``table_full.md``
    (:func:`v2_table`), the figure, and the generated blocks of ``docs``."""
    from .stability_protocol import Settings, evaluate_policy_v2

    settings = settings or Settings(seed=seed)
    if settings.screening:
        raise ConfigError("bogie results writes the protocol's table: a screening run (--quick) does not belong in it")
    json_path, done = _results_folder(out, resume)
    n_sub = env_config["integration"]["n_sub"]
    if done:
        _check_same_run(json_path, n_sub, settings.seed, settings.version)
    specs = list(dict.fromkeys(policies))
    work = {spec: tuple(p for p in parts if spec not in done or V2_PART_KEYS.get(p, p) not in done[spec]) for spec in specs}
    work = {spec: todo for spec, todo in work.items() if todo}
    distributed: dict[str, dict] = {}
    if backend != "local" and work:
        from .evaluation_tasks import evaluate_many_v2

        for spec in work:
            load_policy(spec, env_config, trusted)
        groups: dict[tuple[str, ...], list[str]] = {}
        for spec, todo in work.items():
            groups.setdefault(todo, []).append(spec)
        for todo, group in groups.items():  # one Ray task per (controller, part) of each group
            distributed.update(zip(group, evaluate_many_v2(group, env_config, settings, todo, address, workers,
                                                           store_dir=out / "chunks", trusted=trusted)))  # fmt: skip
    rows = dict(done)  # every row known so far is in each write: a crash loses no finished row
    for spec, todo in work.items():
        result = distributed.get(spec) or evaluate_policy_v2(spec, env_config, settings, todo, trusted=trusted)
        _check_parts_ran(spec, todo, result)
        rows[spec] = {**rows.get(spec, {}), **result, "policy": spec}
        write_text_atomic(json_path, _v2_payload(_ordered(rows, specs), n_sub, settings.seed, settings.version))
    write_text_atomic(json_path, _v2_payload(_ordered(rows, specs), n_sub, settings.seed, settings.version))
    from .scoreboard import render

    payload = render(json_path, docs)
    return {"policies": [r for r in payload["policies"] if r["policy"] in specs]}


def _ordered(rows: dict[str, dict], specs: list[str]) -> list[dict]:
    """The rows of ``specs`` in their order, then every other kept row (a run never drops one)."""
    return [rows[s] for s in specs if s in rows] + [r for s, r in rows.items() if s not in specs]


def _check_parts_ran(spec: str, parts: tuple[str, ...], result: dict) -> None:
    """Each part must leave the key that --resume reads as 'this part has run' (V2_PART_KEYS)."""
    for part in parts:
        if V2_PART_KEYS.get(part, part) not in result:
            raise RuntimeError(f"protocol v2 part {part!r} gave {spec!r} no {V2_PART_KEYS.get(part, part)!r} key; "
                               "results.V2_PART_KEYS names the key each part leaves")  # fmt: skip


def _v2_payload(results: list[dict], n_sub: int | None, seed: int = 0, protocol_version: int = 2) -> str:
    """results.json's text; ``integration_n_sub`` only when a step was set (``--n-sub``), ``seed``
    only when it is not the protocol's 0 (so the default file is unchanged)."""
    head = {"protocol_version": protocol_version} | ({} if n_sub is None else {"integration_n_sub": n_sub}) | ({"seed": seed} if seed else {})
    return json.dumps(head | {"policies": results}, indent=2, default=float)


def _check_same_run(json_path: Path, n_sub: int | None, seed: int, protocol_version: int = 2) -> None:
    """--resume keeps rows (and adds parts to them) only when they ran at this run's integration
    step, seeds and protocol version."""
    before = json.loads(json_path.read_text())
    for key, now, default in (("integration_n_sub", n_sub, None), ("seed", seed, 0), ("protocol_version", protocol_version, 2)):
        if before.get(key, default) != now:
            raise ConfigError(f"--resume: {str(json_path)!r} holds rows run with {key} = {before.get(key, default)}; this "
                              f"run has {now}: rows of different runs do not belong in one table; use another --out")  # fmt: skip


def evaluate_v2(specs: list[str], env_config: dict, settings, parts: tuple[str, ...], backend: str = "local",
                address: str | None = None, workers: int | None = None, store_dir: Path | None = None,
                trusted: bool = False) -> list[dict]:  # fmt: skip
    """Protocol v2 (:mod:`bogie_agents.evaluation.stability_protocol`) for every policy spec: ``bogie evaluate`` on a -v1 id."""
    from .stability_protocol import evaluate_policy_v2

    for spec in specs:
        load_policy(spec, env_config, trusted)  # a bad name or path fails here, before any run
    if backend == "ray":  # one task per controller and part (docs/distributed.md)
        from .evaluation_tasks import evaluate_many_v2

        return evaluate_many_v2(specs, env_config, settings, parts, address, workers, store_dir=store_dir,
                                progress=True, trusted=trusted)  # fmt: skip
    return [evaluate_policy_v2(spec, env_config, settings, parts, trusted=trusted) for spec in specs]


def evaluate_v1(specs: list[str], env_config: dict, requested: tuple[str, ...], seed: int = 0, backend: str = "local",
                address: str | None = None, workers: int | None = None, store_dir: Path | None = None,
                progress: bool = True, trusted: bool = False) -> list[dict]:  # fmt: skip
    """Protocol v1 (:mod:`bogie_agents.evaluation.evaluate`), unchanged, for every policy spec: ``bogie evaluate``
    on a -v0 id; ``margins`` among the ``requested`` parts adds bogie margins' table beside the protocol."""
    parts = tuple(p for p in requested if p != "margins")  # margins: bogie margins' table, beside the protocol
    settings = ProtocolSettings(seed=seed)
    if not parts:
        results = [{} for _ in specs]
    elif backend == "ray":  # one task per controller and part (docs/distributed.md)
        from .evaluation_tasks import evaluate_many

        for spec in specs:
            load_policy(spec, env_config, trusted)  # a bad name or path fails here, before any task starts
        results = evaluate_many(specs, env_config, settings, parts, backend, address, workers,
                                store_dir=store_dir, progress=progress, trusted=trusted)  # fmt: skip
    else:
        results = [evaluate_policy(load_policy(spec, env_config, trusted), env_config, settings, parts)
                   for spec in specs]  # fmt: skip
    for spec, result in zip(specs, results):
        result["policy"] = spec  # as the user named it (a path, or passive, pretrained, ...)
        if "margins" in requested:
            from ..design.margins import margins_table

            result["margins"] = margins_table(load_policy(spec, env_config, trusted), env_config)
    return results


def v1_summary(r: dict) -> str:
    """One line of a protocol-v1 result (``bogie evaluate`` on a -v0 id)."""
    line = f"{r['policy']:>12s}:"
    if "closed_loop_critical_speed_kmh" in r:
        line += (f" closed-loop critical speed {speed_text(r)} km/h "
                 f"(small {r['from_small_perturbation_kmh']}, limit cycle {r['from_passive_limit_cycle_kmh']}; "
                 f"search {r['protocol']['search_kmh'][0]:g}-{r['protocol']['search_kmh'][1]:g} km/h)")  # fmt: skip
    if "ramp" in r:
        line += f"; ramp reached {r['ramp']['mean_reached_kmh']} km/h (hunted {r['ramp']['hunted']}/{len(r['ramp']['seeds'])})"
    if "margins" in r:
        m = r["margins"]
        line += (f"; margins over {m['speeds_kmh'][0]:g}-{m['speeds_kmh'][-1]:g} km/h: "
                 + (f"unstable at {m['unstable_at_kmh']} km/h" if m["unstable_at_kmh"] else
                    f"gain {m['gain_margin']}, delay {m['delay_margin_s']} s"))  # fmt: skip
    return line
