"""The companion's rotations, written once (issue 39, item 8): ZYX Euler angles (roll, pitch,
yaw, rad), scalar-first unit quaternions (w, x, y, z) and the rotation matrix taking body FRD
vectors to world NED.

`rotation_ned_frd` serves both the prediction model (CasADi SX/MX/DM angles: a CasADi matrix,
trq_offboard/model/dynamics.py) and the numeric code (floats: a NumPy 3x3, the fused filter),
the same formula either way. `quat_to_euler` reads ODOMETRY's attitude (link/wire.py).

The vehicle's side has its own copy (sil_vehicle/frames.py): the two packages share no code
but trq_wire's, and rotations are not part of the wire.

Pure functions; no state.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["rotation_ned_frd", "rotation_rows", "quat_to_euler"]

_SYMBOLIC = (ca.SX, ca.MX, ca.DM)


def rotation_ned_frd(roll, pitch, yaw):
    """R taking body FRD vectors to world NED for ZYX Euler angles (rad): a CasADi 3x3 when any
    angle is a CasADi expression, else a NumPy (3, 3) array."""
    symbolic = not (type(roll) is type(pitch) is type(yaw) is float
                    or type(roll) is type(pitch) is type(yaw) is np.float64) \
        and any(isinstance(a, _SYMBOLIC) for a in (roll, pitch, yaw))
    if symbolic:
        return ca.vertcat(*(ca.horzcat(*r) for r in _rows(roll, pitch, yaw, ca.cos, ca.sin)))
    return np.array(_rows(roll, pitch, yaw, math.cos, math.sin))


def rotation_rows(roll: float, pitch: float, yaw: float) -> tuple:
    """rotation_ned_frd's matrix of float angles as its three rows, tuples of floats (for
    products written out in a fixed order: the fused filter's, which its C core repeats)."""
    return _rows(roll, pitch, yaw, math.cos, math.sin)


def _rows(roll, pitch, yaw, cos, sin) -> tuple:
    cr, sr = cos(roll), sin(roll)
    cp, sp = cos(pitch), sin(pitch)
    cy, sy = cos(yaw), sin(yaw)
    return ((cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
            (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
            (-sp, sr * cp, cr * cp))


def quat_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw, rad) of a unit quaternion, scalar first."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
