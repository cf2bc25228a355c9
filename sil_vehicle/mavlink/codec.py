"""The MAVLink codec: bytes <-> typed messages, and the vehicle's MAVLink field scalings.

pymavlink's generated `common` dialect packs and parses; framing of a UDP datagram, error
counting and the conversion of physical quantities to MAVLink fields (degE7, mm, cm/s, cdeg)
live here and nowhere else. The actuator scalings (PWM microseconds, normalised values) are
shared with the controller and live in trq_wire.actuators; signing in trq_wire.signing.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.frames import ned_to_geodetic, quat_to_euler
from trq_wire import actuators
from trq_wire.geodetic import to_e7
from trq_wire.signing import SignatureCheck

SYSTEM_ID = 1
COMPONENT_ID = 1  # MAV_COMP_ID_AUTOPILOT1

_V2_HEADER = 10
_V1_HEADER = 6
_SIGNATURE = 13


@dataclass
class RxCounters:
    """What arrived on a link and what was dropped, by reason."""
    datagrams: int = 0
    messages: int = 0
    bad_frames: int = 0          # garbage, truncated frames, bad checksums
    mavlink1: int = 0
    unknown_ids: int = 0
    other_system: int = 0
    rejected_targets: int = 0    # actuator targets with NaN, inf or out-of-range values
    stale_targets: int = 0       # lockstep targets answering an older stamp
    impaired_lost: int = 0       # lost on purpose by a link impairment (not an error)
    unauthenticated: int = 0     # signing on: unsigned, wrongly signed or replayed frames

    @property
    def dropped(self) -> int:
        return (self.bad_frames + self.unknown_ids + self.other_system + self.rejected_targets
                + self.stale_targets + self.unauthenticated)


@dataclass
class Codec:
    """One per link: its own sequence numbers and receive counters."""
    system_id: int = SYSTEM_ID
    component_id: int = COMPONENT_ID
    counters: RxCounters = field(default_factory=RxCounters)
    check: SignatureCheck | None = None      # signing: what is received must be signed

    def __post_init__(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=self.system_id,
                                   srcComponent=self.component_id)
        self._rx = mavlink.MAVLink(None)

    def encode(self, msg: mavlink.MAVLink_message) -> bytes:
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(data)

    def decode(self, datagram: bytes) -> list[mavlink.MAVLink_message]:
        """All valid messages of one UDP datagram; anything else is counted and skipped.
        Frames never span datagrams, so no state is carried from one to the next."""
        c = self.counters
        c.datagrams += 1
        out = []
        i, n = 0, len(datagram)
        while i < n:
            marker = datagram[i]
            if marker == 0xFD and i + _V2_HEADER <= n:
                length = _V2_HEADER + datagram[i + 1] + 2
                if datagram[i + 2] & mavlink.MAVLINK_IFLAG_SIGNED:
                    length += _SIGNATURE
            elif marker == 0xFE and i + _V1_HEADER <= n:
                length = _V1_HEADER + datagram[i + 1] + 2
            else:
                c.bad_frames += 1
                i = _next_marker(datagram, i + 1)
                continue
            frame = datagram[i:i + length]
            if len(frame) < length:
                c.bad_frames += 1
                break
            if self.check is not None and not self.check.accept(frame):
                c.unauthenticated += 1
                i += length
                continue
            try:
                msg = self._rx.decode(bytearray(frame))
            except Exception:  # pymavlink raises MAVError and, on odd payloads, others
                c.bad_frames += 1
                i = _next_marker(datagram, i + 1)
                continue
            i += length
            if isinstance(msg, mavlink.MAVLink_unknown):
                c.unknown_ids += 1
                continue
            if marker == 0xFE:
                c.mavlink1 += 1
            c.messages += 1
            out.append(msg)
        return out


def _next_marker(data: bytes, start: int) -> int:
    for j in range(start, len(data)):
        if data[j] in (0xFD, 0xFE):
            return j
    return len(data)


# --- actuator targets ----------------------------------------------------------------------

@dataclass(frozen=True)
class Target:
    """A decoded SET_ACTUATOR_CONTROL_TARGET, in physical units."""
    stamp_us: int
    throttle_pct: tuple[float, float, float, float]
    tilt_rad: tuple[float, float, float, float]


def decode_target(msg: mavlink.MAVLink_message, tilt_limit_rad: float) -> Target | None:
    """Group 0: controls[0..3] throttle 0..1 of motors 1..4, controls[4..7] tilt -1..1 of the
    servo half-range. None if any value is not finite or out of range (the whole message)."""
    if msg.group_mlx != 0:
        return None
    c = msg.controls
    if not actuators.controls_in_range(c):
        return None
    throttle_pct, tilt_rad = actuators.from_normalised(c, tilt_limit_rad)
    return Target(int(msg.time_usec), throttle_pct, tilt_rad)


# --- telemetry builders --------------------------------------------------------------------

@dataclass(frozen=True)
class Measured:
    """What the vehicle's sensors report (truth plus noise), SI units, NED / FRD."""
    t_us: int
    pos_ned_m: tuple[float, float, float]
    vel_ned_m_s: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]
    rates_frd_rad_s: tuple[float, float, float]
    # an estimator's (ODOMETRY's fields: the upper triangles, row-major, of the pose covariance
    # (x, y, z, roll, pitch, yaw) and of the velocity covariance (vx, vy, vz, p, q, r)); None:
    # the truth-plus-noise stream, which states none
    pose_covariance: tuple[float, ...] | None = None
    velocity_covariance: tuple[float, ...] | None = None
    quality_pct: int = 100                     # ODOMETRY's quality: -1 failed, 0 unknown


def heartbeat(armed: bool, crashed: bool, flying: bool, custom_mode: int = 0,
              failsafe: bool = False) -> mavlink.MAVLink_message:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    status = (mavlink.MAV_STATE_EMERGENCY if crashed else
              mavlink.MAV_STATE_CRITICAL if failsafe and armed else
              mavlink.MAV_STATE_ACTIVE if (armed or flying) else mavlink.MAV_STATE_STANDBY)
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_GENERIC, base, custom_mode, status, 3)


# SYS_STATUS's sensor bits under `truth` (no sensor is modelled: they are all taken as healthy)
TRUTH_SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                 | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)


@dataclass(frozen=True)
class SensorBits:
    """SYS_STATUS's onboard_control_sensors_present / _enabled / _health (MAV_SYS_STATUS_SENSOR
    bits), as the vehicle's health report sets them (Sitl.sensor_bits)."""
    present: int
    enabled: int
    health: int


def sys_status(load_permille: int, drop_rate_permille: int, errors_comm: int,
               dropped_by_kind: Iterable[int],
               bits: SensorBits | None = None) -> mavlink.MAVLink_message:
    """SYS_STATUS; `bits` None: TRUTH_SENSORS present, enabled and healthy."""
    if bits is None:
        bits = SensorBits(TRUTH_SENSORS, TRUTH_SENSORS, TRUTH_SENSORS)
    e = [min(int(v), 65535) for v in dropped_by_kind][:4] + [0] * 4
    return mavlink.MAVLink_sys_status_message(
        bits.present, bits.enabled, bits.health, min(load_permille, 1000), -1 & 0xFFFF, -1, -1,
        min(drop_rate_permille, 10000), min(errors_comm, 65535), e[0], e[1], e[2], e[3])


def odometry(m: Measured, reset_counter: int = 0) -> mavlink.MAVLink_message:
    """Pose in LOCAL_NED; child frame LOCAL_NED, so the velocity is NED too; rates are body FRD.
    `reset_counter`: the estimator's state resets so far (PX4: EKF2's quaternion, NE and D
    velocity and position reset counts summed), wrapped to a uint8."""
    nan21 = [math.nan] * 21
    estimated = m.pose_covariance is not None
    return mavlink.MAVLink_odometry_message(
        m.t_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, *m.pos_ned_m,
        list(m.quat_wxyz), *m.vel_ned_m_s, *m.rates_frd_rad_s,
        list(m.pose_covariance) if estimated else nan21,
        list(m.velocity_covariance) if m.velocity_covariance is not None else nan21,
        reset_counter & 0xFF,
        mavlink.MAV_ESTIMATOR_TYPE_AUTOPILOT if estimated else mavlink.MAV_ESTIMATOR_TYPE_NAIVE,
        m.quality_pct)


def attitude(m: Measured) -> mavlink.MAVLink_message:
    roll, pitch, yaw = quat_to_euler(*m.quat_wxyz)
    return mavlink.MAVLink_attitude_message(m.t_us // 1000, roll, pitch, yaw, *m.rates_frd_rad_s)


def local_position_ned(m: Measured) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_local_position_ned_message(m.t_us // 1000, *m.pos_ned_m,
                                                      *m.vel_ned_m_s)


def _geo(m: Measured, home: tuple[float, float, float]) -> tuple[int, int, int]:
    return to_e7(*ned_to_geodetic(*m.pos_ned_m, *home))


def _heading_cdeg(m: Measured) -> int:
    yaw = quat_to_euler(*m.quat_wxyz)[2]
    return int(round(math.degrees(yaw) % 360.0 * 100.0)) % 36000


def global_position_int(m: Measured, home: tuple[float, float, float]) -> mavlink.MAVLink_message:
    lat, lon, alt_mm = _geo(m, home)
    vn, ve, vd = (int(round(v * 100.0)) for v in m.vel_ned_m_s)
    return mavlink.MAVLink_global_position_int_message(
        m.t_us // 1000, lat, lon, alt_mm, int(round(-m.pos_ned_m[2] * 1000.0)), vn, ve, vd,
        _heading_cdeg(m))


def gps_raw_int(m: Measured, home: tuple[float, float, float]) -> mavlink.MAVLink_message:
    lat, lon, alt_mm = _geo(m, home)
    vn, ve = m.vel_ned_m_s[0], m.vel_ned_m_s[1]
    speed = math.hypot(vn, ve)
    cog = (int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0)) % 36000
           if speed > 0.2 else 65535)
    return mavlink.MAVLink_gps_raw_int_message(
        m.t_us, mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt_mm, 80, 120,
        int(round(speed * 100.0)), cog, 14)


# --- raw sensors of a sensing profile (sil_vehicle.sensors readings) -----------------------

PA_PER_HPA = 100.0
# HIGHRES_IMU.fields_updated: what each sensor's new sample updates
IMU_FIELDS = (mavlink.HIGHRES_IMU_UPDATED_XACC | mavlink.HIGHRES_IMU_UPDATED_YACC
              | mavlink.HIGHRES_IMU_UPDATED_ZACC | mavlink.HIGHRES_IMU_UPDATED_XGYRO
              | mavlink.HIGHRES_IMU_UPDATED_YGYRO | mavlink.HIGHRES_IMU_UPDATED_ZGYRO)
MAG_FIELDS = (mavlink.HIGHRES_IMU_UPDATED_XMAG | mavlink.HIGHRES_IMU_UPDATED_YMAG
              | mavlink.HIGHRES_IMU_UPDATED_ZMAG)
BARO_FIELDS = (mavlink.HIGHRES_IMU_UPDATED_ABS_PRESSURE | mavlink.HIGHRES_IMU_UPDATED_PRESSURE_ALT
               | mavlink.HIGHRES_IMU_UPDATED_TEMPERATURE)
COG_UNKNOWN = 65535
COG_MIN_SPEED_M_S = 0.2       # below this ground speed the course is left unknown


def highres_imu(imu, baro, mag, fields_updated: int) -> mavlink.MAVLink_message:
    """HIGHRES_IMU from an IMU reading (the caller's mean, bias-corrected: Sitl._highres_imu) and
    the latest barometer and magnetometer readings (`baro`, `mag` None when the profile has none:
    their fields 0): acceleration m/s^2 (specific force) and rates rad/s body FRD, field gauss
    body FRD, pressure hPa, pressure altitude m AMSL, temperature degC; `time_usec` the IMU
    reading's time (its last sample's, as PX4's vehicle_imu timestamp_sample); `fields_updated`
    the HIGHRES_IMU_UPDATED bits of what is new in this message."""
    acc, gyro = imu.accel, imu.gyro
    m = mag.field_frd_gauss if mag is not None else (0.0, 0.0, 0.0)
    p_hpa, alt, temp = ((baro.pressure_pa / PA_PER_HPA, baro.pressure_alt_m, baro.temperature_degc)
                        if baro is not None else (0.0, 0.0, 0.0))
    return mavlink.MAVLink_highres_imu_message(
        imu.t_us, float(acc[0]), float(acc[1]), float(acc[2]), float(gyro[0]), float(gyro[1]),
        float(gyro[2]), float(m[0]), float(m[1]), float(m[2]), p_hpa, 0.0, alt, temp,
        fields_updated, 0)


def geodetic_e7(pos_ned_m, home: tuple[float, float, float]) -> tuple[int, int, int]:
    """(lat degE7, lon degE7, alt mm AMSL) of a NED position around home (flat earth)."""
    return to_e7(*ned_to_geodetic(float(pos_ned_m[0]), float(pos_ned_m[1]),
                                  float(pos_ned_m[2]), *home))


# GPS_RAW_INT's eph / epv are dilutions of precision x100 (MAVLink; PX4 sends sensor_gps.hdop /
# vdop). The receiver model has no satellite geometry: the DOPs PX4's own simulated receiver
# reports (SensorGpsSim: hdop 0.7, vdop 1.1), a choice with that source
HDOP = 0.7
VDOP = 1.1


def gnss_raw_int(r, home: tuple[float, float, float]) -> mavlink.MAVLink_message:
    """GPS_RAW_INT from a GNSS receiver's reading, filled as PX4's stream fills it:
    `time_usec` the reading's arrival (PX4 sends sensor_gps.timestamp, when the driver published
    it: the time of validity is the receiver's delay earlier, EKF2_GPS_DELAY), the profile's fix
    type and satellites (used), lat/lon degE7 and alt mm AMSL around home, eph/epv the DOPs x100
    (HDOP, VDOP), ground speed cm/s, course over ground cdeg (65535 below 0.2 m/s); MAVLink 2
    extensions: alt_ellipsoid mm (= alt: no geoid), h_acc, v_acc mm and vel_acc mm/s (the
    receiver's 1-sigma accuracies), hdg_acc 0 and yaw 0 (no dual-antenna heading)."""
    lat, lon, alt_mm = geodetic_e7(r.pos_ned_m, home)
    vn, ve = float(r.vel_ned_m_s[0]), float(r.vel_ned_m_s[1])
    speed = math.hypot(vn, ve)
    cog = (int(round(math.degrees(math.atan2(ve, vn)) % 360.0 * 100.0)) % 36000
           if speed > COG_MIN_SPEED_M_S else COG_UNKNOWN)
    return mavlink.MAVLink_gps_raw_int_message(
        r.arrival_us, r.fix_type, lat, lon, alt_mm, _u16(HDOP * 100.0), _u16(VDOP * 100.0),
        _u16(speed * 100.0), cog, min(r.satellites, 255), alt_mm,
        _u32(r.eph_m * 1000.0), _u32(r.epv_m * 1000.0), _u32(r.speed_accuracy_m_s * 1000.0), 0,
        0)


def gnss_raw_int_no_gps(t_us: int) -> mavlink.MAVLink_message:
    """GPS_RAW_INT once a receiver has fallen silent (PX4 sends this every second after a
    second without sensor_gps): fix type NO_GPS, the rest unknown or 0."""
    return mavlink.MAVLink_gps_raw_int_message(
        t_us, mavlink.GPS_FIX_TYPE_NO_GPS, 0, 0, 0, 65535, 65535, 65535, COG_UNKNOWN, 255, 0,
        0, 0, 0, 0, 0)


def att_pos_mocap(r) -> mavlink.MAVLink_message:
    """ATT_POS_MOCAP from a motion-capture reading: `time_usec` its time of validity, `q` body
    FRD -> NED (w, x, y, z), x, y, z m NED; covariance unknown (NaN first, as MAVLink asks)."""
    q = r.quat_wxyz
    return mavlink.MAVLink_att_pos_mocap_message(
        r.t_us, [float(q[0]), float(q[1]), float(q[2]), float(q[3])], float(r.pos_ned_m[0]),
        float(r.pos_ned_m[1]), float(r.pos_ned_m[2]), [math.nan] + [0.0] * 20)


def _u16(value: float) -> int:
    """A non-negative value rounded into a uint16 field, saturated below its 'unknown' 65535."""
    return min(int(round(value)), 65534)


def _u32(value: float) -> int:
    return min(int(round(value)), 2**32 - 2)


def home_position(home: tuple[float, float, float], t_us: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_home_position_message(
        *to_e7(*home), 0.0, 0.0, 0.0,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, t_us)


def servo_output_raw(t_us: int, motor_pct: Iterable[float], tilt_rad: Iterable[float],
                     limit_rad: float) -> mavlink.MAVLink_message:
    pwm = actuators.to_pwm(motor_pct, tilt_rad, limit_rad)
    return mavlink.MAVLink_servo_output_raw_message(t_us & 0xFFFFFFFF, 0, *pwm, *([0] * 8))


def actuator_output_status(t_us: int, motor_pct: Iterable[float], tilt_rad: Iterable[float],
                           limit_rad: float) -> mavlink.MAVLink_message:
    values = actuators.to_normalised(motor_pct, tilt_rad, limit_rad)
    return mavlink.MAVLink_actuator_output_status_message(
        t_us, len(values), values + [0.0] * (32 - len(values)))


def statustext(severity: int, text: str) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_statustext_message(severity, text[:50].encode("ascii", "replace"))


def command_ack(command: int, result: int, target_system: int,
                target_component: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_command_ack_message(command, result, 0, 0, target_system,
                                               target_component)


def param_value(name: str, value: float, count: int, index: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_param_value_message(name.encode("ascii"), value,
                                               mavlink.MAV_PARAM_TYPE_REAL32, count, index)


def autopilot_version() -> mavlink.MAVLink_message:
    # (MAV_PROTOCOL_CAPABILITY_SET_ACTUATOR_TARGET, bit 1024, is deprecated: now RESERVED3)
    caps = mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2 | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    return mavlink.MAVLink_autopilot_version_message(
        caps, 0x00010000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5452510001)


def mission_count(target_system: int, target_component: int) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_mission_count_message(target_system, target_component, 0)


_UPPER = operator.itemgetter(*(6 * i + j for i in range(6) for j in range(i, 6)))


def _upper(c: np.ndarray) -> tuple[float, ...]:
    """The upper triangle of a 6x6 matrix, row-major: ODOMETRY's 21 covariance fields."""
    return _UPPER(np.asarray(c, dtype=float).ravel().tolist())


def _floats(a) -> tuple[float, ...]:
    return tuple(np.asarray(a, dtype=float).tolist())


def measured_of(e) -> Measured:
    """What the vehicle reports from its estimator's Estimate (sil_vehicle.estimator.eskf):
    the output predictor's pose, velocity and bias-corrected rates, ODOMETRY's pose covariance
    in (x, y, z, roll, pitch, yaw), its velocity covariance (NED velocity, then the rates'
    variances on the angular diagonal, the rest unknown: NaN), and the quality: 100 with a
    valid position, -1 diverged, 0 otherwise."""
    # the velocity covariance's upper triangle: the NED block, then the rates' variances on the
    # diagonal, NaN elsewhere
    (v00, v01, v02), (_, v11, v12), (_, _, v22) = np.asarray(e.vel_cov_ned_m2_s2,
                                                             dtype=float).tolist()
    r0, r1, r2 = _floats(e.rates_var_frd_rad2_s2)
    nan = math.nan
    vel = (v00, v01, v02, nan, nan, nan, v11, v12, nan, nan, nan, v22, nan, nan, nan,
           r0, nan, nan, r1, nan, r2)
    quality = -1 if e.diverged else (100 if e.position_valid and e.attitude_aligned else 0)
    return Measured(e.t_us, _floats(e.pos_ned_m), _floats(e.vel_ned_m_s),
                    _floats(e.quat_wxyz), _floats(e.rates_frd_rad_s),
                    _upper(e.pose_cov_rpy()), vel, quality)


def estimator_status(e) -> mavlink.MAVLink_message:
    """ESTIMATOR_STATUS of an Estimate: EKF2's test ratios as they are (NaN: no such
    measurement yet), the horizontal and vertical position accuracy (1 sigma, m), and the flags
    (attitude; horizontal and vertical velocity and position, relative and absolute, while a
    position source is fused; none of them, and the accelerometer error flag, once diverged)."""
    flags = 0
    if not e.diverged:
        if e.attitude_aligned:
            flags |= mavlink.ESTIMATOR_ATTITUDE
        if e.position_valid:
            flags |= (mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_VELOCITY_VERT
                      | mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_HORIZ_ABS
                      | mavlink.ESTIMATOR_POS_VERT_ABS | mavlink.ESTIMATOR_PRED_POS_HORIZ_REL
                      | mavlink.ESTIMATOR_PRED_POS_HORIZ_ABS)
    else:
        flags |= mavlink.ESTIMATOR_ACCEL_ERROR
    var = e.pos_var_ned_m2
    horiz, vert = float(var[0]) + float(var[1]), float(var[2])
    return mavlink.MAVLink_estimator_status_message(
        e.t_us, flags, e.vel_ratio, e.pos_horiz_ratio, e.pos_vert_ratio, e.mag_ratio,
        math.nan, math.nan, _std(horiz), _std(vert))


def _std(variance: float) -> float:
    """A variance's square root; NaN (unknown) for a negative or non-finite one, which only a
    diverging filter gives."""
    return math.sqrt(variance) if variance >= 0.0 and math.isfinite(variance) else math.nan
