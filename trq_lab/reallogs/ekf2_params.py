"""EKF2's parameters turned into the vehicle's filter's (sil_vehicle.estimator.EstimatorParams):
the one place that knows both names, so that a rename on either side is one edit here.

    ekf2 = ekf2_values(log.params)          # PX4's defaults, overridden by the log's EKF2_*
    params = estimator_params(ekf2, sources)

PX4_DEFAULTS are PX4's shipped defaults (src/modules/ekf2/module.yaml, v1.14/v1.15, as a PX4
SITL log of that version carries them: pyulog's test/sample_px4_events.ulg). Scaling: EKF2 states
its IMU figures as the standard deviation of a rate (EKF2_GYR_NOISE rad/s, EKF2_ACC_NOISE m/s^2)
and of a bias rate (EKF2_GYR_B_NOISE rad/s^2, EKF2_ACC_B_NOISE m/s^3), applied per filter update
as var = (figure dt)^2 on the delta angle / velocity (covariance.cpp); the vehicle's filter takes
densities, var = density^2 dt; the same variance per 10 ms period is density = figure sqrt(dt).
Measurement figures are standard deviations per sample on both sides; gates in standard
deviations on both sides. EKF2 floors GNSS noise by the receiver's reported accuracy; the
vehicle's filter has fixed figures, so the parameter alone is taken here (the ekf2 branch adds the
floor). EKF2 fuses the GNSS vertical velocity with 1.5 times the horizontal figure
(gps_control.cpp); that factor is kept for the vertical position too, a choice.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from sil_vehicle.estimator.params import FILTER_PERIOD_US, EstimatorParams

__all__ = ["PX4_DEFAULTS", "Sources", "ekf2_values", "estimator_params"]

PX4_DEFAULTS: dict[str, float] = {
    "EKF2_GYR_NOISE": 0.015, "EKF2_ACC_NOISE": 0.35,
    "EKF2_GYR_B_NOISE": 0.001, "EKF2_ACC_B_NOISE": 0.003,
    "EKF2_GBIAS_INIT": 0.1, "EKF2_ABIAS_INIT": 0.2,
    "EKF2_GPS_P_NOISE": 0.5, "EKF2_GPS_V_NOISE": 0.3, "EKF2_GPS_DELAY": 110.0,
    "EKF2_GPS_P_GATE": 5.0, "EKF2_GPS_V_GATE": 5.0,
    "EKF2_BARO_NOISE": 3.5, "EKF2_BARO_GATE": 5.0,
    "EKF2_MAG_NOISE": 0.05, "EKF2_MAG_GATE": 3.0, "EKF2_MAG_DECL": 0.0,
    "EKF2_EVP_NOISE": 0.1, "EKF2_EVA_NOISE": 0.1, "EKF2_EVP_GATE": 5.0, "EKF2_EV_DELAY": 0.0,
    "EKF2_TAU_VEL": 0.25, "EKF2_TAU_POS": 0.25, "EKF2_NOAID_TOUT": 5_000_000.0,
    "EKF2_NOAID_NOISE": 10.0,
}
_GNSS_VERTICAL = 1.5        # EKF2's vertical GNSS velocity noise factor (gps_control.cpp)


@dataclass(frozen=True)
class Sources:
    """What the replay feeds the filter, and the figures it takes from the log itself."""
    imu_rate_hz: int
    gnss: bool                  # real fixes; False: EKF2's fake position at rest instead
    baro: bool
    mag: bool
    vision: bool
    mag_field_ned_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    init_pos_d_m: float = 0.0


def ekf2_values(log_params: Mapping[str, float]) -> dict[str, float]:
    """PX4_DEFAULTS with the log's own values where it carries them."""
    return {k: float(log_params.get(k, v)) for k, v in PX4_DEFAULTS.items()}


def estimator_params(ekf2: Mapping[str, float], src: Sources) -> EstimatorParams:
    """The vehicle's filter set as EKF2 `ekf2` is. Without a real position source the GNSS
    channel carries EKF2's fake position (the origin at rest, EKF2_NOAID_NOISE) so the filter
    has the position constraint EKF2 gives an unaided vehicle."""
    root_dt = math.sqrt(FILTER_PERIOD_US * 1e-6)
    f: dict = dict(
        imu_rate_hz=src.imu_rate_hz,
        gyro_noise_rad_s_rthz=ekf2["EKF2_GYR_NOISE"] * root_dt,
        accel_noise_m_s2_rthz=ekf2["EKF2_ACC_NOISE"] * root_dt,
        gyro_bias_rw_rad_s2_rthz=ekf2["EKF2_GYR_B_NOISE"] * root_dt,
        accel_bias_rw_m_s3_rthz=ekf2["EKF2_ACC_B_NOISE"] * root_dt,
        gyro_bias_init_rad_s=ekf2["EKF2_GBIAS_INIT"],
        accel_bias_init_m_s2=ekf2["EKF2_ABIAS_INIT"],
        gate_gnss_pos=ekf2["EKF2_GPS_P_GATE"], gate_gnss_vel=ekf2["EKF2_GPS_V_GATE"],
        gate_baro=ekf2["EKF2_BARO_GATE"], gate_mag=ekf2["EKF2_MAG_GATE"],
        gate_mocap_pos=ekf2["EKF2_EVP_GATE"], gate_mocap_att=ekf2["EKF2_EVP_GATE"],
        tau_vel_s=ekf2["EKF2_TAU_VEL"], tau_pos_s=ekf2["EKF2_TAU_POS"],
        no_aid_timeout_us=int(ekf2["EKF2_NOAID_TOUT"]),
        init_pos_d_m=src.init_pos_d_m)
    delays = [0.0]
    if src.gnss:
        p, v = ekf2["EKF2_GPS_P_NOISE"], ekf2["EKF2_GPS_V_NOISE"]
        f.update(gnss_pos_noise_ne_m=p, gnss_pos_noise_d_m=_GNSS_VERTICAL * p,
                 gnss_vel_noise_ne_m_s=v, gnss_vel_noise_d_m_s=_GNSS_VERTICAL * v)
        delays.append(ekf2["EKF2_GPS_DELAY"])
    elif not src.vision:
        n = ekf2["EKF2_NOAID_NOISE"]
        f.update(gnss_pos_noise_ne_m=n, gnss_pos_noise_d_m=n, gnss_vel_noise_ne_m_s=n,
                 gnss_vel_noise_d_m_s=n)
    if src.vision:
        f.update(mocap_pos_noise_m=ekf2["EKF2_EVP_NOISE"],
                 mocap_att_noise_rad=ekf2["EKF2_EVA_NOISE"])
        delays.append(ekf2["EKF2_EV_DELAY"])
    if src.baro:
        f.update(baro_noise_m=ekf2["EKF2_BARO_NOISE"], height_ref="baro")
    if src.mag:
        f.update(mag_noise_gauss=ekf2["EKF2_MAG_NOISE"],
                 mag_field_ned_gauss=src.mag_field_ned_gauss,
                 mag_declination_rad=math.radians(ekf2["EKF2_MAG_DECL"]))
    period = FILTER_PERIOD_US
    f["horizon_us"] = -(-int(round(max(delays) * 1000)) // period) * period
    return EstimatorParams(**f)
