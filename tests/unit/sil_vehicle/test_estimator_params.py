"""The estimator's parameters from a sensing profile (sil_vehicle.estimator.params): the delay
horizon, the generator tuning's figures taken from the sensors, overrides and refusals (EKF2's
tuning: test_estimator_ekf2.py)."""

from __future__ import annotations

import math

import pytest

from sil_vehicle.estimator.params import FILTER_PERIOD_US, EstimatorParams
from sil_vehicle.sensors.profile import load_sensing


@pytest.mark.parametrize("name, horizon_us, ekf2_us", [
    ("mocap", 10_000, 10_000), ("rtk", 110_000, 110_000), ("gnss", 120_000, 110_000)])
def test_horizon_is_the_longest_delay_in_filter_periods(name, horizon_us, ekf2_us):
    """The generator's: the profile's delays; EKF2's: the configured ones (EKF2_GPS_DELAY
    110 ms, the mocap profile's EKF2_EV_DELAY 10 ms)."""
    p = EstimatorParams.generator(load_sensing(name, 1000))
    assert p.horizon_us == horizon_us
    assert EstimatorParams.from_profile(load_sensing(name, 1000)).horizon_us == ekf2_us
    assert p.filter_period_us == FILTER_PERIOD_US == 10_000


def test_figures_come_from_the_sensors():
    prof = load_sensing("gnss", 1000)
    p = EstimatorParams.generator(prof)
    assert p.has_gnss and p.has_baro and p.has_mag and not p.has_mocap
    assert p.gnss_markov_ne_m == prof.gnss.position_markov_h_m
    assert p.gnss_pos_noise_d_m == prof.gnss.position_white_v_m
    assert p.mag_noise_gauss == prof.mag.white_gauss
    # the density in EKF2's scaling: the std per 10 ms period
    assert p.gyro_noise_rad_s * math.sqrt(0.01) == pytest.approx(math.hypot(
        prof.imu.gyro_noise_density_rad_s_rthz, prof.imu.gyro_vibration_rad_s / math.sqrt(1000)))
    assert p.mag_field_ned_gauss == pytest.approx(tuple(prof.mag.field_ned_gauss))


def test_overrides_and_refusals():
    prof = load_sensing("mocap", 1000)
    assert EstimatorParams.from_profile(prof, gate_mag=2.0).gate_mag == 2.0
    with pytest.raises(ValueError, match="no IMU"):
        EstimatorParams.from_profile(load_sensing("truth", 1000))
    with pytest.raises(ValueError, match="horizon_us"):
        EstimatorParams.from_profile(prof, horizon_us=15_000)
    with pytest.raises(ValueError, match="no position source"):
        EstimatorParams.from_profile(prof, mocap_pos_noise_m=None)


@pytest.mark.parametrize("name, ref, ekf2_ref", [("mocap", "mocap", "mocap"),
                                                 ("rtk", "gnss", "gnss"),
                                                 ("gnss", "baro", "baro")])
def test_height_reference_by_profile(name, ref, ekf2_ref):
    """The generator's rule: the motion capture's height where there is one, an RTK receiver's
    (centimetres, below the barometer's drift), else the barometer's. EKF2's: EKF2_HGT_REF as
    the profile sets it (PX4's default GNSS under rtk; the barometer under gnss, vision under
    mocap)."""
    prof = load_sensing(name, 1000)
    assert EstimatorParams.generator(prof).height_ref == ref
    assert EstimatorParams.from_profile(prof).height_ref == ekf2_ref
    assert EstimatorParams.from_profile(prof, height_ref="baro").height_ref == "baro"
    with pytest.raises(ValueError, match="height_ref"):
        EstimatorParams.from_profile(prof, height_ref="radar")
    with pytest.raises(ValueError, match="height_ref"):
        EstimatorParams.from_profile(prof, height_ref="baro", baro_noise_m=None)
