"""The estimator (sil_vehicle.estimator.eskf), tuned by the generator's figures (the machinery
against exact noise figures and times of validity; EKF2's tuning: test_estimator_ekf2.py), on
readings of the real sensor models (SensorSuite, seeded) along an analytic trajectory whose
position, velocity, attitude, rates and specific force are known exactly: errors against truth
per profile and against the filter's own variances, bias recovery, fusion of a delayed
measurement at its time of validity, the output predictor without the horizon's lag, innovation
gating, health flags, and determinism."""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache

import numpy as np
import pytest

from sil_vehicle.estimator.eskf import Aid, Eskf
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.frames import euler_to_quat
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuState
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.suite import SensorSuite
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2, Truth, specific_force_frd

# the filter flown along whole trajectories under every profile: the full suite's, not the
# fast tier's (pytest -m "not slow")
pytestmark = pytest.mark.slow

HOVER_S = 2.0
# errors are judged once the filter has converged: at rest the accelerometer's bias, the tilt
# and (through the magnetometer's mostly vertical field) the heading cannot be told apart; the
# turns of the circle (from 2 s) separate them
SETTLE_US = 6_000_000
FLIGHT_S = 14.0


def truth_at(t_us: int) -> Truth:
    """Hover level at (2, 0, -1) with yaw 0.3 rad for HOVER_S, then a circle of radius 2 m about
    the origin, its angular speed ramped up over 2 s to 0.8 rad/s, with a vertical wave and smooth
    roll, pitch and yaw changes; velocity, acceleration and body rates in closed form."""
    t = t_us * 1e-6
    tau = max(0.0, t - HOVER_S)
    w, ramp, radius = 0.8, 2.0, 2.0
    if t <= HOVER_S:
        ph, ph1, ph2 = 0.0, 0.0, 0.0
    elif tau < ramp:
        ph, ph1, ph2 = w * tau * tau / (2 * ramp), w * tau / ramp, w / ramp
    else:
        ph, ph1, ph2 = w * (tau - ramp / 2), w, 0.0
    c, s = math.cos(ph), math.sin(ph)
    pos = (radius * c, radius * s, -1.0 - 0.2 * (1 - math.cos(0.5 * tau)))
    vel = (-radius * s * ph1, radius * c * ph1, -0.1 * math.sin(0.5 * tau))
    acc = (-radius * (c * ph1 ** 2 + s * ph2), radius * (-s * ph1 ** 2 + c * ph2),
           -0.05 * math.cos(0.5 * tau) if tau > 0 else 0.0)
    roll, droll = 0.08 * (1 - math.cos(1.1 * tau)), 0.088 * math.sin(1.1 * tau)
    pitch, dpitch = -0.06 * (1 - math.cos(0.9 * tau)), -0.054 * math.sin(0.9 * tau)
    yaw = 0.3 + 0.5 * ph + 0.4 * (1 - math.cos(0.7 * tau))
    dyaw = 0.5 * ph1 + 0.28 * math.sin(0.7 * tau)
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    rates = (droll - dyaw * sp, dpitch * cr + dyaw * sr * cp, -dpitch * sr + dyaw * cr * cp)
    q = np.array(euler_to_quat(roll, pitch, yaw))
    f = specific_force_frd(q, np.array(acc), STANDARD_GRAVITY_M_S2)
    return Truth.of(t_us, pos, vel, q, rates, f, (55.0,) * 4)


def test_trajectory_is_self_consistent():
    """Velocity and body rates are the derivatives of position and attitude (central
    differences), so the IMU readings describe the same motion as the pose."""
    for t_us in (1_000_000, 2_500_000, 5_300_000, 9_100_000):
        a, b, m = truth_at(t_us - 100), truth_at(t_us + 100), truth_at(t_us)
        np.testing.assert_allclose((b.pos_ned_m - a.pos_ned_m) / 2e-4, m.vel_ned_m_s, atol=1e-6)
        dq = quat_mul(quat_conj(a.quat_wxyz), b.quat_wxyz)
        np.testing.assert_allclose(2 * dq[1:] / 2e-4, m.rates_frd_rad_s, atol=1e-6)


def quat_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array((aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw))


def quat_conj(q):
    return np.array((q[0], -q[1], -q[2], -q[3]))


def att_error(q_est, q_true) -> np.ndarray:
    """The body-frame rotation vector from truth to the estimate (rad)."""
    qe = quat_mul(quat_conj(q_true), q_est)
    return (2.0 if qe[0] >= 0 else -2.0) * qe[1:]


@cache
def flight(profile: str, seed: int = 1, seconds: float = FLIGHT_S, constant_bias: bool = False):
    """The sensor suite's readings per tick (1 kHz physics), home at 30 m AMSL. Without the
    IMU's rotor vibration (issue 39 item 2 gave it the published level: what it costs the
    filter is for the filter's own rework, branch ekf2, and the headline re-runs)."""
    prof = load_sensing(profile, 1000)
    prof = replace(prof, imu=replace(prof.imu, vibration=None))
    if constant_bias:
        prof = replace(prof, imu=replace(prof.imu, gyro_bias_random_walk_rad_s2_rthz=0.0,
                                         accel_bias_random_walk_m_s3_rthz=0.0))
    suite = SensorSuite(prof, np.random.default_rng(seed), home_alt_m=30.0)
    if constant_bias:
        suite.states["imu"] = ImuState(np.array(BIAS_G), np.array(BIAS_A))
    return prof, tuple((k * 1000, tuple(suite.sample(k * 1000, truth_at(k * 1000))))
                       for k in range(int(seconds * 1000)))


BIAS_G = (0.012, -0.02, 0.015)
BIAS_A = (0.25, -0.3, 0.2)


def run(prof, readings, every_us: int = 10_000, **overrides):
    """Step a fresh filter through `readings`; every `every_us` after alignment: (t_us, the
    output, the filter state (t_d, x, P))."""
    # the trajectory starts in the air, not on the ground at the origin: a barometer-referenced
    # height starts where it is (the motion capture and an RTK receiver give their own)
    overrides.setdefault("init_pos_d_m", truth_at(0).pos_ned_m[2])
    est = Eskf(EstimatorParams.generator(prof, **overrides))
    out = []
    for t, rs in readings:
        est.step(t, rs)
        if t % every_us == 0 and est.aligned:
            out.append((t, est.output(), est.filter_state()))
    return est, out


# profile -> (position bound NED (m), attitude bound (rad)) on the output against truth after
# SETTLE_US: mocap millimetres, rtk centimetres, gnss metres (its error is the receiver's
# Gauss-Markov drift, 2 m horizontal and 4 m vertical 1-sigma, one draw per flight: 4 sigma)
BOUNDS = {"mocap": ((0.005,) * 3, 0.002), "rtk": ((0.06,) * 3, 0.01),
          "gnss": ((8.0, 8.0, 16.0), 0.02)}


@pytest.mark.parametrize("profile", ["mocap", "rtk", "gnss"])
def test_errors_against_truth_and_own_variances(profile):
    prof, readings = flight(profile)
    _, out = run(prof, readings)
    settled = [(t, e, f) for t, e, f in out if t >= SETTLE_US]
    pos_bound, att_bound = BOUNDS[profile]
    pos_err = np.array([e.pos_ned_m - truth_at(t).pos_ned_m for t, e, _ in settled])
    att_err = np.array([att_error(e.quat_wxyz, truth_at(t).quat_wxyz) for t, e, _ in settled])
    assert np.all(np.abs(pos_err).max(axis=0) < pos_bound)
    assert np.abs(att_err).max() < att_bound
    # the filter's variances at its (delayed) time against its errors there
    nees_p, nees_a, inside = [], [], []
    for _, _, (t_d, x, P) in settled:
        tr = truth_at(t_d)
        ep, ea = x[0:3] - tr.pos_ned_m, att_error(x[6:10], tr.quat_wxyz)
        sp, sa = np.diag(P)[0:3], np.diag(P)[6:9]
        nees_p.append(ep @ (ep / sp))
        nees_a.append(ea @ (ea / sa))
        inside.append(np.all(np.abs(ep) < 3 * np.sqrt(sp)) and np.all(np.abs(ea) < 3 * np.sqrt(sa)))
    # time-averaged normalised errors under the chi-square(3) 99.9 % point, and most of the
    # time every axis within 3 sigma (the GNSS drift is one draw per flight: a 2-3 sigma draw
    # shows as a steady 2-3 sigma error, hence "most", not "99 %")
    assert np.mean(nees_p) < 16.3 and np.mean(nees_a) < 16.3
    assert np.mean(inside) > 0.7
    last = out[-1][1]
    assert last.attitude_aligned and last.position_valid and not last.diverged
    assert sum(last.rejected) <= 0.02 * sum(last.fused)


@pytest.mark.parametrize("seed", [1, 2])
def test_gnss_height_is_the_barometers(seed):
    """Under `gnss` the barometer is the height reference (EKF2_HGT_REF baro): the height error
    against truth stays within what the barometer's noise and drift allow over the flight (3
    sigma of the offset's error at alignment plus the drift's change), where the receiver's own
    height error is metres; the horizontal is the same as with the GNSS as the height
    reference (the former behaviour), and the GNSS height never resets the height."""
    prof, readings = flight("gnss", seed=seed)
    b = prof.baro
    bound = 3 * math.sqrt(b.noise_m ** 2 + 2 * b.drift_sigma_m ** 2 * FLIGHT_S / b.drift_tau_s)
    assert bound < 1.0
    est, out = run(prof, readings)
    _, by_gnss = run(prof, readings, height_ref="gnss")
    assert est.params.height_ref == "baro"
    err = np.array([e.pos_ned_m - truth_at(t).pos_ned_m for t, e, _ in out])
    err_gnss = np.array([e.pos_ned_m - truth_at(t).pos_ned_m for t, e, _ in by_gnss])
    rx = np.array([r.pos_ned_m[2] - truth_at(r.t_us).pos_ned_m[2]
                   for _, rs in readings for r in rs if isinstance(r, GnssReading)])
    assert np.abs(err[:, 2]).max() < bound
    assert np.abs(err[:, 2]).max() < 0.5 * np.sqrt(np.mean(rx ** 2))
    np.testing.assert_allclose(err[:, :2], err_gnss[:, :2], atol=1e-3)
    last = out[-1][1]
    assert last.fused[Aid.GNSS_POS] > 60 and last.fused[Aid.BARO] > 600
    assert last.pos_resets == 0 and not last.diverged
    if seed == 2:
        # a receiver metres off in height: the former datum was, this one is not
        assert np.abs(err_gnss[:, 2]).max() > 3 * bound


def test_constant_biases_are_recovered():
    prof, readings = flight("mocap", seed=5, seconds=10.0, constant_bias=True)
    est, _ = run(prof, readings)
    e = est.output()
    np.testing.assert_allclose(e.gyro_bias_frd_rad_s, BIAS_G, atol=3e-4)
    np.testing.assert_allclose(e.accel_bias_frd_m_s2, BIAS_A, atol=0.02)
    # and the rates the estimate reports are the gyro's less the bias (one sample: its white
    # noise and vibration, about 0.006 rad/s 1-sigma, remain)
    np.testing.assert_allclose(e.rates_frd_rad_s, truth_at(e.t_us).rates_frd_rad_s, atol=0.03)


def test_a_delayed_measurement_is_fused_at_its_time_of_validity():
    """The gnss profile's 120 ms delay against the same readings handed over undelayed (each GNSS
    reading moved to the tick of its time of validity) to a filter with no horizon: the filter
    states at every delayed time are the same, bit for bit; the delayed filter runs 120 ms
    behind."""
    prof, readings = flight("gnss", seconds=4.0)
    undelayed: dict[int, list] = {t: [r for r in rs if not isinstance(r, GnssReading)]
                                  for t, rs in readings}
    for _, rs in readings:
        for r in rs:
            if isinstance(r, GnssReading):
                undelayed[r.t_us].append(replace(r, arrival_us=r.t_us))
    moved = [(t, tuple(undelayed[t])) for t, _ in readings]
    assert sum(isinstance(r, GnssReading) for _, rs in moved for r in rs) >= 18

    def states(rs, **kw):
        est = Eskf(EstimatorParams.generator(prof, **kw))
        got = {}
        for t, r in rs:
            est.step(t, r)
            if est.aligned:
                t_d, x, P = est.filter_state()
                got.setdefault(t_d, (t, x, P))
        return got, est

    delayed, est_a = states(readings)
    direct, est_b = states(moved, horizon_us=0)
    assert est_a.params.horizon_us == 120_000 and est_b.params.horizon_us == 0
    common = sorted(set(delayed) & set(direct))
    assert len(common) > 300
    for t_d in common:
        assert direct[t_d][0] == t_d
        assert delayed[t_d][0] - t_d == (120_000 if t_d > common[0] else 0)
        np.testing.assert_array_equal(delayed[t_d][1], direct[t_d][1])
        np.testing.assert_array_equal(delayed[t_d][2], direct[t_d][2])
    assert est_a.output().fused[Aid.GNSS_POS] == est_b.output().fused[Aid.GNSS_POS] > 15


def test_output_predictor_removes_the_horizons_lag():
    """rtk (110 ms horizon) on the circle at 1.6 m/s: the filter's state, 110 ms old, is about
    0.18 m and several degrees of yaw behind the vehicle; the output state at `now` is not."""
    prof, readings = flight("rtk")
    _, out = run(prof, readings)
    lag_p, out_p, lag_a, out_a = [], [], [], []
    for t, e, (t_d, x, _) in out:
        if t < 5_000_000:
            continue
        now, then = truth_at(t), truth_at(t_d)
        # the filter's own error at its time is taken out of both, to see the lag alone
        own = x[0:3] - then.pos_ned_m
        lag_p.append(np.linalg.norm(x[0:3] - now.pos_ned_m - own))
        out_p.append(np.linalg.norm(e.pos_ned_m - now.pos_ned_m - own))
        lag_a.append(np.linalg.norm(att_error(x[6:10], now.quat_wxyz)))
        out_a.append(np.linalg.norm(att_error(e.quat_wxyz, now.quat_wxyz)))
    assert np.median(lag_p) > 0.15
    assert np.median(out_p) < 0.05 * np.median(lag_p)
    assert np.median(out_a) < 0.1 * np.median(lag_a)


def test_gating_rejects_an_outlier_and_counts_it():
    prof, readings = flight("rtk")
    bad = []
    hit = None
    for t, rs in readings:
        new = []
        for r in rs:
            if isinstance(r, GnssReading) and hit is None and r.t_us >= 8_000_000:
                hit = r.t_us
                r = replace(r, pos_ned_m=r.pos_ned_m + np.array((3.0, 0.0, 0.0)))
            new.append(r)
        bad.append((t, tuple(new)))
    clean, _ = run(prof, readings)
    est = Eskf(EstimatorParams.generator(prof))
    ratio = None
    for t, rs in bad:
        est.step(t, rs)
        inn = est.innovations[Aid.GNSS_POS]
        if inn is not None and inn.t_us == hit:
            ratio = inn.test_ratio, inn.accepted
    e, c = est.output(), clean.output()
    assert ratio is not None and ratio[0] > 1.0 and not ratio[1]
    assert e.rejected[Aid.GNSS_POS] == c.rejected[Aid.GNSS_POS] + 1
    assert e.fused[Aid.GNSS_POS] == c.fused[Aid.GNSS_POS] - 1
    assert e.fused[Aid.GNSS_VEL] == c.fused[Aid.GNSS_VEL]
    assert np.linalg.norm(e.pos_ned_m - c.pos_ned_m) < 0.01


def test_a_position_source_rejected_too_long_resets_the_position():
    """The GNSS jumps 3 m north for good at 8 s (a new datum): rejected by the gate, then, after
    the reset timeout (1 s here; EKF2's 7 s by default), taken and the position reset to it;
    the fix that reset the velocity is not fused again as a measurement."""
    prof, readings = flight("rtk")
    shifted = [(t, tuple(replace(r, pos_ned_m=r.pos_ned_m + np.array((3.0, 0.0, 0.0)))
                         if isinstance(r, GnssReading) and r.t_us >= 8_000_000 else r
                         for r in rs)) for t, rs in readings]
    est = Eskf(EstimatorParams.generator(prof, reset_timeout_us=1_000_000))
    fuse_vel = []
    real = est._fuse

    def spy(aid, t_us, z, r=None, fn=None):
        if aid == Aid.GNSS_VEL:
            fuse_vel.append(t_us)
        return real(aid, t_us, z, r, fn)
    est._fuse = spy
    seen = {}
    for t, rs in shifted:
        est.step(t, rs)
        if t % 100_000 == 0:
            seen[t] = est.output()
    before, after = seen[8_900_000], seen[13_900_000]
    assert before.rejected[Aid.GNSS_POS] >= 5 and before.pos_resets == 0
    assert after.pos_resets == 1 and after.position_valid
    assert len(fuse_vel) == len(set(fuse_vel))      # no fix's velocity fused twice
    err = after.pos_ned_m - truth_at(13_900_000).pos_ned_m
    assert abs(err[0] - 3.0) < 0.1 and abs(err[1]) < 0.1


def test_position_valid_lapses_in_a_long_dropout():
    """A scripted motion capture occlusion of 1.5 s against a 0.5 s timeout (without the IMU's
    rotor vibration, as `flight`: with it the dead reckoning ends 0.21 m off, issue 39 item 2's
    record)."""
    prof = load_sensing("mocap", 1000)
    prof = replace(prof, imu=replace(prof.imu, vibration=None),
                   mocap=replace(prof.mocap, dropout_windows_us=((3_000_000, 4_500_000),)))
    suite = SensorSuite(prof, np.random.default_rng(3))
    est = Eskf(EstimatorParams.generator(prof, no_aid_timeout_us=500_000))
    flags = {}
    for k in range(6000):
        t = k * 1000
        est.step(t, suite.sample(t, truth_at(t)))
        if t % 100_000 == 0:
            flags[t] = est.output()
    assert not flags[100_000].attitude_aligned
    assert flags[2_900_000].position_valid and not flags[4_000_000].position_valid
    assert flags[5_000_000].position_valid
    assert not any(e.diverged for e in flags.values())
    # dead reckoning through the gap on a well-estimated IMU stays within centimetres
    assert np.linalg.norm(flags[4_400_000].pos_ned_m - truth_at(4_400_000).pos_ned_m) < 0.1


def test_divergence_is_flagged_and_latched():
    prof, readings = flight("mocap")
    est = Eskf(EstimatorParams.generator(prof))
    for t, rs in readings[:1000]:
        est.step(t, rs)
    assert not est.output().diverged
    est.P[4, 4] = math.nan                        # what a numerical failure leaves behind
    for t, rs in readings[1000:1020]:
        est.step(t, rs)
    assert est.output().diverged
    for t, rs in readings[1020:2000]:
        est.step(t, rs)
    assert est.output().diverged


def test_same_readings_same_estimates_bit_for_bit():
    prof, readings = flight("mocap")
    _, a = run(prof, readings[:5000], every_us=1000)
    _, b = run(prof, readings[:5000], every_us=1000)
    assert len(a) == len(b) > 4000
    for (ta, ea, fa), (tb, eb, fb) in zip(a, b):
        assert ta == tb
        for x, y in zip((ea.pos_ned_m, ea.vel_ned_m_s, ea.quat_wxyz, ea.pos_var_ned_m2, fa[1],
                         fa[2]), (eb.pos_ned_m, eb.vel_ned_m_s, eb.quat_wxyz, eb.pos_var_ned_m2,
                                  fb[1], fb[2])):
            np.testing.assert_array_equal(x, y)


def test_interpreted_functions_give_the_same_filter():
    """Without compiled code (CasADi's interpreter, the same Functions) the filter is the same to
    rounding, and the covariance blocks of the estimate are the filter's."""
    prof, readings = flight("mocap")
    a = Eskf(EstimatorParams.generator(prof))
    b = Eskf(EstimatorParams.generator(prof), compiled=False)
    assert b.how == "interpreted"
    for t, rs in readings[:1500]:
        a.step(t, rs)
        b.step(t, rs)
    ea, eb = a.output(), b.output()
    np.testing.assert_allclose(ea.pos_ned_m, eb.pos_ned_m, atol=1e-9)
    np.testing.assert_allclose(ea.quat_wxyz, eb.quat_wxyz, atol=1e-9)
    np.testing.assert_allclose(ea.pose_cov, eb.pose_cov, rtol=1e-6, atol=1e-15)
    np.testing.assert_array_equal(np.diag(ea.pose_cov)[:3], ea.pos_var_ned_m2)
    np.testing.assert_array_equal(np.diag(ea.pose_cov)[3:], ea.att_var_frd_rad2)
    np.testing.assert_array_equal(np.diag(ea.vel_cov_ned_m2_s2), ea.vel_var_ned_m2_s2)


def test_pose_covariance_in_euler_angles():
    """pose_cov_rpy maps the body-frame attitude covariance to roll, pitch, yaw: checked by
    perturbing the attitude along each body axis and differencing the Euler angles."""
    from sil_vehicle.frames import quat_to_euler
    from sil_vehicle.sensors.noise import perturb_quat

    prof, readings = flight("mocap")
    est, _ = run(prof, readings[:7000], every_us=1_000_000)
    e = est.output()
    q = e.quat_wxyz
    J = np.zeros((3, 3))
    for j in range(3):
        d = np.zeros(3)
        d[j] = 1e-6
        J[:, j] = (np.array(quat_to_euler(*perturb_quat(q, d)))
                   - np.array(quat_to_euler(*perturb_quat(q, -d)))) / 2e-6
    cov = e.pose_cov_rpy()
    np.testing.assert_allclose(cov[3:, 3:], J @ e.pose_cov[3:, 3:] @ J.T, rtol=1e-5, atol=1e-16)
    np.testing.assert_array_equal(cov[:3, :3], e.pose_cov[:3, :3])
    assert e.rates_var_frd_rad2_s2.shape == (3,) and np.all(e.rates_var_frd_rad2_s2 > 0)
    # ESTIMATOR_STATUS's ratios: the motion capture feeds position, the magnetometer its own;
    # no GNSS velocity in this profile
    assert 0 <= e.pos_horiz_ratio < 1 and 0 <= e.pos_vert_ratio < 1 and 0 <= e.mag_ratio
    assert math.isnan(e.vel_ratio)
