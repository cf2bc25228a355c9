"""The simulated autopilot without sockets (sil_vehicle.sitl.Sitl): messages in through the codec,
ticks through Sitl.step, replies and telemetry out as Outgoing records."""

from __future__ import annotations

import dataclasses
import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sitl import FORCE_DISARM_MAGIC, Sitl

_CLIENT = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
LIMIT_DEG = 30.0
N_PARAMS = 5 + 4 * 5 + 4 * 2 + 1   # wind, motors, servos, COM_OF_LOSS_T


def wire(msg):
    """What the vehicle receives: the message packed by a client and decoded by the codec."""
    (back,) = Codec().decode(bytes(msg.pack(_CLIENT)))
    return back


def command(cmd, p1=0.0, p2=0.0, p3=0.0, p4=0.0, p5=0.0, p6=0.0, p7=0.0, target=1):
    return wire(mavlink.MAVLink_command_long_message(target, 1, cmd, 0, p1, p2, p3, p4, p5, p6, p7))


def param_set(name, value, target=1):
    return wire(mavlink.MAVLink_param_set_message(target, 1, name.encode(), value,
                                                  mavlink.MAV_PARAM_TYPE_REAL32))


def target(stamp_us, throttle=(0.0,) * 4, tilt=(0.0,) * 4):
    return wire(mavlink.MAVLink_set_actuator_control_target_message(
        stamp_us, 0, 1, 1, list(throttle) + list(tilt)))


def of(out, kind, link=None):
    return [o.msg for o in out if o.msg.get_type() == kind and (link is None or o.link == link)]


def ack(out):
    (a,) = of(out, "COMMAND_ACK")
    return a.result


def encodes(out):
    """Every reply packs (names fit, values in range)."""
    c = Codec()
    for o in out:
        c.encode(o.msg)


@pytest.fixture
def sitl(sim):
    s = Sitl(sim)
    s.telemetry_due()              # what the daemon does first: ODOMETRY at t = 0, the first stamp
    return s


def arm(s):
    out = s.handle("offboard", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    assert s.vehicle.armed


def fly_lockstep(s, ticks, throttle_pct=(0.0,) * 4, tilt=(0.0,) * 4):
    """Answer every lockstep stamp with the same target; return all telemetry produced."""
    out = []
    controls_t = [v / 100.0 for v in throttle_pct]
    for _ in range(ticks):
        if not s.answered:
            s.handle("offboard", target(s.lockstep_stamp_us, controls_t, tilt))
            assert s.answered
        out += s.step()
    return out


# --- parameters -----------------------------------------------------------------------------------

def test_param_request_list(sitl):
    out = sitl.handle("gcs", wire(mavlink.MAVLink_param_request_list_message(1, 1)), ("h", 1))
    values = of(out, "PARAM_VALUE")
    assert len(values) == len(out) == N_PARAMS == len(sitl.params)
    assert [v.param_index for v in values] == list(range(N_PARAMS))
    assert all(v.param_count == N_PARAMS for v in values)
    names = [v.param_id for v in values]
    assert len(set(names)) == N_PARAMS and all(len(n) <= 16 for n in names)
    assert {"SIM_WIND_SPD", "SIM_MOT1_EFF", "SIM_MOT4_OFF", "SIM_SRV4_ANG"} <= set(names)
    by_name = {v.param_id: v.param_value for v in values}
    assert by_name["SIM_MOT1_EFF"] == 1.0 and by_name["SIM_MOT1_OFF"] == 0.0
    assert all(o.to == ("h", 1) and o.link == "gcs" for o in out)          # back to the sender
    encodes(out)


def test_timesync_request_is_answered_with_the_simulated_clock(sitl):
    fly_lockstep(sitl, 37)                      # the clock is past zero
    now_ns = sitl.t_us * 1000
    out = sitl.handle("offboard", wire(mavlink.MAVLink_timesync_message(0, 123456789)), ("c", 2))
    (reply,) = of(out, "TIMESYNC")
    assert (reply.tc1, reply.ts1) == (now_ns, 123456789) and now_ns > 0
    assert [o.to for o in out] == [("c", 2)]
    encodes(out)
    # an answer (tc1 set) is not a request: no reply, so two autopilots never ping-pong
    assert of(sitl.handle("gcs", wire(mavlink.MAVLink_timesync_message(5, 6)), ("h", 1)),
              "TIMESYNC") == []


def test_param_request_read(sitl):
    out = sitl.handle("gcs", wire(mavlink.MAVLink_param_request_read_message(1, 1, b"SIM_GUST_LEN",
                                                                             -1)))
    (v,) = of(out, "PARAM_VALUE")
    assert v.param_id == "SIM_GUST_LEN" and v.param_value == 50.0
    out = sitl.handle("gcs", wire(mavlink.MAVLink_param_request_read_message(1, 1, b"", 5)))
    assert of(out, "PARAM_VALUE")[0].param_index == 5
    nope = wire(mavlink.MAVLink_param_request_read_message(1, 1, b"NOPE", -1))
    assert sitl.handle("gcs", nope) == []


def test_param_set_in_range_changes_the_vehicle(sitl):
    out = sitl.handle("gcs", param_set("SIM_WIND_SPD", 8.0))
    (pv,) = of(out, "PARAM_VALUE")
    assert pv.param_id == "SIM_WIND_SPD" and pv.param_value == 8.0 and pv.param_index == 0
    texts = of(out, "STATUSTEXT")
    assert len(texts) == 2 and texts[0].severity == mavlink.MAV_SEVERITY_INFO     # both links
    assert "SIM_WIND_SPD = 8" in texts[0].text
    assert sitl.vehicle.wind_speed_m_s == 8.0
    sitl.step()
    assert sitl.state.wind_ned_m_s == pytest.approx((-8.0, 0.0, 0.0))  # from the north
    sitl.handle("gcs", param_set("SIM_MOT2_EFF", 0.5))
    assert sitl.vehicle.faults.motors[1].effectiveness == 0.5
    sitl.handle("gcs", param_set("SIM_MOT3_OFF", 1.0))
    assert sitl.vehicle.faults.motors[2].off
    sitl.handle("gcs", param_set("SIM_SRV1_ANG", -12.5))
    assert sitl.vehicle.faults.servos[0].angle_rad == pytest.approx(math.radians(-12.5))
    encodes(out)


@pytest.mark.parametrize("name, value", [("SIM_WIND_SPD", 50.0), ("SIM_WIND_SPD", -1.0),
                                         ("SIM_WIND_SPD", math.nan), ("SIM_MOT1_EFF", 1.5),
                                         ("SIM_SRV2_ANG", 45.0), ("SIM_GUST_LEN", 0.0)])
def test_param_set_out_of_range_changes_nothing(sitl, name, value):
    before = [sitl.params.value(i) for i in range(len(sitl.params))]
    faults, wind = sitl.vehicle.faults, sitl.vehicle.wind_speed_m_s
    out = sitl.handle("gcs", param_set(name, value))
    (pv,) = of(out, "PARAM_VALUE")
    assert pv.param_id == name
    assert pv.param_value == before[sitl.params.index(name)]           # the value in force
    texts = of(out, "STATUSTEXT")
    assert texts and all(t.severity == mavlink.MAV_SEVERITY_ERROR for t in texts)
    assert [sitl.params.value(i) for i in range(len(sitl.params))] == before
    assert sitl.vehicle.faults == faults and sitl.vehicle.wind_speed_m_s == wind


def test_param_set_unknown_name(sitl):
    out = sitl.handle("gcs", param_set("SIM_BOGUS", 1.0))
    assert of(out, "PARAM_VALUE") == []
    assert "unknown" in of(out, "STATUSTEXT")[0].text


# --- commands -------------------------------------------------------------------------------------

def test_inject_motor_off_then_ok(sitl):
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE,
                                     mavlink.FAILURE_UNIT_SYSTEM_MOTOR,
                                     mavlink.FAILURE_TYPE_OFF, 1))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    assert "motor 1 off" in of(out, "STATUSTEXT")[0].text
    assert sitl.vehicle.faults.motors[0].off and not sitl.vehicle.faults.motors[1].off
    arm(sitl)
    out = fly_lockstep(sitl, 500, throttle_pct=(60.0,) * 4)       # on the ground: 4 x 3.27 N < mg
    raw = of(out, "SERVO_OUTPUT_RAW", "offboard")[-1]
    assert raw.servo1_raw == 1000
    assert raw.servo2_raw == raw.servo3_raw == raw.servo4_raw == 1600
    assert sitl.state.landed and not sitl.state.crashed
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE,
                                     mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OK, 1))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    out = fly_lockstep(sitl, 500, throttle_pct=(60.0,) * 4)
    assert of(out, "SERVO_OUTPUT_RAW", "offboard")[-1].servo1_raw == 1600


def test_inject_all_motors_off(sitl):
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE,
                                     mavlink.FAILURE_UNIT_SYSTEM_MOTOR,
                                     mavlink.FAILURE_TYPE_OFF, 0))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    assert all(m.off for m in sitl.vehicle.faults.motors)


def test_servo_stuck(sitl):
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE,
                                     mavlink.FAILURE_UNIT_SYSTEM_SERVO, mavlink.FAILURE_TYPE_STUCK,
                                     2, 10.0))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    assert "servo 2 stuck at 10.0 deg" in of(out, "STATUSTEXT")[0].text
    arm(sitl)
    out = fly_lockstep(sitl, 1000, throttle_pct=(20.0,) * 4, tilt=(1.0,) * 4)
    raw = of(out, "SERVO_OUTPUT_RAW", "offboard")[-1]
    assert raw.servo6_raw == 1500 + round(500 * 10.0 / LIMIT_DEG)          # servo 2 -> servo6
    assert raw.servo5_raw == raw.servo7_raw == raw.servo8_raw == 2000
    assert sitl.state.tilt_rad[1] == pytest.approx(math.radians(10.0))
    # stuck where it is (NaN angle): servo 1 stays at 30 deg even when commanded back to 0
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE,
                                     mavlink.FAILURE_UNIT_SYSTEM_SERVO, mavlink.FAILURE_TYPE_STUCK,
                                     1, math.nan))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    fly_lockstep(sitl, 500, throttle_pct=(20.0,) * 4, tilt=(0.0,) * 4)
    assert sitl.state.tilt_rad[0] == pytest.approx(math.radians(30.0), abs=1e-6)
    assert sitl.state.tilt_rad[2] == pytest.approx(0.0, abs=1e-3)
    # released
    sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SYSTEM_SERVO,
                               mavlink.FAILURE_TYPE_OK, 0))
    assert not any(s.stuck for s in sitl.vehicle.faults.servos)


@pytest.mark.parametrize("p1, p2, p3, p4, result", [
    (mavlink.FAILURE_UNIT_SYSTEM_SERVO, mavlink.FAILURE_TYPE_STUCK, 1, 45.0,
     mavlink.MAV_RESULT_DENIED),                                 # outside the tilt range
    (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, 5, 0.0,
     mavlink.MAV_RESULT_DENIED),                                 # no motor 5
    (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, 1.5, 0.0,
     mavlink.MAV_RESULT_DENIED),
    (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, math.nan, 0.0,
     mavlink.MAV_RESULT_DENIED),
    (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_STUCK, 1, 0.0,
     mavlink.MAV_RESULT_UNSUPPORTED),                            # motors do not stick
    (mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_OFF, 1, 0.0,
     mavlink.MAV_RESULT_DENIED),                                 # truth: no sensor to fail
    (mavlink.FAILURE_UNIT_SENSOR_OPTICAL_FLOW, mavlink.FAILURE_TYPE_OFF, 1, 0.0,
     mavlink.MAV_RESULT_UNSUPPORTED),                            # no such sensor here
])
def test_inject_refused(sitl, p1, p2, p3, p4, result):
    faults = sitl.vehicle.faults
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, p1, p2, p3, p4))
    assert ack(out) == result
    assert sitl.vehicle.faults == faults


def test_unknown_command_unsupported(sitl):
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_NAV_TAKEOFF), ("h", 5))
    assert ack(out) == mavlink.MAV_RESULT_UNSUPPORTED
    (o,) = out
    assert o.to == ("h", 5) and o.msg.target_system == 255 and o.msg.target_component == 190
    out = sitl.handle("gcs", wire(mavlink.MAVLink_command_int_message(
        1, 1, 0, mavlink.MAV_CMD_DO_REPOSITION, 0, 0, 0, 0, 0, 0, 0, 0, 0)))
    assert ack(out) == mavlink.MAV_RESULT_UNSUPPORTED


def test_request_message(sitl):
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                     mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED and len(of(out, "AUTOPILOT_VERSION")) == 1
    encodes(out)
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1.0))
    (ver,) = of(out, "AUTOPILOT_VERSION")
    assert ver.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                     mavlink.MAVLINK_MSG_ID_HOME_POSITION))
    (home,) = of(out, "HOME_POSITION")
    assert home.latitude == round(51.5246 * 1e7) and home.altitude == 30_000
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_REQUEST_MESSAGE,
                                     mavlink.MAVLINK_MSG_ID_SCALED_IMU))
    assert ack(out) == mavlink.MAV_RESULT_UNSUPPORTED
    encodes(out)


def count_stream(sitl, kind, link, ticks):
    n = 0
    for _ in range(ticks):
        n += len(of(sitl.step(), kind, link))
    return n


def test_set_message_interval(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))      # no lockstep stamps to answer
    assert count_stream(s, "ATTITUDE", "gcs", 1000) == 25
    out = s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                  mavlink.MAVLINK_MSG_ID_ATTITUDE, 10_000))     # 100 Hz
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED
    assert count_stream(s, "ATTITUDE", "gcs", 1000) == 100
    assert count_stream(s, "ATTITUDE", "offboard", 1000) == 50                  # per link
    s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_ATTITUDE, -1))               # off
    assert count_stream(s, "ATTITUDE", "gcs", 1000) == 0
    s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_ATTITUDE, 0))                # default
    assert count_stream(s, "ATTITUDE", "gcs", 1000) == 25
    s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                            mavlink.MAVLINK_MSG_ID_ODOMETRY, 100_000))          # off -> 10 Hz
    assert count_stream(s, "ODOMETRY", "gcs", 1000) == 10
    out = s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                  mavlink.MAVLINK_MSG_ID_SCALED_IMU, 10_000))
    assert ack(out) == mavlink.MAV_RESULT_UNSUPPORTED
    out = s.handle("gcs", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                  mavlink.MAVLINK_MSG_ID_ATTITUDE, -5))
    assert ack(out) == mavlink.MAV_RESULT_DENIED


def test_lockstep_odometry_interval_denied(sitl):
    out = sitl.handle("offboard", command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                                          mavlink.MAVLINK_MSG_ID_ODOMETRY, 10_000))
    assert ack(out) == mavlink.MAV_RESULT_DENIED
    assert sitl.lockstep_ticks() == sitl.sim.physics_rate_hz // sitl.sim.control_rate_hz


# --- arming and crash -------------------------------------------------------------------------

def drop(s, height_m):
    v = s.vehicle
    x = list(v.state.x)
    x[2] = -height_m
    v.state = dataclasses.replace(v.state, x=tuple(x), landed=False)


def test_crash_then_arm_refused(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    drop(s, 5.0)
    out = []
    for _ in range(2100):                   # impact at sqrt(2 h / g) = 1.01 s; heartbeat at 2 s
        out += s.step()
    assert s.state.crashed and "ground impact" in s.state.crash_reason
    crash = [t for t in of(out, "STATUSTEXT") if t.text.startswith("CRASH")]
    assert len(crash) == 2 and crash[0].severity == mavlink.MAV_SEVERITY_CRITICAL   # both links
    assert of(out, "HEARTBEAT")[-1].system_status == mavlink.MAV_STATE_EMERGENCY
    out = s.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    assert ack(out) == mavlink.MAV_RESULT_DENIED
    assert not s.vehicle.armed
    assert "crashed" in of(out, "STATUSTEXT")[0].text


def test_disarm_in_flight_needs_force(sitl):
    arm(sitl)
    drop(sitl, 50.0)
    sitl.step()
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0))
    assert ack(out) == mavlink.MAV_RESULT_DENIED and sitl.vehicle.armed
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, FORCE_DISARM_MAGIC))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED and not sitl.vehicle.armed


def test_other_system_is_ignored(sitl):
    assert sitl.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, target=2)) == []
    assert sitl.handle("gcs", param_set("SIM_WIND_SPD", 5.0, target=2)) == []
    assert sitl.counters["gcs"].other_system == 2
    assert not sitl.vehicle.armed and sitl.vehicle.wind_speed_m_s == 0.0
    # system 0 (broadcast) is for everyone
    out = sitl.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, target=0))
    assert ack(out) == mavlink.MAV_RESULT_ACCEPTED


# --- actuator targets and the lockstep ------------------------------------------------------

def test_lockstep_stamps(sitl):
    assert sitl.lockstep_stamp_us == 0 and not sitl.answered
    assert sitl.handle("offboard", target(0, [0.3] * 4)) == []
    assert sitl.answered and sitl.targets_applied == 1
    out = []
    for _ in range(sitl.lockstep_ticks()):
        out += sitl.step()
    (odo,) = of(out, "ODOMETRY", "offboard")
    period_us = 1_000_000 // sitl.sim.control_rate_hz
    assert odo.time_usec == period_us == sitl.lockstep_stamp_us and not sitl.answered


def test_lockstep_stale_target_not_applied(sitl):
    command_before = sitl.vehicle.command
    assert sitl.handle("offboard", target(12_345, [0.5] * 4)) == []
    assert sitl.counters["offboard"].stale_targets == 1
    assert sitl.vehicle.command == command_before and not sitl.answered
    assert sitl.targets_applied == 0
    sitl.handle("offboard", target(0, [0.5] * 4, [0.5, 0.0, 0.0, -1.0]))
    assert sitl.vehicle.command.throttle_pct == pytest.approx((50.0,) * 4)
    assert sitl.vehicle.command.tilt_rad == pytest.approx(
        (math.radians(15.0), 0.0, 0.0, -math.radians(30.0)), rel=1e-6)
    assert sitl.answered and sitl.counters["offboard"].stale_targets == 1


def test_realtime_applies_any_stamp(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    s.telemetry_due()
    s.handle("offboard", target(12_345, [0.5] * 4))
    assert s.vehicle.command.throttle_pct == pytest.approx((50.0,) * 4)
    assert s.counters["offboard"].stale_targets == 0


def test_rejected_target_counted_and_announced_once_a_second(sitl):
    out = sitl.handle("offboard", target(0, [math.nan, 0.5, 0.5, 0.5]))
    assert sitl.counters["offboard"].rejected_targets == 1 and not sitl.answered
    assert of(out, "STATUSTEXT")[0].severity == mavlink.MAV_SEVERITY_WARNING
    assert sitl.handle("offboard", target(0, [2.0] * 4)) == []              # not again so soon
    assert sitl.counters["offboard"].rejected_targets == 2
    assert sitl.vehicle.command.throttle_pct == (0.0,) * 4
    sys_status = sitl.build("SYS_STATUS")
    assert sys_status.errors_count4 == 2


def test_sys_status_counts_bad_frames(sitl):
    c = Codec(counters=sitl.counters["gcs"])
    c.decode(b"\x01\x02\x03")
    c.decode(bytes(mavlink.MAVLink_param_request_list_message(2, 1).pack(_CLIENT)))
    for m in c.decode(bytes(mavlink.MAVLink_param_request_list_message(2, 1).pack(_CLIENT))):
        sitl.handle("gcs", m)
    st = sitl.build("SYS_STATUS")
    assert st.errors_count1 == 1 and st.errors_count3 == 1
    assert st.errors_comm == 2
    assert st.drop_rate_comm == 6660        # 2 dropped of 3 datagrams: 66.6 % in c%


# --- seeds ------------------------------------------------------------------------------------

def odometry_run(sim, seed, ticks=200):
    s = Sitl(sim.with_changes(seed=seed, clock_mode="realtime"))
    c = Codec()
    return b"".join(c.encode(m) for _ in range(ticks) for m in of(s.step(), "ODOMETRY"))


def test_noise_is_seeded(sim):
    assert odometry_run(sim, 3) == odometry_run(sim, 3)
    assert odometry_run(sim, 3) != odometry_run(sim, 4)


def test_log_row_matches_columns(sim):
    from sil_vehicle.sitl import LOG_COLUMNS
    rows = []
    s = Sitl(sim, log_sink=rows.append)
    for _ in range(100):
        s.step()
    assert len(rows) == 10                           # 100 Hz log at 1 kHz physics
    assert all(len(r) == len(LOG_COLUMNS) for r in rows)
    assert rows[-1][0] == 100_000


def test_flight_log_round_trip_with_gusts(sim, tmp_path):
    from trq_wire.logfile import CsvLog as FlightLog
    from trq_wire.logfile import read_csv_log as read_flight_log
    from sil_vehicle.sitl import LOG_COLUMNS
    path = tmp_path / "flight.csv"
    log = FlightLog(path, LOG_COLUMNS, {"seed": 5})
    s = Sitl(sim.with_changes(gusts_enabled=True, wind_speed_m_s=5.0, seed=5), log_sink=log)
    s.handle("offboard", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    s.vehicle.command = dataclasses.replace(s.vehicle.command, throttle_pct=(90.0,) * 4)
    for _ in range(500):
        s.step()
    log.close()
    meta, columns, data = read_flight_log(path)
    assert meta == {"seed": "5"} and columns == list(LOG_COLUMNS)
    assert data.shape == (50, len(LOG_COLUMNS))
    assert data[-1, columns.index("t_us")] == 500_000
    assert data[-1, columns.index("pos_d_m")] < 0.0                     # airborne
    assert data[-1, columns.index("wind_n_m_s")] != data[-2, columns.index("wind_n_m_s")]


def impaired(sim, **impair):
    from sil_vehicle.impair import ImpairParams
    links = tuple(dataclasses.replace(link, impair=ImpairParams(**impair))
                  if link.name == "offboard" else link for link in sim.links)
    return Sitl(sim.with_changes(links=links))


def test_delayed_link_lockstep_starts_and_waits_only_for_stamps_that_left(sim):
    """20 ms each way: the first ODOMETRY leaves at t = 20 ms, so the vehicle must not wait
    for an answer before then (it did: a lockstep deadlock at t = 0); then it waits for the
    answer to the stamp that left, and the target acts 20 ms after it arrived."""
    s = impaired(sim, delay_ms=20.0)
    out = s.telemetry_due()
    assert not of(out, "ODOMETRY") and not of(out, "HEARTBEAT", "offboard")
    assert s.answered and s.lockstep_stamp_us is None
    ticks = 0
    while s.answered:
        out = s.step()
        ticks += 1
        assert ticks <= 20
    assert s.t_us == 20_000 and s.lockstep_stamp_us == 0
    assert [m.time_usec for m in of(out, "ODOMETRY")] == [0]
    assert of(out, "HEARTBEAT", "offboard")
    s.handle("offboard", target(0, [0.3] * 4))
    assert s.answered and s.vehicle.command.throttle_pct == (0.0,) * 4      # still in flight
    for _ in range(19):
        s.step()
    assert s.vehicle.command.throttle_pct == (0.0,) * 4
    s.step()                                                                # t = 40 ms
    assert s.vehicle.command.throttle_pct == pytest.approx((30.0,) * 4)


def test_lockstep_resend_bypasses_the_simulated_impairment(sim):
    """A resend (the daemon's wall-clock recovery) goes out at once: simulated delays cannot
    elapse while the vehicle waits, and a lost first HEARTBEAT would otherwise never be
    followed by another one."""
    s = impaired(sim, delay_ms=20.0, loss=1.0)
    offboard = lambda out: [o for o in out if o.link == "offboard"]          # noqa: E731
    assert offboard(s.telemetry_due()) == []
    out = s.telemetry_due(everything=True, resend=True)
    assert of(out, "HEARTBEAT", "offboard") and of(out, "ODOMETRY", "offboard")
    assert s.lockstep_stamp_us == 0 and not s.answered
    assert offboard(s.telemetry_due(everything=True)) == []     # the impairment is still there


def test_impaired_lockstep_does_not_depend_on_wall_clock_traffic(sim):
    """A controller's heartbeat (1 Hz of its wall clock) lands between targets at places that
    vary from run to run; on a lossy link that must not change which targets are lost or when
    they act (it did: one random stream for every message made impaired flights differ)."""
    heartbeat = wire(mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def fly(extra_every: int | None):
        s = impaired(sim, loss=0.3, delay_ms=10.0)
        s.telemetry_due()
        history = []
        for k in range(150):
            if not s.answered:
                throttle = [0.2 + 0.001 * (k % 50)] * 4
                s.handle("offboard", target(s.lockstep_stamp_us, throttle))
            if extra_every and k % extra_every == 0:
                s.handle("offboard", heartbeat)
            for _ in range(s.lockstep_ticks()):
                s.step()
            history.append((s.t_us, s.vehicle.command.throttle_pct))
        return history, s.counters["offboard"].impaired_lost

    base, lost = fly(None)
    assert lost > 10                                         # the link did lose targets
    assert fly(7)[0] == base and fly(3)[0] == base           # (the heartbeats lost count apart)


def test_extended_sys_state_reports_the_land_detector(sitl):
    s = sitl
    states = [m.landed_state for m in of(fly_lockstep(s, 1000), "EXTENDED_SYS_STATE", "gcs")]
    assert states == [mavlink.MAV_LANDED_STATE_ON_GROUND]               # 1 Hz, disarmed
    arm(s)
    fly_lockstep(s, 300, throttle_pct=(90.0,) * 4)
    assert s.land_detector.state == mavlink.MAV_LANDED_STATE_TAKEOFF
    assert not s.vehicle.state.on_ground
    out = fly_lockstep(s, 1000, throttle_pct=(s.sim.vehicle.hover_throttle_pct,) * 4)
    assert len(of(out, "EXTENDED_SYS_STATE", "gcs")) == 1
    assert s.land_detector.state == mavlink.MAV_LANDED_STATE_IN_AIR     # TAKEOFF_S later
