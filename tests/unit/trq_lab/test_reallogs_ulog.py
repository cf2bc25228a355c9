"""trq_lab.reallogs.ulog: both of PX4's topic layouts read from the test logs (tests/data/ulog), and
a log lacking a topic named with its file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trq_lab.reallogs.ulog import LogError, gnss_to_ned, read_ulog

DATA = Path(__file__).resolve().parents[2] / "data" / "ulog"
NEW = DATA / "px4_sitl_takeoff.ulg"
OLD = DATA / "px4fmu_v4pro_old_layout.ulg"


def test_the_new_layout_reads_each_sensor_from_its_own_topic():
    log = read_ulog(NEW)
    assert "vehicle_magnetometer" in log.topics and "sensor_gps" in log.topics
    assert log.gyro_rad_s.values.shape == (len(log.gyro_rad_s), 3)
    # at rest on the ground at the start: the specific force is g upward in body FRD
    assert np.linalg.norm(log.accel_m_s2.values[:100].mean(axis=0)) == pytest.approx(9.8, abs=0.1)
    assert log.accel_m_s2.values[:100, 2].mean() < -9.5
    assert 0.1 < np.linalg.norm(log.mag_gauss.values[0]) < 1.0       # gauss: the earth's field
    assert log.baro_alt_m is not None and log.gnss is not None
    assert -90 <= log.gnss.values[0, 0] <= 90 and -180 <= log.gnss.values[0, 1] <= 180
    assert log.ekf2_origin is not None and set(log.ekf2_innovations) >= {"gnss_pos", "baro"}
    assert log.rotor_rpm is not None and log.motor_fraction is not None
    assert log.params["EKF2_GYR_NOISE"] == pytest.approx(0.015)


def test_the_old_layout_takes_magnetometer_and_barometer_from_sensor_combined():
    log = read_ulog(OLD)
    assert "vehicle_magnetometer" not in log.topics and "vehicle_air_data" not in log.topics
    assert log.mag_gauss is not None and log.baro_alt_m is not None
    # each reading once, at its own time (sensor_combined repeats it with a relative stamp)
    assert np.all(np.diff(log.mag_gauss.t_us) > 0) and np.all(np.diff(log.baro_alt_m.t_us) > 0)
    assert len(log.mag_gauss) < len(log.gyro_rad_s) / 2
    assert log.gnss is None and log.ekf2_test_ratios is not None


def test_require_names_the_topic_and_the_file():
    log = read_ulog(OLD)
    with pytest.raises(LogError, match=r"px4fmu_v4pro_old_layout\.ulg: a command needs topic "
                                       r"sensor_gps"):
        log.require("gnss", for_="a command")


def test_a_file_that_is_not_a_ulog_is_a_log_error(tmp_path):
    bad = tmp_path / "notes.ulg"
    bad.write_bytes(b"not a log at all")
    with pytest.raises(LogError, match="notes.ulg"):
        read_ulog(bad)
    with pytest.raises(LogError, match="no such file"):
        read_ulog(tmp_path / "missing.ulg")


def test_gnss_to_ned_a_metre_north_and_east():
    lat0, lon0 = 47.0, 8.0
    d = 1.0 / 6_371_000.0
    ned = gnss_to_ned(np.array([lat0 + np.degrees(d)]), np.array([lon0]), np.array([401.0]),
                      (lat0, lon0, 400.0))
    np.testing.assert_allclose(ned, [[1.0, 0.0, -1.0]], atol=1e-6)
