"""trq_lab.reallogs.allan: the static recording is the vehicle's IMU model at rest, and a few
minutes of it calibrate back to its profile within the Allan estimator's own confidence (three
standard errors of the point each figure is read at; the one-hour check is a recorded run:
docs/decisions/2026-12-05-ulog-replay-calibration.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.sensors import imu as imu_model
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2, Truth
from trq_lab.reallogs.allan import (allan_fit, model_bias_instability, relative_sigma,
                                static_recording)

IMU = load_sensing("gnss", 1000).imu
DURATION_S = 200.0


def test_the_static_recording_is_the_imu_model_sample_for_sample():
    t, gyro, accel = static_recording(IMU, 0.05, seed=11)
    rng = np.random.default_rng(11)
    state = imu_model.initial(IMU, rng)
    for k in range(len(t)):
        truth = Truth(int(t[k]), (0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                      (0.0, 0.0, -STANDARD_GRAVITY_M_S2), (0.0,) * 4)
        state, r = imu_model.step(IMU, state, truth, imu_model.draw(rng))
        assert tuple(gyro[k]) == tuple(r.gyro) and tuple(accel[k]) == tuple(r.accel)


def test_the_vehicles_imu_with_its_vibration_lines_at_rest_is_the_recording():
    """The vehicle's own IMU (the sensor suite's, vibration lines on, the airframe's rotors) with
    the motors stopped: the lines' amplitude is zero, the samples the recording's, bit for bit."""
    from sil_vehicle.sensors import suite
    assert IMU.vibration is not None
    t, gyro, accel = static_recording(IMU, 0.3, seed=5)
    vehicle_imu = suite._Imu(IMU, np.random.default_rng(5), suite._rotor(None, IMU), "gnss")
    for k in range(len(t)):
        truth = Truth(int(t[k]), (0.0,) * 3, (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                      (0.0, 0.0, -STANDARD_GRAVITY_M_S2), (0.0,) * 4)
        r = vehicle_imu.step(truth)
        assert tuple(gyro[k]) == tuple(r.gyro) and tuple(accel[k]) == tuple(r.accel)


def test_model_bias_instability_is_the_curves_flat_minimum():
    n, k = IMU.gyro_noise_density_rad_s_rthz, IMU.gyro_bias_random_walk_rad_s2_rthz
    taus = np.logspace(-2, 4, 20001)
    floor = np.sqrt(n * n / taus + k * k * taus / 3).min()
    assert model_bias_instability(n, k) * 0.664 == pytest.approx(floor, rel=1e-6)


@pytest.fixture(scope="module")
def fits():
    _, gyro, accel = static_recording(IMU, DURATION_S, seed=3)
    return allan_fit(gyro, IMU.rate_hz), allan_fit(accel, IMU.rate_hz)


@pytest.mark.parametrize("sensor", [0, 1], ids=["gyro", "accel"])
def test_a_short_static_recording_calibrates_back_within_the_estimators_confidence(fits, sensor):
    fit = fits[sensor]
    n_ref, k_ref = ((IMU.gyro_noise_density_rad_s_rthz, IMU.gyro_bias_random_walk_rad_s2_rthz),
                    (IMU.accel_noise_density_m_s2_rthz,
                     IMU.accel_bias_random_walk_m_s3_rthz))[sensor]
    b_ref = model_bias_instability(n_ref, k_ref)
    tau_b = math.sqrt(3) * n_ref / k_ref                  # where the curve's minimum lies
    for axis in range(3):
        # N read at 1 s: fitted over every tau, it is better than one point's error
        assert fit.n_density[axis] == pytest.approx(n_ref, rel=3 * relative_sigma(DURATION_S,
                                                                                  1.0))
        assert fit.bias_instability[axis] == pytest.approx(
            b_ref, rel=3 * relative_sigma(DURATION_S, tau_b))
        # K: the longest tau's clusters (a ninth of the record) bound what is known of it, once
        # the record reaches three times the curve's minimum (the accelerometer's, at 0.5 s;
        # the gyro's minimum, at 8 s, needs the one-hour run)
        if DURATION_S / 9 >= 3 * tau_b:
            assert fit.k_random_walk[axis] == pytest.approx(
                k_ref, rel=3 * relative_sigma(DURATION_S, DURATION_S / 9))


def test_relative_sigma_counts_clusters():
    assert relative_sigma(3600.0, 1.0) == pytest.approx(1 / math.sqrt(2 * 3599))
