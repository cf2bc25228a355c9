"""Sensor faults on the readings (sil_vehicle.sensors.faults): each MAV_CMD_INJECT_FAILURE type
does what its table says to each sensor's readings, OK ends it, garbage is seeded, and nothing
is touched while no fault is active."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.sensors import faults
from sil_vehicle.sensors.baro import BaroReading, isa_pressure_pa
from sil_vehicle.sensors.faults import GARBAGE, OFF, OK, STUCK, WRONG, SensorFaults
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mag import MagReading
from sil_vehicle.sensors.mocap import MocapReading


def imu_r(t, k=0.0):
    return ImuReading(t, (0.1 + k, 0.2 + k, 0.3 + k), (1.0 + k, 2.0 + k, -9.8 + k))


def baro_r(t, alt=130.0):
    return BaroReading(t, isa_pressure_pa(alt), alt, 15.0)


def mag_r(t):
    return MagReading(t, np.array((0.2, 0.0, 0.4)))


def gnss_r(t, n=1.0):
    return GnssReading(t, t + 100_000, np.array((n, 2.0, -3.0)), np.array((0.1, 0.2, 0.3)),
                       3, 12, 0.5, 0.8, 0.1)


def mocap_r(t, n=1.0):
    return MocapReading(t, t + 10_000, np.array((n, 2.0, -3.0)), np.array((1.0, 0.0, 0.0, 0.0)))


def tick(t):
    return [imu_r(t, t * 1e-6), baro_r(t), mag_r(t), gnss_r(t), mocap_r(t)]


def test_the_units_are_mavlinks():
    from pymavlink.dialects.v20 import common as mavlink
    for unit, name in faults.UNITS.items():
        enum = mavlink.enums["FAILURE_UNIT"][unit].name
        assert enum.startswith("FAILURE_UNIT_SENSOR_")
    assert faults.UNITS[mavlink.FAILURE_UNIT_SENSOR_VIO] == "mocap"
    assert (OK, OFF, STUCK, GARBAGE, WRONG) == (
        mavlink.FAILURE_TYPE_OK, mavlink.FAILURE_TYPE_OFF, mavlink.FAILURE_TYPE_STUCK,
        mavlink.FAILURE_TYPE_GARBAGE, mavlink.FAILURE_TYPE_WRONG)


def test_no_fault_returns_the_same_list():
    f = SensorFaults(np.random.default_rng(0))
    readings = tick(1000)
    assert f.apply(readings) is readings
    assert f.describe() == "none"


@pytest.mark.parametrize("unit, kind", [(u, k) for u in faults.SENSOR for k in (OFF,)])
def test_off_silences_the_sensor_and_ok_restores_it(unit, kind):
    f = SensorFaults(np.random.default_rng(0))
    f.set(unit, kind)
    out = f.apply(tick(1000))
    cls = {"imu": ImuReading, "baro": BaroReading, "mag": MagReading, "gnss": GnssReading,
           "mocap": MocapReading}[faults.SENSOR[unit]]
    assert not any(isinstance(r, cls) for r in out)
    assert len(out) == 4                    # the other sensors untouched
    f.set(unit, OK)
    assert len(f.apply(tick(2000))) == 5 and not f.active


def test_stuck_holds_the_last_reading_with_fresh_times():
    f = SensorFaults(np.random.default_rng(0))
    f.set("gyro", STUCK, latest=imu_r(0, 5.0))
    f.set("mocap", STUCK, latest=mocap_r(0, n=7.0))
    f.set("baro", STUCK, latest=baro_r(0, alt=99.0))
    out = f.apply(tick(1000))
    imu, baro, _, _, mocap = out
    assert imu.t_us == 1000 and imu.gyro == (5.1, 5.2, 5.3)
    assert imu.accel == imu_r(1000, 1e-3).accel               # the accelerometer is healthy
    assert mocap.t_us == 1000 and mocap.arrival_us == 11_000 and mocap.pos_ned_m[0] == 7.0
    assert baro.t_us == 1000 and baro.pressure_alt_m == 99.0


def test_wrong_adds_its_size_or_the_default():
    f = SensorFaults(np.random.default_rng(0))
    f.set("accel", WRONG, 0.5)
    f.set("gnss", WRONG)
    f.set("baro", WRONG, -4.0)
    f.set("mag", WRONG, 90.0)
    imu, baro, mag, gnss, _ = f.apply(tick(0))
    assert imu.accel == pytest.approx((1.5, 2.5, -9.3)) and imu.gyro == imu_r(0).gyro
    assert gnss.pos_ned_m == pytest.approx((1.0 + faults.WRONG_DEFAULT["gnss"], 2.0, -3.0))
    assert baro.pressure_alt_m == 126.0 and baro.pressure_pa == isa_pressure_pa(126.0)
    assert mag.field_frd_gauss == pytest.approx((0.0, 0.2, 0.4))      # turned 90 deg
    assert "gnss wrong by 10" in f.describe()


def test_garbage_is_in_range_and_seeded():
    def run(seed):
        f = SensorFaults(np.random.default_rng(seed))
        for unit in faults.SENSOR:
            f.set(unit, GARBAGE)
        return f.apply(tick(0))
    a, b, c = run(1), run(1), run(2)
    assert np.allclose(a[3].pos_ned_m, b[3].pos_ned_m)
    assert not np.allclose(a[3].pos_ned_m, c[3].pos_ned_m)
    imu, baro, mag, gnss, mocap = a
    assert max(abs(v) for v in imu.gyro) <= faults.GARBAGE_RANGE["gyro"]
    assert max(abs(v) for v in imu.accel) <= faults.GARBAGE_RANGE["accel"]
    assert abs(baro.pressure_alt_m) <= faults.GARBAGE_RANGE["baro"]
    assert np.abs(mag.field_frd_gauss).max() <= faults.GARBAGE_RANGE["mag"]
    assert np.abs(gnss.pos_ned_m).max() <= faults.GARBAGE_RANGE["gnss"]
    assert math.isclose(np.linalg.norm(mocap.quat_wxyz), 1.0)


def test_a_bad_unit_or_kind_is_refused():
    f = SensorFaults(np.random.default_rng(0))
    with pytest.raises(ValueError, match="lidar"):
        f.set("lidar", OFF)
    with pytest.raises(ValueError, match="9"):
        f.set("baro", 9)
