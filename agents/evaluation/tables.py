"""Protocol v2/v3 results as text: a column's speed with its bound and spread, the columns of one
controller's result in the table's order, and the full table (``table_full.md``). Read by
:mod:`bogie_agents.evaluation.results` (the summary line, ``bogie results``) and :mod:`bogie_agents.evaluation.scoreboard`
(the rendered tables); neither imports the other for these."""

from __future__ import annotations


def _fmt(value, suffix=""):
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.1f}{suffix}"
    return f"{value}{suffix}"


def v2_speed(entry: dict | None) -> str:
    """A v2 column's critical speed with its bound and the seeds' spread: "≥ 600", "≤ 40", "352.1 (352-371)"."""
    if not entry:
        return "-"
    value = entry["kmh"]
    if entry["bound"].startswith("at least"):
        return f"≥ {value:g}"
    if entry["bound"].startswith("at most"):
        return f"≤ {value:g}"
    spread = entry.get("spread_kmh", {})
    below = [v for speeds in (entry.get("fails_below_kmh") or {}).values() for v in speeds]
    mark = " †" if any(v < value for v in below) else ""  # a seed fails below the column's value
    return (f"{value:.0f} ({spread.get('median', value):.0f}-{spread.get('max', value):.0f})" if spread else f"{value:.0f}") + mark


def _at_ceiling(entry: dict | None) -> bool:
    return bool(entry) and entry["bound"].startswith("at least")


#: The conicities of the ramp-down parts that the table shows (results.json has all of them).
RAMP_DOWN_COLUMNS = ("0.025", "0.1")
#: The ramp-down parts and the names of their columns.
RAMP_DOWN_PARTS = {"ramp_down": "hunting ends", "ramp_down_ideal": "ideal track: hunting ends"}


def v2_columns(result: dict) -> dict[str, dict | None]:
    """The critical-speed columns of one controller's v2 result, in the table's order."""
    cols: dict[str, dict | None] = {"nominal": result.get("nominal"), "worst case": result.get("worst_case")}
    for lam, entry in result.get("by_conicity", {}).items():
        if entry != result.get("nominal"):  # the nominal conicity is the nominal column
            cols[f"λ {lam}"] = entry
    for name, entry in result.get("degraded", {}).items():
        cols[name] = entry
    failed = result.get("actuator_failed", {})
    if failed:
        worst = min(failed, key=lambda k: failed[k]["kmh"])
        cols["one actuator failed (worst)"] = {**failed[worst], "channel": worst}
    for key, entry in result.items():
        if key.startswith("delay_") and isinstance(entry, dict) and "kmh" in entry:
            cols[f"{key[6:]} delay"] = entry
    for part, title in RAMP_DOWN_PARTS.items():
        ramp_down = (result.get(part) or {}).get("by_conicity", {})
        for lam in RAMP_DOWN_COLUMNS:
            if lam in ramp_down:
                cols[f"{title} λ {lam}"] = ramp_down[lam]
    return cols


def v2_table(results: list[dict], n_sub: int | None = None) -> str:
    """Protocol v2's table: closed-loop critical speeds per column (min over seeds, with the
    median-max of the seeds), margins and cost. A column where every controller sits at the
    search ceiling separates nothing and is left out (named below the table). ``n_sub``: the
    RK4 substeps per env step the rows ran at, if set (``--n-sub``), stated below the table."""
    per = [v2_columns(r) for r in results]
    names = list(dict.fromkeys(name for cols in per for name in cols))
    dropped = [n for n in names if all(_at_ceiling(cols.get(n)) for cols in per)]
    names = [n for n in names if n not in dropped]
    search = next((r["search"] for r in results if "search" in r), None)
    version = next((r["protocol_version"] for r in results if "protocol_version" in r), 2)
    head = ["controller"] + names + ["gain margin", "delay margin (ms)", "rms force 300 km/h (kN, kN m)", "frame accel rms (m/s²)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r, cols in zip(results, per):
        m = r.get("margins") or {}
        cost = (r.get("cost") or {})
        first_cost = next(iter(cost.values()), None)
        force = " / ".join(f"{v / 1e3:.2f}" for v in first_cost["rms_force"].values()) if first_cost and first_cost["rms_force"] else "-"
        accel = f"{first_cost['frame_accel_rms_m_per_s2']:.3f}" if first_cost else "-"
        delay = m.get("delay_margin_s")
        cells = [r["policy"]] + [v2_speed(cols.get(n)) for n in names]
        cells += [_fmt(m.get("gain_margin")), _fmt(delay * 1e3) if isinstance(delay, (int, float)) else "-", force, accel]
        lines.append("| " + " | ".join(cells) + " |")
    notes = ["", "Closed-loop critical speed in km/h: the highest speed all seeds pass, then (median-max) over the seeds."]
    if search:
        notes.append(f"Search {search['floor_kmh']:g}-{search['ceiling_kmh']:g} km/h ('≥' at the ceiling, '≤' at the floor), "
                     f"{search['seeds']} seeds, bisection to {search['tol_kmh']:g} km/h (docs/results.md, protocol v{version})."
                     + ("" if n_sub is None else f" RK4 at {n_sub} substeps per env step (--n-sub)."))  # fmt: skip
    notes.append("† a seed also fails at a grid speed below this value (hunting ends: a window below it fails again; "
                 "fails_below_kmh in results.json).")  # fmt: skip
    if any(n.startswith("hunting ends") for n in names):
        notes.append("Hunting ends λ: the speed where hunting, fully developed at the ceiling, stops once the controller is "
                     "switched on and the speed ramps down (the part ramp_down, lowest of the seeds; "
                     "docs/studies/ramp_down.md; every conicity in results.json).")  # fmt: skip
    if any(n.startswith("ideal track") for n in names):
        notes.append("Ideal track: the same ramp-down on a perfect track with noise-free sensors (the part ramp_down_ideal): "
                     "where the closed loop's hunting stops failing the criterion when nothing random knocks the bogie off "
                     "its cycle; insensitive to the integration step (docs/studies/ramp_down_ideal.md).")  # fmt: skip
    if dropped:
        notes.append(f"Left out (every controller at the ceiling): {', '.join(dropped)}.")
    curving = [{**r["curving"], "policy": r["policy"]} for r in results if r.get("curving")]
    if curving:
        from .curving_evaluation import format_table

        notes += ["", "Curving on the shipped routes at their line speeds (the part `curving`; excess: mean over seeds against passive):",
                  "", format_table(curving)]  # fmt: skip
    return "\n".join(lines + notes) + "\n"
