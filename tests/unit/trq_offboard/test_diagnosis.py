"""The controller's diagnosis for the ground station (issue 20): MOT1_EFF..MOT4_EFF as
NAMED_VALUE_FLOAT at 4 Hz of vehicle time, and one STATUSTEXT per crossing of the warning
threshold, held for 100 ms so that a one-sample dip says nothing."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.diagnosis import EFF_NAMES, Diagnosis

STEP_US = 10_000                       # a 100 Hz controller


def fly(effectiveness_at, seconds: float):
    """(step, message) of every message a flight of `seconds` at 100 Hz gives."""
    d, out = Diagnosis(), []
    for k in range(round(seconds * 1e6 / STEP_US)):
        out += [(k, m) for m in d.messages(k * STEP_US, effectiveness_at(k))]
    return out


def texts(msgs):
    return [(k, m.severity, m.text) for k, m in msgs if m.get_type() == "STATUSTEXT"]


def test_values_at_four_hertz_of_vehicle_time_and_they_pack():
    msgs = fly(lambda k: (0.5, 1.0, 0.97, 1.0), 2.0)
    values = [(k, m) for k, m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"]
    assert [k for k, _ in values[::4]] == list(range(0, 200, 25))       # every 250 ms
    assert [m.name for _, m in values[:4]] == list(EFF_NAMES)
    assert [m.value for _, m in values[:4]] == pytest.approx([0.5, 1.0, 0.97, 1.0])
    assert values[4][1].time_boot_ms == 250                             # vehicle time, ms
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    for _, m in msgs:
        assert mavlink.MAVLink(None).decode(bytearray(m.pack(mav))).get_type() == m.get_type()


def test_one_warning_per_crossing_naming_motor_and_estimate():
    def e(k):        # motor 1 falls to 0.52 at step 50, recovers at step 150
        return (0.52 if 50 <= k < 150 else 1.0, 1.0, 1.0, 1.0)
    assert texts(fly(e, 3.0)) == [(60, mavlink.MAV_SEVERITY_WARNING, "motor 1 at 52 %"),
                                  (160, mavlink.MAV_SEVERITY_NOTICE, "motor 1 back at 100 %")]


def test_a_short_dip_says_nothing_and_a_weak_motor_is_announced_once():
    def dips(k):     # motor 3 dips for 50 ms every 300 ms; motor 2 weak throughout
        return (1.0, 0.6, 0.71 if k % 30 < 5 else 0.98, 1.0)
    said = texts(fly(dips, 5.0))
    assert said == [(10, mavlink.MAV_SEVERITY_WARNING, "motor 2 at 60 %")]


def test_thresholds_are_checked():
    with pytest.raises(ValueError, match="warn_below < rearm_above"):
        Diagnosis(warn_below=0.9, rearm_above=0.8)
