"""trq_lab.reallogs.calibrate: a profile file that the vehicle's loader takes (`--sensing PATH`), from
a static recording of a known profile and from a PX4 log; bad input leaves nothing written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sil_vehicle.config import sensing_profile
from sil_vehicle.estimator.eskf import Eskf
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.sensors.profile import load_sensing
from trq_lab.reallogs import calibrate as cal
from trq_lab.reallogs.allan import relative_sigma, static_recording

DATA = Path(__file__).resolve().parents[2] / "data" / "ulog"
NEW = DATA / "px4_sitl_takeoff.ulg"
OLD = DATA / "px4fmu_v4pro_old_layout.ulg"


def test_a_static_recording_gives_a_profile_the_vehicle_flies(tmp_path):
    out = tmp_path / "profiles" / "bench.yaml"
    rec = tmp_path / "rec.npz"
    assert cal.main(["--static-from", "mocap", "--duration-s", "60", "--seed", "2",
                     "--extends", "mocap", "--out", str(out), "--save-recording", str(rec)]) == 0
    assert {p.name for p in out.parent.iterdir()} == {"bench.yaml", "bench.calibration.json",
                                                      "bench.allan.png"}
    text = out.read_text()
    assert "extends: builtin:sensing/mocap" in text
    prof = sensing_profile(out, 1000, "--sensing")          # what --sensing PATH loads
    ref = load_sensing("mocap", 1000)
    tol = 3 * relative_sigma(60.0, 1.0)
    assert prof.imu.gyro_noise_density_rad_s_rthz == pytest.approx(
        ref.imu.gyro_noise_density_rad_s_rthz, rel=tol)
    assert prof.imu.accel_noise_density_m_s2_rthz == pytest.approx(
        ref.imu.accel_noise_density_m_s2_rthz, rel=tol)
    assert prof.mocap == ref.mocap and prof.imu.rate_hz == ref.imu.rate_hz
    Eskf(EstimatorParams.from_profile(prof))                # the vehicle's filter takes it
    record = json.loads((tmp_path / "profiles" / "bench.calibration.json").read_text())
    assert record["reference"]["gyro"]["n_density"] == ref.imu.gyro_noise_density_rad_s_rthz
    # 60 s reaches the accelerometer's random walk (minimum at 0.5 s), not the gyro's (8 s)
    assert record["imu"]["accel"]["k_written"] and not record["imu"]["gyro"]["k_written"]
    assert "accel_bias_random_walk_m_s3_rthz" in text
    assert "gyro_bias_random_walk_rad_s2_rthz" not in text
    # the recording, saved, is what was calibrated, in the format the command reads back
    back = cal.load_recording(rec)
    _, gyro, accel = static_recording(ref.imu, 60.0, seed=2)
    assert back.rate_hz == ref.imu.rate_hz
    np.testing.assert_array_equal(back.gyro, gyro)
    np.testing.assert_array_equal(back.accel, accel)


def test_a_px4_log_gives_densities_and_its_flight_spectra(tmp_path):
    out = tmp_path / "sitl.yaml"
    assert cal.main([str(NEW), "--out", str(out)]) == 0
    prof = sensing_profile(out, 1000, "--sensing")
    record = json.loads((tmp_path / "sitl.calibration.json").read_text())
    assert record["rest_s"] >= 10 and record["rate_hz"] == pytest.approx(250.0)
    flight = record["flight"]
    assert flight["seconds"] > 5 and flight["rotor_hz"] > 10       # esc_status rpm
    for s in ("gyro", "accel"):
        assert flight["sensors"][s]["nyquist_hz"] == pytest.approx(125.0)
        assert all(p["hz"] >= cal.VIBRATION_BAND_HZ for p in flight["sensors"][s]["peaks_hz"])
    # a MEMS IMU's densities, in Gazebo's order of magnitude
    assert 1e-5 < prof.imu.gyro_noise_density_rad_s_rthz < 1e-2
    assert 1e-4 < prof.imu.accel_noise_density_m_s2_rthz < 1e-1
    assert math.isfinite(prof.imu.accel_vibration_m_s2)
    # Gazebo's IMU has no rotor vibration: no tracked peak follows the rotors, so the base's
    # lines stay (its harmonics, not the log's)
    assert not record["vibration"]["written"] and "vibration" not in out.read_text()
    assert prof.imu.vibration == load_sensing("gnss", 1000).imu.vibration


def test_a_log_never_at_rest_long_enough_is_refused_and_nothing_written(tmp_path, capsys):
    out = tmp_path / "out" / "p.yaml"
    assert cal.main([str(OLD), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "px4fmu_v4pro_old_layout.ulg" in err and "at rest" in err
    assert not out.parent.exists()


def test_a_log_without_the_imu_names_topic_and_file(tmp_path, capsys):
    from pyulog import ULog
    lacking = tmp_path / "no_imu.ulg"
    ULog(str(OLD), ["vehicle_attitude", "vehicle_local_position"]).write_ulog(str(lacking))
    out = tmp_path / "out" / "p.yaml"
    assert cal.main([str(lacking), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no_imu.ulg" in err and "sensor_combined" in err
    assert not out.parent.exists()


def test_rest_span_finds_the_longest_quiet_stretch():
    rate = 100.0
    g = np.zeros((3000, 3))
    g[1000:1200] = np.random.default_rng(0).normal(0, 0.5, (200, 3))      # handled: 2 s
    a = np.tile((0.0, 0.0, -9.80665), (3000, 1))
    rec = cal.Recording("synthetic", rate, np.arange(3000) * 10_000, g, a)
    assert cal.rest_span(rec, 10.0) == (1200, 3000)


def test_a_vibration_that_follows_the_rotors_is_found_at_its_harmonic():
    """A gyro tone at twice the rotors' rotation frequency (a two-blade pass), the rotors
    sweeping 37.5 to 45 Hz over 20 s of flight after 20 s at rest: the tracked peak is the
    second harmonic."""
    rate = 250.0
    n = int(40 * rate)
    t_us = np.arange(1, n + 1, dtype=np.int64) * 4000
    rotor_hz = np.where(np.arange(n) < n // 2, 0.0, np.linspace(30.0, 45.0, n))
    phase = 2 * np.pi * np.cumsum(2.0 * rotor_hz) / rate
    rng = np.random.default_rng(1)
    # each sample the tone's mean over its 4 ms interval, as PX4's integrated IMU logs it
    fi = 2.0 * rotor_hz / rate
    gyro = rng.normal(0, 1e-3, (n, 3)) + (0.05 * np.sinc(fi) * np.sin(phase - np.pi * fi)
                                          )[:, None] * (rotor_hz > 0)[:, None]
    accel = rng.normal(0, 1e-2, (n, 3)) + (0.0, 0.0, -9.80665)
    motors = cal.Series(t_us, np.tile(np.where(rotor_hz > 0, 0.5, 0.0)[:, None], (1, 4)))
    rpm = cal.Series(t_us, np.tile(60.0 * rotor_hz[:, None], (1, 4)))
    rec = cal.Recording("synthetic", rate, t_us, gyro, accel, motors, rpm)
    profile, record = cal.calibrate(rec, extends="gnss", name="x", min_rest_s=10.0)
    track = record["flight"]["sensors"]["gyro"]["peak_track"]
    assert track["harmonic_per_rev"] == pytest.approx(2.0, abs=0.05) and track["r2"] > 0.9
    assert record["flight"]["rotor_hz"] == pytest.approx(41.25, abs=0.5)
    # the profile's vibration: one line per rotor at twice its frequency; four rotors' lines at
    # half thrust (motor output 0.5 squared) make the tone's 0.05 rad/s, so one rotor's at full
    # speed is 0.05 / (0.25 sqrt(4)) = 0.1 rad/s per axis (the log's averaging undone)
    (line,) = profile["imu"]["vibration"]["harmonics"]
    assert line["of"] == "rotor" and line["times"] == 2
    np.testing.assert_allclose(line["gyro_rad_s"], 0.1, rtol=0.1)
    assert max(line["accel_m_s2"]) < 0.01           # no accelerometer tone: its noise only
    assert profile["imu"]["vibration"]["smear_hz"] == 1.0 and record["vibration"]["written"]
