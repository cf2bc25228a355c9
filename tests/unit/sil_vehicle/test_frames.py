"""Frames and conversions (sil_vehicle.frames): round trips and hand-checked special cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sil_vehicle.frames import (EARTH_RADIUS_M, euler_to_quat, geodetic_to_ned, ned_to_geodetic,
                                quat_to_dcm, quat_to_euler, tilt_from_vertical, wind_from_to_ned,
                                wrap_pi)

from conftest import examples

angle = st.floats(-math.pi, math.pi, allow_nan=False)
pitch_ok = st.floats(-1.5, 1.5, allow_nan=False)     # away from gimbal lock


@settings(max_examples=examples(200), deadline=None)
@given(angle, pitch_ok, angle)
def test_euler_quat_round_trip(roll, pitch, yaw):
    q = euler_to_quat(roll, pitch, yaw)
    assert math.isclose(sum(c * c for c in q), 1.0, abs_tol=1e-12)
    r2, p2, y2 = quat_to_euler(*q)
    assert abs(wrap_pi(r2 - roll)) < 1e-9
    assert abs(p2 - pitch) < 1e-9
    assert abs(wrap_pi(y2 - yaw)) < 1e-9


@settings(max_examples=examples(100), deadline=None)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4))
def test_quat_euler_round_trip_up_to_sign(raw):
    n = math.sqrt(sum(c * c for c in raw))
    if n < 0.1:
        return
    q = np.array(raw) / n
    roll, pitch, yaw = quat_to_euler(*q)
    if abs(abs(pitch) - math.pi / 2) < 1e-3:
        return                                  # gimbal lock: the angles are not unique
    q2 = np.array(euler_to_quat(roll, pitch, yaw))
    assert min(np.abs(q2 - q).max(), np.abs(q2 + q).max()) < 1e-9   # q and -q: same rotation


def test_euler_to_quat_special_cases():
    # yaw 90 deg: q = (cos 45, 0, 0, sin 45)
    np.testing.assert_allclose(euler_to_quat(0, 0, math.pi / 2),
                               (math.sqrt(0.5), 0, 0, math.sqrt(0.5)), atol=1e-15)
    # roll 90 deg
    np.testing.assert_allclose(euler_to_quat(math.pi / 2, 0, 0),
                               (math.sqrt(0.5), math.sqrt(0.5), 0, 0), atol=1e-15)


def test_dcm_takes_body_to_world():
    # yaw +90 deg (nose east): body x (forward) is world east, body y (right) is world south
    R = np.array(quat_to_dcm(*euler_to_quat(0.0, 0.0, math.pi / 2)))
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(R @ [0, 1, 0], [-1, 0, 0], atol=1e-15)
    # pitch +30 deg (nose up): body x points up (negative down component)
    R = np.array(quat_to_dcm(*euler_to_quat(0.0, math.radians(30), 0.0)))
    np.testing.assert_allclose(R @ [1, 0, 0], [math.cos(math.radians(30)), 0, -0.5], atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)


def test_tilt_from_vertical():
    assert tilt_from_vertical(1, 0, 0, 0) == 0.0
    assert math.isclose(tilt_from_vertical(*euler_to_quat(0.3, 0, 1.0)), 0.3, rel_tol=1e-12)
    assert math.isclose(tilt_from_vertical(0, 1, 0, 0), math.pi, rel_tol=1e-12)


@settings(max_examples=examples(200), deadline=None)
@given(st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(-500, 500),
       st.floats(-80, 80), st.floats(-179, 179), st.floats(-100, 3000))
def test_ned_geodetic_round_trip(n, e, d, lat0, lon0, alt0):
    lat, lon, alt = ned_to_geodetic(n, e, d, lat0, lon0, alt0)
    n2, e2, d2 = geodetic_to_ned(lat, lon, alt, lat0, lon0, alt0)
    assert abs(n2 - n) < 1e-6 and abs(e2 - e) < 1e-6 and abs(d2 - d) < 1e-9


def test_ned_to_geodetic_hand_values():
    # 1 km north at the equator: 1000 / R rad of latitude; down is minus altitude
    lat, lon, alt = ned_to_geodetic(1000.0, 0.0, -20.0, 0.0, 10.0, 30.0)
    assert math.isclose(lat, math.degrees(1000.0 / EARTH_RADIUS_M), rel_tol=1e-12)
    assert lon == 10.0
    assert alt == 50.0
    # east at 60 deg latitude: a degree of longitude is half as long
    _, lon, _ = ned_to_geodetic(0.0, 1000.0, 0.0, 60.0, 0.0, 0.0)
    assert math.isclose(lon, math.degrees(2000.0 / EARTH_RADIUS_M), rel_tol=1e-9)


@pytest.mark.parametrize("from_deg, expected", [
    (0.0, (-8.0, 0.0, 0.0)),      # from north: blows towards the south
    (90.0, (0.0, -8.0, 0.0)),     # from east: blows towards the west
    (180.0, (8.0, 0.0, 0.0)),     # from south: blows north
    (270.0, (0.0, 8.0, 0.0)),     # from west: blows east
    (-90.0, (0.0, 8.0, 0.0)),
])
def test_wind_from_to_ned(from_deg, expected):
    np.testing.assert_allclose(wind_from_to_ned(8.0, from_deg), expected, atol=1e-12)


def test_wrap_pi():
    assert math.isclose(wrap_pi(3 * math.pi / 2), -math.pi / 2)
    assert math.isclose(wrap_pi(-3 * math.pi / 2), math.pi / 2)
    assert wrap_pi(0.25) == 0.25
