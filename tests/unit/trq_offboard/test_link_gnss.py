"""A GNSS fix from the wire in NED (trq_offboard/link/gnss.py), against the vehicle's own: the
vehicle's codec forms GPS_RAW_INT and HOME_POSITION from a NED position, the bytes go through
MAVLink, and the companion's conversion gives the position back within what degE7 and mm
carry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.mavlink import codec
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sensors.gnss import GnssReading
from trq_offboard.link import gnss
from trq_wire.geodetic import e7_step_m

HOME = (51.5246, -0.134, 30.0)          # params/sim/default.yaml's home


def wire(msg):
    (back,) = Codec().decode(Codec().encode(msg))
    return back


def reading(pos, fix=6, eph=0.0104, epv=0.0112):
    return GnssReading(1_200_000, 1_310_000, np.array(pos, float), np.zeros(3), fix, 24, eph,
                       epv, 0.05)


@pytest.mark.parametrize("pos", [(0.0, 0.0, 0.0), (1.234, -0.567, -2.5), (12.345, -67.891, -4.321),
                                 (-250.0, 180.5, -30.0), (0.004, 0.003, -0.0004)])
def test_a_fix_comes_back_to_the_vehicles_ned_within_the_rounding(pos):
    home = gnss.home_of(wire(codec.home_position(HOME, 0)))
    # stamped at its arrival (as PX4 stamps it); the companion's delay takes it back
    fix = gnss.fix_of(wire(codec.gnss_raw_int(reading(pos), HOME)), home, 110_000)
    assert fix.t_us == 1_200_000                          # its time of validity, not arrival
    step = e7_step_m(home[0])
    for got, want, s in zip(fix.pos_ned_m, pos, step):
        assert abs(got - want) <= 0.5 * s + 1e-9
    # its noise: the receiver's stated 1 sigma (h_acc, v_acc: whole mm) and the rounding's
    assert fix.std_ned_m == pytest.approx(
        (math.hypot(0.010, step[0] / math.sqrt(12)), math.hypot(0.010, step[1] / math.sqrt(12)),
         math.hypot(0.011, step[2] / math.sqrt(12))), rel=1e-6)


def test_the_conversion_is_the_vehicles_inverse_on_a_grid_of_positions():
    """Many positions around home: the error is the rounding's alone (at most half a step,
    spread over the whole step: no bias from the frame)."""
    rng = np.random.default_rng(4)
    home = gnss.home_of(wire(codec.home_position(HOME, 0)))
    step = np.array(e7_step_m(home[0]))
    errs = []
    for pos in rng.uniform([-50, -50, -20], [50, 50, 0], size=(400, 3)):
        fix = gnss.fix_of(codec.gnss_raw_int(reading(pos), HOME), home)
        errs.append(np.array(fix.pos_ned_m) - pos)
    errs = np.array(errs)
    assert np.all(np.abs(errs) <= 0.5 * step + 1e-9)
    assert np.all(np.abs(errs.mean(axis=0)) < 0.1 * step)
    assert np.all(np.abs(errs).max(axis=0) > 0.4 * step)


@pytest.mark.parametrize("fix_type", [mavlink.GPS_FIX_TYPE_NO_GPS, mavlink.GPS_FIX_TYPE_NO_FIX,
                                      mavlink.GPS_FIX_TYPE_2D_FIX])
def test_below_a_3d_fix_is_no_position(fix_type):
    home = gnss.home_of(codec.home_position(HOME, 0))
    assert gnss.fix_of(codec.gnss_raw_int(reading((1.0, 2.0, -3.0), fix=fix_type), HOME),
                       home) is None
    assert gnss.fix_of(codec.gnss_raw_int(reading((1.0, 2.0, -3.0), fix=3), HOME),
                       home) is not None


def test_the_noise_is_h_acc_v_acc_never_the_dops():
    """eph / epv are HDOP / VDOP x100 (PX4 fills them so): a fix without h_acc / v_acc states
    no error, whatever its DOPs."""
    home = gnss.home_of(codec.home_position(HOME, 0))
    msg = codec.gnss_raw_int(reading((1.0, 2.0, -3.0), eph=2.0, epv=4.0), HOME)
    fix = gnss.fix_of(msg, home)
    assert fix.std_ned_m[0] == pytest.approx(2.0, rel=1e-4)
    assert fix.std_ned_m[2] == pytest.approx(4.0, rel=1e-4)
    assert fix.t_us == msg.time_usec                        # no delay configured
    msg.h_acc = msg.v_acc = 0                               # MAVLink 1: no extensions
    assert (msg.eph, msg.epv) == (70, 110)
    assert all(math.isnan(s) for s in gnss.fix_of(msg, home).std_ned_m)


def test_a_home_out_of_range_is_none():
    msg = codec.home_position(HOME, 0)
    msg.latitude = 1_000_000_000
    assert gnss.home_of(msg) is None
