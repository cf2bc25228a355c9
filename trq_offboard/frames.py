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

__all__ = ["rotation_ned_frd", "quat_to_euler"]

_SYMBOLIC = (ca.SX, ca.MX, ca.DM)


def rotation_ned_frd(roll, pitch, yaw):
    """R taking body FRD vectors to world NED for ZYX Euler angles (rad): a CasADi 3x3 when any
    angle is a CasADi expression, else a NumPy (3, 3) array."""
    symbolic = not (type(roll) is type(pitch) is type(yaw) is float
                    or type(roll) is type(pitch) is type(yaw) is np.float64) \
        and any(isinstance(a, _SYMBOLIC) for a in (roll, pitch, yaw))
    cos, sin = (ca.cos, ca.sin) if symbolic else (math.cos, math.sin)
    cr, sr = cos(roll), sin(roll)
    cp, sp = cos(pitch), sin(pitch)
    cy, sy = cos(yaw), sin(yaw)
    rows = ((cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
            (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
            (-sp, sr * cp, cr * cp))
    if symbolic:
        return ca.vertcat(*(ca.horzcat(*r) for r in rows))
    return np.array(rows)


def quat_to_euler(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw, rad) of a unit quaternion, scalar first."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
