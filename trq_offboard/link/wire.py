"""MAVLink messages of the offboard link, converted to and from the controller's records.

ODOMETRY to `StateEstimate`, ACTUATOR_OUTPUT_STATUS / SERVO_OUTPUT_RAW to the applied
`ActuatorCommand`, and the `ActuatorCommand` to SET_ACTUATOR_CONTROL_TARGET (group 0: throttles
0..1, tilts -1..1 of the servo half-range). The actuator scalings themselves are shared with the
vehicle and live in trq_wire.actuators. A target that would carry a NaN is never built; values
out of range are clipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.frames import quat_to_euler
from trq_offboard.records import ActuatorCommand, StateEstimate
from trq_wire import actuators, frames
from trq_wire.mocap import VISION_ESTIMATOR_TYPE

VEHICLE_SYSTEM = 1
HOME_GROUND_DOWN_M = 0.0     # PROTOCOL.md: the NED origin is home, on the ground
VEHICLE_COMPONENT = 1
FORCE_DISARM = 21196


@dataclass(frozen=True)
class Odometry:
    stamp_us: int
    state: StateEstimate


def parse_odometry(msg) -> Odometry | None:
    """ODOMETRY in LOCAL_NED with NED velocity (child frame LOCAL_NED). None if unusable."""
    if msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED \
            or msg.child_frame_id != mavlink.MAV_FRAME_LOCAL_NED:
        return None
    pos, vel = (msg.x, msg.y, msg.z), (msg.vx, msg.vy, msg.vz)
    rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
    q0, q1, q2, q3 = msg.q
    if not all(map(math.isfinite, (*pos, *vel, q0, q1, q2, q3, *rates))):
        return None
    n = math.sqrt(0 + q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)     # sum()'s order, from 0
    if not 0.9 < n < 1.1:
        return None
    return Odometry(int(msg.time_usec), StateEstimate(
        pos, vel, quat_to_euler(q0 / n, q1 / n, q2 / n, q3 / n), rates))


def parse_actuator_outputs(msg, tilt_limit_rad: float) -> ActuatorCommand | None:
    """The outputs the vehicle actually produced (after lag, rate limits and faults)."""
    kind = msg.get_type()
    if kind == "ACTUATOR_OUTPUT_STATUS":
        a = msg.actuator
        if msg.active < 8 or not all(math.isfinite(v) for v in a[:8]):
            return None
        return ActuatorCommand(*actuators.from_normalised(a, tilt_limit_rad))
    if kind == "SERVO_OUTPUT_RAW":
        pwm = [msg.servo1_raw, msg.servo2_raw, msg.servo3_raw, msg.servo4_raw, msg.servo5_raw,
               msg.servo6_raw, msg.servo7_raw, msg.servo8_raw]
        return ActuatorCommand(*actuators.from_pwm(pwm, tilt_limit_rad))
    return None


def actuator_target(stamp_us: int, cmd: ActuatorCommand, tilt_limit_rad: float):
    """SET_ACTUATOR_CONTROL_TARGET for the vehicle (pymavlink's message, packed by one struct:
    trq_wire.frames.ActuatorTarget). Raises ValueError on a non-finite value: the caller must
    never get that far (the controller clips), this is the last check."""
    # check before clipping: min/max would turn an infinity into a limit (and may hide a NaN)
    if not all(map(math.isfinite, (*cmd.throttle_pct, *cmd.tilt_rad))):
        raise ValueError(f"non-finite actuator command {cmd}")
    controls = actuators.clip_controls(
        actuators.to_normalised(cmd.throttle_pct, cmd.tilt_rad, tilt_limit_rad))
    return frames.ActuatorTarget(stamp_us, 0, VEHICLE_SYSTEM, VEHICLE_COMPONENT, controls)


def arm_command(arm: bool, force: bool = False):
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
        1.0 if arm else 0.0, float(FORCE_DISARM) if force else 0.0, 0, 0, 0, 0, 0)


def set_mode_offboard():
    """MAV_CMD_DO_SET_MODE to PX4's OFFBOARD (custom main mode 6)."""
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_DO_SET_MODE, 0,
        float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), 6.0, 0, 0, 0, 0, 0)


def set_mode_land():
    """MAV_CMD_DO_SET_MODE to PX4's AUTO.LAND (main mode 4, sub mode 6): the vehicle lands."""
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_DO_SET_MODE, 0,
        float(mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), 4.0, 6.0, 0, 0, 0, 0)


def message_interval(msg_id: int, rate_hz: float):
    """MAV_CMD_SET_MESSAGE_INTERVAL: the vehicle sends message `msg_id` at rate_hz."""
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
        float(msg_id), float(round(1e6 / rate_hz)), 0, 0, 0, 0, 0)


def stream_off(msg_id: int):
    """MAV_CMD_SET_MESSAGE_INTERVAL with the interval -1: the vehicle stops sending `msg_id`."""
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
        float(msg_id), -1.0, 0, 0, 0, 0, 0)


def request_message(msg_id: int):
    """MAV_CMD_REQUEST_MESSAGE: the vehicle sends message `msg_id` once (HOME_POSITION)."""
    return mavlink.MAVLink_command_long_message(
        VEHICLE_SYSTEM, VEHICLE_COMPONENT, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, float(msg_id),
        0, 0, 0, 0, 0, 0)


ACCEL_UPDATED = (mavlink.HIGHRES_IMU_UPDATED_XACC | mavlink.HIGHRES_IMU_UPDATED_YACC
                 | mavlink.HIGHRES_IMU_UPDATED_ZACC)


def parse_highres_accel(msg) -> tuple[int, tuple[float, float, float]] | None:
    """HIGHRES_IMU's (time_usec, specific force m/s^2 body FRD) if it carries a new
    accelerometer sample (fields_updated) with finite values, else None. The force is the
    mean over the interval since the message before it (PROTOCOL.md), valid at time_usec."""
    if (msg.fields_updated & ACCEL_UPDATED) != ACCEL_UPDATED:
        return None
    acc = (msg.xacc, msg.yacc, msg.zacc)
    return (int(msg.time_usec), acc) if all(map(math.isfinite, acc)) else None


def parse_mocap(msg) -> tuple[int, tuple[float, float, float]] | None:
    """ATT_POS_MOCAP's (time of validity us, position m NED), None if not finite."""
    pos = (msg.x, msg.y, msg.z)
    return (int(msg.time_usec), pos) if all(map(math.isfinite, pos)) else None


def vision_odometry(mocap_msg):
    """The companion's forward of a motion-capture pose (ATT_POS_MOCAP from the mocap system)
    to the autopilot, as PX4 takes external vision: ODOMETRY with `time_usec` the pose's own
    stamp (its time of validity, the mocap's clock taken as the vehicle's), `frame_id`
    LOCAL_NED (position m, `q` body FRD -> NED), `child_frame_id` BODY_FRD with no velocity or
    rates (NaN), `pose_covariance` the mocap's when it states one (else NaN: unknown, the
    autopilot's EKF2_EVP_NOISE / EKF2_EVA_NOISE then), `estimator_type` MOCAP, `quality` 0
    (unknown, which EKF2_EV_QMIN's default accepts)."""
    nan = math.nan
    cov = list(mocap_msg.covariance)
    pose_cov = cov if all(math.isfinite(v) for v in cov) else [nan] * 21
    return mavlink.MAVLink_odometry_message(
        int(mocap_msg.time_usec), mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
        mocap_msg.x, mocap_msg.y, mocap_msg.z, list(mocap_msg.q), nan, nan, nan, nan, nan, nan,
        pose_cov, [nan] * 21, 0, VISION_ESTIMATOR_TYPE, 0)


def is_crashed(heartbeat_msg) -> bool:
    return heartbeat_msg.system_status == mavlink.MAV_STATE_EMERGENCY


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
        mavlink.MAV_STATE_ACTIVE, 3)


def is_armed(heartbeat_msg) -> bool:
    return bool(heartbeat_msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
