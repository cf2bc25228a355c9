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


def _state(o) -> tuple:
    """Everything the predictor holds, as bytes of float64 (bit for bit)."""
    def b(v) -> bytes:
        return np.asarray(v, dtype=np.float64).tobytes()
    return (o.t_us, b(o.q), b(o.v), b(o.p), b(o._c_ang), b(o.tracking_error),
            tuple((t, b(q), b(v), b(p)) for t, q, v, p in o._record))


def test_compiled_sample_equals_the_python_reference_bit_for_bit():
    """The C sample (predictor.c) against the Python one: a tumbling, accelerating vehicle with
    biases, corrections, shifts and a reset, every state and every period's sums equal."""
    from sil_vehicle.estimator import predictor as pr
    if pr._library() is None:
        pytest.skip("no C compiler: the Python reference is the only path")
    kw = dict(gravity_m_s2=G, imu_period_us=1000, filter_period_us=10_000, tau_vel_s=0.25,
              tau_pos_s=0.3, capacity=4)
    py, c = OutputPredictor(**kw), pr.native_predictor(**kw)
    assert isinstance(c, pr.NativeOutputPredictor)
    rng = np.random.default_rng(3)
    q0 = rng.standard_normal(4)
    for o in (py, c):
        o.reset(0, tuple(q0 / np.linalg.norm(q0)), (0.5, -1.0, 0.2), (1.0, 2.0, -3.0))
    for k in range(1, 3001):
        g = tuple((3.0 * rng.standard_normal(3)).tolist())
        f = tuple((rng.standard_normal(3) + (0.0, 0.0, -G)).tolist())
        for o in (py, c):
            o.sample(k * 1000, g, f)
        if k % 10 == 0:
            sums = [o.take_sums() for o in (py, c)]
            assert sums[0][0].tobytes() == sums[1][0].tobytes()
            assert sums[0][1].tobytes() == sums[1][1].tobytes()
            for o in (py, c):
                o.record()
        if k % 10 == 5 and k > 30:
            q = rng.standard_normal(4)
            filt = (tuple(q / np.linalg.norm(q)), tuple(rng.standard_normal(3).tolist()),
                    tuple(rng.standard_normal(3).tolist()))
            bg, ba = (0.01 * rng.standard_normal(3)).tolist(), (0.1 * rng.standard_normal(3))
            for o in (py, c):
                o.correct(k * 1000 - 25_000, *filt)
                o.set_biases(bg, tuple(ba.tolist()))
        if k % 700 == 0:      # a position reset's jump (NumPy floats, as the filter's)
            dv, dp = rng.standard_normal(3), rng.standard_normal(3)
            for o in (py, c):
                o.shift(dv, dp)
        if k == 2000:
            for o in (py, c):
                o.reset(k * 1000, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        if k % 97 == 0:       # propagate alone (the reference's own step) leaves the sums
            for o in (py, c):
                o.propagate(k * 1000, g, f, (0.1, 0.0, -0.1), (0.0, 0.2, 0.0))
        assert _state(py) == _state(c), k
    assert any(py.tracking_error) and any(py._c_ang)      # the corrections did act


def test_without_a_compiler_the_python_reference_runs(monkeypatch):
    from sil_vehicle.estimator import predictor as pr
    monkeypatch.setattr(pr, "find_compiler", lambda: None)
    pr._library.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="no C compiler"):
            o = pr.native_predictor(gravity_m_s2=G, imu_period_us=1000, filter_period_us=10_000,
                                    tau_vel_s=0.25, tau_pos_s=0.25, capacity=3)
        assert type(o) is OutputPredictor
    finally:
        pr._library.cache_clear()      # the next caller builds (or finds) the library again
