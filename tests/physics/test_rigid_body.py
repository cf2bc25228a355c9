"""Rigid-body invariants (sil_vehicle.dynamics.rigid_body, environment): free fall, terminal
velocity, conservation without torque, drag from wind, gust statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.dynamics.environment import drag_force_ned, gust_coefficients, gust_step
from sil_vehicle.dynamics.rigid_body import derivative, rk4_step
from sil_vehicle.frames import euler_to_quat, quat_to_dcm

ZERO_WRENCH = (0.0,) * 6
CALM = (0.0, 0.0, 0.0)
G = 9.80665


def state(pos=(0.0, 0.0, -100.0), vel=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0), w=(0.0, 0.0, 0.0)):
    return tuple(pos) + tuple(vel) + tuple(q) + tuple(w)


def angular_momentum_world(x, inertia):
    R = np.array(quat_to_dcm(*x[6:10]))
    return R @ (np.array(inertia) * np.array(x[10:13]))


@pytest.mark.parametrize("inertia", [(0.01241, 0.01241, 0.02365),     # the trq airframe
                                     (0.01, 0.02, 0.035)])             # fully asymmetric
def test_torque_free_spin_conserves_angular_momentum(inertia):
    # a spin about no principal axis: the body rates wander, I w in the world frame does not
    x = state(q=euler_to_quat(0.2, -0.4, 1.0), w=(1.5, -2.0, 3.0))
    L0 = angular_momentum_world(x, inertia)
    E0 = 0.5 * sum(i * w * w for i, w in zip(inertia, x[10:13]))
    dt = 0.001
    for _ in range(2000):                                 # 2 s at 1 kHz
        x = rk4_step(x, dt, ZERO_WRENCH, CALM, 2.1, inertia, 0.0, 0.0)
    L1 = angular_momentum_world(x, inertia)
    E1 = 0.5 * sum(i * w * w for i, w in zip(inertia, x[10:13]))
    assert np.linalg.norm(L1 - L0) / np.linalg.norm(L0) < 1e-6
    assert abs(np.linalg.norm(L1) - np.linalg.norm(L0)) / np.linalg.norm(L0) < 1e-6
    assert abs(E1 - E0) / E0 < 1e-6
    assert math.isclose(sum(c * c for c in x[6:10]), 1.0, abs_tol=1e-12)
    if inertia[0] != inertia[1]:
        assert abs(x[10] - 1.5) > 0.01                    # the rates did change: a real test


def test_free_fall_rk4_is_exact():
    x = state(q=euler_to_quat(0.3, 0.2, -1.0), w=(0.1, 0.2, 0.3))   # attitude is irrelevant
    for _ in range(1000):
        x = rk4_step(x, 0.001, ZERO_WRENCH, CALM, 2.1, (0.01, 0.01, 0.02), G, 0.0)
    assert x[5] == pytest.approx(G * 1.0, rel=1e-9)
    assert x[2] == pytest.approx(-100.0 + 0.5 * G, rel=1e-9)
    assert x[3] == 0.0 and x[4] == 0.0


def test_thrust_is_rotated_into_the_world():
    # rolled right by 30 deg, 10 N up the body z: horizontal force east 10 sin 30 = 5 N
    q = euler_to_quat(math.radians(30), 0.0, 0.0)
    d = derivative(state(q=q), (0.0, 0.0, -10.0, 0.0, 0.0, 0.0), CALM, 2.0, (1, 1, 1), G, 0.0)
    assert d[3] == pytest.approx(0.0, abs=1e-12)
    assert d[4] == pytest.approx(5.0 / 2.0, rel=1e-12)
    assert d[5] == pytest.approx(G - 10.0 * math.cos(math.radians(30)) / 2.0, rel=1e-12)


def test_moment_gives_angular_acceleration():
    d = derivative(state(), (0.0, 0.0, 0.0, 0.1, -0.2, 0.3), CALM, 2.0, (0.01, 0.02, 0.03), G, 0.0)
    assert d[10:13] == pytest.approx((10.0, -10.0, 10.0), rel=1e-12)


@pytest.mark.parametrize("wind, force", [((8.0, 0.0, 0.0), (2.0, 0.0, 0.0)),
                                         ((0.0, -8.0, 0.0), (0.0, -2.0, 0.0))])
def test_wind_drag_on_a_vehicle_at_rest(wind, force):
    k, m = 0.03125, 2.1
    assert drag_force_ned(CALM, wind, k) == pytest.approx(force, rel=1e-12)    # 0.03125 * 64
    d = derivative(state(), ZERO_WRENCH, wind, m, (1, 1, 1), G, k)
    assert (m * d[3], m * d[4], m * (d[5] - G)) == pytest.approx(force, rel=1e-12)


def test_terminal_velocity():
    m, k = 2.1, 0.03125
    vt = math.sqrt(m * G / k)                                      # 25.67 m/s
    x = state(pos=(0.0, 0.0, -5000.0), vel=(0.0, 0.0, vt))
    for _ in range(1000):
        x = rk4_step(x, 0.001, ZERO_WRENCH, CALM, m, (1, 1, 1), G, k)
    assert x[5] == pytest.approx(vt, rel=1e-9)                     # no net force: it stays
    # from rest: v(t) = vt tanh(g t / vt)
    x = state(pos=(0.0, 0.0, -5000.0))
    for _ in range(3000):
        x = rk4_step(x, 0.001, ZERO_WRENCH, CALM, m, (1, 1, 1), G, k)
    assert x[5] == pytest.approx(vt * math.tanh(G * 3.0 / vt), rel=1e-8)


def test_gust_statistics():
    sigma, length, speed, dt = 1.5, 50.0, 10.0, 0.01
    a, b = gust_coefficients(sigma, length, speed, dt)
    assert a == pytest.approx(math.exp(-speed * dt / length))
    assert b == pytest.approx(sigma * math.sqrt(1 - a * a))
    rng = np.random.default_rng(12345)
    noise = rng.standard_normal((100_000, 3))
    g = (0.0, 0.0, 0.0)
    out = np.empty((len(noise), 3))
    for i, w in enumerate(noise):
        g = gust_step(g, w, a, b)
        out[i] = g
    out = out[2000:]                                         # past the start-up transient
    assert out.std(axis=0) == pytest.approx([sigma] * 3, rel=0.15)
    lag1 = np.mean([np.corrcoef(out[:-1, j], out[1:, j])[0, 1] for j in range(3)])
    assert lag1 == pytest.approx(a, abs=2e-3)


def test_gust_airspeed_floor():
    assert gust_coefficients(1.0, 50.0, 0.0, 0.001) == gust_coefficients(1.0, 50.0, 1.0, 0.001)
    assert gust_coefficients(0.0, 50.0, 5.0, 0.001)[1] == 0.0
