"""A GNSS fix from the wire in the vehicle's local NED frame (PROTOCOL.md: GPS_RAW_INT under a
sensing profile with a receiver, HOME_POSITION the origin of NED).

    home = home_of(home_position_msg)          # (lat degE7, lon degE7, alt mm), or None
    fix = fix_of(gps_raw_int_msg, home, delay_us)   # records.PositionFix, or None

`fix_of` keeps a fix of fix_type 3 (3D) or better with finite fields. Its time of validity is
`time_usec` less `delay_us`: PX4 stamps GPS_RAW_INT with the time its driver published the fix
(sensor_gps.timestamp), which is the receiver's delay after the fix is valid, and EKF2 takes it
back with its configured EKF2_GPS_DELAY; so does the companion with its own figure. It turns
lat/lon/alt around home into NED with trq_wire.geodetic (the vehicle's own flat earth,
inverted), and gives its 1-sigma errors per axis from h_acc / v_acc (mm, the MAVLink 2
extensions), each with the variance of the degE7 / mm rounding added (step^2 / 12). eph / epv
are dilutions of precision (x100, unitless), not errors: never read as metres. Errors the fix
does not state (h_acc / v_acc 0 or unknown) are NaN (the filter then uses its configured
noise). Pure.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.records import PositionFix
from trq_wire.geodetic import e7_step_m, e7_to_ned

__all__ = ["MIN_FIX_TYPE", "fix_of", "home_of"]

MIN_FIX_TYPE = mavlink.GPS_FIX_TYPE_3D_FIX     # 2D and no-fix reports are not positions
_U32_UNKNOWN = 2**32 - 1


def home_of(msg) -> tuple[int, int, int] | None:
    """HOME_POSITION's (lat degE7, lon degE7, alt mm AMSL): the origin of the NED frame."""
    home = (int(msg.latitude), int(msg.longitude), int(msg.altitude))
    if not (-900_000_000 <= home[0] <= 900_000_000 and -1_800_000_000 <= home[1] <= 1_800_000_000):
        return None
    return home


def _sigma_m(acc_mm: int) -> float:
    """The fix's stated 1-sigma error (m) from h_acc / v_acc (mm), NaN if not stated."""
    if 0 < acc_mm < _U32_UNKNOWN:
        return acc_mm * 1e-3
    return math.nan


def fix_of(msg, home: tuple[int, int, int], delay_us: int = 0) -> PositionFix | None:
    """GPS_RAW_INT as a position in NED around `home` at its time of validity, `delay_us`
    before its stamp (module docstring); None below a 3D fix."""
    if msg.fix_type < MIN_FIX_TYPE:
        return None
    pos = e7_to_ned(msg.lat, msg.lon, msg.alt, home)
    if not all(math.isfinite(v) for v in pos):
        return None
    h = _sigma_m(getattr(msg, "h_acc", 0))
    v = _sigma_m(getattr(msg, "v_acc", 0))
    step = e7_step_m(home[0])
    std = (math.sqrt(h * h + step[0] ** 2 / 12.0), math.sqrt(h * h + step[1] ** 2 / 12.0),
           math.sqrt(v * v + step[2] ** 2 / 12.0))
    return PositionFix(int(msg.time_usec) - delay_us, pos, std)
