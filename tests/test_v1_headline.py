"""The shipped v1 headline: the protocol's critical-speed columns of the shipped learned policy
(``pretrained``) and of passive, rerun now, equal those in ``docs/results/v1/results.json``
(from which the README's and docs' tables are made). A change to the env, the policy, the
protocol or its settings that moves a published figure fails here; so does a results.json that
was edited by hand."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bogie_agents.evaluation import stability_protocol as sp
from bogie_env.envs.config import make_config

RESULTS = Path(__file__).resolve().parent.parent / "docs" / "results" / "v1" / "results.json"


def _published(policy: str) -> dict:
    payload = json.loads(RESULTS.read_text())
    return next(r for r in payload["policies"] if r["policy"] == policy), payload


def _column_values(result: dict) -> dict[str, float]:
    out = {f"conicity {k}": v["kmh"] for k, v in result["by_conicity"].items()}
    out |= {f"degraded {k}": v["kmh"] for k, v in result["degraded"].items()}
    out |= {f"failed {k}": v["kmh"] for k, v in result["actuator_failed"].items()}
    out |= {k: result[k]["kmh"] for k in ("delay_20ms", "worst_case") if k in result}
    return out


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["passive", "pretrained"])
def test_the_published_critical_columns_reproduce(policy):
    published, payload = _published(policy)
    assert payload["protocol_version"] == sp.PROTOCOL_VERSION and "integration_n_sub" not in payload
    rerun = sp.evaluate_policy_v2(policy, make_config(variant="v1"), sp.Settings(progress=False), parts=("critical",))
    assert rerun["closed_loop_critical_speed_kmh"] == published["closed_loop_critical_speed_kmh"]
    assert _column_values(rerun) == _column_values(published)
