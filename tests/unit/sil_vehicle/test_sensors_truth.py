"""The truth the IMU reads (sil_vehicle.sensors.truth.imu_truth): the rates from the attitude's
change over a tick (exact for a constant rate, the shorter way round, a touchdown's levelling
seen as a rotation), the specific force in the tick's middle attitude."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.frames import euler_to_quat, quat_to_dcm, quat_to_euler
from sil_vehicle.sensors.truth import imu_truth


def quat_mul(p, q):
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw)


G = 9.80665
V = (1.0, -2.0, 0.5)


def mean_rates_frd(q0, q1, dt):
    return imu_truth(q0, q1, V, V, dt, G)[0]


def rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return (math.cos(angle / 2), *(math.sin(angle / 2) * a))


@pytest.mark.parametrize("rates", [(0.0, 0.0, 0.0), (0.3, -0.2, 1.5), (20.0, 0.0, -5.0),
                                   (1e-7, 0.0, 0.0)])
def test_a_constant_rate_is_read_exactly(rates):
    q0 = euler_to_quat(0.3, -0.2, 2.0)
    dt = 1e-3
    w = np.array(rates)
    angle = float(np.linalg.norm(w)) * dt
    q1 = quat_mul(q0, rotation(w if angle else (1, 0, 0), angle))    # body-frame increment
    assert mean_rates_frd(q0, q1, dt) == pytest.approx(rates, abs=1e-9)


def test_the_sign_of_the_quaternion_does_not_matter():
    q0 = euler_to_quat(0.1, 0.2, 0.3)
    q1 = quat_mul(q0, rotation((0, 0, 1), 0.01))
    minus = tuple(-c for c in q1)
    assert mean_rates_frd(q0, minus, 1e-3) == pytest.approx(mean_rates_frd(q0, q1, 1e-3))


def test_a_touchdown_levelling_is_a_rotation_that_integrates_back():
    q0 = euler_to_quat(math.radians(23.6), math.radians(-16.7), math.radians(-102.0))
    yaw = quat_to_euler(*q0)[2]
    q1 = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    r = np.array(mean_rates_frd(q0, q1, 1e-3)) * 1e-3
    back = quat_mul(q0, rotation(r, float(np.linalg.norm(r))))
    assert np.allclose(back, q1, atol=1e-12)


def test_at_rest_it_reads_minus_g_in_any_attitude_frame():
    q = euler_to_quat(0.0, 0.0, 1.0)
    rates, f = imu_truth(q, q, V, V, 1e-3, G)
    assert rates == (0.0, 0.0, 0.0) and f == pytest.approx((0.0, 0.0, -G), abs=1e-12)


def test_the_force_is_rotated_at_the_middle_attitude():
    q0 = euler_to_quat(0.2, -0.1, 0.7)
    axis, angle = (0.3, -1.0, 0.4), 0.05                     # a 50 rad/s tick, to see it
    q1 = quat_mul(q0, rotation(axis, angle))
    mid = quat_mul(q0, rotation(axis, angle / 2))
    v0, v1, dt = (0.0, 0.0, 0.0), (0.01, -0.02, 0.03), 1e-3
    a_minus_g = np.array(v1) / dt - (0.0, 0.0, G)
    _, f = imu_truth(q0, q1, v0, v1, dt, G)
    assert f == pytest.approx(np.array(quat_to_dcm(*mid)).T @ a_minus_g, abs=1e-9)
    # and not at the end (the difference is what the test can see)
    assert not np.allclose(f, np.array(quat_to_dcm(*q1)).T @ a_minus_g, atol=1e-3)
