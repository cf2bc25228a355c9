"""A campaign's report (trq_lab.reporting.campaign) with the outage axis: the success table
gains the outage's column when it varies and the largest error in the outage's window (median
and max per controller) whenever a flight has an outage; the cell sections are per outage; a
flight target naming an outage judges the flights with one; metrics.json carries the figures
per outage. Without the axis, the report says nothing of outages."""

from __future__ import annotations

import json

from conftest import PARAMS

from trq_lab.campaign.spec import load_campaign
from trq_lab.campaign.store import rows_of
from trq_lab.reporting.campaign import write_report

OUTAGE_SMOKE = PARAMS / "campaigns" / "outage_smoke.yaml"
SMOKE = PARAMS / "campaigns" / "smoke.yaml"
# the largest error in the dropout's window per controller (a made-up figure each)
IN_OUTAGE = {"trq_nmpc_eso": 0.08, "trq_nmpc_eso_fused": 0.03}


def _rows(plan, in_outage=IN_OUTAGE):
    results = {f["id"]: {"id": f["id"], "status": "done", "metrics": {
        "crashed": False, "rmse_pos_after_fault_m": 0.004,
        "max_pos_err_outage_m": in_outage[f["controller"]] if "outage" in f else None}}
        for f in plan.flights}
    return rows_of(plan, results)


def test_the_table_and_sections_per_outage(tmp_path):
    plan = load_campaign(OUTAGE_SMOKE)
    text = write_report(plan, _rows(plan), tmp_path, figures=False).read_text()
    assert "## Success rate per controller and outage" in text
    assert "| outage | controller |" in text and "median max error in outage m |" in text
    assert "| none | trq_nmpc_eso | 1 | 100% | 0 | 0 | 0.004 | - | - | - |" in text
    assert "| mocap 2-3 s | trq_nmpc_eso | 1 | 100% | 0 | 0 | 0.004 | - | 0.080 | 0.080 |" \
        in text
    assert "| mocap 2-3 s | trq_nmpc_eso_fused | 1 | 100% | 0 | 0 | 0.004 | - | 0.030 |" in text
    assert "## `trq_nmpc_eso` under `outage none`" in text
    assert "## `trq_nmpc_eso_fused` under `outage mocap 2-3 s`" in text
    summary = json.loads((tmp_path / "metrics.json").read_text())
    fused = summary["outage"]["mocap 2-3 s"]["trq_nmpc_eso_fused"]
    assert fused["outage_err_median_m"] == fused["outage_err_max_m"] == 0.03
    assert summary["outage"]["none"]["trq_nmpc_eso"]["outage_err_median_m"] is None


def test_a_target_on_the_outage_judges_the_flights_with_one(tmp_path):
    plan = load_campaign(OUTAGE_SMOKE)
    text = write_report(plan, _rows(plan), tmp_path, figures=False).read_text()
    assert ("`trq_nmpc_eso_fused` with a mocap outage: max_pos_err_outage_m <= 0.05 on >= 100% "
            "of its flights: 1 of 1") in text and "**met**" in text
    summary = json.loads((tmp_path / "metrics.json").read_text())
    assert summary["flight_targets"][0]["outage"] == "mocap"
    assert summary["failures"] == []
    worse = dict(IN_OUTAGE, trq_nmpc_eso_fused=0.06)
    write_report(plan, _rows(plan, worse), tmp_path, figures=False)
    summary = json.loads((tmp_path / "metrics.json").read_text())
    assert summary["flight_targets"][0]["met"] is False
    assert summary["failures"] == [
        "trq_nmpc_eso_fused outage mocap max_pos_err_outage_m <= 0.05: 0/1 (target >= 100%)"]


def test_without_the_axis_the_report_says_nothing_of_outages(tmp_path):
    plan = load_campaign(SMOKE)
    text = write_report(plan, _rows(plan, {c: None for c in plan.controllers}), tmp_path,
                        figures=False).read_text()
    assert "outage" not in text
    summary = json.loads((tmp_path / "metrics.json").read_text())
    assert "outage" not in json.dumps(summary)
