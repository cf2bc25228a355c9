"""The sensing profile's sensors in the vehicle's tick (sil_vehicle.sitl.Sitl): no suite under
truth; under a profile, one sample per physics tick from its own generator (`Sitl._sense`, the
estimator's seam), the raw sensors on the wire (HIGHRES_IMU at its rate, GPS_RAW_INT and
ATT_POS_MOCAP at each arrival) and the position source in the flight log."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import sensing_profile
from sil_vehicle.dynamics.rigid_body import derivative
from sil_vehicle.dynamics.rotors import body_wrench
from sil_vehicle.frames import geodetic_to_ned, quat_to_dcm
from sil_vehicle.mavlink import codec
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mocap import MocapReading
from sil_vehicle.sensors.truth import imu_truth
from sil_vehicle.sitl import ESTIMATE_LOG_COLUMNS, LOG_COLUMNS, Sitl
from sil_vehicle.vehicle import ActuatorCommand

_CLIENT = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)


def command(cmd, p1=0.0, p2=0.0):
    """A COMMAND_LONG as the vehicle receives it (packed by a client, decoded by the codec)."""
    msg = mavlink.MAVLink_command_long_message(1, 1, cmd, 0, p1, p2, 0, 0, 0, 0, 0)
    (back,) = Codec().decode(bytes(msg.pack(_CLIENT)))
    return back


def sitl(sim, profile, **changes) -> Sitl:
    p = profile if not isinstance(profile, str) else sensing_profile(profile, 1000, "test")
    # the motion capture wired to the autopilot: these tests have no companion to forward it
    changes.setdefault("mocap_wiring", "autopilot")
    return Sitl(sim.with_changes(sensing=p, clock_mode="realtime", **changes))


@pytest.fixture(scope="module")
def exact(tmp_path_factory):
    """The mocap profile without noise, bias, vibration or dropouts: readings are the truth."""
    path = tmp_path_factory.mktemp("sensing") / "exact.yaml"
    path.write_text(yaml.safe_dump({
        "extends": "builtin:sensing/mocap", "name": "exact",
        "imu": {k: 0.0 for k in ("gyro_noise_density_rad_s_rthz",
                                 "gyro_bias_random_walk_rad_s2_rthz", "gyro_turn_on_bias_rad_s",
                                 "accel_noise_density_m_s2_rthz",
                                 "accel_bias_random_walk_m_s3_rthz", "accel_turn_on_bias_m_s2")}
        | {"vibration": None},
        "mocap": {"position_noise_m": 0.0, "attitude_noise_rad": 0.0,
                  "dropout_probability": 0.0}}))
    return sensing_profile(str(path), 1000, "test")


def run(s: Sitl, ticks: int) -> list[tuple[int, object]]:
    """(the tick's time, Outgoing) of everything sent over `ticks` ticks."""
    out = []
    for _ in range(ticks):
        out += [(s.t_us, o) for o in s.step()]
    return out


def of(sent, kind, link="gcs"):
    return [(t, o.msg) for t, o in sent if o.msg.get_type() == kind and o.link == link]


def until_ready(*sitls: Sitl) -> None:
    """Step them together, at rest, until each one's estimator allows arming."""
    for _ in range(5000):
        if all(s.estimator_ready() for s in sitls):
            return
        for s in sitls:
            s.step()
    raise AssertionError("the estimator never became ready")


def fly(s: Sitl, throttle_pct=80.0, tilt_rad=0.2) -> None:
    until_ready(s)
    s.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    assert s.vehicle.armed
    s.vehicle.command = ActuatorCommand((throttle_pct,) * 4, (tilt_rad, -tilt_rad, 0.1, 0.0))
    s._last_target_us = 10**12          # no failsafe: the test commands the vehicle itself


# --- truth: nothing of it -------------------------------------------------------------------

def test_truth_builds_no_suite_and_sends_no_raw_sensor(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    assert sim.sensing.name == "truth" and s.suite is None and s.readings == []
    sent = run(s, 1000)
    kinds = {o.msg.get_type() for _, o in sent}
    assert not kinds & {"HIGHRES_IMU", "ATT_POS_MOCAP"}
    gps = of(sent, "GPS_RAW_INT")
    assert len(gps) == 5 and gps[0][1].fix_type == mavlink.GPS_FIX_TYPE_3D_FIX    # as today
    assert s.log_columns == list(LOG_COLUMNS) and len(s.log_row()) == len(LOG_COLUMNS)
    replies = s.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                      mavlink.MAVLINK_MSG_ID_HIGHRES_IMU))
    assert replies[0].msg.result == mavlink.MAV_RESULT_UNSUPPORTED and len(replies) == 1


def test_sensors_leave_the_flight_and_the_other_generators_alone(sim):
    """The suite has its own generator: the plant (gusts on) is the same with and without
    sensors; with them, what the vehicle reports is its estimator's estimate (with its
    covariances), without them the state stream of truth plus noise."""
    windy = dict(gusts_enabled=True, wind_speed_m_s=5.0, seed=7)
    a, b = Sitl(sim.with_changes(clock_mode="realtime", **windy)), sitl(sim, "rtk", **windy)
    until_ready(a, b)
    for s in (a, b):
        fly(s)
    for _ in range(300):
        a.step(), b.step()
        assert a.state == b.state
    assert a.measured().pose_covariance is None
    assert repr(b.measured()) == repr(codec.measured_of(b.estimator.output()))   # NaNs alike
    assert b.measured().pose_covariance is not None


# --- the tick's readings ------------------------------------------------------------------

def test_one_sample_per_tick_at_the_sensors_rates(sim):
    s = sitl(sim, "mocap")
    assert s.suite is not None and s.suite.sensors == ("imu", "baro", "mag", "mocap")
    assert [type(r) for r in s.readings][0] is ImuReading and s.readings[0].t_us == 0
    counts: dict[type, int] = {}
    for _ in range(1000):
        s.step()
        for r in s.readings:
            counts[type(r)] = counts.get(type(r), 0) + 1
            assert r.arrival_us == s.t_us
    assert counts[ImuReading] == 1000
    assert 90 <= counts[MocapReading] <= 100        # 100 Hz less the dropouts
    assert s.latest["imu"].t_us == s.t_us


def test_the_accelerometer_reads_minus_g_at_rest_before_arming(sim, exact):
    s = sitl(sim, exact)
    g = sim.vehicle.gravity_m_s2
    for _ in range(50):
        s.step()
        r = s.latest["imu"]
        assert np.allclose(r.accel_frd_m_s2, (0.0, 0.0, -g), atol=1e-12)
        assert np.allclose(r.gyro_frd_rad_s, 0.0, atol=1e-12)


def test_the_specific_force_is_the_acceleration_less_gravity_in_flight(sim, exact):
    """Against the rigid-body derivative: the mean of its values at both ends of the tick (the
    wrench is held over a tick), within the trapezoid's error."""
    s = sitl(sim, exact)
    vp, rb = sim.vehicle, sim.vehicle
    fly(s)
    worst = 0.0
    for k in range(800):
        before = s.state
        s.step()
        after = s.state
        if before.on_ground or after.on_ground:     # the gear's contact: stiff, not a trapezoid
            continue
        w = body_wrench(after.motor_pct, after.tilt_rad, vp)
        args = (w, after.wind_ned_m_s, rb.mass_kg, rb.inertia_kg_m2, rb.gravity_m_s2,
                rb.drag_N_s2_m2)
        a = 0.5 * (np.array(derivative(before.x, *args)[3:6])
                   + np.array(derivative(after.x, *args)[3:6]))
        # rotated at the tick's middle attitude (sensors.truth.imu_truth): the slerp midpoint,
        # which for two unit quaternions in one hemisphere is their normalised sum
        mid = np.array(before.x[6:10]) + after.x[6:10]
        r = np.array(quat_to_dcm(*(mid / np.linalg.norm(mid))))
        expected = r.T @ (a - (0.0, 0.0, vp.gravity_m_s2))
        got = s.latest["imu"].accel_frd_m_s2
        worst = max(worst, float(np.max(np.abs(got - expected))))
        # the gyro: the attitude's change over the tick, near the rates' trapezoid mean
        assert np.allclose(s.latest["imu"].gyro_frd_rad_s,
                           imu_truth(before.x[6:10], after.x[6:10], before.x[3:6],
                                     after.x[3:6], 1e-3, vp.gravity_m_s2)[0], atol=1e-12)
        assert np.allclose(s.latest["imu"].gyro_frd_rad_s,
                           0.5 * (np.array(before.x[10:13]) + after.x[10:13]), atol=2e-3)
    assert s.state.pos_ned_m[2] < -0.05 and not s.state.landed         # it flew
    assert worst < 1e-3


def test_same_seed_same_readings_other_seed_others(sim):
    def readings(seed):
        s = sitl(sim, "rtk", seed=seed)
        fly(s)
        out = []
        for _ in range(400):
            s.step()
            out += [np.concatenate([np.atleast_1d(np.asarray(v, float)) for v in vars(r).values()])
                    for r in s.readings]
        return out
    a, b, c = readings(4), readings(4), readings(5)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


# --- on the wire ----------------------------------------------------------------------------

def test_highres_imu_at_its_rate_with_what_each_message_updates(sim):
    links = tuple(l if l.name != "gcs" else type(l)(**{**vars(l), "rates_hz": tuple(
        (st, 200 if st == "HIGHRES_IMU" else hz) for st, hz in l.rates_hz)})
        for l in sim.links)
    s = sitl(sim, "mocap", links=links)
    sent = of(run(s, 1000), "HIGHRES_IMU")
    assert len(sent) == 200 and all(t % 5000 == 0 for t, _ in sent)
    assert not of(run(s, 0), "HIGHRES_IMU", "offboard")
    for i, (t, m) in enumerate(sent):
        assert m.time_usec == t
        assert m.fields_updated & codec.IMU_FIELDS == codec.IMU_FIELDS         # 1 kHz IMU
        # the first message: the samples of t = 0 are new too
        baro_new = t % 20_000 == 0 or i == 0                                 # 50 Hz
        mag_new = t % 10_000 == 0 or i == 0                                  # 100 Hz
        assert bool(m.fields_updated & codec.BARO_FIELDS) == baro_new
        assert bool(m.fields_updated & codec.MAG_FIELDS) == mag_new
        assert not m.fields_updated & mavlink.HIGHRES_IMU_UPDATED_DIFF_PRESSURE
        assert 900.0 < m.abs_pressure < 1100.0                               # hPa
        assert abs(m.pressure_alt - sim.home_alt_m) < 5.0
    # the offboard link is off by default; a rate set by the command turns it on
    s.handle("offboard", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                 mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 10_000))
    assert len(of(run(s, 100), "HIGHRES_IMU", "offboard")) == 10



def test_highres_imu_carries_the_mean_of_its_integration_interval(sim):
    """As PX4's sensor_combined: the accelerometer and gyro of HIGHRES_IMU are the mean of the
    IMU's samples over the last interval of imu.integration_rate_hz (200 Hz: five 1 kHz
    samples), not the latest sample; the vibration noise of one sample averages down."""
    links = tuple(l if l.name != "gcs" else type(l)(**{**vars(l), "rates_hz": tuple(
        (st, 200 if st == "HIGHRES_IMU" else hz) for st, hz in l.rates_hz)})
        for l in sim.links)
    s = sitl(sim, "mocap", links=links)
    fly(s)
    samples: dict[int, ImuReading] = {}
    sent = []
    for _ in range(200):
        out = s.step()
        samples.update({r.t_us: r for r in s.readings if isinstance(r, ImuReading)})
        e = s.estimate()          # the biases the message was corrected with
        sent += [(o.msg, e.gyro_bias_frd_rad_s, e.accel_bias_frd_m_s2) for o in out
                 if o.link == "gcs" and o.msg.get_type() == "HIGHRES_IMU"]
    assert len(sent) >= 35
    period = 1_000_000 // s.suite.profile.imu.rate_hz
    for m, bg, ba in sent[1:]:
        window = [samples[m.time_usec - k * period] for k in range(5)]
        acc = np.mean([w.accel for w in window], axis=0) - ba
        gyro = np.mean([w.gyro for w in window], axis=0) - bg
        np.testing.assert_allclose([m.xacc, m.yacc, m.zacc], acc, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose([m.xgyro, m.ygyro, m.zgyro], gyro, rtol=1e-6, atol=1e-7)
        latest = samples[m.time_usec].accel
        assert not np.allclose([m.xacc, m.yacc, m.zacc], latest, atol=1e-4)     # not one sample

def test_att_pos_mocap_at_the_mocaps_rate_and_latency(sim, exact):
    s = sitl(sim, exact)
    fly(s)
    sent = of(run(s, 1000), "ATT_POS_MOCAP")
    latency = exact.mocap.latency_ticks * sim.dt_us
    assert len(sent) == 100
    assert all(t == m.time_usec + latency and m.time_usec % 10_000 == 0 for t, m in sent)
    assert not of(run(s, 0), "ATT_POS_MOCAP", "offboard")
    t, m = sent[-1]
    r = s.latest["mocap"]
    assert (m.time_usec, m.x, m.y, m.z) == (r.t_us, *r.pos_ned_m)
    assert m.q == pytest.approx(list(r.quat_wxyz), abs=1e-7)
    assert math.isnan(m.covariance[0])


def test_att_pos_mocap_at_most_at_the_links_rate(sim, exact):
    s = sitl(sim, exact)
    s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_ATT_POS_MOCAP, 40_000))
    sent = of(run(s, 1000), "ATT_POS_MOCAP")
    assert len(sent) == 25 and all(b - a == 40_000 for (a, _), (b, _) in zip(sent, sent[1:]))


def test_gps_raw_int_of_the_rtk_receiver_at_its_arrival(sim):
    s = sitl(sim, "rtk")
    fly(s)
    gnss = s.suite.params["gnss"]
    home = (sim.home_lat_deg, sim.home_lon_deg, sim.home_alt_m)
    arrived, sent = [], []
    t0 = s.t_us
    for _ in range(1500):
        out = s.step()
        arrived += [r for r in s.readings if isinstance(r, GnssReading)]
        sent += [(s.t_us, o.msg, arrived[-1]) for o in out
                 if o.link == "gcs" and o.msg.get_type() == "GPS_RAW_INT"]
    # 10 Hz, each 110 ms after its time of validity (the ticks after fly()'s wait for the
    # estimator); the ground station's 5 Hz at most: every other one
    expected = [t for t in range(t0 + 1000, t0 + 1_500_001, 1000)
                if t >= gnss.delay_us and (t - gnss.delay_us) % gnss.period_us == 0]
    assert [r.arrival_us for r in arrived] == expected and len(expected) >= 14
    assert len(sent) == (len(expected) + 1) // 2
    for t, m, r in sent:
        # stamped as PX4 stamps it: the arrival (the time of validity is the delay earlier)
        assert t == r.arrival_us == m.time_usec == r.t_us + gnss.delay_us
        assert m.fix_type == mavlink.GPS_FIX_TYPE_RTK_FIXED == 6
        assert m.satellites_visible == gnss.satellites
        n, e, d = geodetic_to_ned(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, *home)
        # what degE7 can carry: half a step (1.1 cm of latitude) each way
        step_n = math.radians(1e-7) * 6_378_137.0
        assert abs(n - r.pos_ned_m[0]) <= step_n / 2 + 1e-9
        assert abs(e - r.pos_ned_m[1]) <= step_n / 2 + 1e-9
        assert abs(d - r.pos_ned_m[2]) <= 0.0005 + 1e-9
        assert m.h_acc == round(gnss.eph_m * 1000) and m.v_acc == round(gnss.epv_m * 1000)
        assert m.vel_acc == round(gnss.velocity_white_h_m_s * 1000)
    assert "GPS_RAW_INT" not in {o.msg.get_type() for o in s.telemetry_due(everything=True)}


def test_no_gps_raw_int_without_a_receiver(sim):
    sent = run(sitl(sim, "mocap"), 1000)
    assert not of(sent, "GPS_RAW_INT") and of(sent, "GLOBAL_POSITION_INT")


def test_a_request_for_a_raw_sensor_message(sim):
    s = sitl(sim, "mocap")
    replies = s.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                      mavlink.MAVLINK_MSG_ID_ATT_POS_MOCAP))
    assert replies[0].msg.result == mavlink.MAV_RESULT_UNSUPPORTED     # none arrived yet
    run(s, 20)
    replies = s.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                      mavlink.MAVLINK_MSG_ID_HIGHRES_IMU))
    assert replies[0].msg.result == mavlink.MAV_RESULT_ACCEPTED
    assert replies[1].msg.get_type() == "HIGHRES_IMU" and replies[1].msg.time_usec == s.t_us


# --- the flight log ---------------------------------------------------------------------------

def test_the_log_keeps_the_position_sources_latest_sample(sim, exact):
    rows = []
    s = Sitl(sim.with_changes(sensing=exact, clock_mode="realtime",
                              mocap_wiring="autopilot"), log_sink=rows.append)
    assert s.log_columns == list(LOG_COLUMNS) + ["mocap_t_us", "mocap_pos_n_m",
                                                 "mocap_pos_e_m", "mocap_pos_d_m"] \
        + list(ESTIMATE_LOG_COLUMNS)
    first = s.log_row()
    src = slice(len(LOG_COLUMNS), len(LOG_COLUMNS) + 4)
    assert len(first) == len(s.log_columns) and all(math.isnan(v) for v in first[src])
    fly(s)
    run(s, 500)
    assert all(len(r) == len(s.log_columns) for r in rows)
    t_us, *_ = rows[-1]
    latency = exact.mocap.latency_ticks * sim.dt_us
    assert rows[-1][src.start] == t_us - latency - (t_us - latency) % 10_000
    rtk = Sitl(sim.with_changes(sensing=sensing_profile("rtk", 1000, "t")))
    assert rtk.log_columns[src] == ["gnss_t_us", "gnss_pos_n_m", "gnss_pos_e_m", "gnss_pos_d_m"]


def test_the_specific_force_is_the_sensors_own_formula(sim, exact):
    """Sitl._sense's plain-float R^T (a - g), at the tick's middle attitude, against
    sensors.truth.specific_force_frd on the slerp midpoint (the normalised sum)."""
    from sil_vehicle.sensors.truth import specific_force_frd
    s = sitl(sim, exact)
    fly(s, tilt_rad=0.4)
    for _ in range(300):
        v0, q0 = np.array(s.state.x[3:6]), np.array(s.state.x[6:10])
        s.step()
        a = (np.array(s.state.x[3:6]) - v0) / (sim.dt_us * 1e-6)
        mid = q0 + s.state.x[6:10]
        expected = specific_force_frd(mid / np.linalg.norm(mid), a, sim.vehicle.gravity_m_s2)
        assert np.allclose(s.latest["imu"].accel_frd_m_s2, expected, rtol=0, atol=1e-9)


# --- the estimator: what the vehicle reports ---------------------------------------------------

def test_arming_waits_for_the_estimator(sim):
    """PX4's preflight check: before the estimator has its attitude and a position, arming is
    temporarily rejected (the companion retries) and a STATUSTEXT says why; then accepted."""
    s = sitl(sim, "mocap")
    assert not s.estimator_ready()
    out = s.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    acks = [o.msg for o in out if o.msg.get_type() == "COMMAND_ACK"]
    texts = [o.msg.text for o in out if o.msg.get_type() == "STATUSTEXT"]
    assert acks[0].result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED and not s.vehicle.armed
    assert any("estimator not ready" in t for t in texts)
    until_ready(s)
    out = s.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    acks = [o.msg for o in out if o.msg.get_type() == "COMMAND_ACK"]
    assert acks[0].result == mavlink.MAV_RESULT_ACCEPTED and s.vehicle.armed
    assert Sitl(sim.with_changes(clock_mode="realtime")).estimator_ready()    # truth: no check


def test_odometry_carries_the_estimate_and_its_covariances(sim):
    s = sitl(sim, "mocap")
    fly(s)
    sent = run(s, 400)
    odo = of(sent, "ODOMETRY", link="offboard")[-1][1]
    e = s.estimator.output()
    assert odo.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT and odo.quality == 100
    # the pose's variances on the diagonal of the upper triangle (x, y, z, roll, pitch, yaw)
    # (EKF2's tuning: the attitude's within its initial EKF2_ANGERR_INIT^2, the position's
    # within EKF2_EVP_NOISE^2 as the mocap profile sets it)
    diag = [odo.pose_covariance[i] for i in (0, 6, 11, 15, 18, 20)]
    assert all(0.0 < v < 1e-4 for v in diag[:3]) and all(0.0 < v < 1e-2 for v in diag[3:])
    assert all(0.0 < odo.velocity_covariance[i] for i in (0, 6, 11))
    # it is the estimate (near the truth: millimetres), not the truth itself
    pos = np.array([odo.x, odo.y, odo.z])
    truth = np.array(s.state.x[0:3])
    assert 0.0 < np.max(np.abs(pos - truth)) < 0.01
    assert np.allclose(pos, e.pos_ned_m, atol=0.05)
    # the ground station's ESTIMATOR_STATUS: aligned, position valid, its accuracies
    status = of(sent, "ESTIMATOR_STATUS")
    assert len(status) == 2                                    # 5 Hz over 0.4 s
    st = status[-1][1]
    assert st.flags & mavlink.ESTIMATOR_ATTITUDE and st.flags & mavlink.ESTIMATOR_POS_HORIZ_ABS
    assert 0.0 < st.pos_horiz_accuracy < 0.01 and 0.0 < st.pos_vert_accuracy < 0.01


def test_truth_reports_truth_plus_noise_and_no_estimator_status(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    sent = run(s, 400)
    assert s.estimator is None and not of(sent, "ESTIMATOR_STATUS")
    odo = of(sent, "ODOMETRY", link="offboard")[-1][1]
    assert odo.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_NAIVE
    assert all(math.isnan(v) for v in odo.pose_covariance)


def test_estimator_status_of_a_diverged_filter_does_not_raise(sim):
    """A diverging filter's variances may go negative: ESTIMATOR_STATUS says unknown (NaN)
    rather than failing the vehicle's tick (a campaign flight under gnss met it)."""
    import dataclasses
    s = sitl(sim, "mocap")
    run(s, 50)
    e = dataclasses.replace(s.estimator.output(), pos_var_ned_m2=np.array([-1e-3, 0.0, -2.0]),
                            diverged=True)
    st = codec.estimator_status(e)
    assert math.isnan(st.pos_vert_accuracy) and math.isnan(st.pos_horiz_accuracy)
    assert st.flags & mavlink.ESTIMATOR_ACCEL_ERROR
