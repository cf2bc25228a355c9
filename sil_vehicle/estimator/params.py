"""The estimator's parameters: a frozen record, built from a sensing profile so that the filter's
noise figures match the profile's sensors by default (`EstimatorParams.from_profile`).

Noise figures are continuous-time densities, as the sensor models state them
(sil_vehicle.sensors.*); the filter turns them into variances per filter period:

    var(dA) per axis = (gyro density^2 + gyro vibration^2 / imu rate) dt    (rad^2)
    var(dV) per axis = (accel density^2 + accel vibration^2 / imu rate) dt  (m^2/s^2)
    var(d bias)      = random walk density^2 dt

with the vibration taken at full throttle (the models scale it with the square of the mean motor
output; the filter does not know the throttle, so it takes the bound). Measurement standard
deviations are per sample. Gates are in standard deviations, as EKF2's EKF2_*_GATE parameters
(defaults: EKF2_GPS_P_GATE = EKF2_GPS_V_GATE = EKF2_EVP_GATE = EKF2_BARO_GATE = 5,
EKF2_MAG_GATE = 3; EKF2 has no gate for a whole vision attitude, the motion capture's takes
the position's 5); the output predictor's time constants are EKF2_TAU_VEL and EKF2_TAU_POS
(0.25 s); EKF2_NOAID_TOUT (5 s) is the position-valid timeout. `height_ref` is EKF2_HGT_REF
(sil_vehicle.estimator.eskf: "Height reference").

The delay horizon is the longest delay of the profile's delayed sensors (GNSS, motion capture)
rounded up to whole filter periods; it is at most DELAY_BUFFER_MS (trq_params.schema), which
the profile's loader already checks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from trq_params.schema import DELAY_BUFFER_MS

from sil_vehicle.sensors.profile import SensingProfile
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2

__all__ = ["FILTER_PERIOD_US", "EstimatorParams"]

FILTER_PERIOD_US = 10_000       # EKF2's FILTER_UPDATE_PERIOD_MS (10 ms)


@dataclass(frozen=True)
class EstimatorParams:
    imu_rate_hz: int
    horizon_us: int                         # the delayed fusion horizon behind `now`
    # IMU (densities)
    gyro_noise_rad_s_rthz: float
    accel_noise_m_s2_rthz: float
    gyro_bias_rw_rad_s2_rthz: float
    accel_bias_rw_m_s3_rthz: float
    gyro_bias_init_rad_s: float             # 1-sigma of the initial bias
    accel_bias_init_m_s2: float
    # aiding sources: None when the profile does not carry the sensor
    mocap_pos_noise_m: float | None = None
    mocap_att_noise_rad: float | None = None
    gnss_pos_noise_ne_m: float | None = None        # the white part
    gnss_pos_noise_d_m: float | None = None
    gnss_markov_ne_m: float = 0.0                   # the correlated part (state bn)
    gnss_markov_d_m: float = 0.0
    gnss_markov_tau_s: float = 60.0
    gnss_vel_noise_ne_m_s: float | None = None
    gnss_vel_noise_d_m_s: float | None = None
    baro_noise_m: float | None = None
    baro_drift_sigma_m: float = 0.0                 # the offset state bb
    baro_drift_tau_s: float = 300.0
    mag_noise_gauss: float | None = None
    mag_field_ned_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_declination_rad: float = 0.0
    # gates (standard deviations)
    gate_mocap_pos: float = 5.0
    gate_mocap_att: float = 5.0
    gate_gnss_pos: float = 5.0
    gate_gnss_vel: float = 5.0
    gate_baro: float = 5.0
    gate_mag: float = 3.0
    # output predictor, alignment, health
    tau_vel_s: float = 0.25
    tau_pos_s: float = 0.25
    filter_period_us: int = FILTER_PERIOD_US
    align_us: int = 200_000                 # IMU (and magnetometer) averaged at rest
    no_aid_timeout_us: int = 5_000_000
    init_pos_var_m2: float = 100.0          # before the first position measurement
    init_vel_var_m2_s2: float = 0.25
    # the height reference (EKF2_HGT_REF): the source whose datum the local frame's down axis
    # keeps. "baro": the height starts at init_pos_d_m at alignment and the barometer's offset
    # is taken against it there; the GNSS height is fused as an aid through its own error state
    # and never resets the height. "gnss" / "mocap": the height is reset to the source's with
    # the position and the barometer's offset taken against it. from_profile: mocap when the
    # profile has motion capture, gnss when the receiver's height error is below the
    # barometer's drift (an RTK receiver), baro otherwise; None: that rule.
    height_ref: str | None = None
    init_pos_d_m: float = 0.0               # the height at alignment: on the ground at the origin
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2
    max_var: float = 1.0e6                  # a variance beyond this (or not finite): diverged

    def __post_init__(self) -> None:
        if self.filter_period_us % (1_000_000 // self.imu_rate_hz):
            raise ValueError(f"filter_period_us {self.filter_period_us}: not a whole number of "
                             f"IMU periods at {self.imu_rate_hz} Hz")
        if self.horizon_us % self.filter_period_us or not \
                0 <= self.horizon_us <= DELAY_BUFFER_MS * 1000 + self.filter_period_us:
            raise ValueError(f"horizon_us {self.horizon_us}: whole filter periods up to "
                             f"DELAY_BUFFER_MS ({DELAY_BUFFER_MS} ms) rounded up")
        if self.align_us % self.filter_period_us:
            raise ValueError(f"align_us {self.align_us}: whole filter periods")
        if self.mocap_pos_noise_m is None and self.gnss_pos_noise_ne_m is None:
            raise ValueError("no position source (motion capture or GNSS): the filter needs one")
        if self.height_ref is None:
            object.__setattr__(self, "height_ref", self._default_height_ref())
        has = {"baro": self.has_baro, "gnss": self.has_gnss, "mocap": self.has_mocap}
        if not has.get(self.height_ref, False):
            raise ValueError(f"height_ref {self.height_ref!r}: one of the fused sources "
                             f"{[k for k, v in has.items() if v]}")

    def _default_height_ref(self) -> str:
        if self.has_mocap:
            return "mocap"
        gnss_d = math.hypot(self.gnss_markov_d_m, self.gnss_pos_noise_d_m or 0.0)
        if self.has_baro and not (self.has_gnss and gnss_d < self.baro_drift_sigma_m):
            return "baro"
        return "gnss" if self.has_gnss else "baro"

    @property
    def imu_period_us(self) -> int:
        return 1_000_000 // self.imu_rate_hz

    # which sensors the filter fuses: those whose noise figure is set
    has_mocap = property(lambda self: self.mocap_pos_noise_m is not None)
    has_gnss = property(lambda self: self.gnss_pos_noise_ne_m is not None)
    has_baro = property(lambda self: self.baro_noise_m is not None)
    has_mag = property(lambda self: self.mag_noise_gauss is not None)

    @classmethod
    def from_profile(cls, profile: SensingProfile, **overrides) -> EstimatorParams:
        """The filter matched to `profile`'s sensors; `overrides` replace any field."""
        imu = profile.imu
        if imu is None:
            raise ValueError(f"sensing profile {profile.name!r} has no IMU: nothing to estimate "
                             "with (the `truth` profile keeps the truth-plus-noise stream)")
        f: dict = dict(
            imu_rate_hz=imu.rate_hz,
            gyro_noise_rad_s_rthz=math.hypot(imu.gyro_noise_density_rad_s_rthz,
                                             imu.gyro_vibration_rad_s / math.sqrt(imu.rate_hz)),
            accel_noise_m_s2_rthz=math.hypot(imu.accel_noise_density_m_s2_rthz,
                                             imu.accel_vibration_m_s2 / math.sqrt(imu.rate_hz)),
            gyro_bias_rw_rad_s2_rthz=imu.gyro_bias_random_walk_rad_s2_rthz,
            accel_bias_rw_m_s3_rthz=imu.accel_bias_random_walk_m_s3_rthz,
            gyro_bias_init_rad_s=max(imu.gyro_turn_on_bias_rad_s, 1e-4),
            accel_bias_init_m_s2=max(imu.accel_turn_on_bias_m_s2, 1e-3))
        delays = [0]
        if profile.mocap is not None:
            m = profile.mocap
            f.update(mocap_pos_noise_m=max(m.position_noise_m, 1e-5),
                     mocap_att_noise_rad=max(m.attitude_noise_rad, 1e-5))
            delays.append(m.latency_us)
        if profile.gnss is not None:
            g = profile.gnss
            f.update(gnss_pos_noise_ne_m=max(g.position_white_h_m, 1e-4),
                     gnss_pos_noise_d_m=max(g.position_white_v_m, 1e-4),
                     gnss_markov_ne_m=g.position_markov_h_m, gnss_markov_d_m=g.position_markov_v_m,
                     gnss_markov_tau_s=g.position_markov_tau_s,
                     gnss_vel_noise_ne_m_s=max(g.velocity_white_h_m_s, 1e-3),
                     gnss_vel_noise_d_m_s=max(g.velocity_white_v_m_s, 1e-3))
            delays.append(g.delay_us)
        if profile.baro is not None:
            b = profile.baro
            f.update(baro_noise_m=max(b.noise_m, 1e-3), baro_drift_sigma_m=b.drift_sigma_m,
                     baro_drift_tau_s=b.drift_tau_s)
        if profile.mag is not None:
            m = profile.mag
            f.update(mag_noise_gauss=max(m.white_gauss, 1e-4),
                     mag_field_ned_gauss=tuple(float(c) for c in m.field_ned_gauss),
                     mag_declination_rad=m.declination_rad)
        period = overrides.get("filter_period_us", FILTER_PERIOD_US)
        f["horizon_us"] = -(-max(delays) // period) * period
        f.update(overrides)
        return cls(**f)
