"""Frames and conversions. World frame NED, body frame FRD, quaternions scalar first (w, x, y, z)
rotating body vectors into the world frame, Euler angles ZYX (roll, pitch, yaw) in radians.

Every conversion of the package lives here, with round-trip tests in
tests/unit/sil_vehicle/test_frames.py.
"""

from __future__ import annotations

import math

# the flat-earth NED <-> geodetic conversion is the wire's (the companion inverts it): kept in
# trq_wire.geodetic, named here too
from trq_wire.geodetic import EARTH_RADIUS_M, geodetic_to_ned, ned_to_geodetic

__all__ = ["EARTH_RADIUS_M", "euler_to_quat", "geodetic_to_ned", "ned_to_geodetic", "quat_to_dcm",
           "quat_to_euler", "tilt_from_vertical", "wind_from_to_ned", "wrap_pi"]


def quat_to_euler(qw: float, qx: float, qy: float, qz: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in rad of a unit quaternion; pitch in [-pi/2, pi/2]."""
    roll = math.atan2(2.0 * (qw * qx + qy * qz), 1.0 - 2.0 * (qx * qx + qy * qy))
    s = 2.0 * (qw * qy - qz * qx)
    pitch = math.asin(1.0 if s > 1.0 else -1.0 if s < -1.0 else s)
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return roll, pitch, yaw


def euler_to_quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def quat_to_dcm(qw: float, qx: float, qy: float, qz: float) -> tuple[tuple[float, ...], ...]:
    """Rotation matrix (rows) taking body FRD vectors to world NED."""
    return ((1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)),
            (2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)),
            (2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)))


def tilt_from_vertical(qw: float, qx: float, qy: float, qz: float) -> float:
    """Angle (rad) between body z and world z: 0 level, pi upside down."""
    c = 1 - 2 * (qx * qx + qy * qy)
    return math.acos(1.0 if c > 1.0 else -1.0 if c < -1.0 else c)


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def wind_from_to_ned(speed_m_s: float, from_deg: float) -> tuple[float, float, float]:
    """Wind velocity in NED of a wind blowing FROM `from_deg` (clockwise from north)."""
    a = math.radians(from_deg)
    return (-speed_m_s * math.cos(a), -speed_m_s * math.sin(a), 0.0)
