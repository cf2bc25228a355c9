"""The controller's MAVLink codec (trq_offboard/link/wire.py) and connection strings (udp.py),
against hand-computed values and pymavlink's own packing and parsing. The actuator scalings
themselves are trq_wire.actuators' (tests/unit/trq_wire/test_actuators.py); here only which
message fields they are applied to, and the controller's clipping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.link import wire
from trq_offboard.records import ActuatorCommand

LIMIT = math.radians(30.0)
NAN21 = [math.nan] * 21


def over_the_wire(msg):
    """Pack with one pymavlink instance (as system 1, the vehicle), parse with another."""
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    rx = mavlink.MAVLink(None)
    out = rx.parse_buffer(bytes(msg.pack(tx)))
    assert out is not None and len(out) == 1
    return out[0]


def quat_zyx(roll, pitch, yaw):
    """Scalar-first quaternion of R = Rz(yaw) Ry(pitch) Rx(roll), built as the product of the
    three elementary rotations (not from the closed-form inverse under test)."""
    def mul(a, b):
        w1, x1, y1, z1 = a
        w2, x2, y2, z2 = b
        return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)
    qz = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    qy = (math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0)
    qx = (math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0)
    return mul(mul(qz, qy), qx)


def odometry(q=(1.0, 0.0, 0.0, 0.0), *, stamp=1_230_000, frame=mavlink.MAV_FRAME_LOCAL_NED,
             child=mavlink.MAV_FRAME_LOCAL_NED, pos=(1.5, -2.0, -3.25), vel=(0.5, -0.25, 0.125),
             rates=(0.01, -0.02, 0.03)):
    return mavlink.MAVLink_odometry_message(stamp, frame, child, *pos, list(q), *vel, *rates,
                                            NAN21, NAN21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE,
                                            100)


# --- ODOMETRY -> StateEstimate -------------------------------------------------------------------

def test_parse_odometry_fields_and_units():
    odo = wire.parse_odometry(over_the_wire(odometry()))
    assert odo is not None
    assert odo.stamp_us == 1_230_000 and isinstance(odo.stamp_us, int)
    s = odo.state
    assert s.pos_ned_m == pytest.approx((1.5, -2.0, -3.25))       # exact in float32
    assert s.vel_ned_m_s == pytest.approx((0.5, -0.25, 0.125))
    assert s.rates_frd_rad_s == pytest.approx((0.01, -0.02, 0.03), abs=1e-7)
    assert s.euler_rad == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


@pytest.mark.parametrize("q, euler", [
    # hand-computed: half angles of 90 deg give cos = sin = sqrt(1/2)
    ((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)), (0.0, 0.0, math.pi / 2)),      # yaw east
    ((math.sqrt(0.5), 0.0, 0.0, -math.sqrt(0.5)), (0.0, 0.0, -math.pi / 2)),    # yaw west
    ((math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0), (math.pi / 2, 0.0, 0.0)),      # roll right
    ((math.cos(0.15), 0.0, math.sin(0.15), 0.0), (0.0, 0.3, 0.0)),              # nose up 0.3
    ((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, math.pi)),                                # yaw south
])
def test_parse_odometry_euler_hand_checked(q, euler):
    odo = wire.parse_odometry(over_the_wire(odometry(q)))
    assert odo is not None
    got = np.array(odo.state.euler_rad)
    diff = (got - np.array(euler) + math.pi) % (2 * math.pi) - math.pi    # yaw pi == -pi
    assert np.abs(diff).max() < 1e-6


def test_parse_odometry_combined_attitude_round_trips():
    roll, pitch, yaw = 0.1, -0.2, 2.5
    q = quat_zyx(roll, pitch, yaw)
    # the ZYX quaternion of (0.1, -0.2, 2.5), worked out by hand to 4 decimals
    assert q == pytest.approx((0.3086, 0.1103, 0.0158, 0.9446), abs=1e-4)
    odo = wire.parse_odometry(over_the_wire(odometry(q)))
    assert odo.state.euler_rad == pytest.approx((roll, pitch, yaw), abs=1e-6)


def test_parse_odometry_normalises_a_slightly_off_quaternion():
    q = [1.02 * v for v in quat_zyx(0.2, 0.1, -1.0)]
    odo = wire.parse_odometry(odometry(q))
    assert odo.state.euler_rad == pytest.approx((0.2, 0.1, -1.0), abs=1e-9)


@pytest.mark.parametrize("kwargs", [
    {"frame": mavlink.MAV_FRAME_LOCAL_FRD},
    {"frame": mavlink.MAV_FRAME_GLOBAL},
    {"child": mavlink.MAV_FRAME_BODY_FRD},       # body velocity: not what the protocol sends
    {"pos": (math.nan, 0.0, 0.0)},
    {"vel": (0.0, math.inf, 0.0)},
    {"rates": (0.0, 0.0, math.nan)},
    {"q": (math.nan, 0.0, 0.0, 0.0)},
    {"q": (0.0, 0.0, 0.0, 0.0)},
    {"q": (2.0, 0.0, 0.0, 0.0)},
    {"q": (0.5, 0.0, 0.0, 0.0)},
])
def test_parse_odometry_rejects_unusable_messages(kwargs):
    assert wire.parse_odometry(over_the_wire(odometry(**kwargs))) is None


# --- actual outputs -> ActuatorCommand ---------------------------------------------------------

def test_parse_actuator_output_status():
    values = [0.0, 0.25, 0.5, 1.0, -1.0, -0.5, 0.25, 1.0] + [0.0] * 24
    msg = over_the_wire(mavlink.MAVLink_actuator_output_status_message(5_000, 8, values))
    cmd = wire.parse_actuator_outputs(msg, LIMIT)
    assert cmd.throttle_pct == pytest.approx((0.0, 25.0, 50.0, 100.0))
    assert cmd.tilt_rad == pytest.approx((-LIMIT, -LIMIT / 2, LIMIT / 4, LIMIT))


def test_parse_actuator_output_status_needs_eight_finite_outputs():
    values = [0.5] * 8 + [0.0] * 24
    assert wire.parse_actuator_outputs(
        mavlink.MAVLink_actuator_output_status_message(0, 4, values), LIMIT) is None
    values[5] = math.nan
    assert wire.parse_actuator_outputs(
        mavlink.MAVLink_actuator_output_status_message(0, 8, values), LIMIT) is None


def test_parse_servo_output_raw():
    # motors: 1000 + 10 x throttle %; tilts: 1500 + 500 x tilt / half-range
    msg = over_the_wire(mavlink.MAVLink_servo_output_raw_message(
        5_000, 0, 1000, 1250, 1775, 2000, 1000, 1250, 1500, 2000))
    cmd = wire.parse_actuator_outputs(msg, LIMIT)
    assert cmd.throttle_pct == pytest.approx((0.0, 25.0, 77.5, 100.0))
    assert cmd.tilt_rad == pytest.approx((-LIMIT, -LIMIT / 2, 0.0, LIMIT))


def test_parse_actuator_outputs_ignores_other_messages():
    assert wire.parse_actuator_outputs(odometry(), LIMIT) is None


# --- ActuatorCommand -> SET_ACTUATOR_CONTROL_TARGET ------------------------------------------

def test_actuator_target_scaling():
    cmd = ActuatorCommand((0.0, 10.0, 55.0, 100.0), (-LIMIT, -LIMIT / 2, 0.0, LIMIT / 3))
    msg = wire.actuator_target(2_340_000, cmd, LIMIT)
    assert list(msg.controls) == pytest.approx([0.0, 0.1, 0.55, 1.0, -1.0, -0.5, 0.0, 1 / 3])
    assert msg.time_usec == 2_340_000 and msg.group_mlx == 0
    assert (msg.target_system, msg.target_component) == (1, 1)


def test_actuator_target_clips_out_of_range_values():
    cmd = ActuatorCommand((-5.0, 130.0, 50.0, 100.0001), (-2 * LIMIT, 1.5 * LIMIT, 0.0, -1e9))
    msg = wire.actuator_target(0, cmd, LIMIT)
    assert list(msg.controls) == pytest.approx([0.0, 1.0, 0.5, 1.0, -1.0, 1.0, 0.0, -1.0])


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["throttle", "tilt"])
def test_actuator_target_refuses_non_finite_values(bad, where):
    thr, tilt = [50.0] * 4, [0.0] * 4
    (thr if where == "throttle" else tilt)[2] = bad
    with pytest.raises(ValueError, match="non-finite"):
        wire.actuator_target(0, ActuatorCommand(tuple(thr), tuple(tilt)), LIMIT)


def test_actuator_target_round_trips_through_pymavlink():
    stamp = 12_345_678_901            # beyond 32 bits: time_usec is uint64
    cmd = ActuatorCommand((12.5, 60.0, 75.25, 99.0), (0.1, -0.2, 0.3, -0.4))
    got = over_the_wire(wire.actuator_target(stamp, cmd, LIMIT))
    assert got.get_type() == "SET_ACTUATOR_CONTROL_TARGET"
    assert got.time_usec == stamp and got.group_mlx == 0
    assert (got.target_system, got.target_component) == (1, 1)
    expected = [v / 100 for v in cmd.throttle_pct] + [v / LIMIT for v in cmd.tilt_rad]
    assert list(got.controls) == pytest.approx(expected, abs=1e-7)       # float32 on the wire


def test_arm_disarm_and_heartbeat():
    arm = over_the_wire(wire.arm_command(True))
    assert arm.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and arm.param1 == 1.0
    assert (arm.target_system, arm.target_component) == (1, 1) and arm.param2 == 0.0
    disarm = wire.arm_command(False, force=True)
    assert disarm.param1 == 0.0 and disarm.param2 == 21196.0
    hb = wire.heartbeat()
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    armed = mavlink.MAVLink_heartbeat_message(
        2, 0, mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        0, 4, 3)
    assert wire.is_armed(armed)
    assert not wire.is_armed(mavlink.MAVLink_heartbeat_message(
        2, 0, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, 3, 3))
