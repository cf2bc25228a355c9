"""trq-inject-fault's arguments into MAV_CMD_INJECT_FAILURE actions (trq_lab.gcs.inject): the
sensor units and failure types, and usage errors that name what is wrong (exit status 2)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from trq_lab.gcs import inject


def actions(*argv):
    return inject.actions_from_args(inject.build_parser().parse_args(list(argv)))


def test_sensor_off():
    (a,), text = actions("sensor", "mocap", "off")
    assert (a.unit, a.kind, a.instance) == (mavlink.FAILURE_UNIT_SENSOR_VIO,
                                            mavlink.FAILURE_TYPE_OFF, 1)
    assert math.isnan(a.param4) and text == "sensor mocap off"


def test_sensor_wrong_with_a_size():
    (a,), text = actions("sensor", "gnss", "wrong", "5")
    assert (a.unit, a.kind, a.param4) == (mavlink.FAILURE_UNIT_SENSOR_GPS,
                                          mavlink.FAILURE_TYPE_WRONG, 5.0)
    assert text == "sensor gnss wrong by 5"


@pytest.mark.parametrize("argv, words", [
    (("sensor", "lidar", "off"), ("lidar", "mocap")),
    (("sensor", "baro", "melted"), ("melted", "garbage")),
    (("sensor", "baro", "off", "3"), ("takes no value",)),
    (("sensor", "gyro", "wrong", "x"), ("not a number",)),
])
def test_bad_sensor_arguments(argv, words):
    with pytest.raises(inject.SystemExit2) as err:
        actions(*argv)
    for w in words:
        assert w in str(err.value)


def test_main_exits_2_on_a_bad_sensor(capsys):
    assert inject.main(["--connect", "udpout:127.0.0.1:9", "sensor", "lidar", "off"]) == 2
    assert "lidar" in capsys.readouterr().err
