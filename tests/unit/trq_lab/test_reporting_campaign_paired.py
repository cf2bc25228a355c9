"""A campaign's paired comparison (trq_lab.reporting.campaign.paired_by_seed): each controller's
flight against the first controller's under the same conditions and seed, per sensing profile;
a failed flight makes no pair, a crash is never in the ratio, a later diagnosis is counted."""

from __future__ import annotations

import pytest
from conftest import PARAMS

from trq_lab.campaign.spec import load_campaign
from trq_lab.campaign.store import flight_inputs
from trq_lab.reporting.campaign import paired_by_seed

SENSING_SMOKE = PARAMS / "campaigns" / "sensing_smoke.yaml"


def _plan(tmp_path):
    path = tmp_path / "c.yaml"
    text = SENSING_SMOKE.read_text()
    start = text.index("controllers:")
    end = text.index("\n", start)
    path.write_text(text[:start] + "controllers: [trq_nmpc_eso, trq_nmpc]\nrepeats: 3"
                    + text[end:])
    return load_campaign(path)


def _rows(plan, results):
    """results[(controller, sensing)] lists (rmse, diagnosis, crashed, status) per seed."""
    rows, seen = [], {}
    for f in plan.flights:
        key = (f["controller"], f["sensing"])
        k = seen.setdefault(key, 0)
        seen[key] += 1
        rmse, diag, crashed, status = results[key][k]
        rows.append(dict(flight_inputs(f), crashed=crashed, status=status,
                         rmse_pos_after_fault_m=rmse, diagnosis_s=diag))
    return rows


def test_each_flight_meets_the_first_controllers_on_its_seed(tmp_path):
    plan = _plan(tmp_path)
    profiles = sorted({f["sensing"] for f in plan.flights})
    assert len(profiles) == 2 and len(plan.flights) == 12
    a, b = profiles
    ok = "done"
    results = {
        ("trq_nmpc_eso", a): [(0.010, 0.1, False, ok), (0.020, 0.1, False, ok),
                              (0.040, 0.1, False, ok)],
        ("trq_nmpc", a): [(0.005, 0.2, False, ok), (0.030, 0.1, False, ok),
                          (0.020, None, False, ok)],
        ("trq_nmpc_eso", b): [(0.010, 0.1, False, ok), (0.010, 0.1, True, ok),
                              (None, None, False, "failed")],
        ("trq_nmpc", b): [(0.020, 0.1, False, ok), (0.015, 0.1, False, ok),
                          (0.010, 0.1, False, ok)],
    }
    lines, summary = paired_by_seed(plan, _rows(plan, results))
    sa = summary[a]["trq_nmpc"]
    # seed by seed: 0.5, 1.5, 0.5; better on two; a later diagnosis on the first and the third
    assert (sa["pairs"], sa["better"], sa["later_diagnosis"]) == (3, 2, 2)
    assert sa["median_ratio"] == pytest.approx(0.5)
    assert (sa["min_ratio"], sa["max_ratio"]) == (pytest.approx(0.5), pytest.approx(1.5))
    sb = summary[b]["trq_nmpc"]
    # the failed flight makes no pair; the crash is out of the ratio but flying there is better
    assert (sb["pairs"], sb["better"], sb["other_crashed"]) == (2, 1, 1)
    assert sb["median_ratio"] == pytest.approx(2.0)
    assert any("| trq_nmpc | 3 | 2 | 0.500 (0.500-1.500) | 2 |" in line for line in lines)


def _with_targets(tmp_path, targets: str):
    path = tmp_path / "t.yaml"
    text = SENSING_SMOKE.read_text()
    start = text.index("controllers:")
    end = text.index("\n", start)
    path.write_text(text[:start] + "controllers: [trq_nmpc_eso, trq_nmpc]\nrepeats: 3\n"
                    "paired_targets:\n" + targets + text[end:])
    return load_campaign(path)


def test_a_paired_target_judges_the_median_crashes_and_diagnosis(tmp_path):
    from trq_lab.reporting.campaign import judge_paired_targets
    plan = _with_targets(tmp_path, "  - {controller: trq_nmpc, sensing: mocap, "
                                   "max_median_ratio: 0.8}\n"
                                   "  - {controller: trq_nmpc, sensing: mocap, "
                                   "max_median_ratio: 0.8, no_later_diagnosis: false}\n"
                                   "  - {controller: trq_nmpc, max_median_ratio: 2.5}\n")
    assert plan.paired_targets[0].against == "trq_nmpc_eso"          # the first controller
    ok = "done"
    fine = [(0.010, 0.1, False, ok)] * 3
    results = {("trq_nmpc_eso", "truth"): fine, ("trq_nmpc", "truth"): [
                   (0.020, 0.1, False, ok), (0.020, 0.1, False, ok), (0.020, 0.1, False, ok)],
               ("trq_nmpc_eso", "mocap"): fine, ("trq_nmpc", "mocap"): [
                   (0.005, 0.1, False, ok), (0.007, 0.3, False, ok), (0.009, 0.1, False, ok)]}
    lines, failures, headline, judged = judge_paired_targets(plan, _rows(plan, results))
    # under mocap the median ratio is 0.7, but one pair diagnoses later: missed, unless not asked
    assert judged[0]["median_ratio"] == pytest.approx(0.7) and judged[0]["later_diagnosis"] == 1
    assert [j["met"] for j in judged] == [False, True, False]
    # both profiles: ratios 2, 2, 2, 0.5, 0.7, 0.9: median 1.45 <= 2.5, but the later diagnosis
    assert judged[2]["pairs"] == 6 and judged[2]["median_ratio"] == pytest.approx(1.45)
    assert len(failures) == 2 and "0.700 <= 0.8" in failures[0]
    assert failures[0].endswith("(later diagnosis on 1 of 3 pairs)")     # the clause missed
    assert any("**missed**" in line for line in lines)


@pytest.mark.parametrize("target, match", [
    ("{controller: quad_nmpc, max_median_ratio: 0.8}", r"paired_targets\[0\]\.controller"),
    ("{controller: trq_nmpc_eso, max_median_ratio: 0.8}", r"paired_targets\[0\]\.against"),
    ("{controller: trq_nmpc, sensing: rtk, max_median_ratio: 0.8}",
     r"paired_targets\[0\]\.sensing.*'rtk'"),
    ("{controller: trq_nmpc, max_median_ratio: -1}", r"max_median_ratio"),
])
def test_a_paired_target_the_campaign_cannot_judge_is_an_error(tmp_path, target, match):
    from trq_params.loader import ConfigError
    with pytest.raises(ConfigError, match=match):
        _with_targets(tmp_path, f"  - {target}\n")
