"""A GNSS fix from the wire in the vehicle's local NED frame (PROTOCOL.md: GPS_RAW_INT under a
sensing profile with a receiver, HOME_POSITION the origin of NED).

    home = home_of(home_position_msg)          # (lat degE7, lon degE7, alt mm), or None
    fix = fix_of(gps_raw_int_msg, home)        # records.PositionFix, or None

`fix_of` keeps a fix of fix_type 3 (3D) or better with finite fields, takes `time_usec` as its
time of validity (it arrives the receiver's delay later), turns lat/lon/alt around home into
NED with trq_wire.geodetic (the vehicle's own flat earth, inverted), and gives its 1-sigma
errors per axis: h_acc / v_acc (mm; eph / epv in cm when the MAVLink 2 extensions are absent
or zero), each with the variance of the degE7 / mm rounding added (step^2 / 12). Errors the fix
does not state are NaN (the filter then uses its configured noise). Pure.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.records import PositionFix
from trq_wire.geodetic import e7_step_m, e7_to_ned

__all__ = ["MIN_FIX_TYPE", "fix_of", "home_of"]

MIN_FIX_TYPE = mavlink.GPS_FIX_TYPE_3D_FIX     # 2D and no-fix reports are not positions
_U16_UNKNOWN = 65535                           # eph, epv: unknown
_U32_UNKNOWN = 2**32 - 1


def home_of(msg) -> tuple[int, int, int] | None:
    """HOME_POSITION's (lat degE7, lon degE7, alt mm AMSL): the origin of the NED frame."""
    home = (int(msg.latitude), int(msg.longitude), int(msg.altitude))
    if not (-900_000_000 <= home[0] <= 900_000_000 and -1_800_000_000 <= home[1] <= 1_800_000_000):
        return None
    return home


def _sigma_m(acc_mm: int, ep_cm: int) -> float:
    """The fix's stated 1-sigma error (m): h_acc / v_acc in mm if given, else eph / epv in cm,
    else NaN."""
    if 0 < acc_mm < _U32_UNKNOWN:
        return acc_mm * 1e-3
    if 0 < ep_cm < _U16_UNKNOWN:
        return ep_cm * 1e-2
    return math.nan


def fix_of(msg, home: tuple[int, int, int]) -> PositionFix | None:
    """GPS_RAW_INT as a position in NED around `home` at its time of validity (module
    docstring); None below a 3D fix."""
    if msg.fix_type < MIN_FIX_TYPE:
        return None
    pos = e7_to_ned(msg.lat, msg.lon, msg.alt, home)
    if not all(math.isfinite(v) for v in pos):
        return None
    h = _sigma_m(getattr(msg, "h_acc", 0), msg.eph)
    v = _sigma_m(getattr(msg, "v_acc", 0), msg.epv)
    step = e7_step_m(home[0])
    std = (math.sqrt(h * h + step[0] ** 2 / 12.0), math.sqrt(h * h + step[1] ** 2 / 12.0),
           math.sqrt(v * v + step[2] ** 2 / 12.0))
    return PositionFix(int(msg.time_usec), pos, std)
