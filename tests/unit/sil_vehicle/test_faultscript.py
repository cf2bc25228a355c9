"""Fault scripts (sil_vehicle/faultscript.py): every shipped script loads, each kind of event
becomes the MAVLink actions PROTOCOL.md defines, events are sorted stably by time, and every bad
script is a ConfigError that names the file and the dotted key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from conftest import PARAMS

from sil_vehicle.faultscript import (MOTOR, SERVO, TYPE_OFF, TYPE_OK, TYPE_STUCK, InjectAction,
                                     ParamAction, load_script)
from sil_vehicle.config import ConfigError     # the loader's, re-exported
from sil_vehicle.sensors import faults as sensor_faults

FAULT_FILES = sorted((PARAMS / "faults").glob("*.yaml"))


def write(tmp_path: Path, text: str, name: str = "script.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def one_event(tmp_path: Path, event: str, **kw):
    events = load_script(write(tmp_path, f"events:\n  - {event}\n"), **kw)
    assert len(events) == 1
    return events[0]


# --- the shipped scripts ----------------------------------------------------------------------

def test_there_are_fault_scripts():
    names = {p.name for p in FAULT_FILES}
    assert {"motor1_50.yaml", "motor1_timevarying.yaml", "tour.yaml"} <= names


@pytest.mark.parametrize("path", FAULT_FILES, ids=lambda p: p.name)
def test_every_shipped_script_loads(path):
    events = load_script(path, (-30.0, 30.0))       # within the trq servo range too
    assert events
    times = [e.at_us for e in events]
    assert times == sorted(times) and times[0] >= 0
    for e in events:
        assert e.actions and e.text
        for a in e.actions:
            assert isinstance(a, (ParamAction, InjectAction))


def test_paper_fault_script():
    (event,) = load_script(PARAMS / "faults" / "motor1_50.yaml")
    assert event.at_us == 12_000_000
    assert event.actions == (ParamAction("SIM_MOT1_EFF", 0.5), ParamAction("SIM_MOT1_TVB", 0.0))


def test_paper_timevarying_script():
    (event,) = load_script(PARAMS / "faults" / "motor1_timevarying.yaml")
    assert event.at_us == 12_000_000
    assert event.actions == (ParamAction("SIM_MOT1_EFF", 0.8), ParamAction("SIM_MOT1_TVB", 0.2),
                             ParamAction("SIM_MOT1_TVW", 0.01), ParamAction("SIM_MOT1_TVP", 0.0))


def test_tour_script_covers_every_kind():
    events = load_script(PARAMS / "faults" / "tour.yaml")
    assert [e.at_us for e in events] == [2_000_000, 4_000_000, 6_000_000, 8_000_000, 8_500_000,
                                         9_000_000, 10_000_000]
    assert events[0].actions == (ParamAction("SIM_WIND_SPD", 4.0),
                                 ParamAction("SIM_WIND_DIR", 90.0),
                                 ParamAction("SIM_GUST_EN", 1.0))
    assert events[1].actions == (ParamAction("SIM_MOT2_EFF", 0.8), ParamAction("SIM_MOT2_TVB", 0.0))
    assert events[2].actions == (InjectAction(SERVO, TYPE_STUCK, 3, 5.0),)
    assert events[3].actions == (InjectAction(MOTOR, TYPE_OFF, 4),)
    assert events[4].actions == (InjectAction(MOTOR, TYPE_OK, 4),)
    (free,) = events[5].actions
    assert (free.unit, free.kind, free.instance) == (SERVO, TYPE_OK, 3)
    clear = events[6].actions
    assert len(clear) == 16 + len(sensor_faults.UNITS)
    assert {(a.unit, a.kind, a.instance) for a in clear[16:]} == {
        (unit, TYPE_OK, 0) for unit in sensor_faults.UNITS}


# --- each kind of event -----------------------------------------------------------------------

def test_sensor_event(tmp_path):
    e = one_event(tmp_path, "{at_s: 3, sensor: mocap, failure: off}")
    (a,) = e.actions
    assert (a.unit, a.kind, a.instance) == (6, sensor_faults.OFF, 1) and math.isnan(a.param4)
    assert e.text == "mocap off"
    e = one_event(tmp_path, "{at_s: 3, sensor: gnss, failure: wrong, size: 5}")
    (a,) = e.actions
    assert (a.unit, a.kind, a.instance, a.param4) == (4, sensor_faults.WRONG, 1, 5.0)
    assert e.text == "gnss wrong by 5"
    (a,) = one_event(tmp_path, "{at_s: 3, sensor: gyro, failure: garbage}").actions
    assert (a.unit, a.kind) == (0, sensor_faults.GARBAGE) and math.isnan(a.param4)


@pytest.mark.parametrize("text, words", [
    ("{at_s: 1, sensor: lidar, failure: off}", ("sensor", "lidar")),
    ("{at_s: 1, sensor: baro, failure: melted}", ("failure", "melted")),
    ("{at_s: 1, sensor: baro, failure: off, size: 2}", ("size", "2")),
    ("{at_s: 1, sensor: baro}", ("failure",)),
])
def test_bad_sensor_event_names_key_and_value(tmp_path, text, words):
    with pytest.raises(ConfigError) as err:
        one_event(tmp_path, text)
    for w in words:
        assert w in str(err.value)


def test_protocol_constants():
    # MAV_CMD_INJECT_FAILURE units and types of PROTOCOL.md
    assert (MOTOR, SERVO, TYPE_OK, TYPE_OFF, TYPE_STUCK) == (101, 102, 0, 1, 2)


def test_effectiveness(tmp_path):
    e = one_event(tmp_path, "{at_s: 1.5, motor: 3, effectiveness: 0.25}")
    assert e.at_us == 1_500_000
    assert e.actions == (ParamAction("SIM_MOT3_EFF", 0.25), ParamAction("SIM_MOT3_TVB", 0.0))
    assert "motor 3" in e.text and "0.25" in e.text


def test_time_varying_with_and_without_phase(tmp_path):
    e = one_event(tmp_path, "{at_s: 0, motor: 2, time_varying: {a: 0.9, b: 0.1, w: 2, phi: -1.5}}")
    assert e.at_us == 0
    assert e.actions == (ParamAction("SIM_MOT2_EFF", 0.9), ParamAction("SIM_MOT2_TVB", 0.1),
                         ParamAction("SIM_MOT2_TVW", 2.0), ParamAction("SIM_MOT2_TVP", -1.5))
    e = one_event(tmp_path, "{at_s: 3, motor: 4, time_varying: {a: 0.8, b: 0.2, w: 0.01}}")
    assert e.actions[-1] == ParamAction("SIM_MOT4_TVP", 0.0)      # phi defaults to 0


def test_stopped_true_and_false(tmp_path):
    e = one_event(tmp_path, "{at_s: 2, motor: 1, stopped: true}")
    assert e.actions == (InjectAction(MOTOR, TYPE_OFF, 1),)
    assert math.isnan(e.actions[0].param4)
    e = one_event(tmp_path, "{at_s: 2, motor: 1, stopped: false}")
    assert e.actions == (InjectAction(MOTOR, TYPE_OK, 1),)


def test_servo_stuck_and_freed(tmp_path):
    e = one_event(tmp_path, "{at_s: 1, servo: 2, stuck_deg: -12.5}")
    assert e.actions == (InjectAction(SERVO, TYPE_STUCK, 2, -12.5),)
    e = one_event(tmp_path, "{at_s: 1, servo: 4, stuck_deg: 7}")     # an int angle is a float
    (a,) = e.actions
    assert a.param4 == 7.0 and isinstance(a.param4, float)
    e = one_event(tmp_path, "{at_s: 1, servo: 2, stuck_deg: null}")
    (a,) = e.actions
    assert (a.unit, a.kind, a.instance) == (SERVO, TYPE_OK, 2)


def test_wind(tmp_path):
    e = one_event(tmp_path, "{at_s: 5, wind: {speed_m_s: 8, direction_deg: -45, gusts: false, "
                            "gust_sigma_m_s: 1.5}}")
    assert e.actions == (ParamAction("SIM_WIND_SPD", 8.0), ParamAction("SIM_WIND_DIR", -45.0),
                         ParamAction("SIM_GUST_EN", 0.0), ParamAction("SIM_GUST_SIG", 1.5))
    e = one_event(tmp_path, "{at_s: 5, wind: {gusts: true}}")
    assert e.actions == (ParamAction("SIM_GUST_EN", 1.0),)


def test_clear(tmp_path):
    e = one_event(tmp_path, "{at_s: 10, clear: true}")
    assert len(e.actions) == 16 + len(sensor_faults.UNITS)
    for n in range(1, 5):
        assert ParamAction(f"SIM_MOT{n}_EFF", 1.0) in e.actions
        assert ParamAction(f"SIM_MOT{n}_TVB", 0.0) in e.actions
        assert InjectAction(MOTOR, TYPE_OK, n) in e.actions
        assert any(isinstance(a, InjectAction) and (a.unit, a.kind, a.instance)
                   == (SERVO, TYPE_OK, n) for a in e.actions)


def test_sorted_by_time_and_stable(tmp_path):
    path = write(tmp_path, "events:\n"
                 "  - {at_s: 3.0, motor: 1, effectiveness: 0.1}\n"
                 "  - {at_s: 1.0, motor: 2, effectiveness: 0.2}\n"
                 "  - {at_s: 3.0, motor: 3, effectiveness: 0.3}\n"
                 "  - {at_s: 1.0, motor: 4, effectiveness: 0.4}\n"
                 "  - {at_s: 0.000001, servo: 1, stuck_deg: 1}\n")
    events = load_script(path)
    assert [e.at_us for e in events] == [1, 1_000_000, 1_000_000, 3_000_000, 3_000_000]
    first = [e.actions[0] for e in events]
    assert [a.name for a in first[1:]] == ["SIM_MOT2_EFF", "SIM_MOT4_EFF", "SIM_MOT1_EFF",
                                           "SIM_MOT3_EFF"]


# --- bad scripts ------------------------------------------------------------------------------

BAD_EVENTS = [
    ("motor 5",
     "[{at_s: 1, motor: 1, effectiveness: 0.5}, {at_s: 2, motor: 5, effectiveness: 0.5}]",
     "events[1].motor"),
    ("motor 0", "[{at_s: 1, motor: 0, stopped: true}]", "events[0].motor"),
    ("effectiveness 1.5", "[{at_s: 1, motor: 1, effectiveness: 1.5}]", "events[0].effectiveness"),
    ("negative effectiveness", "[{at_s: 1, motor: 1, effectiveness: -0.1}]",
     "events[0].effectiveness"),
    ("time-varying b out of range", "[{at_s: 1, motor: 1, time_varying: {a: 0.8, b: 2, w: 1}}]",
     "events[0].time_varying.b"),
    ("time-varying unknown key",
     "[{at_s: 1, motor: 1, time_varying: {a: 0.8, b: 0.2, w: 1, omega: 3}}]",
     "events[0].time_varying.omega"),
    ("servo angle beyond 90", "[{at_s: 1, servo: 1, stuck_deg: 95}]", "events[0].stuck_deg"),
    ("servo angle a string", "[{at_s: 1, servo: 1, stuck_deg: here}]", "events[0].stuck_deg"),
    ("servo angle a bool", "[{at_s: 1, servo: 1, stuck_deg: true}]", "events[0].stuck_deg"),
    ("servo without angle", "[{at_s: 1, servo: 1}]", "events[0].stuck_deg"),
    ("unknown key", "[{at_s: 1, motor: 1, effectiveness: 0.5, efficiency: 0.4}]",
     "events[0].efficiency"),
    ("unknown wind key", "[{at_s: 1, wind: {speed: 3}}]", "events[0].wind.speed"),
    ("empty wind", "[{at_s: 1, wind: {}}]", "events[0].wind"),
    ("missing at_s", "[{at_s: 1, motor: 1, effectiveness: 0.5}, {motor: 1, effectiveness: 0.5}]",
     "events[1].at_s"),
    ("negative at_s", "[{at_s: -1, motor: 1, effectiveness: 0.5}]", "events[0].at_s"),
    ("at_s a string", "[{at_s: soon, motor: 1, effectiveness: 0.5}]", "events[0].at_s"),
    ("motor without action", "[{at_s: 1, motor: 2}]", "events[0].motor"),
    ("none of motor/servo/wind/clear",
     "[{at_s: 1, motor: 1, effectiveness: 0.5}, {at_s: 2, effectiveness: 0.5}]", "'events[1]'"),
    ("clear false", "[{at_s: 1, clear: false}]", "events[0].clear"),
    ("stopped not a bool", "[{at_s: 1, motor: 1, stopped: 1}]", "events[0].stopped"),
    ("non-mapping event", "[{at_s: 1, motor: 1, effectiveness: 0.5}, motor 1 off]", "events[1]"),
    ("a list as event", "[[1, 2]]", "events[0]"),
    # the loader reads booleans as YAML 1.2 does (true/false only): `off` stays a string key
    ("off instead of stopped", "[{at_s: 1, motor: 1, off: true}]", "events[0]"),
    ("stopped: off is not a boolean", "[{at_s: 1, motor: 1, stopped: off}]", "events[0].stopped"),
    ("off next to an action", "[{at_s: 1, motor: 1, effectiveness: 0.5, off: true}]",
     "events[0]"),
]


@pytest.mark.parametrize("name, events, key", BAD_EVENTS, ids=[b[0] for b in BAD_EVENTS])
def test_bad_event_names_file_and_key(tmp_path, name, events, key):
    path = write(tmp_path, f"events: {events}\n", name="bad_script.yaml")
    with pytest.raises(ConfigError) as info:
        load_script(path)
    message = str(info.value)
    assert "bad_script.yaml" in message
    assert key in message, message


def test_off_key_beside_another_unknown_key(tmp_path):
    path = write(tmp_path, "events: [{at_s: 1, motor: 1, stopped: true, off: true, zz: 1}]\n",
                 name="mixed.yaml")
    with pytest.raises(ConfigError, match=r"mixed\.yaml.*events\[0\]"):
        load_script(path)


def test_stuck_angle_outside_the_tilt_range(tmp_path):
    path = write(tmp_path, "events: [{at_s: 1, servo: 3, stuck_deg: 45}]\n", name="tilt.yaml")
    (event,) = load_script(path)                      # inside the default +-90
    assert event.actions[0].param4 == 45.0
    with pytest.raises(ConfigError) as info:
        load_script(path, (-30.0, 30.0))
    assert "tilt.yaml" in str(info.value) and "events[0].stuck_deg" in str(info.value)
    assert "45" in str(info.value)
    (event,) = load_script(write(tmp_path, "events: [{at_s: 1, servo: 3, stuck_deg: -30}]\n"),
                           (-30.0, 30.0))             # the limit itself is in range
    assert event.actions[0].param4 == -30.0


@pytest.mark.parametrize("text", ["events: []\n", "events: {at_s: 1, motor: 1, stopped: true}\n",
                                  "events: motor 1 off\n", "events: null\n", "events:\n"],
                         ids=["empty", "mapping", "string", "null", "bare"])
def test_events_must_be_a_non_empty_list(tmp_path, text):
    path = write(tmp_path, text, name="events.yaml")
    with pytest.raises(ConfigError) as info:
        load_script(path)
    assert "events.yaml" in str(info.value) and "'events'" in str(info.value)


def test_missing_events_and_unknown_top_level_key(tmp_path):
    with pytest.raises(ConfigError, match=r"top\.yaml.*events"):
        load_script(write(tmp_path, "event: [{at_s: 1, clear: true}]\n", name="top.yaml"))
    with pytest.raises(ConfigError, match=r"extra\.yaml.*unknown key 'note'"):
        load_script(write(tmp_path, "events: [{at_s: 1, clear: true}]\nnote: hi\n",
                          name="extra.yaml"))


def test_not_a_mapping_or_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="list.yaml"):
        load_script(write(tmp_path, "- {at_s: 1, clear: true}\n", name="list.yaml"))
    with pytest.raises(ConfigError, match="nowhere.yaml"):
        load_script(tmp_path / "nowhere.yaml")
