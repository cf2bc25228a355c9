"""The companion's body-rate observer against the vehicle's published-rate low-pass: the rates as
the vehicle sends them (sil_vehicle.estimator.lowpass.LowPass2, PX4's IMU_GYRO_CUTOFF filter at
the IMU's rate) fed to trq_offboard.rate_observer.RateObserver, which carries the same filter in
its output. A step of angular acceleration (a motor losing thrust) must be found as fast as the
observer's bandwidth says, and the present rate without the filter's lag."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.estimator.lowpass import LowPass2
from trq_offboard.rate_observer import RateObserver, observer_gain

IMU_HZ, CUTOFF_HZ, DT, SUBSTEPS = 1000.0, 40.0, 0.01, 10


def _fly(omega_o: float, steps: int, cutoff_hz: float = CUTOFF_HZ):
    """A body at rest, then (from step 10) an angular acceleration step; the measured rates
    through the vehicle's low-pass at IMU_HZ, sampled every control period. Rows of (true rate,
    measured rate, estimated rate, estimated d), each (3,)."""
    lp = LowPass2(IMU_HZ, cutoff_hz)
    ro = RateObserver(cutoff_hz, omega_o, DT, SUBSTEPS)
    ro.reset(np.zeros(3))
    w = np.zeros(3)
    step = np.array([80.0, -80.0, 5.0])
    rows = []
    per = int(round(DT * IMU_HZ))
    for k in range(steps):
        for _ in range(per):
            w = w + (step if k >= 10 else 0.0) / IMU_HZ
            y = np.array(lp.apply(tuple(w)))
        ro.update(y, np.zeros(3))
        rows.append((w.copy(), y, ro.rates, ro.disturbance))
    return rows


def test_the_gain_places_the_filter_pair_and_the_bandwidth():
    wc = 2.0 * math.pi * CUTOFF_HZ
    ro = RateObserver(CUTOFF_HZ, 300.0, DT, SUBSTEPS)
    poles = np.sort_complex(np.linalg.eigvals(ro.a - np.outer(ro.l, ro.c)))
    want = np.sort_complex(np.array([-300.0, -300.0, wc * complex(-1, 1) / math.sqrt(2),
                                     wc * complex(-1, -1) / math.sqrt(2)]))
    # a double pole is found to about the square root of the rounding
    np.testing.assert_allclose(poles, want, atol=1e-3 * wc)


@pytest.mark.parametrize("omega_o", [100.0, 300.0])
def test_a_step_is_found_at_the_bandwidth_and_the_rate_without_the_lag(omega_o):
    rows = _fly(omega_o, 80)
    w, y, w_hat, d_hat = (np.array(c) for c in zip(*rows))
    # a double pole at -w: 90 % of a step within 3.9 / w (1 - (1 + x) e^-x = 0.9 at x = 3.89),
    # to the control period's resolution, after the step's first period
    k90 = 10 + int(math.ceil(3.9 / omega_o / DT)) + 1
    assert np.all(d_hat[k90, 0:2] / np.array([80.0, -80.0]) > 0.9), d_hat[k90]
    np.testing.assert_allclose(d_hat[-1], [80.0, -80.0, 5.0], rtol=1e-3)
    # settled: the measurement lags the true rate by the filter's group delay (80 rad/s^2 x
    # 5.6 ms, 0.45 rad/s); the estimate is within a fifth of that
    lag = np.abs(y[-1, 0] - w[-1, 0])
    assert lag > 0.4
    assert np.abs(w_hat[-1, 0] - w[-1, 0]) < 0.2 * lag


def test_bad_figures_are_refused():
    with pytest.raises(ValueError, match="cutoff_hz"):
        observer_gain(0.0, 100.0)
    with pytest.raises(ValueError, match="omega_o_rad_s"):
        observer_gain(40.0, -1.0)


@pytest.mark.skipif(__import__("trq_offboard.nmpc.cache", fromlist=["find_compiler"])
                    .find_compiler() is None, reason="no C compiler")
def test_the_compiled_period_is_the_numpy_loop_to_the_bit():
    """One control period as the compiled function (codegen) and as the NumPy loop: the same
    arithmetic in the same order, so the same bits; other gaps (lost samples) take the loop on
    both; the clip on d applies to both. A change of the kernel's arithmetic alone fails."""
    rng = np.random.default_rng(5)
    loop = RateObserver(CUTOFF_HZ, 100.0, DT, SUBSTEPS, max_disturbance=20.0)
    kern = RateObserver(CUTOFF_HZ, 100.0, DT, SUBSTEPS, max_disturbance=20.0, codegen=True)
    assert loop._period_fn is None and kern._period_fn is not None
    for ro in (loop, kern):
        ro.reset(np.array([0.1, -0.2, 0.05]))
    for k in range(400):
        dt = DT if k % 7 else 2 * DT           # a lost sample now and then
        y, b0 = rng.normal(size=3), rng.normal(size=3) * 30.0
        loop.update(y, b0, dt)
        kern.update(y, b0, dt)
        assert np.array_equal(loop.s, kern.s), (k, loop.s - kern.s)
    assert np.any(np.abs(kern.disturbance) == 20.0)     # the clip was reached
