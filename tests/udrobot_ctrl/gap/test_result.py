"""diagnose() returns a named result (udrobot_ctrl.gap.report.Diagnosis); with selection=True the report carries the
one-criterion table beside the verdict."""
from __future__ import annotations

import json

import pytest

from udrobot_ctrl.gap import decide
from udrobot_ctrl.gap.report import Diagnosis, diagnose, summary

from .truth import generate


@pytest.fixture(scope="module")
def result():
    runs = generate({"buoyancy_offset": {"dB0": 2.0, "beta": 0.0}}, n_runs=2, duration=40.0, rate=20.0, seed=11)
    return diagnose("pendulum:chin", runs[:1], runs[1:], effects=["buoyancy_offset", "thruster_lag"], selection=True)


def test_the_result_is_named_and_says_what_the_report_says(result):
    assert isinstance(result, Diagnosis)
    report, context = result  # unpacks as before
    assert report is result.report and context is result.context
    assert json.loads(result.to_json()) == result.report
    assert result.summary() == summary(result.report)
    assert result.significant == tuple(e["name"] for e in report["effects"] if e["significant"])


def test_a_constant_buoyancy_error_is_named_with_its_size_and_the_table_is_consistent(result):
    """The truth's net buoyancy is 2 N more than the model's (constant: the catalogue's own form). It is named with
    its size; the table agrees, its weights sum to 1 and each inclusion probability is the weight of the sets holding
    it."""
    assert result.significant == ("buoyancy_offset",)
    by = {e["name"]: e for e in result.report["effects"]}
    assert by["buoyancy_offset"]["params"]["dB_N"] == pytest.approx(2.0, abs=0.2)
    sel = result.report["selection"]
    rows = sel["candidates"]
    assert sum(r["weight"] for r in rows) == pytest.approx(1.0, abs=1e-5)
    for name, p in sel["inclusion_probability"].items():
        assert p == pytest.approx(sum(r["weight"] for r in rows if name in r["effects"]), abs=1e-5)
    assert sel["named"] == ["buoyancy_offset"]
    assert sel["inclusion_probability"]["buoyancy_offset"] >= decide.P_NAMED
