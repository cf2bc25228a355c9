"""A campaign's flight targets (trq_lab.campaign.spec; the schema's FlightTarget): a bar on one
metric of one controller's flights, restricted to one sensing profile when it names one, its
profile resolved as the flights carry it; a metric that is not a flight's, a controller or a
profile the campaign does not fly is refused naming the file, the key and the value; the
shipped sensing_seeds states issue 33's targets."""

from __future__ import annotations

import pytest
from conftest import PARAMS
from trq_params import ConfigError
from trq_params.schema import FLIGHT_METRICS

from trq_lab.campaign.spec import load_campaign
from trq_lab.campaign.store import METRIC_KEYS

SENSING_SMOKE = PARAMS / "campaigns" / "sensing_smoke.yaml"


def _with(tmp_path, targets: str):
    path = tmp_path / "c.yaml"
    path.write_text(SENSING_SMOKE.read_text().replace(
        "grid:", "flight_targets:\n" + targets + "grid:"))
    return path


def test_every_target_metric_is_a_flights_csv_column():
    assert METRIC_KEYS == ("vehicle", *FLIGHT_METRICS)
    assert "diagnosis_s" in FLIGHT_METRICS and "crashed" in FLIGHT_METRICS


def test_a_target_per_profile_is_loaded_with_its_profile(tmp_path):
    plan = load_campaign(_with(tmp_path, (
        "  - {controller: trq_nmpc_eso, sensing: mocap, metric: diagnosis_s, max: 2}\n"
        "  - {controller: trq_nmpc_eso, metric: rmse_pos_after_fault_m, max: 1.5,"
        " per: est_rmse_pos_m, share: 0.9}\n")))
    a, b = plan.flight_targets
    assert (a.controller, a.sensing, a.metric, a.max, a.per, a.share) == (
        "trq_nmpc_eso", "mocap", "diagnosis_s", 2.0, None, 1.0)
    assert (b.sensing, b.per, b.share) == (None, "est_rmse_pos_m", 0.9)
    # targets change no flight
    assert plan.flights == load_campaign(SENSING_SMOKE).flights
    assert load_campaign(SENSING_SMOKE).flight_targets == ()


def test_a_profile_by_path_is_resolved_as_the_flights_carry_it(tmp_path):
    (tmp_path / "mine.yaml").write_text("extends: builtin:sensing/mocap\nname: mine\n"
                                        "description: mocap, my copy\n")
    path = _with(tmp_path, "  - {controller: trq_nmpc_eso, sensing: mine.yaml, metric: "
                           "crashed, max: 0}\n")
    path.write_text(path.read_text().replace("sensing: [truth, mocap]",
                                             "sensing: [truth, mine.yaml]"))
    plan = load_campaign(path)
    assert plan.flight_targets[0].sensing == str(tmp_path / "mine.yaml")
    assert plan.flight_targets[0].sensing in {f["sensing"] for f in plan.flights}


def test_a_controller_by_path_is_resolved_as_the_flights_carry_it(tmp_path):
    """A controller the campaign names by a path (a study's variant beside it) is named the same
    way by its flight and paired targets, and judged on the flights that carry it (absolute)."""
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / "mine.yaml").write_text("extends: builtin:controller/trq_nmpc_eso\n"
                                              "name: mine\n")
    path = _with(tmp_path, "  - {controller: v/mine.yaml, metric: crashed, max: 0}\n")
    path.write_text(path.read_text().replace(
        "controllers: [trq_nmpc_eso]",
        "controllers: [trq_nmpc_eso, v/mine.yaml]\n"
        "paired_targets:\n  - {controller: v/mine.yaml, max_median_ratio: 1.0}"))
    plan = load_campaign(path)
    mine = str(tmp_path / "v" / "mine.yaml")
    assert plan.flight_targets[0].controller == mine
    assert mine in {f["controller"] for f in plan.flights}
    assert (plan.paired_targets[0].controller, plan.paired_targets[0].against) == (
        mine, "trq_nmpc_eso")


@pytest.mark.parametrize("target, key, value", [
    ("{controller: trq_nmpc_eso, metric: rmse_after_fault, max: 0.01}",
     "flight_targets[0].metric", "rmse_after_fault"),
    ("{controller: trq_nmpc, metric: crashed, max: 0}", "flight_targets[0].controller",
     "trq_nmpc"),
    ("{controller: trq_nmpc_eso, sensing: gnss, metric: crashed, max: 0}",
     "flight_targets[0].sensing", "gnss"),
    ("{controller: trq_nmpc_eso, sensing: gnsss, metric: crashed, max: 0}",
     "flight_targets[0].sensing", "gnsss"),
    ("{controller: trq_nmpc_eso, metric: crashed, max: -1}", "flight_targets[0].max", "-1"),
    ("{controller: trq_nmpc_eso, metric: crashed, max: 0, share: 1.5}",
     "flight_targets[0].share", "1.5"),
    ("{controller: trq_nmpc_eso, metric: crashed, max: 0, per: est_rmse}",
     "flight_targets[0].per", "est_rmse"),
    ("{controller: trq_nmpc_eso, metric: crashed, max: 0, within: 1}",
     "flight_targets[0].within", "1"),
])
def test_a_bad_target_names_the_file_key_and_value(tmp_path, target, key, value):
    path = _with(tmp_path, f"  - {target}\n")
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    msg = str(err.value)
    assert str(path) in msg and key in msg and value in msg, msg


def test_sensing_seeds_states_issue_33s_targets():
    plan = load_campaign(PARAMS / "campaigns" / "sensing_seeds.yaml")
    issue_34 = [t for t in plan.flight_targets if t.controller == "trq_nmpc_eso_fused"]
    assert [(t.outage, t.metric, t.max) for t in issue_34] == [
        ("mocap", "max_pos_err_outage_m", 0.05)]
    assert {(t.controller, t.sensing, t.outage, t.max_median_ratio, t.against)
            for t in plan.paired_targets} == {
        ("trq_nmpc_eso_fused", "mocap", "none", 0.8, "trq_nmpc_eso"),
        ("trq_nmpc_eso_fused_gnss", "rtk", "none", 0.8, "trq_nmpc_eso")}
    got = {(t.sensing, t.metric, t.max, t.per) for t in plan.flight_targets
           if t.controller == "trq_nmpc_eso"}
    assert got == {("mocap", "rmse_pos_after_fault_m", 0.01, None),
                   ("mocap", "max_yaw_err_deg", 3.0, None), ("mocap", "diagnosis_s", 2.0, None),
                   ("rtk", "rmse_pos_after_fault_m", 0.05, None),
                   ("rtk", "max_yaw_err_deg", 5.0, None), ("gnss", "crashed", 0.0, None),
                   ("gnss", "rmse_pos_after_fault_m", 1.5, "est_rmse_pos_m")}
    assert {t.controller for t in plan.flight_targets} == {"trq_nmpc_eso", "trq_nmpc_eso_fused"}
    assert {t.share for t in plan.flight_targets} == {1.0}
