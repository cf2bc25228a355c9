"""The outage axis of a campaign (trq_lab.campaign.spec): derived from its schema model
(AXIS_MODELS) as the other axes are; `none` (or the axis left out) keeps a campaign's ids and
flights; an outage enters the spec and the id but not the seed; its two sensor events (off at
at_s, ok at at_s + duration_s) join the flight's fault script beside the fault, whose onset stays
the fault's; a grid's outage flies under the profiles that carry its sensor; a bad outage
(unknown sensor, a duration not above 0, a missing or unknown key, a sensor no profile carries)
is refused naming the file, the key and the value; flights.csv gains the outage's columns with
the axis only."""

from __future__ import annotations

import pytest
from conftest import PARAMS
from sil_vehicle.faultscript import InjectAction
from sil_vehicle.sensors import faults as sensor_faults
from trq_params import ConfigError
from trq_params.schema import OUTAGE_METRICS, OutageAxis

from trq_lab.campaign.flight import flight_script
from trq_lab.campaign.spec import (AXIS_KEYS, flight_id, load_campaign, outage_events,
                                   outage_label, outage_window_us)
from trq_lab.campaign.store import flight_inputs, metric_keys, rows_of

SMOKE = PARAMS / "campaigns" / "smoke.yaml"
SENSING_SMOKE = PARAMS / "campaigns" / "sensing_smoke.yaml"
OUTAGE_SMOKE = PARAMS / "campaigns" / "outage_smoke.yaml"
MOCAP_1S = "{sensor: mocap, at_s: 2.0, duration_s: 1.0}"


def _with(tmp_path, text: str, name: str = "c.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return load_campaign(path)


def _mocap(text: str) -> str:
    """sensing_smoke under mocap alone (its grid's last line is the sensing axis)."""
    return text.replace("  sensing: [truth, mocap]\n", "  sensing: mocap\n")


def test_the_axis_is_its_schema_model():
    assert set(AXIS_KEYS["outage"]) == set(OutageAxis.model_fields) == {
        "sensor", "at_s", "duration_s"}
    assert AXIS_KEYS["outage"]["sensor"].kind == "text"
    assert AXIS_KEYS["outage"]["duration_s"].kind == "float"


def test_none_or_no_axis_keeps_the_ids_and_flights(tmp_path):
    plain = load_campaign(SMOKE)
    assert plain.outages == ("none",)
    assert all("outage" not in f for f in plain.flights)
    none = _with(tmp_path, SMOKE.read_text() + "  outage: none\n")
    assert none.flights == plain.flights and none.outages == ("none",)
    listed = _with(tmp_path, SMOKE.read_text() + "  outage: [none]\n")
    assert listed.flights == plain.flights


def test_an_outage_enters_the_id_but_not_the_seed(tmp_path):
    base = _with(tmp_path, _mocap(SENSING_SMOKE.read_text()))
    both = _with(tmp_path, _mocap(SENSING_SMOKE.read_text())
                 + f"  outage: [none, {MOCAP_1S}]\n")
    assert len(both.flights) == 2 * len(base.flights)
    assert both.outages == ("none", "mocap 2-3 s")
    without = [f for f in both.flights if "outage" not in f]
    with_ = [f for f in both.flights if "outage" in f]
    assert without == list(base.flights)                     # the same specs, ids and seeds
    assert [f["seed"] for f in with_] == [f["seed"] for f in without]   # common random numbers
    assert not {f["id"] for f in with_} & {f["id"] for f in without}
    assert with_[0]["outage"] == {"sensor": "mocap", "at_s": 2.0, "duration_s": 1.0}
    assert all(f["id"] == flight_id(f) for f in both.flights)
    # a list of values in a key is a dimension, as in every axis
    two = _with(tmp_path, _mocap(SENSING_SMOKE.read_text())
                + "  outage: {sensor: mocap, at_s: 2.0, duration_s: [0.5, 1.0]}\n")
    assert two.outages == ("mocap 2-2.5 s", "mocap 2-3 s")


def test_the_outage_events_join_the_fault_script():
    spec = next(f for f in load_campaign(OUTAGE_SMOKE).flights if "outage" in f)
    events, onset, window = flight_script(spec)
    assert [e.at_us for e in events] == [1_500_000, 2_000_000, 3_000_000]
    assert onset == 1_500_000                 # the fault's onset, not the outage's
    assert window == (2_000_000, 3_000_000)
    mocap = sensor_faults.UNIT_OF["mocap"]
    for event, kind in ((events[1], sensor_faults.OFF), (events[2], sensor_faults.OK)):
        (action,) = event.actions
        assert isinstance(action, InjectAction)
        assert (action.unit, action.kind, action.instance) == (mocap, kind, 1)
    assert "mocap off" in events[1].text and "mocap ok" in events[2].text
    # without an outage: the fault's event alone, no window
    plain = next(f for f in load_campaign(OUTAGE_SMOKE).flights if "outage" not in f)
    events, onset, window = flight_script(plain)
    assert [e.at_us for e in events] == [1_500_000] and window is None
    # an outage before the fault: still in time order, the onset still the fault's
    early = dict(spec, outage={"sensor": "mocap", "at_s": 0.5, "duration_s": 0.25})
    events, onset, window = flight_script(early)
    assert [e.at_us for e in events] == [500_000, 750_000, 1_500_000] and onset == 1_500_000


def test_the_window_is_whole_microseconds():
    outage = {"sensor": "gnss", "at_s": 14.0000004, "duration_s": 5.0}
    assert outage_window_us(outage) == (14_000_000, 19_000_000)
    assert [e.at_us for e in outage_events(outage, "f", "outage")] == [14_000_000, 19_000_000]
    assert outage_label(outage).startswith("gnss 14-19")
    assert outage_label(None) == "none" and outage_events(None, "f", "outage") == ()


@pytest.mark.parametrize("value, key, words", [
    ("{sensor: lidar, at_s: 2.0, duration_s: 1.0}", "grid.outage.sensor", "lidar"),
    ("{sensor: mocap, at_s: 2.0, duration_s: -1.0}", "grid.outage.duration_s", "-1"),
    ("{sensor: mocap, at_s: 2.0, duration_s: 0.0}", "grid.outage.duration_s", "(0,"),
    ("{sensor: mocap, at_s: -2.0, duration_s: 1.0}", "grid.outage.at_s", "-2"),
    ("{sensor: mocap, at_s: 2.0}", "grid.outage.duration_s", "missing"),
    ("{sensor: mocap, at_s: 2.0, duration_s: 1.0, size: 3}", "grid.outage.size", "unknown"),
    ("[none, {sensor: mocap, at_s: 2.0, duration_s: 1.0}, off]", "grid.outage[2]", "off"),
    # a sensor the profile does not carry: the vehicle would refuse the fault
    ("{sensor: gnss, at_s: 2.0, duration_s: 1.0}", "grid.outage.sensor", "mocap: baro, imu"),
])
def test_a_bad_outage_names_the_file_key_and_value(tmp_path, value, key, words):
    path = tmp_path / "bad.yaml"
    path.write_text(_mocap(SENSING_SMOKE.read_text()) + f"  outage: {value}\n")
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    msg = str(err.value)
    assert str(path) in msg and f"'{key}" in msg and words in msg, msg


def test_an_outage_flies_under_the_profiles_that_carry_its_sensor(tmp_path):
    """A grid's outage flies under each profile that carries its sensor, and not under the
    others (there it would be the flight without it); one that no profile carries is refused."""
    both = _with(tmp_path, SENSING_SMOKE.read_text().replace(
        "  sensing: [truth, mocap]\n", "  sensing: [truth, mocap, rtk]\n")
        + "  outage: [none, {sensor: mocap, at_s: 2.0, duration_s: 1.0},\n"
          "           {sensor: gnss, at_s: 2.0, duration_s: 5.0}]\n")
    assert [(f["sensing"], outage_label(f.get("outage"))) for f in both.flights] == [
        ("truth", "none"), ("mocap", "none"), ("mocap", "mocap 2-3 s"), ("rtk", "none"),
        ("rtk", "gnss 2-7 s")]
    with pytest.raises(ConfigError, match=r"'grid.outage.sensor': got 'mocap'.*\(truth: none\)"):
        _with(tmp_path, SMOKE.read_text() + f"  outage: {MOCAP_1S}\n")


def test_a_sample_draws_an_outage_and_checks_every_draw(tmp_path):
    head = _mocap(SENSING_SMOKE.read_text()).split("grid:")[0] + (
        "sample:\n  n: 5\n  seed: 3\n  sensing: mocap\n"
        "  fault: {motor: 1, effectiveness: 0.6, at_s: 1.5}\n")
    plain = _with(tmp_path, head)
    drawn = _with(tmp_path, head + "  outage: {sensor: mocap, at_s: {uniform: [1.0, 3.0]}, "
                  "duration_s: [0.5, 1.0]}\n")
    # the fixed cell is one flight without the outage (the same draw five times), five with it,
    # all on its seed
    assert len(plain.flights) == 1 and len(drawn.flights) == 5
    assert {f["seed"] for f in drawn.flights} == {plain.flights[0]["seed"]}
    assert all(1.0 <= f["outage"]["at_s"] <= 3.0 for f in drawn.flights)
    assert {f["outage"]["duration_s"] for f in drawn.flights} <= {0.5, 1.0}
    # the outage draws from its own generator: the other axes' draws do not move
    wide = head.replace("{motor: 1, effectiveness: 0.6, at_s: 1.5}",
                        "{motor: [1, 2, 3, 4], effectiveness: {uniform: [0.3, 1.0]}, at_s: 1.5}")
    faults = [f["fault"] for f in _with(tmp_path, wide).flights]
    assert [f["fault"] for f in _with(tmp_path, wide + "  outage: {sensor: mocap, at_s: "
                                      "{uniform: [1.0, 3.0]}, duration_s: [0.5, 1.0]}\n"
                                      ).flights] == faults
    with pytest.raises(ConfigError, match=r"sample.outage.sensor.*draw"):
        _with(tmp_path, head + "  outage: {sensor: [mocap, gnss], at_s: 2.0, duration_s: 1.0}\n")


def test_a_target_on_the_outage_metric_names_a_flown_outage(tmp_path):
    assert "max_pos_err_outage_m" in OUTAGE_METRICS
    text = OUTAGE_SMOKE.read_text()
    plan = load_campaign(OUTAGE_SMOKE)
    assert [t.outage for t in plan.flight_targets] == ["mocap"]
    with pytest.raises(ConfigError, match=r"'flight_targets\[0\].outage': got None"):
        _with(tmp_path, text.replace("outage: mocap, metric", "metric"))
    with pytest.raises(ConfigError, match=r"'flight_targets\[0\].outage': got 'none'"):
        _with(tmp_path, text.replace("outage: mocap, metric", "outage: none, metric"))
    with pytest.raises(ConfigError, match=r"'flight_targets\[0\].outage': got 'gnss'.*mocap"):
        _with(tmp_path, text.replace("outage: mocap, metric", "outage: gnss, metric"))


def test_flights_csv_gains_the_outage_columns_with_the_axis_only():
    plan = load_campaign(OUTAGE_SMOKE)
    results = {f["id"]: {"id": f["id"], "status": "done", "metrics": {
        "crashed": False, "max_pos_err_outage_m": 0.02 if "outage" in f else None}}
        for f in plan.flights}
    rows = rows_of(plan, results)
    assert {tuple(r) for r in rows} == {tuple(rows[0])}      # one header for every row
    assert [r["outage"] for r in rows] == ["none", "none", "mocap 2-3 s", "mocap 2-3 s"]
    assert [r["outage_sensor"] for r in rows] == [None, None, "mocap", "mocap"]
    assert [r["outage_duration_s"] for r in rows] == [None, None, 1.0, 1.0]
    assert [r["max_pos_err_outage_m"] for r in rows] == [None, None, 0.02, 0.02]
    smoke = load_campaign(SMOKE)
    assert "max_pos_err_outage_m" not in metric_keys(smoke)
    row = rows_of(smoke, {f["id"]: {"id": f["id"], "status": "done", "metrics": {}}
                          for f in smoke.flights})[0]
    assert not any(k.startswith("outage") or "outage" in k for k in row)
    assert "outage" not in flight_inputs(smoke.flights[0])
