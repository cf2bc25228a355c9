"""The wire as PX4 sends it (sil_vehicle.sitl.Sitl, PROTOCOL.md's "Where this vehicle and PX4
differ"): HIGHRES_IMU the bias-corrected mean since the link's last one (no interval lost at
any rate), GPS_RAW_INT stamped at its arrival with NO_GPS once the receiver is silent,
ODOMETRY's reset_counter, SYS_STATUS's sensor bits following the sensors and the estimator, and
LOCAL_POSITION_NED / GLOBAL_POSITION_INT while the estimate is invalid."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import sensing_profile
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mocap import MocapReading
from sil_vehicle.sitl import SENSOR_TIMEOUT_US, Sitl

_CLIENT = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
GPS_BIT = mavlink.MAV_SYS_STATUS_SENSOR_GPS
XY_BIT = mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL


def command(cmd, *p):
    p = tuple(p) + (0.0,) * (7 - len(p))
    msg = mavlink.MAVLink_command_long_message(1, 1, cmd, 0, *p)
    (back,) = Codec().decode(bytes(msg.pack(_CLIENT)))
    return back


def vehicle(sim, profile: str) -> Sitl:
    s = Sitl(sim.with_changes(sensing=sensing_profile(profile, 1000, "test"),
                              clock_mode="realtime", mocap_wiring="autopilot"))
    for _ in range(8000):
        if s.estimator_ready():
            return s
        s.step()
    raise AssertionError("the estimator never became ready")


def mavsdk_global_position_ok(m) -> bool:
    """MAVSDK's telemetry health (TelemetryImpl::process_sys_status): the GPS bit present and
    healthy."""
    return bool(m.onboard_control_sensors_present & GPS_BIT
                and m.onboard_control_sensors_health & GPS_BIT)


def test_highres_imu_at_125_hz_loses_no_200_hz_interval(sim):
    """The shipped 125 Hz request against the IMU's 200 Hz intervals: each message carries the
    mean since the one before, so the messages' sums (mean x samples, the biases added back)
    are every sample's sum; the biases subtracted are the estimator's, and not zero."""
    s = vehicle(sim, "mocap")
    s.handle("offboard", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                 mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 8000))
    period_us = s.suite.profile.imu.period_us
    samples, sent = {}, []
    for _ in range(400):
        out = s.step()
        samples.update({r.t_us: r for r in s.readings if isinstance(r, ImuReading)})
        e = s.estimate()
        sent += [(o.msg, e.gyro_bias_frd_rad_s.copy(), e.accel_bias_frd_m_s2.copy())
                 for o in out if o.link == "offboard" and o.msg.get_type() == "HIGHRES_IMU"]
    assert len(sent) >= 49                       # 125 Hz over 0.4 s (the first: none yet)
    gaps = {b[0].time_usec - a[0].time_usec for a, b in zip(sent, sent[1:])}
    assert gaps == {5000, 10_000}                # 3 of every 8 messages carry two intervals
    for (prev, _, _), (m, bg, ba) in zip(sent, sent[1:]):
        window = [samples[t] for t in range(prev.time_usec + period_us, m.time_usec + 1,
                                            period_us)]
        np.testing.assert_allclose(np.array([m.xgyro, m.ygyro, m.zgyro]) + bg,
                                   np.mean([w.gyro for w in window], axis=0), atol=1e-9)
        np.testing.assert_allclose(np.array([m.xacc, m.yacc, m.zacc]) + ba,
                                   np.mean([w.accel for w in window], axis=0), atol=1e-9)
        assert m.fields_updated & 0b111111 == 0b111111
    assert np.linalg.norm(sent[-1][1]) > 0 and np.linalg.norm(sent[-1][2]) > 0


def gnss_off(sim, ticks: int):
    """An rtk vehicle, ready; `sensor gnss off`; (time since the fault, message) of what the
    ground station's link got over `ticks` ticks after it, and the vehicle."""
    s = vehicle(sim, "rtk")
    status = [o.msg for _ in range(1000) for o in s.step()
              if o.link == "gcs" and o.msg.get_type() == "SYS_STATUS"]
    assert status and mavsdk_global_position_ok(status[-1])
    assert status[-1].onboard_control_sensors_health & XY_BIT
    s.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SENSOR_GPS,
                            mavlink.FAILURE_TYPE_OFF, 1))
    t_off = s.t_us
    seen = [(s.t_us - t_off, o.msg) for _ in range(ticks) for o in s.step() if o.link == "gcs"]
    return s, seen


def of(seen, name):
    return [(t, m) for t, m in seen if m.get_type() == name]


def test_gnss_off_clears_the_global_position_health_within_the_timeouts(sim):
    """`trq-inject-fault sensor gnss off` on a GNSS vehicle: a ground station reading
    SYS_STATUS at 1 Hz sees the GPS bit unhealthy (MAVSDK: no global position) within the
    sensor timeout and one SYS_STATUS period, the GPS still present; GPS_RAW_INT turns to
    NO_GPS. Back on: healthy again."""
    s, seen = gnss_off(sim, 2500)
    sys_status = of(seen, "SYS_STATUS")
    first_bad = next(t for t, m in sys_status if not mavsdk_global_position_ok(m))
    assert first_bad <= SENSOR_TIMEOUT_US + 1_000_000
    assert all(not mavsdk_global_position_ok(m) for t, m in sys_status if t >= first_bad)
    assert all(m.onboard_control_sensors_present & GPS_BIT for _, m in sys_status)
    no_gps = [t for t, m in of(seen, "GPS_RAW_INT") if m.fix_type == mavlink.GPS_FIX_TYPE_NO_GPS]
    assert no_gps and no_gps[0] <= 2_000_000
    s.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SENSOR_GPS,
                            mavlink.FAILURE_TYPE_OK, 1))
    status = [o.msg for _ in range(1500) for o in s.step()     # a fix, then a SYS_STATUS
              if o.link == "gcs" and o.msg.get_type() == "SYS_STATUS"]
    assert mavsdk_global_position_ok(status[-1])


@pytest.mark.slow
def test_gnss_off_the_position_goes_after_the_no_aid_timeout(sim):
    """The estimator's position (XY_POSITION_CONTROL) goes after its no-aid timeout, and with
    it LOCAL_POSITION_NED, while GLOBAL_POSITION_INT keeps coming (PX4's streams); NO_GPS every
    second."""
    _, seen = gnss_off(sim, 8000)
    xy_lost = next(t for t, m in of(seen, "SYS_STATUS")
                   if not m.onboard_control_sensors_health & XY_BIT)
    assert 4_000_000 <= xy_lost <= 7_000_000      # the no-aid timeout (5 s), a 1 Hz stream
    local = [t for t, _ in of(seen, "LOCAL_POSITION_NED")]
    assert local and max(local) < xy_lost
    assert max(t for t, _ in of(seen, "GLOBAL_POSITION_INT")) > xy_lost + 500_000
    no_gps = [t for t, m in of(seen, "GPS_RAW_INT") if m.fix_type == mavlink.GPS_FIX_TYPE_NO_GPS]
    assert len(no_gps) >= 6


def test_imu_off_clears_gyro_accel_and_attitude_health(sim):
    s = vehicle(sim, "mocap")
    bits = s.sensor_bits()
    imu_bits = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    vision = mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION
    assert bits.health & imu_bits == imu_bits and bits.health & vision
    assert bits.present & mavlink.MAV_SYS_STATUS_AHRS and not bits.present & GPS_BIT
    s.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SENSOR_GYRO,
                            mavlink.FAILURE_TYPE_OFF, 1))
    for _ in range(200):
        s.step()
    bits = s.sensor_bits()
    assert not bits.health & imu_bits and bits.present & imu_bits


def test_odometry_reset_counter_counts_the_estimators_position_resets(sim):
    """Under GNSS the first fix places the filter (EKF2 counts that reset: NE and D position,
    NE and D velocity); ODOMETRY carries the estimator's count, steady while nothing resets."""
    s = vehicle(sim, "rtk")
    counts = set()
    for _ in range(500):
        counts |= {o.msg.reset_counter for o in s.step() if o.msg.get_type() == "ODOMETRY"}
    assert counts == {s.estimator.state_resets} and s.estimator.state_resets > 0


def test_truth_keeps_its_sensor_bits_and_sends_the_position_streams(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    kinds = [o.msg for _ in range(1000) for o in s.step() if o.link == "gcs"]
    (status,) = [m for m in kinds if m.get_type() == "SYS_STATUS"]
    assert mavsdk_global_position_ok(status)
    assert any(m.get_type() == "LOCAL_POSITION_NED" for m in kinds)


def test_mocap_wired_to_the_companion_reaches_the_estimator_only_forwarded(sim):
    """`mocap_wiring: companion`: the vehicle sends no ATT_POS_MOCAP of its own; the mocap PC's
    poses leave from its own system (trq_wire.mocap); the estimator gets no pose until the
    companion forwards them (ODOMETRY, external vision), then takes each as arriving when it
    came (here at the end of each 10 ms control period, as a lockstep companion answers)."""
    from sil_vehicle.sitl import MOCAP_SOURCE
    from trq_offboard.link.wire import vision_odometry

    s = Sitl(sim.with_changes(sensing=sensing_profile("mocap", 1000, "test"),
                              clock_mode="realtime", mocap_wiring="companion"))
    assert s.mocap_to_companion
    poses = []
    for _ in range(3000):
        out = s.step()
        assert not [o for o in out if o.msg.get_type() == "ATT_POS_MOCAP" and o.source is None]
        poses += [o.msg for o in out if o.source == MOCAP_SOURCE]
    assert len(poses) > 250 and not s.estimate().position_valid       # nothing forwarded
    ages, poses = [], []
    for _ in range(3000):
        out = s.step()
        poses += [o.msg for o in out if o.source == MOCAP_SOURCE]
        if s.tick % 10 == 0:                 # the companion's turn: it forwards what it got
            for m in poses:
                s.handle("offboard", Codec().decode(Codec().encode(vision_odometry(m)))[0])
                ages.append(s.t_us - m.time_usec)
            poses = []
    assert s.estimator_ready()
    assert min(ages) >= 10_000 and max(ages) <= 20_000       # the mocap's 10 ms and the wait


def test_the_daemon_sends_the_mocap_pcs_poses_from_its_own_system(sim):
    """Over UDP the vehicle daemon encodes the simulated mocap PC's poses with the mocap's
    system and component ids (its own sequence), to the offboard link's peer."""
    from sil_vehicle.daemon import VehicleDaemon
    from sil_vehicle.sitl import MOCAP_SOURCE, Outgoing
    from sil_vehicle.mavlink import codec

    class Transport:
        def __init__(self):
            self.sent = []

        def sendto(self, data, dest):
            self.sent.append(data)

    d = VehicleDaemon(sim.with_changes(sensing=sensing_profile("mocap", 1000, "test"),
                                       clock_mode="realtime", mocap_wiring="companion"), None)
    d.transports["offboard"] = t = Transport()
    pose = MocapReading(10_000, 20_000, np.zeros(3), np.array((1.0, 0.0, 0.0, 0.0)))
    d.send([Outgoing("offboard", codec.att_pos_mocap(pose), source=MOCAP_SOURCE),
            Outgoing("offboard", codec.heartbeat(False, False, False))])
    msgs = [m for data in t.sent for m in Codec().decode(data)]
    assert [(m.get_type(), m.get_srcSystem(), m.get_srcComponent()) for m in msgs] == [
        ("ATT_POS_MOCAP", *MOCAP_SOURCE), ("HEARTBEAT", 1, 1)]
