"""The output predictor (sil_vehicle.estimator.predictor): dead reckoning on exact IMU samples,
and EKF2's complementary correction pulling the output track onto the filter's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.estimator.predictor import OutputPredictor

G = 9.80665


def predictor(**kw) -> OutputPredictor:
    return OutputPredictor(gravity_m_s2=G, imu_period_us=1000, filter_period_us=10_000,
                           tau_vel_s=kw.get("tau", 0.25), tau_pos_s=kw.get("tau", 0.25),
                           capacity=kw.get("capacity", 3))


def test_dead_reckoning_of_a_yawing_climb():
    """Constant yaw rate, level, accelerating up at 1 m/s^2 from rest: exact in closed form."""
    o = predictor()
    o.reset(0, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    r = 0.5
    for k in range(1, 2001):
        o.propagate(k * 1000, (0.0, 0.0, r), (0.0, 0.0, -G - 1.0), (0.0, 0.0, 0.0),
                    (0.0, 0.0, 0.0))
    t = 2.0
    np.testing.assert_allclose(o.q, (math.cos(r * t / 2), 0, 0, math.sin(r * t / 2)), atol=1e-9)
    np.testing.assert_allclose(o.v, (0, 0, -t), atol=1e-9)
    np.testing.assert_allclose(o.p, (0, 0, -t * t / 2), atol=1e-9)


def test_biases_are_removed():
    o = predictor()
    o.reset(0, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    bg, ba = (0.01, -0.02, 0.03), (0.1, 0.2, -0.3)
    for k in range(1, 1001):
        o.propagate(k * 1000, bg, (ba[0], ba[1], -G + ba[2]), bg, ba)
    np.testing.assert_allclose(o.q, (1, 0, 0, 0), atol=1e-12)
    np.testing.assert_allclose(o.v, (0, 0, 0), atol=1e-12)
    np.testing.assert_allclose(o.p, (0, 0, 0), atol=1e-12)


@pytest.mark.parametrize("tau", [0.25, 0.5])
def test_correction_pulls_the_output_onto_the_filter(tau):
    """At rest, the filter says 1 m north and 0.1 rad of yaw: the output follows within a few
    time constants, overshooting as EKF2's design does (about 5 %), the attitude without
    overshoot."""
    o = predictor(tau=tau)
    o.reset(0, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    yaw = 0.1
    q_f = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
    north, yaws = [], []
    for k in range(1, 10_001):
        o.propagate(k * 1000, (0.0, 0.0, 0.0), (0.0, 0.0, -G), (0.0, 0.0, 0.0),
                    (0.0, 0.0, 0.0))
        if k % 10 == 0:
            o.record()
            o.correct(k * 1000, q_f, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
            north.append(o.p[0])
            yaws.append(2 * math.atan2(o.q[3], o.q[0]))
    assert north[int(tau / 0.01)] > 0.6                 # within one time constant
    assert north[int(2 * tau / 0.01)] > 0.9
    assert max(north) < 1.1
    assert abs(north[-1] - 1.0) < 0.02
    assert max(yaws) <= yaw + 1e-9
    assert yaws[20] == pytest.approx(yaw, abs=1e-4)


def test_shift_moves_the_record_too():
    o = predictor(capacity=4)
    o.reset(0, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    o.record()
    o.shift((1.0, 0.0, 0.0), (0.0, 2.0, 0.0))
    assert o.v == (1.0, 0.0, 0.0) and o.p == (0.0, 2.0, 0.0)
    o.correct(0, (1.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 2.0, 0.0))
    assert o.tracking_error == (0.0, 0.0, 0.0)         # the recorded state was shifted too
