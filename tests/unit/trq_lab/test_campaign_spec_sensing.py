"""The sensing axis of a campaign (trq_lab.campaign.spec): derived from its schema model
(AXIS_MODELS) as the other axes are; a grid lists profiles (names or paths), a sample fixes or
draws one; every spec carries its sensing, and truth, the default, keeps the ids and seeds of a
campaign without the axis; an unknown profile is refused naming the file, the key and the value;
flights.csv has a sensing column and the report groups its tables by the profile."""

from __future__ import annotations

import json

import pytest
from conftest import PARAMS
from trq_params import ConfigError
from trq_params.schema import SensingAxis

from trq_lab.campaign.flight import plant_id
from trq_lab.campaign.spec import AXIS_KEYS, flight_id, load_campaign
from trq_lab.campaign.store import flight_inputs
from trq_lab.reporting.campaign import write_report

SMOKE = PARAMS / "campaigns" / "smoke.yaml"
SENSING_SMOKE = PARAMS / "campaigns" / "sensing_smoke.yaml"


def _with(tmp_path, text: str, name: str = "c.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return load_campaign(path)


def test_the_axis_is_its_schema_model():
    assert set(AXIS_KEYS["sensing"]) == set(SensingAxis.model_fields) == {"profile"}
    assert AXIS_KEYS["sensing"]["profile"].kind == "text"


def test_a_grid_lists_profiles_and_truth_keeps_the_ids(tmp_path):
    plain = load_campaign(SMOKE)
    assert {f["sensing"] for f in plain.flights} == {"truth"}
    assert plain.sensings == ("truth",)
    listed = _with(tmp_path, SMOKE.read_text() + "  sensing: [truth, mocap]\n")
    assert len(listed.flights) == 2 * len(plain.flights)
    assert listed.sensings == ("truth", "mocap")
    truth = [f for f in listed.flights if f["sensing"] == "truth"]
    mocap = [f for f in listed.flights if f["sensing"] == "mocap"]
    assert truth == list(plain.flights)                     # the same specs, ids and seeds
    assert [f["seed"] for f in mocap] == [f["seed"] for f in truth]   # common random numbers
    assert not {f["id"] for f in mocap} & {f["id"] for f in truth}
    assert all(f["id"] == flight_id(f) for f in listed.flights)
    # the mapping form and a single profile say the same
    mapped = _with(tmp_path, SMOKE.read_text() + "  sensing: {profile: [truth, mocap]}\n")
    assert mapped.flights == listed.flights
    one = _with(tmp_path, SMOKE.read_text() + "  sensing: mocap\n")
    assert one.flights == tuple(mocap) and one.sensings == ("mocap",)
    # the plant's pairing key leaves the default out too, and tells the profiles apart
    assert plant_id(truth[0]) != plant_id(mocap[0])


@pytest.mark.parametrize("value, key", [
    ("[truth, mocapp]", "grid.sensing"), ("rtkk", "grid.sensing"),
    ("{profile: gnsss}", "grid.sensing"), ("[truth, missing/profile.yaml]", "grid.sensing")])
def test_an_unknown_profile_names_the_file_key_and_value(tmp_path, value, key):
    path = tmp_path / "bad.yaml"
    path.write_text(SMOKE.read_text() + f"  sensing: {value}\n")
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    msg = str(err.value)
    bad = [v for v in ("mocapp", "rtkk", "gnsss", "profile.yaml") if v in value][0]
    assert str(path) in msg and f"'{key}'" in msg and bad in msg, msg


def test_a_bad_key_or_type_in_the_axis_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"unknown key 'grid.sensing.name'"):
        _with(tmp_path, SMOKE.read_text() + "  sensing: {name: mocap}\n")
    with pytest.raises(ConfigError, match=r"grid.sensing"):
        _with(tmp_path, SMOKE.read_text() + "  sensing: [truth, 3]\n")


def test_a_profile_by_path_is_read_beside_the_campaign_and_in_the_digest(tmp_path):
    (tmp_path / "mine.yaml").write_text("extends: builtin:sensing/mocap\nname: mine\n"
                                        "description: mocap, my copy\n")
    plan = _with(tmp_path, SMOKE.read_text() + "  sensing: mine.yaml\n")
    assert {f["sensing"] for f in plan.flights} == {str(tmp_path / "mine.yaml")}
    assert flight_inputs(plan.flights[0])["sensing"] == str(tmp_path / "mine.yaml")
    mocap = _with(tmp_path, SMOKE.read_text() + "  sensing: mocap\n", "m.yaml")
    assert plan.flights[0]["params_digest"] != mocap.flights[0]["params_digest"]
    (tmp_path / "mine.yaml").write_text("extends: builtin:sensing/mocap\nname: mine\n"
                                        "description: mocap, my copy, edited\n")
    again = _with(tmp_path, SMOKE.read_text() + "  sensing: mine.yaml\n")
    assert again.flights[0]["params_digest"] != plan.flights[0]["params_digest"]


def test_a_sample_fixes_or_draws_a_profile_without_moving_the_other_draws(tmp_path):
    head = SMOKE.read_text().split("grid:")[0] + (
        "sample:\n  n: 6\n  seed: 3\n"
        "  fault: {motor: [1, 2, 3, 4], effectiveness: {uniform: [0.3, 1.0]}, at_s: 2.0}\n")
    plain = _with(tmp_path, head)
    fixed = _with(tmp_path, head + "  sensing: rtk\n")
    assert {f["sensing"] for f in fixed.flights} == {"rtk"}
    assert [f["fault"] for f in fixed.flights] == [f["fault"] for f in plain.flights]
    drawn = _with(tmp_path, head + "  sensing: [truth, mocap, rtk, gnss]\n")
    assert {f["sensing"] for f in drawn.flights} <= {"truth", "mocap", "rtk", "gnss"}
    assert len({f["sensing"] for f in drawn.flights}) > 1


def test_the_shipped_sensing_campaigns():
    plan = load_campaign(PARAMS / "campaigns" / "sensing_seeds.yaml")
    # five controllers, 20 seeds; each outage under the profiles that carry its sensor
    outages = {"truth": 1, "mocap": 2, "rtk": 2, "gnss": 2}
    assert len(plan.flights) == 100 * sum(outages.values())
    assert plan.sensings == ("truth", "mocap", "rtk", "gnss")
    assert set(plan.controllers) == {"trq_nmpc_eso", "trq_nmpc_eso_fused",
                                     "trq_nmpc_eso_fused_gnss", "trq_nmpc_eso_paper", "trq_nmpc"}
    for p in plan.sensings:
        fs = [f for f in plan.flights if f["sensing"] == p]
        assert len(fs) == 100 * outages[p] and len({f["seed"] for f in fs}) == 20
        assert {json.dumps(f["fault"], sort_keys=True) for f in fs} == {json.dumps(
            {"at_s": 12.0, "effectiveness": 0.5, "motor": 1}, sort_keys=True)}
        assert {(f["wind"]["speed_m_s"], f["wind"]["direction_deg"]) for f in fs} == {(8.0, 0.0)}
    smoke = load_campaign(SENSING_SMOKE)
    assert len(smoke.flights) == 2 and smoke.sensings == ("truth", "mocap")


def _rows(plan, rmse):
    return [dict(flight_inputs(f), crashed=False, success=True, status="done",
                 rmse_pos_after_fault_m=rmse[f["sensing"]],
                 est_rmse_pos_m=None if f["sensing"] == "truth" else 0.002)
            for f in plan.flights]


def test_the_report_groups_its_tables_by_the_profile(tmp_path):
    plan = load_campaign(SENSING_SMOKE)
    rows = _rows(plan, {"truth": 0.004, "mocap": 0.006})
    assert [r["sensing"] for r in rows] == ["truth", "mocap"]
    text = write_report(plan, rows, tmp_path, figures=False).read_text()
    assert "| sensing | controller |" in text
    assert "| truth | trq_nmpc_eso | 1 | 100% |" in text
    assert "| mocap | trq_nmpc_eso | 1 | 100% | 0 | 0 | 0.006 | 0.002 |" in text
    assert "## `trq_nmpc_eso` under `truth`" in text
    assert "## `trq_nmpc_eso` under `mocap`" in text
    summary = json.loads((tmp_path / "metrics.json").read_text())
    assert summary["sensing"]["mocap"]["trq_nmpc_eso"]["rmse_median_m"] == 0.006
    # one profile: the report as it was, no sensing column
    plain = load_campaign(SMOKE)
    text = write_report(plain, _rows(plain, {"truth": 0.004}), tmp_path,
                        figures=False).read_text()
    assert "sensing" not in text and "## `trq_nmpc_eso`\n" in text
