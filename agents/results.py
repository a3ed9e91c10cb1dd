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
from bogie_env.envs.core import HuntingTask

from .evaluate import ProtocolSettings, _policy_config, evaluate_policy
from .policies import load_policy


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
        s = task.scal[0, 2]
        y_rel = task.x[0, 0] - task.track.at(s + task.model.params.L1)
        speeds.append(task.info[0, 0])
        lateral.append(1e3 * float(y_rel))
        if task.flags[0, 0] or task.flags[0, 1]:
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


def _fmt(value, suffix=""):
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.1f}{suffix}"
    return f"{value}{suffix}"


def table(results: list[dict], passive_kmh: float | None) -> str:
    lines = [
        "| controller | observations | closed-loop critical speed (km/h) | from small perturbation | from passive limit cycle "
        "| gain over passive | ramp: reached / hunted | rms force at 400 km/h (kN, kN m) | peak force (kN, kN m) "
        "| Csy -50 % | Kpz -50 % | Wpa -50 % | Wpa +50 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        bounds = r.get("bounds", {})

        def speed(key, kind):
            value = r.get(key)
            at_least = "at least" in bounds.get(kind, "")
            return ("≥ " if at_least else "") + _fmt(value)

        gain = (r["closed_loop_critical_speed_kmh"] - passive_kmh) if passive_kmh is not None else None
        effort = r.get("effort", {})
        rms = effort.get("rms_force", {})
        peak = effort.get("peak_force", {})
        rms_text = " / ".join(f"{v / 1e3:.2f}" for v in rms.values()) if rms else "-"
        peak_text = " / ".join(f"{v / 1e3:.1f}" for v in peak.values()) if peak else "-"
        ramp = r.get("ramp", {})
        ramp_text = f"{ramp.get('mean_reached_kmh', '-')} / {ramp.get('hunted', '-')} of {len(ramp.get('seeds', []))}" if ramp else "-"
        robust = r.get("robustness", {})

        def robust_text(name):
            entry = robust.get(name)
            if not entry:
                return "-"
            b = entry.get("bounds", {})
            prefix = "≥ " if all("at least" in v for v in b.values()) else ("≤ " if any("at most" in v for v in b.values()) else "")
            return prefix + _fmt(entry["closed_loop_critical_speed_kmh"])

        lines.append(
            f"| {r['policy']} | {r['observation_type']} | "
            f"{('≥ ' if all('at least' in v for v in bounds.values()) else '') + _fmt(r.get('closed_loop_critical_speed_kmh'))} | "
            f"{speed('from_small_perturbation_kmh', 'small')} | {speed('from_passive_limit_cycle_kmh', 'limit_cycle')} | "
            f"{_fmt(gain) if gain is not None else '-'} | {ramp_text} | {rms_text} | {peak_text} | "
            f"{robust_text('Csy-50%')} | {robust_text('Kpz-50%')} | {robust_text('Wpa-50%')} | {robust_text('Wpa+50%')} |"
        )
    return "\n".join(lines) + "\n"


def run(policies: list[str], env_config: dict, out: Path, resume: bool = False, seed: int = 0) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    json_path = out / "results.json"
    done: dict[str, dict] = {}
    if resume and json_path.is_file():
        done = {r["policy"]: r for r in json.loads(json_path.read_text()).get("policies", [])}
    settings = ProtocolSettings(seed=seed)
    passive_trace = ramp_trace(load_policy("passive", env_config), env_config, seed)
    results = []
    for spec in policies:
        if spec in done:
            results.append(done[spec])
            continue
        policy = load_policy(spec, env_config)
        result = evaluate_policy(policy, env_config, settings)
        result["policy"] = spec
        progress = Path(spec) / "progress.json" if Path(spec).is_dir() else None
        if progress is not None and progress.is_file():
            result["training"] = json.loads(progress.read_text())
        results.append(result)
        if spec != "passive":
            ramp_figure(spec, passive_trace, ramp_trace(load_policy(spec, env_config), env_config, seed),
                        out / f"ramp_{slug(spec)}.png")  # fmt: skip
        write_text_atomic(json_path, json.dumps({"policies": results}, indent=2, default=float))
    passive = next((r for r in results if r["policy"] == "passive"), None)
    write_text_atomic(out / "table.md", table(results, passive["closed_loop_critical_speed_kmh"] if passive else None))
    return {"policies": results}
