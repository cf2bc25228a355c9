"""The raw sensors' messages (sil_vehicle.mavlink.codec): HIGHRES_IMU, GPS_RAW_INT of a GNSS
receiver, ATT_POS_MOCAP, against hand-computed fields, and through the wire (pack, decode)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.frames import geodetic_to_ned, ned_to_geodetic
from sil_vehicle.mavlink import codec
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sensors.baro import BaroReading
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mag import MagReading
from sil_vehicle.sensors.mocap import MocapReading

HOME = (51.5246, -0.134, 30.0)


def wire(msg):
    (back,) = Codec().decode(Codec().encode(msg))
    return back


def test_highres_imu_fields_and_units():
    imu = ImuReading(20_000, np.array((0.1, -0.2, 0.3)), np.array((0.5, 0.25, -9.75)))
    baro = BaroReading(20_000, 100_000.0, 110.5, 14.25)
    mag = MagReading(10_000, np.array((0.2, 0.0, 0.45)))
    m = wire(codec.highres_imu(imu, baro, mag, codec.IMU_FIELDS | codec.BARO_FIELDS))
    assert m.time_usec == 20_000
    assert (m.xacc, m.yacc, m.zacc) == (0.5, 0.25, -9.75)
    assert (m.xgyro, m.ygyro, m.zgyro) == pytest.approx((0.1, -0.2, 0.3), abs=1e-7)
    assert (m.xmag, m.ymag, m.zmag) == pytest.approx((0.2, 0.0, 0.45), abs=1e-7)
    assert m.abs_pressure == 1000.0 and m.diff_pressure == 0.0        # hPa
    assert (m.pressure_alt, m.temperature) == (110.5, 14.25)
    assert m.fields_updated == 0x1A3F == (0x3F | 0x200 | 0x800 | 0x1000)
    assert codec.MAG_FIELDS == 0x1C0


def test_highres_imu_without_baro_and_mag():
    imu = ImuReading(0, np.zeros(3), np.array((0.0, 0.0, -9.80665)))
    m = wire(codec.highres_imu(imu, None, None, codec.IMU_FIELDS))
    assert (m.xmag, m.abs_pressure, m.pressure_alt) == (0.0, 0.0, 0.0)
    assert m.fields_updated == codec.IMU_FIELDS


def gnss(pos, vel, fix=6):
    return GnssReading(1_200_000, 1_310_000, np.array(pos), np.array(vel), fix, 24, 0.0104,
                       0.0112, 0.05)


def test_gps_raw_int_of_a_receiver_by_hand():
    m = wire(codec.gnss_raw_int(gnss((1.0, 2.0, -3.0), (3.0, 4.0, -0.5)), HOME))
    # as PX4 fills it: the arrival's time, the DOPs x100 in eph / epv, the accuracies in mm
    assert m.time_usec == 1_310_000 and m.fix_type == 6 and m.satellites_visible == 24
    assert m.alt == 33_000 and m.alt_ellipsoid == 33_000             # mm AMSL
    assert (m.eph, m.epv) == (70, 110)                                # HDOP 0.7, VDOP 1.1
    assert (m.h_acc, m.v_acc, m.vel_acc) == (10, 11, 50)              # mm, mm/s
    assert m.vel == 500                                               # cm/s
    assert m.cog == round(math.degrees(math.atan2(4.0, 3.0)) * 100)   # cdeg
    slow = wire(codec.gnss_raw_int(gnss((0, 0, 0), (0.1, 0.0, 0.0), fix=3), HOME))
    assert slow.cog == 65535 and slow.fix_type == 3


@pytest.mark.parametrize("pos", [(0.0, 0.0, 0.0), (12.345, -67.891, -4.321),
                                 (-250.0, 180.5, -30.0)])
def test_gps_raw_int_lat_lon_round_trip(pos):
    """NED -> degE7 -> NED: within what degE7 and mm carry (half a step), and the conversion
    before rounding within a millimetre."""
    m = codec.gnss_raw_int(gnss(pos, (0.0, 0.0, 0.0)), HOME)
    n, e, d = geodetic_to_ned(m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, *HOME)
    half_n = math.radians(0.5e-7) * 6_378_137.0
    half_e = half_n * math.cos(math.radians(HOME[0]))
    assert abs(n - pos[0]) <= half_n + 1e-9 and abs(e - pos[1]) <= half_e + 1e-9
    assert abs(d - pos[2]) <= 0.0005 + 1e-9
    assert codec.geodetic_e7(pos, HOME) == (m.lat, m.lon, m.alt)
    back = geodetic_to_ned(*ned_to_geodetic(*pos, *HOME), *HOME)
    assert back == pytest.approx(pos, abs=1e-3)


def test_att_pos_mocap():
    q = np.array((math.cos(0.3), 0.0, 0.0, math.sin(0.3)))
    m = wire(codec.att_pos_mocap(MocapReading(50_000, 60_000, np.array((1.5, -2.0, -0.75)), q)))
    assert m.time_usec == 50_000 and (m.x, m.y, m.z) == (1.5, -2.0, -0.75)
    assert m.q == pytest.approx(list(q), abs=1e-7)
    assert math.isnan(m.covariance[0])                     # unknown, as MAVLink asks
    assert m.get_msgId() == mavlink.MAVLINK_MSG_ID_ATT_POS_MOCAP
