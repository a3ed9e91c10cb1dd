"""The score, the headline table, the figure and the docs' generated blocks, all from one results.json.

Everything here reads a protocol-v2 ``results.json`` (``bogie results``) and runs nothing, so
``bogie results --render-only --out DIR`` re-renders a folder in seconds and
``tests/test_docs_results.py`` checks that the docs say what the file says. Keys this module
does not know (a later protocol's extra columns or parts) are carried along and ignored.

**The score** (:func:`score`): the mean, over the protocol's conicity grid and its fault and
degradation columns, of a controller's closed-loop critical speed divided by passive's in the
same column. Passive scores 1 by construction. A ratio rather than a difference, because
passive's speeds span 73-358 km/h over the columns: a difference in km/h would be set by the
new-wheel and healthy-bogie columns, while a ratio weighs worn wheels (λ 0.2, 0.3) and faults
as much as new wheels. A column at the search ceiling counts at the ceiling, so such a score is
a lower bound (written "≥").

**Generated blocks.** A markdown file holds a block of this module's output between

    <!-- results:NAME docs/results/v1/results.json -->
    ...
    <!-- results:end -->

NAME is one of :data:`BLOCKS`; :func:`refresh_text` rewrites the block from the named file. A
number quoted in prose is tagged ``358.6<!-- rj:passive/nominal/kmh -->``: the number must equal
that value of ``docs/results/v1/results.json`` at the number's own precision (a path's first
part is a policy's name; ``A - B`` quotes a difference, ``A * 1000`` a scaled value; ``rj@FILE:PATH``
reads another file).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

#: The results file the docs' tags read unless they name another (``rj@FILE:``).
DEFAULT_SOURCE = "docs/results/v1/results.json"

SCORE_DEFINITION = ("mean over the conicity grid, the degraded parts, the worst single failed actuator, every extra-delay "
                    "column and the worst case over randomisation of the closed-loop critical speed divided by passive's "
                    "in the same column (passive = 1; a column at the search ceiling counts at the ceiling: '>=')")  # fmt: skip


def _is_column(entry) -> bool:
    return isinstance(entry, dict) and isinstance(entry.get("kmh"), (int, float))


def score_columns(result: dict) -> dict[str, dict]:
    """The critical-speed columns the score averages, by name: ``λ <c>`` for each conicity of
    the grid, each degraded part, ``one actuator failed (worst)``, each ``delay_*`` column and
    ``worst case``. Columns absent from ``result`` are absent here."""
    cols: dict[str, dict] = {}
    for lam, entry in (result.get("by_conicity") or {}).items():
        if _is_column(entry):
            cols[f"λ {lam}"] = entry
    for name, entry in (result.get("degraded") or {}).items():
        if _is_column(entry):
            cols[name] = entry
    failed = {k: e for k, e in (result.get("actuator_failed") or {}).items() if _is_column(e)}
    if failed:
        cols["one actuator failed (worst)"] = min(failed.values(), key=lambda e: e["kmh"])
    for key, entry in result.items():
        if key.startswith("delay_") and _is_column(entry):
            cols[key] = entry
    if _is_column(result.get("worst_case")):
        cols["worst case"] = result["worst_case"]
    return cols


def _at_ceiling(entry: dict) -> bool:
    return str(entry.get("bound", "")).startswith("at least")


def score(result: dict, passive: dict) -> dict | None:
    """The controller's score against ``passive`` (both protocol-v2 results), or None when
    passive has no critical columns or the controller lacks one of passive's columns."""
    ref = score_columns(passive)
    cols = score_columns(result)
    if not ref or set(ref) - set(cols):
        return None
    ratios = {name: cols[name]["kmh"] / ref[name]["kmh"] for name in ref}
    return {"value": round(sum(ratios.values()) / len(ratios), 3),
            "at_least": any(_at_ceiling(cols[name]) for name in ref),
            "columns": {name: round(r, 3) for name, r in ratios.items()}}  # fmt: skip


def _passive(rows: list[dict]) -> dict | None:
    return next((r for r in rows if r.get("policy") == "passive"), None)


def scores(rows: list[dict]) -> dict[str, dict | None]:
    """Each row's score against the passive row among them (every score None without one)."""
    passive = _passive(rows)
    return {r["policy"]: (score(r, passive) if passive else None) for r in rows}


def with_scores(payload: dict) -> dict:
    """``payload`` with ``scores`` first (policy -> value, "≥" as ``at_least``), its definition,
    and each row's ``score`` after its ``policy``; every other key kept as it was."""
    rows = payload.get("policies", [])
    table = scores(rows)
    head = {"scores": {name: (s and {"value": s["value"], "at_least": s["at_least"]}) for name, s in table.items()},
            "score_definition": SCORE_DEFINITION}  # fmt: skip
    new_rows = [{"policy": r["policy"], "score": table[r["policy"]], **{k: v for k, v in r.items() if k not in ("policy", "score")}}
                for r in rows]  # fmt: skip
    rest = {k: v for k, v in payload.items() if k not in ("scores", "score_definition", "policies")}
    return head | rest | {"policies": new_rows}


def score_text(s: dict | None) -> str:
    if not s:
        return "-"
    return ("≥ " if s["at_least"] else "") + f"{s['value']:.2f}"


# ---- the headline table -------------------------------------------------------------------------
def _speed(entry: dict | None) -> str:
    """A column's value (lowest seed) with its bound: "358", "≥ 600", "≤ 40"."""
    if not _is_column(entry):
        return "-"
    bound = str(entry.get("bound", ""))
    prefix = "≥ " if bound.startswith("at least") else ("≤ " if bound.startswith("at most") else "")
    return f"{prefix}{entry['kmh']:.0f}"


def worst_fault(result: dict) -> tuple[str, dict] | None:
    """The lowest of the fault and degradation columns (degraded parts, a failed actuator,
    extra delay): its name and entry."""
    cols = {n: e for n, e in score_columns(result).items() if not n.startswith("λ ") and n != "worst case"}
    if not cols:
        return None
    name = min(cols, key=lambda n: cols[n]["kmh"])
    return FAULT_NAMES.get(name, name.replace("delay_", "") + " delay" if name.startswith("delay_") else name), cols[name]


#: Short names of the fault columns in the headline table.
FAULT_NAMES = {"one actuator failed (worst)": "failed actuator"}


def _all_columns(result: dict) -> dict[str, dict]:
    """Every critical-speed column by name, each failed actuator on its own (``failed <channel>``)."""
    cols = {n: e for n, e in score_columns(result).items() if n != "one actuator failed (worst)"}
    cols.update({f"failed {k}": e for k, e in (result.get("actuator_failed") or {}).items() if _is_column(e)})
    return cols


def fails_below_passive(result: dict, passive: dict | None) -> tuple[str, float] | None:
    """The lowest grid speed where a seed fails (``fails_below_kmh``: a failing window below the
    column's value, which the value does not count) that is also below passive's value in the same
    column, with that column's name; None when there is none. Such a controller is worse than
    passive at that speed, whatever its column's value says."""
    if passive is None:
        return None
    reference = _all_columns(passive)
    worst = None
    for name, entry in _all_columns(result).items():
        speeds = [v for seed in (entry.get("fails_below_kmh") or {}).values() for v in seed]
        if name not in reference or not speeds:
            continue
        low = min(speeds)
        if low < reference[name]["kmh"] and (worst is None or low < worst[1]):
            worst = (name, float(low))
    return worst


def curving_verdict(result: dict) -> str:
    """"yes" when the controller is no worse than passive on every shipped route, else the
    routes and columns where it is worse; "-" without the curving part."""
    routes = (result.get("curving") or {}).get("routes") or {}
    if not routes:
        return "-"
    worse = [f"{route} ({', '.join(k for k, ok in r['no_worse_than_passive'].items() if not ok)})"
             for route, r in routes.items() if not all((r.get("no_worse_than_passive") or {}).values())]  # fmt: skip
    return "yes" if not worse else "no: " + "; ".join(worse).replace("flange_contact_s", "flange contact")


def _margins(result: dict) -> str:
    m = result.get("margins") or {}
    gain, delay = m.get("gain_margin"), m.get("delay_margin_s")
    if gain is None or delay is None:
        return "-"
    return f"{gain:.1f} / {delay * 1e3:.0f}"


def _nominal_conicity(payload: dict) -> str | None:
    row = next(iter(payload.get("policies", [])), {})
    return next((lam for lam, e in (row.get("by_conicity") or {}).items() if e == row.get("nominal")), None)


#: What a row is told when its result does not say (rows evaluated before ``knows`` was recorded).
DEFAULT_TOLD = "conicity class"


def _attribute(result: dict, name: str, default):
    """A row's ``name`` (``knows``, ``privileged``): its own, else its classical controller's class
    attribute, else ``default``."""
    if name in result:
        return result[name]
    from ..controllers.classical import CLASSICAL

    return getattr(CLASSICAL.get(result.get("policy")), name, default)


def controller_label(result: dict) -> str:
    """The row's name, with what it sees and is told where that is not the sensors and the
    conicity class; a privileged reference is marked ‡ (not a baseline)."""
    told = _attribute(result, "knows", DEFAULT_TOLD)
    sees = "full state" if result.get("observation_type") == "state" else "sensors"
    extra = [x for x in (told if told != DEFAULT_TOLD else None, sees if sees != "sensors" else None) if x]
    mark = " ‡" if _attribute(result, "privileged", False) else ""
    return f"{result['policy']}{mark}" + (f" ({', '.join(extra)})" if extra else "")


def headline_table(payload: dict) -> str:
    """At most 8 columns, the score first: controller, score, nominal, λ 0.1, λ 0.3, worst fault,
    margins (gain / delay), curving; notes below."""
    rows = payload.get("policies", [])
    table = scores(rows)
    head = ["controller", "score", "nominal", "λ 0.1", "λ 0.3", "worst fault", "gain / delay margin (ms)",
            "curving: no worse than passive"]  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    passive = _passive(rows)
    marked = False
    for r in rows:
        fault = worst_fault(r)
        by = r.get("by_conicity") or {}
        fault_cell = f"{_speed(fault[1])} ({fault[0]})" if fault else "-"
        below = fails_below_passive(r, passive)
        if below:
            fault_cell += f"; § fails at {below[1]:.0f} ({below[0]})"
            marked = True
        cells = [controller_label(r), score_text(table[r["policy"]]), _speed(r.get("nominal")), _speed(by.get("0.1")),
                 _speed(by.get("0.3")), fault_cell, _margins(r), curving_verdict(r)]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    search = next((r["search"] for r in rows if "search" in r), None)
    notes = ["", f"Score: {SCORE_DEFINITION}."]
    if any(_attribute(r, "privileged", False) for r in rows):
        notes.append("‡ The privileged reference: told each run's true scenario and sees the full state; it measures the "
                     "headroom and is not a baseline to beat. Every other row sees the sensors and is told the conicity "
                     "class unless its name says otherwise.")  # fmt: skip
    if search:
        notes.append(f"Speeds: closed-loop critical speed in km/h, the highest speed all {search['seeds']} seeds pass "
                     f"(search {search['floor_kmh']:g}-{search['ceiling_kmh']:g} km/h, bisection to {search['tol_kmh']:g} km/h); "
                     f"nominal: conicity {_nominal_conicity(payload) or '-'}; worst fault: the lowest of the degraded parts, "
                     "the worst single failed actuator and the extra delay.")  # fmt: skip
    if marked:
        notes.append("§ Below its value, some seed fails again at this grid speed, which is below passive's critical speed "
                     "in the same column (fails_below_kmh in results.json; a value is the top of each seed's highest passing "
                     "range, docs/results.md 'Protocol v3'): worse than passive there.")  # fmt: skip
    notes.append("Margins: worst actuator loop over 300-500 km/h at conicity 0.025; delay margin beyond the loop's own "
                 "10 ms. Curving: the three shipped routes at their line speeds, 8 seeds. Every column: table_full.md.")  # fmt: skip
    return "\n".join(lines + notes) + "\n"


def full_table(payload: dict) -> str:
    from .tables import v2_table

    return v2_table(payload.get("policies", []), payload.get("integration_n_sub"))


def scores_table(payload: dict) -> str:
    """Each controller's ratio to passive per column of the score (the score's own reasons)."""
    table = {n: s for n, s in scores(payload.get("policies", [])).items() if s}
    if not table:
        return "No passive row: no score.\n"
    names = list(next(iter(table.values()))["columns"])
    lines = ["| controller | score | " + " | ".join(names) + " |", "|" + "---|" * (len(names) + 2)]
    for policy, s in table.items():
        lines.append(f"| {policy} | {score_text(s)} | " + " | ".join(f"{s['columns'][n]:.2f}" for n in names) + " |")
    return "\n".join(lines) + "\n"


#: The blocks a doc can hold, by name.
BLOCKS = {"headline": headline_table, "full": full_table, "scores": scores_table}


# ---- the figure ---------------------------------------------------------------------------------
FIGURE = "critical_speed_vs_conicity.png"


def conicity_figure(payload: dict, path: Path) -> Path:
    """Closed-loop critical speed (lowest seed) against conicity for every controller, the
    region passive reaches shaded; open markers at the search ceiling."""
    from bogie_env.analysis.plots import plt, save

    fig, ax = plt.subplots(figsize=(8, 4.6))
    rows = [r for r in payload.get("policies", []) if r.get("by_conicity")]
    ceiling = None
    styles = iter(["-", "--", "-.", ":"] * 5)
    colors = iter(plt.get_cmap("tab10").colors + plt.get_cmap("Dark2").colors)  # more rows than tab10's 10 colours
    for r in rows:
        by = {float(lam): e for lam, e in r["by_conicity"].items() if _is_column(e)}
        lams = sorted(by)
        if not lams:
            continue
        kmh = [by[lam]["kmh"] for lam in lams]
        ceiling = ceiling or by[lams[0]].get("ceiling_kmh")
        if r["policy"] == "passive":
            ax.fill_between(lams, 0, kmh, color="0.85", label="passive", zorder=0)
            ax.plot(lams, kmh, color="0.4", lw=1.2, zorder=1)
            continue
        if _attribute(r, "privileged", False):  # the headroom, not a baseline
            (line,) = ax.plot(lams, kmh, marker="s", ms=4, lw=1.6, ls=":", color="k", label=f"{r['policy']} ‡ (reference)")
        else:
            (line,) = ax.plot(lams, kmh, marker="o", ms=4, lw=1.4, ls=next(styles), color=next(colors),
                             label=r["policy"])
        top = [(lam, by[lam]["kmh"]) for lam in lams if _at_ceiling(by[lam])]
        if top:
            ax.plot(*zip(*top), ls="none", marker="o", ms=8, mfc="none", color=line.get_color())
    if ceiling:
        ax.axhline(ceiling, color="0.5", ls=":", lw=1)
        ax.text(0.3, ceiling, "search ceiling", ha="right", va="bottom", fontsize=8, color="0.4")
    ax.set_xscale("log")
    ax.set_xticks([0.025, 0.05, 0.1, 0.2, 0.3], ["0.025", "0.05", "0.1", "0.2", "0.3"])
    ax.set_xticks([], minor=True)
    ax.set_xlabel("equivalent conicity λ (new wheels → worn)")
    ax.set_ylabel("closed-loop critical speed (km/h)")
    ax.set_ylim(0, (ceiling or 600) * 1.05)
    search = next((r["search"] for r in rows if r.get("search")), {})
    ax.set_title(f"Protocol v{payload.get('protocol_version', '?')} on Bogie/Hunting-v1: lowest of {search.get('seeds', '?')} seeds")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    return save(fig, path)


# ---- rendering a folder and the docs ------------------------------------------------------------
def render(json_path: Path, docs: list[Path] = ()) -> dict:
    """From ``json_path`` (a protocol-v2 results.json): rewrite it with the scores first, write
    ``table.md`` (the headline table), ``table_full.md`` (every column) and the figure beside it,
    and refresh the blocks of ``docs`` that name this file. Returns the payload."""
    from bogie_env.analysis.report import write_text_atomic

    json_path = Path(json_path)
    payload = with_scores(json.loads(json_path.read_text()))
    out = json_path.parent
    write_text_atomic(json_path, json.dumps(payload, indent=2, default=float) + "\n")
    write_text_atomic(out / "table.md", headline_table(payload))
    write_text_atomic(out / "table_full.md", full_table(payload))
    conicity_figure(payload, out / FIGURE)
    for doc in docs:
        doc = Path(doc)
        text = doc.read_text()
        new = refresh_text(text, {json_path.resolve(): payload})
        if new != text:
            write_text_atomic(doc, new)
    return payload


BLOCK = re.compile(r"(<!-- results:(\w+) (\S+) -->\n)(.*?)(<!-- results:end -->)", re.DOTALL)


def blocks(text: str) -> list[tuple[str, str, str]]:
    """Every generated block of ``text``: (name, source file, content)."""
    return [(m.group(2), m.group(3), m.group(4)) for m in BLOCK.finditer(text)]


def refresh_text(text: str, payloads: dict[Path, dict], root: Path | None = None) -> str:
    """``text`` with every block whose source (relative to ``root``, default the working folder)
    is a key of ``payloads`` rewritten from it; other blocks stay. An unknown block name fails."""
    base = Path(root) if root is not None else Path.cwd()

    def one(m: re.Match) -> str:
        name, source = m.group(2), m.group(3)
        if name not in BLOCKS:
            raise ValueError(f"unknown generated block {name!r}; known: {', '.join(BLOCKS)}")
        payload = payloads.get((base / source).resolve())
        return m.group(0) if payload is None else m.group(1) + BLOCKS[name](payload) + m.group(5)

    return BLOCK.sub(one, text)


# ---- numbers quoted in prose --------------------------------------------------------------------
TAG = re.compile(r"([+\-−]?\d+(?:\.\d+)?)\s?(?:km/h|ms|%)?<!-- rj(?:@(\S+?))?:([^>]+?) -->")


def lookup(payload: dict, path: str):
    """The value at ``path`` ("/"-separated; a first part naming a policy selects its row)."""
    parts = [p for p in path.strip().split("/") if p]
    rows = {r.get("policy"): r for r in payload.get("policies", [])}
    node = rows[parts[0]] if parts[0] in rows else payload[parts[0]]
    for part in parts[1:]:
        node = node[int(part)] if isinstance(node, list) else node[part]
    return node


def tag_value(payload: dict, expression: str) -> float:
    """``PATH``, ``PATH - PATH``, either times a factor (``PATH * 1000``: seconds quoted in ms)."""
    expression, _, factor = expression.partition(" * ")
    terms = expression.split(" - ")
    value = float(lookup(payload, terms[0]))
    for term in terms[1:]:
        value -= float(lookup(payload, term))
    return value * float(factor or 1)


def tag_mismatches(text: str, root: Path) -> list[str]:
    """Each tagged number of ``text`` that differs from its results file at its own precision."""
    cache: dict[str, dict] = {}
    wrong = []
    for m in TAG.finditer(text):
        quoted, source, expression = m.group(1), m.group(2) or DEFAULT_SOURCE, m.group(3)
        if source not in cache:
            cache[source] = with_scores(json.loads((root / source).read_text()))
        digits = len(quoted.split(".")[1]) if "." in quoted else 0
        expected = tag_value(cache[source], expression)
        if abs(float(quoted.replace("−", "-")) - expected) > 0.5 * 10**-digits + 1e-9:
            wrong.append(f"{quoted} for {expression} ({source}: {expected:.{digits + 1}f})")
    return wrong
