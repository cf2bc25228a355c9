"""The estimator's parameters: a frozen record, built from a sensing profile's `estimator:`
section (trq_params.schema.Ekf2) by `EstimatorParams.from_profile`.

Two tunings:

    ekf2 (the default)  PX4's EKF2 parameters, PX4's shipped defaults unless the profile sets
                        them (`EstimatorParams.ekf2`): the filter knows nothing of the
                        simulator's figures, as on a real vehicle (STYLE.md, principle 13)
    generator           the filter matched to the profile's own sensor figures: their noise
                        densities, the GNSS receiver's and the barometer's correlated errors as
                        states, each reading's exact time of validity (`EstimatorParams.
                        generator`; a study's option: the inverse crime of estimation)

The filter's process noise is EKF2's scaling (covariance.cpp, predictCovariance): per filter
period of dt (the sum of its IMU samples' intervals),

    var(dA) per axis = (dt * gyro_noise_rad_s)^2              EKF2_GYR_NOISE: rad/s per sample
    var(dV) per axis = (dt * accel_noise_m_s2)^2              EKF2_ACC_NOISE: m/s^2 per sample
                       (dt * bad_acc_noise_m_s2)^2 on an axis that clipped in the period
    var(d bg)        = (dt * gyro_bias_noise_rad_s2)^2        EKF2_GYR_B_NOISE
    var(d ba)        = (dt * accel_bias_noise_m_s3)^2         EKF2_ACC_B_NOISE

so EKF2_GYR_NOISE is a standard deviation of the rate over one 10 ms period, not a density; the
generator tuning converts its densities d into that scaling (d / sqrt(dt_filter)), which gives
its former variances d^2 dt exactly at the nominal period. Measurement noise is per sample: a
floor under the accuracy a message reports where the tuning takes it (`use_reported_accuracy`,
EKF2's max(h_acc, EKF2_GPS_P_NOISE) and so on). Gates are in standard deviations (EKF2_*_GATE).
The output predictor's time constants are EKF2_TAU_VEL and EKF2_TAU_POS; EKF2_NOAID_TOUT is the
position-valid timeout, `reset_timeout_us` EKF2's reset_timeout_max (7 s) after which a
rejected position source resets the position. `height_ref` is EKF2_HGT_REF.

Delays. With `gnss_delay_us` / `ev_delay_us` set (the ekf2 tuning: EKF2_GPS_DELAY,
EKF2_EV_DELAY) a reading's time of validity is its arrival less the configured delay, as EKF2
takes it; None (the generator tuning) takes the reading's exact time of validity. The delayed
horizon is the longest delay the filter expects (the configured ones of the sources it fuses, or
the profile's), rounded up to whole filter periods, at most DELAY_BUFFER_MS (trq_params.schema).
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
    # IMU, EKF2's scaling (see above)
    gyro_noise_rad_s: float                 # EKF2_GYR_NOISE
    accel_noise_m_s2: float                 # EKF2_ACC_NOISE
    gyro_bias_noise_rad_s2: float           # EKF2_GYR_B_NOISE
    accel_bias_noise_m_s3: float            # EKF2_ACC_B_NOISE
    gyro_bias_init_rad_s: float             # 1-sigma of the initial bias (EKF2_GBIAS_INIT)
    accel_bias_init_m_s2: float             # EKF2_ABIAS_INIT
    # aiding sources: None when the filter does not fuse the sensor
    mocap_pos_noise_m: float | None = None          # EKF2_EVP_NOISE
    mocap_att_noise_rad: float | None = None        # EKF2_EVA_NOISE
    gnss_pos_noise_ne_m: float | None = None        # EKF2_GPS_P_NOISE (the white part)
    gnss_pos_noise_d_m: float | None = None         # EKF2: 1.5 EKF2_GPS_P_NOISE
    gnss_markov_ne_m: float = 0.0                   # the correlated part (state bn); EKF2: none
    gnss_markov_d_m: float = 0.0
    gnss_markov_tau_s: float = 60.0
    gnss_hgt_walk_m_s_rthz: float = 0.0             # bn_d's walk while the barometer keeps
                                                    # the height (EKF2's GNSS height bias)
    gnss_vel_noise_ne_m_s: float | None = None      # EKF2_GPS_V_NOISE
    gnss_vel_noise_d_m_s: float | None = None       # EKF2: 1.5 EKF2_GPS_V_NOISE
    baro_noise_m: float | None = None               # EKF2_BARO_NOISE
    baro_drift_sigma_m: float = 0.0                 # the offset state bb (Gauss-Markov)
    baro_drift_tau_s: float = 300.0
    baro_walk_m_s_rthz: float = 0.0                 # a random walk added to bb (EKF2's),
                                                    # unless the barometer is the reference
    mag_noise_gauss: float | None = None            # EKF2_MAG_NOISE
    mag_field_ned_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_declination_rad: float = 0.0
    # gates (standard deviations)
    gate_mocap_pos: float = 5.0                     # EKF2_EVP_GATE
    gate_mocap_att: float = 5.0                     # the vision yaw's: EKF2_EVP_GATE too here
    gate_gnss_pos: float = 5.0                      # EKF2_GPS_P_GATE
    gate_gnss_vel: float = 5.0                      # EKF2_GPS_V_GATE
    gate_baro: float = 5.0                          # EKF2_BARO_GATE
    gate_mag: float = 3.0                           # EKF2_MAG_GATE
    # how the measurements are taken
    use_reported_accuracy: bool = False     # GNSS noise: max(reported accuracy, parameter)
    gnss_delay_us: int | None = None        # EKF2_GPS_DELAY; None: the exact time of validity
    ev_delay_us: int | None = None          # EKF2_EV_DELAY; likewise
    ev_ctrl: int = 0b1011                   # EKF2_EV_CTRL bits: 0 hpos, 1 vpos, 2 vel, 3 yaw
    ev_yaw_only: bool = False               # EKF2: vision yaw (bit 3), no magnetometer while
                                            # it is fused; False: the whole attitude, and the
                                            # magnetometer beside it
    tilt_init_rad: float | None = None      # EKF2_ANGERR_INIT; None: from the accel bias
    # EKF2's IMU checks (predictCovariance): the clipping response and bias learning inhibited
    bad_acc_noise_m_s2: float = 4.9         # EKF2's BADACC_BIAS_PNOISE (a constant there)
    abl_acc_lim_m_s2: float = 25.0          # EKF2_ABL_ACCLIM
    abl_gyr_lim_rad_s: float = 3.0          # EKF2_ABL_GYRLIM
    abl_tau_s: float = 0.5                  # EKF2_ABL_TAU
    zero_velocity_update: bool = True       # EKF2's ZVU while at rest on the ground
    # output predictor, alignment, health
    tau_vel_s: float = 0.25
    tau_pos_s: float = 0.25
    filter_period_us: int = FILTER_PERIOD_US
    align_us: int = 200_000                 # IMU (and magnetometer) averaged at rest
    no_aid_timeout_us: int = 5_000_000      # EKF2_NOAID_TOUT: position valid
    reset_timeout_us: int = 7_000_000       # EKF2's reset_timeout_max: position reset
    init_pos_var_m2: float = 100.0          # before the first position measurement
    init_vel_var_m2_s2: float = 0.25
    # the height reference (EKF2_HGT_REF): the source whose datum the local frame's down axis
    # keeps. "baro": the height starts at init_pos_d_m at alignment and the barometer's offset
    # is taken against it there; the GNSS height is fused as an aid through its own error state
    # and never resets the height. "gnss" / "mocap": the height is reset to the source's with
    # the position and the barometer's offset taken against it. None: mocap when the filter
    # fuses motion capture, gnss when the receiver's height error is below the barometer's
    # drift (an RTK receiver), baro otherwise.
    height_ref: str | None = None
    init_pos_d_m: float = 0.0               # the height at alignment: on the ground at the origin
    gravity_m_s2: float = STANDARD_GRAVITY_M_S2
    max_var: float = 1.0e6                  # a variance beyond this (or not finite): diverged
    tuning: str = "custom"                  # "ekf2", "generator" (the builder that made it)
    # the published body rates' low-pass (PX4's IMU_GYRO_CUTOFF, Hz; 0: none, the raw sample)
    gyro_cutoff_hz: float = 0.0

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
        for name in ("gyro_noise_rad_s", "accel_noise_m_s2", "gyro_bias_noise_rad_s2",
                     "accel_bias_noise_m_s3", "gyro_bias_init_rad_s", "accel_bias_init_m_s2",
                     "mocap_pos_noise_m", "mocap_att_noise_rad", "gnss_pos_noise_ne_m",
                     "gnss_pos_noise_d_m", "gnss_vel_noise_ne_m_s", "gnss_vel_noise_d_m_s",
                     "baro_noise_m", "mag_noise_gauss", "bad_acc_noise_m_s2"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} {v!r}: a noise figure, finite and at least 0")
        for name in ("gnss_delay_us", "ev_delay_us"):
            v = getattr(self, name)
            if v is not None and not 0 <= v <= DELAY_BUFFER_MS * 1000:
                raise ValueError(f"{name} {v!r}: a delay in [0, DELAY_BUFFER_MS] "
                                 f"({DELAY_BUFFER_MS} ms)")
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
        """The filter as the profile's `estimator:` section tunes it (PX4's EKF2 defaults when
        the file leaves it out; `tuning: generator` for the generator-matched filter);
        `overrides` replace any field."""
        if profile.estimator.tuning == "generator":
            return cls.generator(profile, **overrides)
        return cls.ekf2(profile, **overrides)

    @classmethod
    def ekf2(cls, profile: SensingProfile, **overrides) -> EstimatorParams:
        """The filter tuned by EKF2's parameters (the profile's `estimator:` section, PX4's
        defaults for the keys it leaves out): of the profile it reads only which sensors the
        vehicle carries, the IMU's rate and the magnetic field's model (EKF2's world magnetic
        model: the declination and inclination at home), never a noise figure or a delay.
        A vision source is fused as EKF2_EV_CTRL allows (0: not at all)."""
        imu = _imu_of(profile)
        e = profile.estimator
        f: dict = dict(
            tuning="ekf2", imu_rate_hz=imu.rate_hz, gyro_cutoff_hz=e.IMU_GYRO_CUTOFF,
            gyro_noise_rad_s=e.EKF2_GYR_NOISE, accel_noise_m_s2=e.EKF2_ACC_NOISE,
            gyro_bias_noise_rad_s2=e.EKF2_GYR_B_NOISE, accel_bias_noise_m_s3=e.EKF2_ACC_B_NOISE,
            gyro_bias_init_rad_s=e.EKF2_GBIAS_INIT, accel_bias_init_m_s2=e.EKF2_ABIAS_INIT,
            tilt_init_rad=e.EKF2_ANGERR_INIT,
            abl_acc_lim_m_s2=e.EKF2_ABL_ACCLIM, abl_gyr_lim_rad_s=e.EKF2_ABL_GYRLIM,
            abl_tau_s=e.EKF2_ABL_TAU, use_reported_accuracy=True, ev_yaw_only=True,
            ev_ctrl=e.EKF2_EV_CTRL, gate_mocap_pos=e.EKF2_EVP_GATE,
            gate_mocap_att=e.EKF2_EVP_GATE, gate_gnss_pos=e.EKF2_GPS_P_GATE,
            gate_gnss_vel=e.EKF2_GPS_V_GATE, gate_baro=e.EKF2_BARO_GATE,
            gate_mag=e.EKF2_MAG_GATE, no_aid_timeout_us=e.EKF2_NOAID_TOUT,
            reset_timeout_us=e.EKF2_RESET_TOUT, tau_vel_s=e.EKF2_TAU_VEL,
            tau_pos_s=e.EKF2_TAU_POS, gnss_delay_us=round(e.EKF2_GPS_DELAY * 1000),
            ev_delay_us=round(e.EKF2_EV_DELAY * 1000))
        delays = [0]
        if profile.mocap is not None and e.EKF2_EV_CTRL & 0b1011:
            f.update(mocap_pos_noise_m=e.EKF2_EVP_NOISE, mocap_att_noise_rad=e.EKF2_EVA_NOISE)
            delays.append(f["ev_delay_us"])
        if profile.gnss is not None:
            # EKF2 fuses the GNSS height beside a barometer reference through a bias estimate
            # (its gps_hgt_bias_nsd, 0.13 m/s/rthz, a constant there): here the receiver's down
            # error state bn_d as a walk of that density, no Gauss-Markov pull
            f.update(gnss_pos_noise_ne_m=e.EKF2_GPS_P_NOISE,
                     gnss_pos_noise_d_m=1.5 * e.EKF2_GPS_P_NOISE,
                     gnss_hgt_walk_m_s_rthz=GNSS_HGT_BIAS_NSD, gnss_markov_tau_s=math.inf,
                     gnss_vel_noise_ne_m_s=e.EKF2_GPS_V_NOISE,
                     gnss_vel_noise_d_m_s=1.5 * e.EKF2_GPS_V_NOISE)
            delays.append(f["gnss_delay_us"])
        if profile.baro is not None:
            # EKF2's barometer offset: a bias estimated beside the height (BiasEstimator, its
            # process noise baro_bias_nsd 0.13 m/s/rthz, a constant there); here the offset
            # state bb as a walk of that density (a Gauss-Markov of infinite time constant)
            f.update(baro_noise_m=e.EKF2_BARO_NOISE, baro_drift_sigma_m=0.0,
                     baro_drift_tau_s=math.inf, baro_walk_m_s_rthz=BARO_BIAS_NSD)
        if profile.mag is not None:
            f.update(_mag_model(profile), mag_noise_gauss=e.EKF2_MAG_NOISE)
        ref = {0: "baro", 1: "gnss", 3: "mocap"}[e.EKF2_HGT_REF]
        has = {"baro": "baro_noise_m", "gnss": "gnss_pos_noise_ne_m",
               "mocap": "mocap_pos_noise_m"}
        # EKF2 falls back to the barometer when the reference's source is not fused
        f["height_ref"] = ref if f.get(has[ref]) is not None else (
            "baro" if profile.baro is not None else None)
        return cls._with_horizon(f, delays, overrides)

    @classmethod
    def generator(cls, profile: SensingProfile, **overrides) -> EstimatorParams:
        """The filter matched to `profile`'s sensors (its noise densities, the GNSS receiver's
        and the barometer's correlated errors, each reading's exact time of validity): the
        vehicle's filter before EKF2's tuning, kept for studies (the headroom record)."""
        imu = _imu_of(profile)
        root_dt = math.sqrt(overrides.get("filter_period_us", FILTER_PERIOD_US) * 1e-6)
        f: dict = dict(
            tuning="generator", imu_rate_hz=imu.rate_hz,
            gyro_noise_rad_s=math.hypot(imu.gyro_noise_density_rad_s_rthz,
                                        imu.gyro_vibration_rad_s / math.sqrt(imu.rate_hz))
            / root_dt,
            accel_noise_m_s2=math.hypot(imu.accel_noise_density_m_s2_rthz,
                                        imu.accel_vibration_m_s2 / math.sqrt(imu.rate_hz))
            / root_dt,
            gyro_bias_noise_rad_s2=imu.gyro_bias_random_walk_rad_s2_rthz / root_dt,
            accel_bias_noise_m_s3=imu.accel_bias_random_walk_m_s3_rthz / root_dt,
            gyro_bias_init_rad_s=max(imu.gyro_turn_on_bias_rad_s, 1e-4),
            accel_bias_init_m_s2=max(imu.accel_turn_on_bias_m_s2, 1e-3),
            zero_velocity_update=False)
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
            f.update(_mag_model(profile), mag_noise_gauss=max(profile.mag.white_gauss, 1e-4))
        return cls._with_horizon(f, delays, overrides)

    @classmethod
    def _with_horizon(cls, f: dict, delays: list[int], overrides: dict) -> EstimatorParams:
        period = overrides.get("filter_period_us", FILTER_PERIOD_US)
        f["horizon_us"] = -(-max(delays) // period) * period
        f.update(overrides)
        return cls(**f)


BARO_BIAS_NSD = 0.13
"""EKF2's baro_bias_nsd (m/s/rthz; src/modules/ekf2/EKF/common.h, a constant there): the
process noise of its barometer offset estimate."""


GNSS_HGT_BIAS_NSD = 0.13
"""EKF2's gps_hgt_bias_nsd (m/s/rthz; src/modules/ekf2/EKF/common.h, a constant there): the
process noise of its GNSS height bias estimate."""


def _imu_of(profile: SensingProfile):
    if profile.imu is None:
        raise ValueError(f"sensing profile {profile.name!r} has no IMU: nothing to estimate "
                         "with (the `truth` profile keeps the truth-plus-noise stream)")
    return profile.imu


def _mag_model(profile: SensingProfile) -> dict:
    m = profile.mag
    return dict(mag_field_ned_gauss=tuple(float(c) for c in m.field_ned_gauss),
                mag_declination_rad=m.declination_rad)
