"""The error-state Kalman filter on a delayed horizon, with an output predictor (PX4 EKF2's
architecture: src/modules/ekf2/EKF, ekf.cpp, covariance.cpp, output_predictor.cpp; the
error-state formulation of Sola 2017, "Quaternion kinematics for the error-state Kalman
filter"). The states and equations: sil_vehicle.estimator.derivation.

    est = Eskf(EstimatorParams.from_profile(load_sensing("mocap", 1000)))
    every physics tick:   est.step(t_us, suite.sample(t_us, truth))
    whenever wanted:      est.output()      -> Estimate at the last tick

Timing. IMU samples (rates and specific force, each held over its own interval dt_us ending at
its t_us, EKF2's delta_ang_dt; 0 the IMU's nominal period) are accumulated into delta angles and
delta velocities (the delta velocity rotated into the frame at the start of the period with the
first-order sculling term dV += dv + (dA_acc + dA / 2) x dv) until their intervals add up to
the filter period (10 ms, EKF2's FILTER_UPDATE_PERIOD_MS, less half an IMU period, as EKF2's
down-sampler closes on accumulated time); the period, its own dt and the axes that clipped in it
are pushed into a buffer. A missing sample shortens the period's integrated time; it never merges
two periods. The filter state sits at the delayed horizon t_d = now - horizon (the longest delay of
the profile's sensors): a period ending at t_end is processed once now >= t_end + horizon, and
every buffered measurement whose time of validity is at or before t_end (and after the last
processed period: an older one, come too late, is dropped and counted as stale) is then fused,
in a fixed order (mocap position, vision attitude or yaw, GNSS position, GNSS velocity, baro,
mag, the zero-velocity update). A delayed reading's time of validity is its arrival less the
configured delay (EKF2_GPS_DELAY, EKF2_EV_DELAY: params.gnss_delay_us, ev_delay_us), as EKF2
takes it, or with those None (the generator tuning) the reading's exact one; the barometer and
magnetometer, undelayed, wait in their buffers for the horizon too.

EKF2's behaviours (ekf2 and generator tunings alike, unless said):
- vision as EKF2_EV_CTRL allows, its reported variances (when the reading carries them) floored
  by EKF2_EVP_NOISE / EKF2_EVA_NOISE, as EKF2_EV_NOISE_MD 0: horizontal and vertical position
  (bits 0, 1; an axis left out is fused with no weight), yaw (bit 3; with `ev_yaw_only`, EKF2's way, the vision's heading alone
  and the magnetometer not fused; otherwise the whole attitude beside the magnetometer);
- GNSS noise from the fix's reported accuracies floored by the parameters (use_reported_accuracy:
  max(eph, EKF2_GPS_P_NOISE), max(epv, 1.5 EKF2_GPS_P_NOISE), max(s_acc, EKF2_GPS_V_NOISE));
- the clipping response: an accelerometer axis that clipped in a period gets the bad-accel
  process noise (EKF2's BADACC_BIAS_PNOISE) and its bias is not learnt that period; no axis's
  accel bias is learnt while the peak-held rate or specific force exceeds EKF2_ABL_GYRLIM or
  EKF2_ABL_ACCLIM (decay EKF2_ABL_TAU): the bias's variance held, its correlations cut;
- the zero-velocity update (`zero_velocity_update`, EKF2's ZVU): while the vehicle says it is at
  rest (`set_at_rest`, its land detector) for two periods running and no velocity is fused,
  zero velocity with 0.2 m/s noise every 200 ms;
- a position source rejected for longer than `reset_timeout_us` (EKF2's reset_timeout_max, 7 s)
  resets the position (and from GNSS the velocity: that fix's velocity is not fused again).
The output predictor (sil_vehicle.estimator.predictor) carries the delayed state to `now`.

Fusion. For a measurement z with prediction h(x) and Jacobian H (one compiled CasADi function per
kind computes all of it; the gate's decision is taken here):

    y = z - h,  S = H P H^T + R,  test ratio r = max_i y_i^2 / (gate^2 S_ii)
    r > 1: rejected and counted (EKF2's innovation gates: a chi-square test of one degree of
           freedom per axis at gate^2, `gate` in standard deviations, one per measurement kind)
    else:  K = P H^T S^-1,  dx = K y,  P = (I - K H) P (I - K H)^T + K R K^T  (Joseph form),
           P = (P + P^T) / 2,  x = inject(x, dx)

The reset of the covariance after injection (Sola 2017, eq. 287, G = I - [dtheta / 2]x on the
attitude block) is left out, as EKF2 and most implementations do: dtheta is small.

Initialisation. The first `align_us` of IMU (and magnetometer) readings are averaged with the
vehicle at rest: the attitude from the motion capture's latest pose when the profile has one,
else tilt from the mean specific force and heading from the mean magnetic field and the
profile's declination. The position (and from GNSS the velocity) is reset to the first position
measurement fused after t_align, the jump applied to the output predictor too. The filter starts
at t_align (a filter-period boundary): what it computes never depends on the horizon, only when
it does.

Height reference (params.height_ref, EKF2_HGT_REF). "mocap" or "gnss": the position reset sets
the height too, and the barometer's offset is taken from the first barometer reading after it.
"baro" (EKF2's default; a plain receiver's height is metres off and wanders): at t_align the
height is init_pos_d_m (the vehicle at rest at the origin) and the offset the mean pressure
altitude over the alignment taken against it; a position reset (the first GNSS fix, a source
rejected too long) moves the horizontal position only, and sets the receiver's height error
state to what it reads against the height, as EKF2 initialises its GNSS height bias estimate.
The GNSS height is then fused with its own variance through that error state (bn_d, the
receiver's Gauss-Markov error): an aid whose slow error is modelled, which can move the height
only as far as its figures against the barometer's allow; it never resets it. EKF2 fuses GNSS
height beside a baro reference too (EKF2_GPS_CTRL's VPOS bit, through a bias estimator).

Health: attitude aligned (after the initialisation); position valid (a position measurement
fused within `no_aid_timeout_us` of the filter's time; a position source rejected by its gate
for longer than `reset_timeout_us` resets the position to it, as EKF2 does; horizontally only
when the barometer keeps the height); diverged (a state or variance not finite, a variance above
`max_var` or below zero; checked after each filter period and latched). The variances the
Estimate carries are the filter's, at the delayed horizon (EKF2 reports the same).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from sil_vehicle.estimator import derivation as d
from sil_vehicle.estimator.derivation import (BA, BB_I, BG, BN, BN_D, DBA, DBB_I, DBG, DBN,
                                              DBN_D, DP, DP_D, DTH, DV, P_, P_D, Q_, V_)
from sil_vehicle.estimator.codegen import load
from sil_vehicle.estimator.lowpass import LowPass2
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.estimator.predictor import OutputPredictor, native_predictor
from sil_vehicle.frames import euler_to_quat, quat_to_dcm, quat_to_euler
from sil_vehicle.sensors.baro import BaroReading
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mag import MagReading
from sil_vehicle.sensors.mocap import MocapReading

__all__ = ["Aid", "Eskf", "Estimate", "Innovation"]


class Aid(IntEnum):
    """The measurement kinds, in their fusion order."""
    MOCAP_POS = 0
    MOCAP_ATT = 1       # the vision's attitude: its yaw alone under EKF2 (ev_yaw_only)
    GNSS_POS = 2
    GNSS_VEL = 3
    BARO = 4
    MAG = 5


_FUSE = {Aid.MOCAP_POS: "fuse_mocap_pos", Aid.MOCAP_ATT: "fuse_mocap_att",
         Aid.GNSS_POS: "fuse_gnss_pos", Aid.GNSS_VEL: "fuse_gnss_vel", Aid.BARO: "fuse_baro",
         Aid.MAG: "fuse_mag"}
_NAID = len(Aid)
# the measurement buffer each kind of reading waits in until the delayed horizon reaches it
_ZVU_PERIOD_US = 200_000        # EKF2's zero-velocity update: every 200 ms
_ZVU_VAR = 0.2 ** 2             # its observation variance after tilt alignment ((m/s)^2)
_NO_WEIGHT = 1.0e12             # the variance of an axis EKF2_EV_CTRL leaves out
_BUFFER_OF = {MocapReading: Aid.MOCAP_POS, GnssReading: Aid.GNSS_POS, BaroReading: Aid.BARO,
              MagReading: Aid.MAG}
_POSE = np.r_[DP, DTH]                   # dp, dtheta in the error state
_POSE_ROWS, _POSE_COLS = _POSE[:, None], _POSE[None, :]     # P's pose block: np.ix_(_POSE, _POSE)


@dataclass(frozen=True)
class Innovation:
    """The last fusion attempt of one kind, at the delayed horizon."""
    aid: Aid
    t_us: int                       # the measurement's time of validity
    innovation: np.ndarray          # (m,) z - h(x)
    variance: np.ndarray            # (m,) diag(S)
    test_ratio: float               # max_i y_i^2 / (gate^2 S_ii): above 1 rejected
    accepted: bool
    axis_ratios: np.ndarray         # (m,) y_i^2 / (gate^2 S_ii)


@dataclass(frozen=True)
class Estimate:
    """The estimate at `t_us` (the output predictor's state) with the filter's variances."""
    t_us: int
    pos_ned_m: np.ndarray               # (3,)
    vel_ned_m_s: np.ndarray             # (3,)
    quat_wxyz: np.ndarray               # (4,) body FRD -> NED
    rates_frd_rad_s: np.ndarray         # (3,) the gyro through IMU_GYRO_CUTOFF's low-pass, less
                                        # the bias estimate (PX4's vehicle_angular_velocity)
    pos_var_ned_m2: np.ndarray          # (3,)
    vel_var_ned_m2_s2: np.ndarray       # (3,)
    att_var_frd_rad2: np.ndarray        # (3,) of the body-frame attitude error
    gyro_bias_frd_rad_s: np.ndarray     # (3,)
    accel_bias_frd_m_s2: np.ndarray     # (3,)
    delayed_t_us: int                   # the filter's (delayed horizon's) time
    attitude_aligned: bool
    position_valid: bool
    diverged: bool
    test_ratios: tuple[float, ...]      # by Aid: the last test ratio (nan: never tried)
    fused: tuple[int, ...]              # by Aid: measurements fused
    rejected: tuple[int, ...]           # by Aid: measurements rejected by the gate
    stale: int                          # measurements dropped: older than the horizon
    pos_resets: int                     # position resets: the source rejected too long
    output_tracking_error: tuple[float, float, float]   # rad, m/s, m (the predictor's fit)
    pose_cov: np.ndarray                # (6, 6) of (dp NED m, dtheta FRD rad)
    vel_cov_ned_m2_s2: np.ndarray       # (3, 3)
    rates_var_frd_rad2_s2: np.ndarray   # (3,) one gyro sample's noise plus the bias's variance
    # ESTIMATOR_STATUS's test ratios (EKF2's: the largest of the last ones; nan: none yet)
    vel_ratio: float                    # GNSS velocity
    pos_horiz_ratio: float              # north and east of the position source
    pos_vert_ratio: float               # down of the position source, the barometer
    mag_ratio: float

    def pose_cov_rpy(self) -> np.ndarray:
        """(6, 6) covariance of (x, y, z, roll, pitch, yaw), ODOMETRY's pose_covariance (before
        taking its upper triangle): the body-frame attitude error mapped to ZYX Euler angles,
        d(rpy) = E^-1 dtheta with dtheta = E d(rpy) the Euler-rate to body-rate map (singular
        at pitch +-90 deg)."""
        roll, pitch, _ = quat_to_euler(*self.quat_wxyz)
        sr, cr = math.sin(roll), math.cos(roll)
        sp, cp = math.sin(pitch), math.cos(pitch)
        e_inv = np.array(((1.0, sr * sp / cp, cr * sp / cp), (0.0, cr, -sr),
                          (0.0, sr / cp, cr / cp)))
        j = np.eye(6)
        j[3:, 3:] = e_inv
        return j @ self.pose_cov @ j.T


class Eskf:
    """The filter, its buffers and its output predictor. `step` once per physics tick."""

    def __init__(self, params: EstimatorParams, *, compiled: bool = True) -> None:
        self.params = p = params
        self._f, self.how = load(d.functions(p.gravity_m_s2), compiled,
                                 key=("eskf", p.gravity_m_s2))
        self._configure(p)
        capacity = p.horizon_us // p.filter_period_us + 2
        self._imu_buf: deque = deque()          # (t_end_us, dA (3,), dV (3,), dt_us, clipped)
        self._meas: list[deque] = [deque() for _ in range(_NAID)]
        # the output predictor, which also sums the IMU samples over each filter period: in C
        # when `compiled` (the same numbers as the Python reference, bit for bit)
        self.out = (native_predictor if compiled else OutputPredictor)(
            gravity_m_s2=p.gravity_m_s2, imu_period_us=p.imu_period_us,
            filter_period_us=p.filter_period_us, tau_vel_s=p.tau_vel_s, tau_pos_s=p.tau_pos_s,
            capacity=capacity)
        # the filter
        self.x = np.zeros(d.NX)
        self.x[Q_.start] = 1.0
        self.P = np.zeros((d.NDX, d.NDX))
        self.t_filter_us = 0
        # alignment
        self._t_first: int | None = None
        self._t_align = 0
        self._sum_f = np.zeros(3)
        self._sum_m = np.zeros(3)
        self._n_f = self._n_m = 0
        self.aligned = False
        self._pos_init = False
        self._baro_init = False
        self._baro_ref = p.height_ref == "baro"
        # health and diagnostics
        self._now = -1
        self._gyro = (0.0, 0.0, 0.0)           # the last gyro sample through the rates' low-pass
        self._gyro_lpf = LowPass2(p.imu_rate_hz, p.gyro_cutoff_hz)
        self._last_pos_fuse_us: int | None = None
        self.innovations: list[Innovation | None] = [None] * _NAID
        self._fused = [0] * _NAID
        # the IMU period being summed: its time, the axes that clipped
        self._acc_us = 0
        self._clip = [False, False, False]
        # EKF2's accel bias learning inhibition and the zero-velocity update
        self._ang_filt = self._acc_filt = 0.0
        self._ba_inhibit = [False, False, False]
        self._ba_prev_var = [0.0, 0.0, 0.0]
        self.at_rest = False
        self._at_rest_prev = False
        self._last_zvu_us = 0
        self._last_vel_fuse_us: int | None = None
        self.zvu_fused = 0
        self._rejected = [0] * _NAID
        self._stale = 0                 # measurements older than the horizon when they came
        self._pos_resets = 0            # position resets after a lost position source
        # state resets as EKF2 counts them for ODOMETRY.reset_counter (its quaternion, NE and D
        # velocity and position reset counts summed): each position reset adds its NE (and D)
        # position, and from GNSS its NE and D velocity
        self.state_resets = 0
        self._diverged = False          # latched: checked after each filter period
        self._bg = (0.0, 0.0, 0.0)
        self._ba = (0.0, 0.0, 0.0)

    def _configure(self, p: EstimatorParams) -> None:
        """What the parameters give: the noise, gates, delays and which sources are taken."""
        self._dt_f = dt_f = p.filter_period_us * 1e-6
        self._period_us = p.filter_period_us
        self._close_us = p.filter_period_us - p.imu_period_us // 2    # a period's end
        a = math.exp(-dt_f / p.gnss_markov_tau_s)
        a_b = math.exp(-dt_f / p.baro_drift_tau_s)
        self._a = np.array((a, a_b, 0.0))      # (a_gnss, a_baro, bb_ref: set at the offset's init)
        # the period's process noise (see params): the IMU's terms scaled by the period's own dt
        # in `_qd`, the others per nominal period here
        self._qd = np.array((
            0.0, 0.0, 0.0, 0.0,
            (dt_f * p.gyro_bias_noise_rad_s2) ** 2, (dt_f * p.accel_bias_noise_m_s3) ** 2,
            p.gnss_markov_ne_m ** 2 * (1 - a * a), p.gnss_markov_d_m ** 2 * (1 - a * a)
            + (p.gnss_hgt_walk_m_s_rthz ** 2 * dt_f if p.height_ref == "baro" else 0.0),
            p.baro_drift_sigma_m ** 2 * (1 - a_b * a_b)
            + (p.baro_walk_m_s_rthz ** 2 * dt_f if p.height_ref != "baro" else 0.0)))
        # (EKF2: the height reference's own bias is not estimated; the other sources' biases
        # walk with its bias estimators' densities)
        self._m_ned = np.array(p.mag_field_ned_gauss)
        # one gyro sample's variance: EKF2_GYR_NOISE is the rate's std over a filter period
        self._gyro_var = p.gyro_noise_rad_s ** 2 * dt_f * p.imu_rate_hz
        self._gate = (p.gate_mocap_pos, p.gate_mocap_att, p.gate_gnss_pos, p.gate_gnss_vel,
                      p.gate_baro, p.gate_mag)
        ev = p.ev_ctrl
        pos_ev = np.array([(p.mocap_pos_noise_m or 0.0) ** 2] * 3)
        pos_ev[0:2] = pos_ev[0:2] if ev & 1 else _NO_WEIGHT
        pos_ev[2] = pos_ev[2] if ev & 2 else _NO_WEIGHT
        self._ev_yaw = p.has_mocap and p.ev_yaw_only and bool(ev & 8)
        self._ev_att = p.has_mocap and (not p.ev_yaw_only or self._ev_yaw)
        self._att_fn = "fuse_ev_yaw" if p.ev_yaw_only else "fuse_mocap_att"
        self._r = (
            pos_ev,
            np.full(1 if p.ev_yaw_only else 3, (p.mocap_att_noise_rad or 0.0) ** 2),
            np.array((p.gnss_pos_noise_ne_m or 0.0, p.gnss_pos_noise_ne_m or 0.0,
                      p.gnss_pos_noise_d_m or 0.0)) ** 2,
            np.array((p.gnss_vel_noise_ne_m_s or 0.0, p.gnss_vel_noise_ne_m_s or 0.0,
                      p.gnss_vel_noise_d_m_s or 0.0)) ** 2,
            np.full(1, (p.baro_noise_m or 0.0) ** 2),
            np.full(3, (p.mag_noise_gauss or 0.0) ** 2))
        # which measurements it takes (the others are dropped on arrival)
        # (EKF2: no magnetometer while the vision's yaw is fused)
        self._takes = {Aid.MOCAP_POS: p.has_mocap, Aid.GNSS_POS: p.has_gnss, Aid.BARO: p.has_baro,
                       Aid.MAG: p.has_mag and not self._ev_yaw}
        # each delayed kind's configured delay (None: the reading's own time of validity)
        self._delay = {Aid.MOCAP_POS: p.ev_delay_us, Aid.GNSS_POS: p.gnss_delay_us}
        self._alpha_abl = min(max(dt_f / p.abl_tau_s, 0.0), 1.0)

    def retune(self, params: EstimatorParams) -> None:
        """New parameters in flight (a ground station's PARAM_SET), the filter's state kept. What
        sizes or places the filter (its horizon, period, IMU rate, height reference, the
        sources it fuses, gravity, the initial figures) is EKF2's reboot_required: refused."""
        old = self.params
        fixed = ("horizon_us", "filter_period_us", "imu_rate_hz", "height_ref", "has_mocap",
                 "has_gnss", "has_baro", "has_mag", "gravity_m_s2", "ev_yaw_only",
                 "gnss_markov_ne_m", "gnss_markov_d_m")
        changed = [k for k in fixed if getattr(old, k) != getattr(params, k)]
        if changed:
            raise ValueError(f"{', '.join(changed)} changed: takes effect at the next start "
                             "(EKF2: reboot required)")
        bb_ref = self._a[2]
        self._gyro_lpf.set_cutoff(params.imu_rate_hz, params.gyro_cutoff_hz)
        self.params = params
        self._configure(params)
        self._a[2] = bb_ref
        dt_f = self._dt_f
        self.out._k_v = dt_f / min(max(params.tau_vel_s, dt_f), 10.0)
        self.out._k_p = dt_f / min(max(params.tau_pos_s, dt_f), 10.0)

    # ---------------------------------------------------------------- per physics tick

    def step(self, t_us: int, readings) -> None:
        """Take one physics tick's readings (the sensor suite's output at t_us)."""
        if t_us <= self._now:
            raise ValueError(f"step: t_us {t_us} after {self._now} expected (one call per tick)")
        self._now = t_us
        takes = self._takes
        for r in readings:
            if isinstance(r, ImuReading):
                self._imu(r)
                continue
            aid = _BUFFER_OF[type(r)]          # a position, height or field measurement
            if not takes[aid]:
                continue
            delay = self._delay.get(aid)
            self._meas[aid].append((r.t_us if delay is None else r.arrival_us - delay, r))
            if aid == Aid.MAG and not self.aligned:
                self._sum_m += r.field_frd_gauss
                self._n_m += 1
        if not self.aligned:
            if self._t_first is not None and t_us >= self._t_align and self._n_f:
                self._align()
            return
        horizon = self.params.horizon_us
        buf = self._imu_buf
        while buf and buf[0][0] + horizon <= t_us:
            self._update(*buf.popleft())

    def set_at_rest(self, at_rest: bool) -> None:
        """The vehicle's land detector: at rest on the ground (EKF2's vehicle_at_rest), for the
        zero-velocity update."""
        self.at_rest = bool(at_rest)

    def _imu(self, r: ImuReading) -> None:
        g = r.gyro
        self._gyro = self._gyro_lpf.apply(g)
        t = r.t_us
        if not self.aligned:
            if self._t_first is None:
                period = self.params.filter_period_us
                self._t_first = t
                self._t_align = -(-(t + self.params.align_us) // period) * period
            if t <= self._t_align:
                self._sum_f += [float(v) for v in r.accel]
                self._n_f += 1
            return
        out = self.out
        dt_us = r.dt_us or self.params.imu_period_us
        out.sample(t, g, r.accel, dt_us * 1e-6)     # the output state forward, the period's sums
        self._acc_us += dt_us
        c = r.accel_clipped
        if c[0] or c[1] or c[2]:
            clip = self._clip
            clip[0], clip[1], clip[2] = clip[0] or c[0], clip[1] or c[1], clip[2] or c[2]
        if self._acc_us >= self._close_us:
            self._imu_buf.append((t, *out.take_sums(), self._acc_us, tuple(self._clip)))
            out.record()
            self._acc_us = 0
            self._clip = [False, False, False]

    # ---------------------------------------------------------------- initialisation

    def _align(self) -> None:
        p = self.params
        fx, fy, fz = self._sum_f / self._n_f
        roll = math.atan2(-fy, -fz)
        pitch = math.atan2(fx, math.hypot(fy, fz))
        mocap = self._meas[Aid.MOCAP_POS]
        yaw_var = 0.3 ** 2            # the magnetometer heading: a wide prior (tilt error x tan I)
        tilt_var = (p.accel_bias_init_m_s2 / p.gravity_m_s2) ** 2 + 1e-6 \
            if p.tilt_init_rad is None else p.tilt_init_rad ** 2
        if mocap:
            q = np.array(mocap[-1][1].quat_wxyz, float)
            yaw_var = tilt_var = max(p.mocap_att_noise_rad, 1e-3) ** 2
        elif self._n_m:
            r_rp = np.array(quat_to_dcm(*euler_to_quat(roll, pitch, 0.0)))
            m = r_rp @ (self._sum_m / self._n_m)
            q = np.array(euler_to_quat(roll, pitch,
                                       math.atan2(-m[1], m[0]) + p.mag_declination_rad))
        else:
            q = np.array(euler_to_quat(roll, pitch, 0.0))
            yaw_var = math.pi ** 2
        x = np.zeros(d.NX)
        x[Q_] = q / np.linalg.norm(q)
        P = np.diag(np.concatenate((
            np.full(3, p.init_pos_var_m2), np.full(3, p.init_vel_var_m2_s2),
            (tilt_var, tilt_var, yaw_var), np.full(3, p.gyro_bias_init_rad_s ** 2),
            np.full(3, p.accel_bias_init_m_s2 ** 2),
            (p.gnss_markov_ne_m ** 2, p.gnss_markov_ne_m ** 2, p.gnss_markov_d_m ** 2),
            ((p.baro_drift_sigma_m ** 2 + (p.baro_noise_m or 0.0) ** 2),))))
        self.x, self.P = x, P
        self.t_filter_us = t = self._t_align
        self.aligned = True
        if self._baro_ref:
            self._init_height(t)
        for buf in self._meas:
            while buf and buf[0][0] <= t:
                buf.popleft()
        self._imu_buf.clear()
        self._acc_us = 0
        self._clip = [False, False, False]
        self.out.reset(t, self.x[Q_], self.x[V_], self.x[P_])      # its sums zero too

    def _reset_position(self, r, t_us: int) -> None:
        """Position (and, from GNSS, velocity) set to the measurement's; applied as a jump to
        the output predictor too (EKF2's resetHorizontalPositionTo and its output reset)."""
        old_p, old_v = self.x[P_].copy(), self.x[V_].copy()
        is_gnss = isinstance(r, GnssReading)
        r_pos, r_vel = self._gnss_r(r) if is_gnss else (self._r[Aid.MOCAP_POS], None)
        # the axes reset: all three, or the horizontal ones when the barometer keeps the height
        n = 2 if self._baro_ref else 3
        ax, bn = slice(DP.start, DP.start + n), slice(DBN.start, DBN.start + n)
        self.x[P_.start:P_.start + n] = r.pos_ned_m[:n] - (
            self.x[BN.start:BN.start + n] if is_gnss else 0.0)
        self.P[ax, :] = 0.0
        self.P[:, ax] = 0.0
        if is_gnss:
            # p = z - bn: the receiver's error is the position's, anticorrelated
            p_bn = self.P[bn, bn].copy()
            self.P[ax, ax] = np.diag(r_pos[:n]) + p_bn
            self.P[ax, bn] = -p_bn
            self.P[bn, ax] = -p_bn
            if self._baro_ref:
                # the height stays; the receiver's height error is taken as what it reads
                # against it (EKF2 sets its GNSS height bias estimate so): bn_d = z_d - p_d
                self.x[BN_D] = r.pos_ned_m[2] - self.x[P_D]
                self.P[DBN_D, :] = -self.P[DP_D, :]
                self.P[:, DBN_D] = -self.P[:, DP_D]
                self.P[DBN_D, DBN_D] = self.P[DP_D, DP_D] + r_pos[2]
        else:
            self.P[ax, ax] = np.diag(np.minimum(r_pos[:n], self.params.init_pos_var_m2))
        if is_gnss:
            self.x[V_] = r.vel_ned_m_s
            self.P[DV, :] = 0.0
            self.P[:, DV] = 0.0
            self.P[DV, DV] = np.diag(r_vel)
        self.state_resets += (1 if n == 2 else 2) + (2 if is_gnss else 0)
        self._pos_init = True
        if not self._baro_ref:
            self._baro_init = False     # its offset is taken again against the new height
        self._last_pos_fuse_us = t_us
        self.out.shift(self.x[V_] - old_v, self.x[P_] - old_p)

    def _reset_if_lost(self, r) -> bool:
        """The position source rejected for longer than the reset timeout: the filter, not the
        source, is taken to be wrong, and the position reset to the measurement (EKF2 does the
        same for GNSS after its reset_timeout_max, 7 s, of failed innovation checks). True when
        it did."""
        last = self._last_pos_fuse_us
        if last is not None and self.t_filter_us - last > self.params.reset_timeout_us:
            self._reset_position(r, self.t_filter_us)
            self._pos_resets += 1
            return True
        return False

    def _gnss_r(self, r: GnssReading) -> tuple[np.ndarray, np.ndarray]:
        """The fix's position and velocity variances: EKF2's, the reported accuracies floored by
        the parameters (use_reported_accuracy), or the parameters alone."""
        rp, rv = self._r[Aid.GNSS_POS], self._r[Aid.GNSS_VEL]
        if not self.params.use_reported_accuracy:
            return rp, rv
        h, v, s = r.eph_m ** 2, r.epv_m ** 2, r.speed_accuracy_m_s ** 2
        return (np.maximum((h, h, v), rp), np.maximum((s, s, 2.25 * s), rv))

    def _init_baro(self, r: BaroReading) -> None:
        """bb = z + p_d: its error is the height's plus the reading's noise, and correlates
        with the other states as the height does."""
        self._set_baro_offset(r.pressure_alt_m, self._r[Aid.BARO][0])

    def _set_baro_offset(self, alt_m: float, var_m2: float) -> None:
        self.x[BB_I] = alt_m + self.x[P_D]
        self._a[2] = self.x[BB_I]         # the drift's Gauss-Markov is about this offset
        P = self.P
        P[DBB_I, :] = P[DP_D, :]
        P[:, DBB_I] = P[:, DP_D]
        P[DBB_I, DBB_I] = P[DP_D, DP_D] + var_m2
        self._baro_init = True

    def _init_height(self, t_us: int) -> None:
        """The barometer as the height reference (EKF2_HGT_REF baro): the height is the
        vehicle's at alignment, init_pos_d_m, known to the barometer's noise (EKF2's height
        reset to the baro), and the offset is the mean pressure altitude over the alignment
        (the vehicle at rest) taken against it. Without a reading yet, the first one after
        alignment gives the offset."""
        p = self.params
        self.x[P_D] = p.init_pos_d_m
        self.P[DP_D, :] = 0.0
        self.P[:, DP_D] = 0.0
        self.P[DP_D, DP_D] = self._r[Aid.BARO][0]
        alts = [r.pressure_alt_m for t, r in self._meas[Aid.BARO] if t <= t_us]
        if alts:
            self._set_baro_offset(sum(alts) / len(alts), self._r[Aid.BARO][0] / len(alts))

    # ---------------------------------------------------------------- the delayed horizon

    def _update(self, t_end: int, dA: np.ndarray, dV: np.ndarray, dt_us: int,
                clip: tuple[bool, bool, bool]) -> None:
        p = self.params
        dt = dt_us * 1e-6
        qd = self._qd
        qd[0] = (dt * p.gyro_noise_rad_s) ** 2
        for i in range(3):
            qd[1 + i] = (dt * (p.bad_acc_noise_m_s2 if clip[i] else p.accel_noise_m_s2)) ** 2
        inhibit = self._inhibit_accel_bias(dA, dV, dt, clip)
        x_next, P_next = self._f["predict"](self.x, self.P, dA, dV, dt, self._a, qd)
        self.x = x_next.ravel().copy()
        self.P = P_next.copy()
        if inhibit:
            self._hold_accel_bias()
        t_prev, self.t_filter_us = self.t_filter_us, t_end
        meas = self._meas
        for aid in (Aid.MOCAP_POS, Aid.GNSS_POS, Aid.BARO, Aid.MAG):
            buf = meas[aid]
            while buf and buf[0][0] <= t_end:
                t_valid, r = buf.popleft()
                if t_valid > t_prev:
                    self._fuse_reading(aid, r, t_valid)
                else:
                    self._stale += 1
        if p.zero_velocity_update:
            self._zero_velocity_update()
        self._diverged = self._diverged or self._check_divergence()
        x = self.x.tolist()
        self._bg = tuple(x[BG])
        self._ba = tuple(x[BA])
        self.out.set_biases(self._bg, self._ba)
        self.out.correct(t_end, x[Q_], x[V_], x[P_])

    def _inhibit_accel_bias(self, dA: np.ndarray, dV: np.ndarray, dt: float,
                            clip: tuple[bool, bool, bool]) -> bool:
        """EKF2's accel bias learning inhibition (predictCovariance): the peak-held rate and
        specific force magnitudes against EKF2_ABL_GYRLIM and EKF2_ABL_ACCLIM, and each axis
        that clipped. An axis newly inhibited keeps its variance to hold; one released gets it
        back before the prediction. True when an axis is inhibited this period."""
        p, P = self.params, self.P
        beta = 1.0 - self._alpha_abl
        self._ang_filt = max(math.sqrt(float(dA @ dA)) / dt, beta * self._ang_filt)
        self._acc_filt = max(math.sqrt(float(dV @ dV)) / dt, beta * self._acc_filt)
        high = self._ang_filt > p.abl_gyr_lim_rad_s or self._acc_filt > p.abl_acc_lim_m_s2
        any_axis = False
        for i in range(3):
            k = DBA.start + i
            now = high or clip[i]
            if now and not self._ba_inhibit[i]:
                self._ba_prev_var[i] = float(P[k, k])
            elif not now and self._ba_inhibit[i]:
                P[k, k] = self._ba_prev_var[i]
            self._ba_inhibit[i] = now
            any_axis = any_axis or now
        return any_axis

    def _hold_accel_bias(self) -> None:
        """Each inhibited accel bias axis: its variance held, its correlations cut (so that no
        fusion moves it)."""
        P = self.P
        for i in range(3):
            if self._ba_inhibit[i]:
                k = DBA.start + i
                P[k, :] = 0.0
                P[:, k] = 0.0
                P[k, k] = self._ba_prev_var[i]

    def _zero_velocity_update(self) -> None:
        """EKF2's ZVU: at rest for this period and the last, no velocity fused lately (EKF2:
        no vertical velocity aiding), at most every 200 ms: zero velocity, 0.2 m/s noise,
        ungated."""
        t = self.t_filter_us
        at_rest, self._at_rest_prev = self.at_rest and self._at_rest_prev, self.at_rest
        last_v = self._last_vel_fuse_us
        if not (at_rest and self._pos_init and t - self._last_zvu_us >= _ZVU_PERIOD_US
                and (last_v is None or t - last_v > self.params.no_aid_timeout_us)):
            return
        _, _, x_next, P_next = self._f["fuse_gnss_vel"](self.x, self.P, np.zeros(3),
                                                        np.full(3, _ZVU_VAR), self._m_ned)
        self.x = x_next.ravel().copy()
        self.P = P_next.copy()
        self._last_zvu_us = t
        self.zvu_fused += 1

    def _fuse_reading(self, aid: Aid, r, t_us: int) -> None:
        """One reading at its time of validity t_us (as the filter takes it)."""
        if aid in (Aid.MOCAP_POS, Aid.GNSS_POS):
            # a position source: the first one places the filter; then its position, and the
            # vision's attitude or the receiver's velocity
            if not self._pos_init:
                self._reset_position(r, t_us)
                return
            if aid == Aid.MOCAP_POS:
                # the reported variances floored by the parameters (EKF2_EV_NOISE_MD 0)
                rp = ra = None
                if r.pos_var_m2 is not None:
                    rp = np.maximum(self._r[aid], r.pos_var_m2)
                if r.att_var_rad2 is not None:
                    ra = np.maximum(self._r[Aid.MOCAP_ATT], r.att_var_rad2)
                if not self._fuse(aid, t_us, r.pos_ned_m, rp):
                    self._reset_if_lost(r)
                if self._ev_att:
                    self._fuse(Aid.MOCAP_ATT, t_us, r.quat_wxyz, ra, fn=self._att_fn)
                return
            r_pos, r_vel = self._gnss_r(r)
            if not self._fuse(aid, t_us, r.pos_ned_m, r_pos) and self._reset_if_lost(r):
                return      # the reset took this fix's velocity: it is not fused again
            if self._fuse(Aid.GNSS_VEL, t_us, r.vel_ned_m_s, r_vel):
                self._last_vel_fuse_us = self.t_filter_us
        elif aid == Aid.BARO:
            if not (self._pos_init or self._baro_ref):
                return                  # the offset is taken against a known height
            if not self._baro_init:
                self._init_baro(r)
                return
            self._fuse(Aid.BARO, t_us, np.array((r.pressure_alt_m,)))
        else:
            self._fuse(Aid.MAG, t_us, r.field_frd_gauss)

    def _fuse(self, aid: Aid, t_us: int, z: np.ndarray, r: np.ndarray | None = None,
              fn: str | None = None) -> bool:
        y, s, x_next, P_next = self._f[fn or _FUSE[aid]](
            self.x, self.P, z, self._r[aid] if r is None else r, self._m_ned)
        y, s = y.ravel().copy(), s.ravel().copy()
        gate = self._gate[aid]
        axes = y * y / (gate * gate * s)
        ratio = float(np.maximum.reduce(axes))     # ndarray.max without its Python wrapper
        ok = ratio <= 1.0
        self.innovations[aid] = Innovation(aid, t_us, y, s, ratio, ok, axes)
        if not ok:
            self._rejected[aid] += 1
            return False
        self.x = x_next.ravel().copy()
        self.P = P_next.copy()
        self._fused[aid] += 1
        if aid == Aid.MOCAP_POS or aid == Aid.GNSS_POS:
            self._last_pos_fuse_us = self.t_filter_us
        return True

    # ---------------------------------------------------------------- outputs

    def _check_divergence(self) -> bool:
        """A state or variance not finite, a variance below zero or above max_var (the
        variances' extremes, taken once all entries are known finite)."""
        x, P = self.x, self.P
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            return True
        diag = P.diagonal()
        return bool(diag.min() < 0.0 or diag.max() > self.params.max_var)

    @property
    def diverged(self) -> bool:
        """Latched once a filter period ended with a state or variance out of bounds."""
        return self._diverged

    def position_valid(self) -> bool:
        last = self._last_pos_fuse_us
        return bool(self._pos_init and last is not None
                    and self.t_filter_us - last <= self.params.no_aid_timeout_us)

    def output(self) -> Estimate:
        """The estimate at the last tick (before alignment: the initial state, not aligned)."""
        o, x, P = self.out, self.x, self.P
        diag = P.diagonal()
        g = self._gyro
        bg = self._bg
        return Estimate(
            self._now, np.array(o.p), np.array(o.v), np.array(o.q),
            np.array((g[0] - bg[0], g[1] - bg[1], g[2] - bg[2])),
            diag[DP].copy(), diag[DV].copy(), diag[DTH].copy(), x[BG].copy(),
            x[BA].copy(), self.t_filter_us, self.aligned, self.position_valid(),
            self._diverged,
            tuple(i.test_ratio if i is not None else math.nan for i in self.innovations),
            tuple(self._fused), tuple(self._rejected), self._stale, self._pos_resets,
            o.tracking_error,
            P[_POSE_ROWS, _POSE_COLS], P[DV, DV].copy(),
            self._gyro_var + diag[DBG], *self._status_ratios())

    def _status_ratios(self) -> tuple[float, float, float, float]:
        """EKF2's four: the largest of the last axis ratios of the kinds each takes (nan: none
        yet). A kind's ratio over all its axes is its test ratio (the same maximum), over one
        axis that axis's ratio; only the horizontal pair takes a maximum here."""
        inn = self.innovations

        def worst(vals) -> float:
            return max(vals) if vals else math.nan

        def whole(aid) -> list[float]:
            i = inn[aid]
            return [] if i is None else [i.test_ratio]
        pos = [i for i in (inn[Aid.MOCAP_POS], inn[Aid.GNSS_POS]) if i is not None]
        return (worst(whole(Aid.GNSS_VEL)),
                worst([float(i.axis_ratios[0:2].max()) for i in pos]),
                worst([float(i.axis_ratios[2]) for i in pos] + whole(Aid.BARO)),
                worst(whole(Aid.MAG)))

    def filter_state(self) -> tuple[int, np.ndarray, np.ndarray]:
        """(t_us, x, P) at the delayed horizon (copies)."""
        return self.t_filter_us, self.x.copy(), self.P.copy()
