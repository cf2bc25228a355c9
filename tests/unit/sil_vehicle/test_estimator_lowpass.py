"""The published rates' low-pass (sil_vehicle.estimator.lowpass, PX4's IMU_GYRO_CUTOFF): unity at
DC, -3 dB at the cutoff, the second order's roll-off above it, off at 0; and the estimate's rates
carry it."""

import math

import numpy as np
import pytest

from sil_vehicle.estimator.lowpass import LowPass2


def gain(rate_hz: float, cutoff_hz: float, f_hz: float) -> float:
    """The filter's measured amplitude gain for a sine at f_hz (after its transient)."""
    lp = LowPass2(rate_hz, cutoff_hz)
    n = int(rate_hz * max(2.0, 40.0 / f_hz))
    t = np.arange(n) / rate_hz
    x = np.sin(2 * math.pi * f_hz * t)
    y = np.array([lp.apply((v, 0.0, -v))[0] for v in x])
    tail = slice(n // 2, n)
    return float(np.sqrt(2 * np.mean(y[tail] ** 2)))


def test_unity_at_dc_and_half_power_at_the_cutoff():
    lp = LowPass2(1000.0, 40.0)
    for _ in range(2000):
        out = lp.apply((1.0, -2.0, 0.5))
    assert out == pytest.approx((1.0, -2.0, 0.5), abs=1e-9)
    assert gain(1000.0, 40.0, 40.0) == pytest.approx(1 / math.sqrt(2), rel=0.02)


def test_a_vibration_line_is_attenuated_as_a_second_order():
    # a decade above the cutoff: -40 dB for a 2-pole Butterworth (less near Nyquist: bilinear)
    assert gain(1000.0, 40.0, 400.0) < 0.012
    assert gain(1000.0, 40.0, 10.0) > 0.99


def test_zero_cutoff_or_beyond_nyquist_passes_the_samples():
    for cutoff in (0.0, 500.0, 800.0):
        lp = LowPass2(1000.0, cutoff)
        assert not lp.active and lp.apply((0.3, -0.1, 2.0)) == (0.3, -0.1, 2.0)
    with pytest.raises(ValueError, match="cutoff_hz"):
        LowPass2(1000.0, -1.0)


def test_a_retune_does_not_jump_the_output():
    lp = LowPass2(1000.0, 40.0)
    for _ in range(500):
        lp.apply((1.0, 1.0, 1.0))
    lp.set_cutoff(1000.0, 20.0)
    assert lp.apply((1.0, 1.0, 1.0))[0] == pytest.approx(1.0, abs=1e-6)


def test_the_estimates_rates_are_filtered():
    """The vehicle's estimate publishes the gyro through IMU_GYRO_CUTOFF: a vibration line on a
    still vehicle is (nearly) gone from its rates, and with the cutoff at 0 it is there."""
    from sil_vehicle.estimator.eskf import Eskf
    from sil_vehicle.estimator.params import EstimatorParams
    from sil_vehicle.sensors.imu import ImuReading
    from sil_vehicle.sensors.profile import load_sensing

    profile = load_sensing("mocap", 1000)
    amp, f_hz = 0.05, 180.0
    out = {}
    for cutoff in (40.0, 0.0):
        e = Eskf(EstimatorParams.from_profile(profile, gyro_cutoff_hz=cutoff))
        rates = []
        for k in range(1, 1001):
            w = amp * math.sin(2 * math.pi * f_hz * k * 1e-3)
            e.step(k * 1000, [ImuReading(k * 1000, (w, 0.0, 0.0), (0.0, 0.0, -9.80665))])
            if k > 500:
                rates.append(e.output().rates_frd_rad_s[0])
        out[cutoff] = float(np.std(rates))
    assert out[0.0] > 0.6 * amp / math.sqrt(2)
    assert out[40.0] < 0.1 * out[0.0]
