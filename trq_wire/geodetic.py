"""The vehicle's local NED frame and geodetic coordinates: the one flat-earth conversion both ends
use (PROTOCOL.md: GLOBAL_POSITION_INT, GPS_RAW_INT and HOME_POSITION carry lat, lon in degE7 and
alt in mm AMSL of a NED position around home).

The vehicle forms a fix's lat/lon/alt from its NED position with `ned_to_geodetic` and rounds to
degE7 and mm (`to_e7`); a companion that reads the fix turns it back into NED around the home
it was sent (HOME_POSITION) with `e7_to_ned`, the exact inverse before the rounding. What the
rounding leaves (`e7_step_m`): about 1.1 cm of latitude, less of longitude, 1 mm of altitude.

Flat earth around home: fine for the few hundred metres a flight covers. Pure functions.
"""

from __future__ import annotations

import math

__all__ = ["EARTH_RADIUS_M", "e7_step_m", "e7_to_ned", "geodetic_to_ned", "ned_to_geodetic",
           "to_e7"]

EARTH_RADIUS_M = 6_378_137.0   # WGS-84 equatorial radius


def ned_to_geodetic(north_m: float, east_m: float, down_m: float, lat0_deg: float,
                    lon0_deg: float, alt0_m: float) -> tuple[float, float, float]:
    """Local NED around a home point to (lat_deg, lon_deg, alt_m AMSL): flat earth, fine for
    the few hundred metres a SIL flight covers."""
    lat = lat0_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = lon0_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0_deg))))
    return lat, lon, alt0_m - down_m


def geodetic_to_ned(lat_deg: float, lon_deg: float, alt_m: float, lat0_deg: float,
                    lon0_deg: float, alt0_m: float) -> tuple[float, float, float]:
    """The inverse of `ned_to_geodetic` (same home, same flat earth)."""
    north = math.radians(lat_deg - lat0_deg) * EARTH_RADIUS_M
    east = math.radians(lon_deg - lon0_deg) * EARTH_RADIUS_M * math.cos(math.radians(lat0_deg))
    return north, east, alt0_m - alt_m


def to_e7(lat_deg: float, lon_deg: float, alt_m: float) -> tuple[int, int, int]:
    """(lat degE7, lon degE7, alt mm) as MAVLink's integer fields carry them (rounded)."""
    return int(round(lat_deg * 1e7)), int(round(lon_deg * 1e7)), int(round(alt_m * 1000.0))


def e7_to_ned(lat_e7: int, lon_e7: int, alt_mm: int,
              home_e7: tuple[int, int, int]) -> tuple[float, float, float]:
    """A fix's (lat degE7, lon degE7, alt mm) in NED metres around home (its HOME_POSITION
    lat, lon degE7 and alt mm): `geodetic_to_ned` of the fields' values."""
    h_lat, h_lon, h_alt = home_e7
    return geodetic_to_ned(lat_e7 * 1e-7, lon_e7 * 1e-7, alt_mm * 1e-3, h_lat * 1e-7,
                           h_lon * 1e-7, h_alt * 1e-3)


def e7_step_m(home_lat_e7: int) -> tuple[float, float, float]:
    """What one unit of each integer field is in metres around home (north, east, down): the
    resolution a fix carries; rounding leaves at most half of it, uniformly spread (a variance
    of step^2 / 12)."""
    north = math.radians(1e-7) * EARTH_RADIUS_M
    return north, north * math.cos(math.radians(home_lat_e7 * 1e-7)), 1e-3
