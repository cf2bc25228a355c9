"""A campaign's report (trq_lab.reporting.campaign) with flight targets and the diagnosis time:
each target judged on its controller's flights under its profile (a failed flight, a crashed
one unless the target is on `crashed`, a missing metric never meet it; `per` scales the bar by
the flight's own metric), the misses in metrics.json's failures and headline (trq-results reads
them), the median diagnosis time per controller in the table and in metrics.json."""

from __future__ import annotations

import json

import pytest
from conftest import PARAMS

from trq_lab.campaign.spec import load_campaign
from trq_lab.campaign.store import flight_inputs
from trq_lab.reporting.campaign import judge_flight_targets, meets, write_report

SENSING_SMOKE = PARAMS / "campaigns" / "sensing_smoke.yaml"


def _plan(tmp_path, targets: str):
    path = tmp_path / "c.yaml"
    path.write_text(SENSING_SMOKE.read_text().replace(
        "grid:", "repeats: 4\nflight_targets:\n" + targets + "grid:"))
    return load_campaign(path)


def _rows(plan, **by_sensing):
    """One row per flight: by_sensing[profile] lists (rmse, est, diagnosis, crashed, status)
    for its flights in order."""
    rows, seen = [], {}
    for f in plan.flights:
        k = seen.setdefault(f["sensing"], 0)
        seen[f["sensing"]] += 1
        rmse, est, diag, crashed, status = by_sensing[f["sensing"]][k]
        rows.append(dict(flight_inputs(f), crashed=crashed, status=status,
                         success=status == "done" and not crashed,
                         error="RuntimeError: boom" if status == "failed" else "",
                         rmse_pos_after_fault_m=rmse, est_rmse_pos_m=est, diagnosis_s=diag))
    return rows


OK = "done"
MOCAP = [(0.003, 0.001, 0.4, False, OK), (0.004, 0.001, 0.6, False, OK),
         (0.012, 0.001, 2.5, False, OK), (None, None, None, False, "failed")]
TRUTH = [(0.002, None, 0.3, False, OK), (0.002, None, 0.3, False, OK),
         (0.002, None, 0.3, False, OK), (0.9, None, None, True, OK)]


def test_a_target_under_one_profile_counts_only_its_flights(tmp_path):
    plan = _plan(tmp_path, "  - {controller: trq_nmpc_eso, sensing: mocap, "
                           "metric: rmse_pos_after_fault_m, max: 0.01, share: 0.5}\n"
                           "  - {controller: trq_nmpc_eso, sensing: mocap, "
                           "metric: diagnosis_s, max: 2, share: 0.75}\n"
                           "  - {controller: trq_nmpc_eso, metric: crashed, max: 0}\n")
    rows = _rows(plan, mocap=MOCAP, truth=TRUTH)
    lines, failures, headline, judged = judge_flight_targets(plan, rows)
    # mocap: 2 of 4 within 0.01 (the failed flight does not meet it): 50 % >= 50 %, met
    assert (judged[0]["flights"], judged[0]["met_by"], judged[0]["met"]) == (4, 2, True)
    assert judged[0]["median"] == pytest.approx(0.004)
    # the diagnosis within 2 s: 2 of 4, under 75 %: missed
    assert (judged[1]["met_by"], judged[1]["met"]) == (2, False)
    # no crash over every profile: the truth flight that crashed (and the failed one) miss
    assert (judged[2]["flights"], judged[2]["met_by"], judged[2]["met"]) == (8, 6, False)
    assert len(failures) == 2 and "diagnosis_s <= 2" in failures[0]
    assert "trq_nmpc_eso mocap rmse_pos_after_fault_m <= 0.01: 2/4 met" == headline[0]
    assert any("**missed**" in ln for ln in lines) and any("**met**" in ln for ln in lines)


def test_per_scales_the_bar_by_the_flights_own_metric(tmp_path):
    plan = _plan(tmp_path, "  - {controller: trq_nmpc_eso, sensing: mocap, metric: "
                           "rmse_pos_after_fault_m, max: 3, per: est_rmse_pos_m}\n")
    t = plan.flight_targets[0]
    row = {"status": "done", "crashed": False, "rmse_pos_after_fault_m": 0.003,
           "est_rmse_pos_m": 0.001}
    assert meets(row, t)                                     # 0.003 <= 3 x 0.001
    assert not meets(dict(row, rmse_pos_after_fault_m=0.0031), t)
    assert not meets(dict(row, est_rmse_pos_m=None), t)      # no estimate: not met
    assert not meets(dict(row, crashed=True), t)             # crashed: not met
    assert not meets(dict(row, status="failed"), t)


def test_the_report_and_metrics_json(tmp_path):
    plan = _plan(tmp_path, "  - {controller: trq_nmpc_eso, sensing: mocap, "
                           "metric: diagnosis_s, max: 2}\n")
    text = write_report(plan, _rows(plan, mocap=MOCAP, truth=TRUTH), tmp_path,
                        figures=False).read_text()
    assert "## Flight targets" in text and "**Missed:**" in text
    assert "median diagnosis s |" in text
    # mocap's diagnosis median over the three that have one: 0.6
    assert "| mocap | trq_nmpc_eso | 4 |" in text and "| 0.60 |" in text
    summary = json.loads((tmp_path / "metrics.json").read_text())
    assert summary["sensing"]["mocap"]["trq_nmpc_eso"]["diagnosis_median_s"] == 0.6
    assert summary["failures"] == ["trq_nmpc_eso mocap diagnosis_s <= 2: 2/4 (target >= 100%)"]
    assert summary["headline"] == "trq_nmpc_eso mocap diagnosis_s <= 2: 2/4 missed"
    assert summary["flight_targets"][0]["sensing"] == "mocap"


def test_without_flight_targets_no_section_and_no_failures_key(tmp_path):
    plan = load_campaign(SENSING_SMOKE)
    rows = [dict(flight_inputs(f), crashed=False, status="done", success=True,
                 rmse_pos_after_fault_m=0.003, diagnosis_s=None) for f in plan.flights]
    text = write_report(plan, rows, tmp_path, figures=False).read_text()
    assert "Flight targets" not in text
    assert "failures" not in json.loads((tmp_path / "metrics.json").read_text())
