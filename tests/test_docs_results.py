"""The docs say what results.json says: generated tables, the score and the numbers quoted in prose.

Every block between ``<!-- results:NAME FILE -->`` and ``<!-- results:end -->`` in the README
and docs/ must be what ``bogie_agents.evaluation.scoreboard`` renders from FILE now, and every number tagged
``<!-- rj:PATH -->`` must equal FILE's value at its own precision. After a new protocol run:
``bogie results --render-only --out docs/results/v1 --docs README.md --docs docs/results.md``.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from bogie_agents.evaluation import scoreboard as sb

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / sb.DEFAULT_SOURCE
RERENDER = "bogie results --render-only --out docs/results/v1 --docs README.md --docs docs/results.md"


def _docs() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))


def _stale_blocks(text: str) -> list[str]:
    payloads = {(ROOT / src).resolve(): sb.with_scores(json.loads((ROOT / src).read_text())) for _, src, _ in sb.blocks(text)}
    fresh = sb.refresh_text(text, payloads, root=ROOT)
    return [name for (name, _, old), (_, _, new) in zip(sb.blocks(text), sb.blocks(fresh)) if old != new]


def test_every_generated_block_of_the_docs_is_what_results_json_renders():
    found = {}
    for doc in _docs():
        text = doc.read_text()
        found[doc.relative_to(ROOT).as_posix()] = [name for name, _, _ in sb.blocks(text)]
        assert not _stale_blocks(text), f"{doc.relative_to(ROOT)}: blocks {_stale_blocks(text)} are stale; run {RERENDER}"
    # the tables the docs must carry (a doc that lost its markers would otherwise pass unchecked)
    assert "headline" in found["README.md"]
    assert {"headline", "scores"} <= set(found["docs/results.md"])


def test_every_tagged_number_in_the_docs_is_results_json_s():
    tags = 0
    for doc in _docs():
        text = doc.read_text()
        tags += len(sb.TAG.findall(text))
        # a tag the pattern does not read (a number not right before it) would check nothing
        assert text.count("<!-- rj") - text.count("`<!-- rj") == len(sb.TAG.findall(text)), doc
        assert not sb.tag_mismatches(text, ROOT), f"{doc.relative_to(ROOT)}: {sb.tag_mismatches(text, ROOT)}"
    assert tags >= 50, tags


def test_the_results_folder_is_rendered_from_its_own_json():
    payload = json.loads(RESULTS.read_text())
    assert list(payload)[0] == "scores", "the score comes first in results.json"
    assert payload == sb.with_scores(payload), f"stale scores in results.json; run {RERENDER}"
    folder = RESULTS.parent
    assert (folder / "table.md").read_text() == sb.headline_table(payload)
    assert (folder / "table_full.md").read_text() == sb.full_table(payload)
    assert (folder / sb.FIGURE).is_file()


def test_a_changed_number_in_a_block_or_in_tagged_prose_is_caught():
    """The two checks above fail on a planted change of one figure."""
    readme = (ROOT / "README.md").read_text()
    name, _, content = sb.blocks(readme)[0]
    row = next(line for line in content.splitlines() if line.startswith("| passive |"))
    cells = row.split("|")
    cells[3] = f" {int(cells[3]) + 1} "  # passive's nominal speed, one km/h off
    planted = readme.replace(row, "|".join(cells), 1)
    assert planted != readme and _stale_blocks(planted) == [name]
    tagged = next(m for m in sb.TAG.finditer(readme))
    number = tagged.group(1)
    wrong = str(float(number.replace("−", "-")) + 1).rstrip("0").rstrip(".") if "." in number else str(int(number) + 1)
    changed = readme[: tagged.start(1)] + wrong + readme[tagged.end(1):]
    assert sb.tag_mismatches(changed, ROOT), (number, wrong)


# ---- the score ----------------------------------------------------------------------------------
def _col(kmh: float, bound: str = "bisection to 2 km/h") -> dict:
    return {"kmh": kmh, "bound": bound}


def _row(policy: str, scale: float, ceiling: bool = False) -> dict:
    return {"policy": policy, "nominal": _col(300 * scale),
            "by_conicity": {"0.025": _col(300 * scale), "0.1": _col(100 * scale)},
            "degraded": {"Kpx-50%": _col(200 * scale)},
            "actuator_failed": {"a": _col(250 * scale), "b": _col(150 * scale)},
            "delay_20ms": _col(600.0, "at least: every seed passes at the ceiling") if ceiling else _col(280 * scale),
            "worst_case": _col(80 * scale)}  # fmt: skip


def test_the_score_is_the_mean_ratio_to_passive_over_the_columns():
    passive, active = _row("passive", 1.0), _row("a", 1.5)
    active["by_conicity"]["0.1"] = _col(300.0)  # ratio 3 in one of six columns
    s = sb.score(active, passive)
    assert set(s["columns"]) == {"λ 0.025", "λ 0.1", "Kpx-50%", "one actuator failed (worst)", "delay_20ms", "worst case"}
    assert s["value"] == pytest.approx((5 * 1.5 + 3.0) / 6, abs=1e-3) and not s["at_least"]
    assert s["columns"]["one actuator failed (worst)"] == 1.5  # the worst channel against passive's worst
    assert sb.score(passive, passive)["value"] == 1.0
    top = sb.score(_row("b", 1.0, ceiling=True), passive)
    assert top["at_least"] and top["columns"]["delay_20ms"] == pytest.approx(600 / 280, abs=1e-3)


def test_the_score_needs_every_passive_column_and_ignores_unknown_keys():
    passive, active = _row("passive", 1.0), _row("a", 2.0)
    lacking = copy.deepcopy(active)
    del lacking["degraded"]
    assert sb.score(lacking, passive) is None
    extra = {**copy.deepcopy(active), "new_part_v3": {"kmh_like": 1}, "by_track_level": {"intervention": _col(10.0)}}
    assert sb.score(extra, passive) == sb.score(active, passive)
    payload = sb.with_scores({"protocol_version": 3, "new_key": [1], "policies": [passive, active]})
    assert list(payload)[:2] == ["scores", "score_definition"] and payload["new_key"] == [1]
    assert payload["scores"]["a"] == {"value": 2.0, "at_least": False}
    assert sb.with_scores({"policies": [active]})["scores"] == {"a": None}  # no passive row: no score
    assert "| a | 2.00 |" in sb.headline_table(payload)


def test_the_headline_table_has_at_most_eight_columns_with_the_score_first():
    payload = json.loads(RESULTS.read_text())
    header = sb.headline_table(payload).splitlines()[0].strip("|").split("|")
    assert len(header) <= 8 and header[1].strip() == "score"


def test_worst_fault_and_curving_verdict_name_the_column_and_the_route():
    row = _row("a", 1.0)
    assert sb.worst_fault(row)[0] == "failed actuator" and sb.worst_fault(row)[1]["kmh"] == 150
    row["curving"] = {"routes": {"r1": {"no_worse_than_passive": {"wear_number_n": True}},
                                 "r2": {"no_worse_than_passive": {"flange_contact_s": False, "wear_number_n": True}}}}
    assert sb.curving_verdict(row) == "no: r2 (flange contact)"


def test_a_failing_window_below_passive_is_marked_in_the_headline():
    """A seed failing at a grid speed below the column's value does not lower the value, but where
    passive passes that speed the headline says so; a window above passive's value is not marked."""
    passive, active = _row("passive", 1.0), _row("a", 2.0)
    active["actuator_failed"]["a"]["fails_below_kmh"] = {"3": [240.0, 330.0]}  # passive's "a": 250
    active["by_conicity"]["0.1"]["fails_below_kmh"] = {"1": [120.0]}  # passive: 100, not marked
    assert sb.fails_below_passive(active, passive) == ("failed a", 240.0)
    assert sb.fails_below_passive(passive, passive) is None
    table = sb.headline_table({"policies": [passive, active]})
    assert "; § fails at 240 (failed a)" in table and "§ Below its value" in table
    del active["actuator_failed"]["a"]["fails_below_kmh"]
    assert sb.fails_below_passive(active, passive) is None and "§" not in sb.headline_table({"policies": [passive, active]})


# ---- the blocks and the command -----------------------------------------------------------------
def test_refresh_rewrites_only_the_blocks_of_its_own_file(tmp_path):
    mine, other = tmp_path / "a" / "results.json", tmp_path / "b" / "results.json"
    payload = {"policies": [_row("passive", 1.0), _row("x", 2.0)]}
    text = ("intro\n<!-- results:scores a/results.json -->\nold\n<!-- results:end -->\n"
            "<!-- results:scores b/results.json -->\nkept\n<!-- results:end -->\n")
    new = sb.refresh_text(text, {mine.resolve(): payload}, root=tmp_path)
    assert "old" not in new and "| x | 2.00 |" in new and "kept" in new and new.startswith("intro\n")
    with pytest.raises(ValueError, match="unknown generated block"):
        sb.refresh_text("<!-- results:nope a/results.json -->\n<!-- results:end -->", {mine.resolve(): payload}, root=tmp_path)
    assert other  # the b block names a file not rendered here


def test_render_only_writes_the_folder_and_the_docs_blocks_without_running(tmp_path, monkeypatch):
    import bogie_agents.evaluation.stability_protocol as sp
    from bogie_agents.cli import main as cli_main

    monkeypatch.setattr(sp, "evaluate_policy_v2", lambda *a, **k: pytest.fail("--render-only ran the protocol"))
    out = tmp_path / "res"
    out.mkdir()
    payload = json.loads(RESULTS.read_text())
    payload.pop("scores")
    (out / "results.json").write_text(json.dumps(payload))
    doc = tmp_path / "doc.md"
    doc.write_text("# t\n<!-- results:headline res/results.json -->\nstale\n<!-- results:end -->\n")
    monkeypatch.chdir(tmp_path)
    assert cli_main(["results", "--render-only", "--out", "res", "--docs", "doc.md"]) == 0
    written = json.loads((out / "results.json").read_text())
    assert list(written)[0] == "scores" and written == sb.with_scores(payload)
    assert (out / "table.md").read_text() == sb.headline_table(written)
    assert (out / "table_full.md").read_text() == sb.full_table(written)
    assert (out / sb.FIGURE).stat().st_size > 10_000
    assert "stale" not in doc.read_text() and sb.headline_table(written) in doc.read_text()


def test_evaluate_puts_the_score_first_against_the_passive_row_of_its_run(monkeypatch, capsys):
    import bogie_agents.evaluation.stability_protocol as sp
    from bogie_agents.cli import main as cli_main

    search = {"floor_kmh": 40.0, "ceiling_kmh": 600.0, "seeds": 10, "tol_kmh": 2.0}
    rows = {name: {**_row(name, scale), "search": search} for name, scale in (("passive", 1.0), ("skyhook", 1.25))}
    monkeypatch.setattr(sp, "evaluate_policy_v2", lambda spec, *a, **k: copy.deepcopy(rows[spec]))
    assert cli_main(["evaluate", "--policy", "passive", "--policy", "skyhook", "--parts", "critical", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert list(payload)[0] == "scores"
    assert payload["scores"] == {"passive": {"value": 1.0, "at_least": False}, "skyhook": {"value": 1.25, "at_least": False}}
    assert cli_main(["evaluate", "--policy", "skyhook", "--parts", "critical"]) == 0  # no passive row: no score line
    assert "score (" not in capsys.readouterr().out
    assert cli_main(["evaluate", "--policy", "passive", "--policy", "skyhook", "--parts", "critical"]) == 0
    assert "skyhook 1.25" in capsys.readouterr().out


def test_the_per_seed_envelope_of_the_published_columns():
    """studies/per_seed_envelope.py against the protocol's own column values: one policy's
    envelope is its column (the lowest seed); several policies' is at least the best of them,
    and per seed the best of their values."""
    import sys

    sys.path.insert(0, str(ROOT / "studies"))
    from per_seed_envelope import envelope

    results = json.loads(RESULTS.read_text())
    policies = ["lqg_rate", "adaptive_lqg_rate", "robust_steering"]
    for column in ("by_conicity/0.05", "by_conicity/0.1", "by_conicity/0.3", "worst_case"):
        alone = [envelope(results, column, [p]) for p in policies]
        assert all(a["envelope_kmh"] == a["policies"][p]["kmh"] for a, p in zip(alone, policies))
        together = envelope(results, column, policies)
        assert together["envelope_kmh"] >= max(a["envelope_kmh"] for a in alone)
        columns = zip(*(a["envelope_per_seed_kmh"] for a in alone))
        assert together["envelope_per_seed_kmh"] == [max(values) for values in columns]
