"""The vehicle's estimator tuned as PX4 ships EKF2 (sil_vehicle.estimator.params, eskf): its
parameters' defaults, scaling and refusals, the profile's `estimator:` section and PARAM_SET;
the clipping response, missing IMU samples, the zero-velocity update; and (slow) its
consistency checked two-sided (the normalised errors neither too large nor too small) for
position, velocity, attitude and biases, with EKF2's defaults on sensors they describe and with
deliberately mistuned filters that must fail, and a mis-set vision delay that must cost."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from trq_params.loader import ConfigError

from sil_vehicle.config import sensing_profile
from sil_vehicle.estimator import derivation as d
from sil_vehicle.estimator.eskf import Aid, Eskf
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mocap import MocapReading
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.suite import SensorSuite
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2
from sil_vehicle.sitl import Sitl

from .test_estimator_eskf import att_error, truth_at

G = STANDARD_GRAVITY_M_S2


def write_profile(tmp_path, name: str, body: dict):
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump({"name": name, **body}))
    return path


# ------------------------------------------------------------------ parameters


def test_defaults_are_px4s_and_scaled_as_ekf2_scales_them():
    p = EstimatorParams.from_profile(load_sensing("gnss", 1000))
    assert p.tuning == "ekf2"
    assert (p.gyro_noise_rad_s, p.accel_noise_m_s2) == (0.015, 0.35)
    assert (p.gyro_bias_noise_rad_s2, p.accel_bias_noise_m_s3) == (0.001, 0.003)
    assert (p.gnss_pos_noise_ne_m, p.gnss_vel_noise_ne_m_s, p.baro_noise_m,
            p.mag_noise_gauss) == (0.5, 0.3, 3.5, 0.05)
    assert p.gnss_pos_noise_d_m == pytest.approx(0.75)            # EKF2: 1.5 EKF2_GPS_P_NOISE
    assert p.gnss_markov_ne_m == 0.0 and p.baro_drift_sigma_m == 0.0   # no generator figure
    assert (p.gnss_delay_us, p.horizon_us) == (110_000, 110_000)  # EKF2_GPS_DELAY
    assert (p.no_aid_timeout_us, p.reset_timeout_us) == (5_000_000, 7_000_000)
    assert p.height_ref == "baro"              # the gnss profile's EKF2_HGT_REF 0
    assert EstimatorParams.from_profile(load_sensing("rtk", 1000)).height_ref == "gnss"  # PX4's
    assert p.use_reported_accuracy
    # EKF2_GYR_NOISE is the rate's std per filter period: var(dA) = (dt 0.015)^2 per 10 ms
    est = Eskf(p)
    dA = np.zeros(3)
    dV = np.array((0.0, 0.0, -G * 0.01))
    est._update(10_000, dA, dV, 10_000, (False, False, False))
    assert est._qd[0] == pytest.approx((0.01 * 0.015) ** 2)
    assert est._qd[1:4] == pytest.approx([(0.01 * 0.35) ** 2] * 3)


def test_the_mocap_profile_sets_what_a_motion_capture_user_sets():
    prof = load_sensing("mocap", 1000)
    p = EstimatorParams.from_profile(prof)
    assert (p.mocap_pos_noise_m, p.mocap_att_noise_rad) == (0.01, 0.05)   # EKF2's minimums
    assert p.ev_delay_us == prof.mocap.latency_us == p.horizon_us == 10_000
    assert p.height_ref == "mocap" and p.ev_yaw_only and p.ev_ctrl == 11
    est = Eskf(p)
    assert not est._takes[Aid.MAG]          # no magnetometer while the vision's yaw is fused


def test_the_generator_tuning_is_an_option_and_matches_the_old_variances(tmp_path):
    path = write_profile(tmp_path, "gen", {"extends": "builtin:sensing/mocap",
                                           "description": "d",
                                           "estimator": {"tuning": "generator"}})
    prof = load_sensing(path, 1000)
    p = EstimatorParams.from_profile(prof)
    assert p.tuning == "generator" and not p.use_reported_accuracy and p.ev_delay_us is None
    assert p.mocap_pos_noise_m == prof.mocap.position_noise_m
    imu = prof.imu
    density = math.hypot(imu.gyro_noise_density_rad_s_rthz,
                         imu.gyro_vibration_rad_s / math.sqrt(imu.rate_hz))
    # (dt * noise)^2 at the nominal period is the density's d^2 dt
    assert (0.01 * p.gyro_noise_rad_s) ** 2 == pytest.approx(density ** 2 * 0.01)


@pytest.mark.parametrize("key, value", [("EKF2_GYR_NOISE", -0.01), ("EKF2_EVP_NOISE", 0.001),
                                        ("EKF2_HGT_REF", 2), ("EKF2_GPS_DELAY", 600.0)])
def test_a_bad_parameter_names_the_file_and_key(tmp_path, key, value):
    path = write_profile(tmp_path, "bad", {"extends": "builtin:sensing/mocap",
                                           "description": "d", "estimator": {key: value}})
    with pytest.raises(ConfigError) as exc:
        load_sensing(path, 1000)
    assert str(path) in str(exc.value) and f"estimator.{key}" in str(exc.value)


def test_param_set_retunes_the_filter_and_refuses_a_restart_parameter(sim):
    s = Sitl(sim.with_changes(sensing=sensing_profile("mocap", 1000, "t"),
                              clock_mode="realtime"))
    table = s.params
    i = table.index("EKF2_EVP_NOISE")
    assert table.value(i) == pytest.approx(0.01)
    assert table.set("EKF2_EVP_NOISE", 0.05) == (i, None)
    assert s.estimator.params.mocap_pos_noise_m == pytest.approx(0.05)
    assert table.value(i) == pytest.approx(0.05)
    # out of EKF2's range, a fraction for a bitmask, or a horizon change: refused, nothing changes
    assert table.set("EKF2_EVP_NOISE", 0.001)[1] is not None
    assert table.set("EKF2_EV_CTRL", 2.5)[1] is not None
    i_delay = table.index("EKF2_EV_DELAY")
    _, err = table.set("EKF2_EV_DELAY", 50.0)
    assert "reboot" in err and table.value(i_delay) == pytest.approx(10.0)
    assert s.estimator.params.ev_delay_us == 10_000
    assert s.estimator.params.mocap_pos_noise_m == pytest.approx(0.05)


# ------------------------------------------------------------------ IMU handling

def level_imu(t_us: int, dt_us: int = 1000, clipped=(False, False, False)) -> ImuReading:
    return ImuReading(t_us, (0.0, 0.0, 0.0), (0.0, 0.0, -G), dt_us, clipped)


def pose(t_us: int, latency_us: int = 10_000, var_m2: float | None = None) -> MocapReading:
    return MocapReading(t_us - latency_us, t_us, np.zeros(3), np.array((1.0, 0.0, 0.0, 0.0)),
                        var_m2)


def static_filter(seconds: float, *, skip=(), clip_at=(), at_rest=False, pose_var=None,
                  **overrides):
    """The mocap-tuned filter on a vehicle at rest (exact readings, pose at 100 Hz); the IMU
    samples at `skip` (ms) missing, those at `clip_at` (ms) clipped on x. Returns the filter
    and the periods it processed (t_end, dt_us, clip)."""
    p = EstimatorParams.from_profile(load_sensing("mocap", 1000), **overrides)
    est = Eskf(p)
    est.set_at_rest(at_rest)
    periods = []
    real = est._update

    def spy(t_end, dA, dV, dt_us, clip):
        periods.append((t_end, dt_us, clip))
        real(t_end, dA, dV, dt_us, clip)
    est._update = spy
    last = 0
    for ms in range(1, int(seconds * 1000) + 1):
        t = ms * 1000
        rs = []
        if ms not in skip:
            rs.append(level_imu(t, t - last, (ms in clip_at, False, False)))
            last = t
        if ms % 10 == 0 and ms >= 20:
            rs.append(pose(t, var_m2=pose_var))
        est.step(t, rs)
    return est, periods


def test_missing_imu_samples_never_merge_two_periods():
    # samples 1008..1013 missing: the dropout spans the period boundary at 1010 ms
    skip = set(range(1008, 1014))
    est, periods = static_filter(1.3, skip=skip)
    assert est.aligned
    dts = [dt for _, dt, _ in periods]
    # every period closes on its own accumulated time: never two periods' worth
    assert max(dts) <= 10_000 + 6_000 and all(dt >= 9_500 for dt in dts)
    # the sample after the gap carries the gap as its interval; the filter's time is kept
    assert sum(dts) == periods[-1][0] - periods[0][0] + periods[0][1]
    e = est.output()
    assert np.abs(e.vel_ned_m_s).max() < 1e-3 and np.abs(e.pos_ned_m).max() < 1e-3


def test_jittered_imu_stamps_are_integrated_with_their_own_intervals():
    """Each sample's time of validity up to 0.6 ms early (its interval to the last one's): the
    periods close on their summed intervals, and a vehicle at rest stays at rest."""
    est = Eskf(EstimatorParams.from_profile(load_sensing("mocap", 1000)))
    periods = []
    real = est._update

    def spy(t_end, dA, dV, dt_us, clip):
        periods.append(dt_us)
        real(t_end, dA, dV, dt_us, clip)
    est._update = spy
    last = 0
    for ms in range(1, 1300):
        t = ms * 1000
        t_imu = t - (ms * 300) % 900
        rs = [level_imu(t_imu, t_imu - last)]
        last = t_imu
        if ms % 10 == 0 and ms >= 20:
            rs.append(pose(t))
        est.step(t, rs)
    assert est.aligned and len(periods) > 90
    assert all(9_500 <= dt <= 11_000 for dt in periods)
    e = est.output()
    assert np.abs(e.vel_ned_m_s).max() < 1e-3 and np.abs(e.pos_ned_m).max() < 1e-3


def test_a_clipped_axis_inflates_its_noise_and_holds_its_bias():
    clip = set(range(500, 520))
    est, periods = static_filter(0.8, clip_at=clip)
    assert any(c[0] for _, _, c in periods) and not any(c[1] or c[2] for _, _, c in periods)
    k, v = d.DBA.start, d.DV.start
    # while it clips: the x axis's bias learning inhibited (its variance held, correlations
    # cut), the other axes' not; its velocity variance raised by EKF2's bad-accel noise
    during, _ = static_filter(0.515, clip_at=clip)
    clean, _ = static_filter(0.515)
    P = during.P
    assert during._ba_inhibit == [True, False, False]
    assert np.all(P[k, :k] == 0.0) and np.all(P[k, k + 1:] == 0.0)
    assert P[k + 1, v + 1] != 0.0
    assert P[k, k] == pytest.approx(clean.P[k, k], rel=0.05)
    assert P[v, v] > clean.P[v, v] + 0.5 * (0.01 * 4.9) ** 2      # a 10 ms period's worth
    assert P[v + 1, v + 1] == pytest.approx(clean.P[v + 1, v + 1], rel=0.05)
    # after: released, learnt again
    assert est._ba_inhibit == [False, False, False] and est.P[k, v] != 0.0


def test_the_poses_reported_variance_is_floored_by_the_parameter():
    """EKF2_EV_NOISE_MD 0: the larger of the reported variance and EKF2_EVP_NOISE^2."""
    told, _ = static_filter(0.5, pose_var=0.2 ** 2)
    floored, _ = static_filter(0.5, pose_var=1e-8)
    none, _ = static_filter(0.5)
    s_told = told.innovations[Aid.MOCAP_POS].variance
    s_floor = floored.innovations[Aid.MOCAP_POS].variance
    assert np.all(s_told > 0.2 ** 2)
    np.testing.assert_array_equal(s_floor, none.innovations[Aid.MOCAP_POS].variance)
    assert np.all(s_floor < 2 * 0.01 ** 2 + 1e-4)


def test_zero_velocity_update_on_the_ground():
    on_ground, _ = static_filter(1.0, at_rest=True)
    flying, _ = static_filter(1.0, at_rest=False)
    assert on_ground.zvu_fused >= 3 and flying.zvu_fused == 0
    assert on_ground.P[d.DV.start, d.DV.start] < flying.P[d.DV.start, d.DV.start]


# ------------------------------------------------------------------ consistency (slow)

def ekf2_world(tmp_path, **estimator):
    """A sensing profile whose sensors are what EKF2's defaults describe: IMU white noise of
    EKF2_GYR_NOISE / EKF2_ACC_NOISE per 10 ms period (density = noise sqrt(0.01 s)), bias walks
    of EKF2_*_B_NOISE likewise, turn-on biases of EKF2_*BIAS_INIT, no vibration, motion
    capture noise at EKF2_EVP_NOISE / EKF2_EVA_NOISE with the latency EKF2_EV_DELAY says, the
    barometer at EKF2_BARO_NOISE without drift; and the filter tuned with the mocap profile's
    EKF2 settings, changed by `estimator`."""
    root = math.sqrt(0.01)
    body = {"extends": "builtin:sensing/mocap", "description": "EKF2's world",
            "imu": {"gyro_noise_density_rad_s_rthz": 0.015 * root,
                    "accel_noise_density_m_s2_rthz": 0.35 * root,
                    "gyro_bias_random_walk_rad_s2_rthz": 0.001 * root,
                    "accel_bias_random_walk_m_s3_rthz": 0.003 * root,
                    "gyro_turn_on_bias_rad_s": 0.1, "accel_turn_on_bias_m_s2": 0.2,
                    "vibration": None},          # EKF2's world: white noise only
            "mocap": {"position_noise_m": 0.01, "attitude_noise_rad": 0.05,
                      "dropout_probability": 0.0},
            "baro": {"noise_m": 3.5, "drift_sigma_m": 0.0},
            "estimator": {"EKF2_EV_CTRL": 11, "EKF2_HGT_REF": 3, "EKF2_EV_DELAY": 10.0,
                          "EKF2_EVP_NOISE": 0.01, "EKF2_EVA_NOISE": 0.05, **estimator}}
    return load_sensing(write_profile(tmp_path, "ekf2world", body), 1000)


SETTLE_US = 6_000_000
FLIGHT_S = 14.0


def nees(prof, seed: int, **overrides):
    """Time-averaged NEES per degree of freedom of position, velocity, attitude, gyro and
    accel biases, at the filter's delayed time, after SETTLE_US."""
    suite = SensorSuite(prof, np.random.default_rng(seed), home_alt_m=30.0)
    est = Eskf(EstimatorParams.from_profile(prof, **overrides))
    sums = np.zeros(5)
    n = 0
    for k in range(int(FLIGHT_S * 1000)):
        t = k * 1000
        est.step(t, suite.sample(t, truth_at(t)))
        if t % 20_000 or t < SETTLE_US:
            continue
        t_d, x, P = est.filter_state()
        tr = truth_at(t_d)
        bias = suite.states["imu"]           # the bias now: it walks slowly past t_d
        errs = (x[d.P_] - tr.pos_ned_m, x[d.V_] - tr.vel_ned_m_s,
                att_error(x[d.Q_], tr.quat_wxyz), x[d.BG] - bias.gyro_bias_frd_rad_s,
                x[d.BA] - bias.accel_bias_frd_m_s2)
        for i, (e, sl) in enumerate(zip(errs, (d.DP, d.DV, d.DTH, d.DBG, d.DBA))):
            sums[i] += e @ np.linalg.solve(P[sl, sl], e) / 3
        n += 1
    return sums / n


# two-sided bounds on the time-averaged NEES per degree of freedom, over two flights: the errors
# are correlated in time, so a flight holds a few independent stretches of position, velocity
# and attitude error (bounds [0.25, 4]: a standard deviation off by a factor of 2 in either
# direction lies outside), and a single draw of each bias (its turn-on value, walking slowly):
# two flights give chi-square(6) of the biases, whose 0.5 % and 99.5 % points per degree of
# freedom are 0.11 and 3.1
NEES_LO = np.array((0.25, 0.25, 0.25, 0.11, 0.11))
NEES_HI = np.array((4.0, 4.0, 4.0, 3.1, 3.1))


@pytest.mark.slow
def test_ekf2_defaults_are_consistent_on_sensors_they_describe(tmp_path):
    prof = ekf2_world(tmp_path)
    got = (nees(prof, 3) + nees(prof, 4)) / 2
    assert np.all(got > NEES_LO) and np.all(got < NEES_HI), got


@pytest.mark.slow
@pytest.mark.parametrize("estimator, which, side", [
    ({"EKF2_EVP_NOISE": 0.2}, 0, "low"),          # the pose trusted 20x too little
    ({"EKF2_ACC_NOISE": 0.01}, 1, "high"),         # the accelerometer trusted 35x too much
])
def test_a_mistuned_filter_fails_the_two_sided_test(tmp_path, estimator, which, side):
    got = nees(ekf2_world(tmp_path, **estimator), 3)
    assert (got[which] < NEES_LO[which]) if side == "low" else (got[which] > NEES_HI[which]), got


@pytest.mark.slow
def test_a_mis_set_vision_delay_costs_accuracy(tmp_path):
    """EKF2_EV_DELAY 10 ms (the system's latency) against 0 (PX4's default) and 40 ms: the
    pose taken at the wrong time shows as a position error along the circle's velocity."""
    errs = {}
    for delay in (0.0, 10.0, 40.0):
        prof = ekf2_world(tmp_path, EKF2_EV_DELAY=delay, EKF2_EVP_NOISE=0.01)
        prof = replace(prof, mocap=replace(prof.mocap, position_noise_m=0.0005))
        suite = SensorSuite(prof, np.random.default_rng(5), home_alt_m=30.0)
        est = Eskf(EstimatorParams.from_profile(prof))
        e = []
        for k in range(int(10.0 * 1000)):
            t = k * 1000
            est.step(t, suite.sample(t, truth_at(t)))
            if t % 10_000 == 0 and t >= SETTLE_US:
                e.append(np.linalg.norm(est.output().pos_ned_m - truth_at(t).pos_ned_m))
        errs[delay] = float(np.sqrt(np.mean(np.square(e))))
    assert errs[0.0] > 1.5 * errs[10.0] and errs[40.0] > 1.5 * errs[10.0], errs
