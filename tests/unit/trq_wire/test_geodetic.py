"""The shared flat-earth conversion (trq_wire/geodetic.py): the companion's inverse of the
vehicle's degE7 / mm fields, by hand and round trip."""

from __future__ import annotations

import math

import pytest

from trq_wire.geodetic import EARTH_RADIUS_M, e7_step_m, e7_to_ned, ned_to_geodetic, to_e7

HOME = (51.5246, -0.134, 30.0)
HOME_E7 = (515_246_000, -1_340_000, 30_000)


def test_home_in_its_fields():
    assert to_e7(*HOME) == HOME_E7
    assert e7_to_ned(*HOME_E7, HOME_E7) == (0.0, 0.0, 0.0)


def test_one_unit_of_each_field_by_hand():
    north, east, down = e7_step_m(HOME_E7[0])
    assert north == pytest.approx(math.radians(1e-7) * EARTH_RADIUS_M, rel=1e-12)   # ~1.1 cm
    assert east == pytest.approx(north * math.cos(math.radians(51.5246)), rel=1e-12)
    assert down == 1e-3
    lat, lon, alt = HOME_E7
    assert e7_to_ned(lat + 1, lon, alt, HOME_E7) == pytest.approx((north, 0.0, 0.0), rel=1e-6)
    assert e7_to_ned(lat, lon + 1, alt, HOME_E7)[1] == pytest.approx(east, rel=1e-6)
    assert e7_to_ned(lat, lon, alt + 1, HOME_E7)[2] == pytest.approx(-1e-3, rel=1e-9)


@pytest.mark.parametrize("pos", [(0.3, -0.2, -1.0), (150.0, -75.25, -40.0), (-0.006, 0.004, 0.0)])
def test_the_fields_back_to_ned_within_half_a_step(pos):
    fields = to_e7(*ned_to_geodetic(*pos, *HOME))
    back = e7_to_ned(*fields, HOME_E7)
    for got, want, step in zip(back, pos, e7_step_m(HOME_E7[0])):
        assert abs(got - want) <= 0.5 * step + 1e-9
