"""A second-order Butterworth low-pass, as PX4 filters the body rates it publishes.

PX4's sensors module runs the bias-corrected gyro through a 2-pole low-pass at IMU_GYRO_CUTOFF
(default 40 Hz) before vehicle_angular_velocity, which feeds the rate controller, ATTITUDE's and
ODOMETRY's angular velocity. The vehicle's estimate does the same, so that what a companion reads
carries the filter's phase lag and not the rotors' vibration lines (sil_vehicle/sensors/imu.py).

The filter: the analogue 2-pole Butterworth mapped by the bilinear transform with the cutoff
prewarped, run in direct form II (two delay elements per axis). A cutoff of 0, or at or above the
Nyquist frequency, passes the samples through unchanged.
"""

from __future__ import annotations

import math

__all__ = ["LowPass2"]


class LowPass2:
    """Three axes filtered at `cutoff_hz` for samples at `rate_hz`, starting from rest (zero)."""

    def __init__(self, rate_hz: float, cutoff_hz: float) -> None:
        self._d1 = [0.0, 0.0, 0.0]
        self._d2 = [0.0, 0.0, 0.0]
        self._y = (0.0, 0.0, 0.0)          # the last output
        self.set_cutoff(rate_hz, cutoff_hz)

    def set_cutoff(self, rate_hz: float, cutoff_hz: float) -> None:
        """New coefficients (a retune in flight), the filter settled at its last output so that
        the output does not jump."""
        if rate_hz <= 0.0 or cutoff_hz < 0.0:
            raise ValueError(f"LowPass2: rate_hz {rate_hz} > 0 and cutoff_hz {cutoff_hz} >= 0 "
                             "expected")
        self.cutoff_hz = cutoff_hz
        self.active = 0.0 < cutoff_hz < rate_hz / 2
        if not self.active:
            self._b = (1.0, 0.0, 0.0)
            self._a = (0.0, 0.0)
            return
        w = math.tan(math.pi * cutoff_hz / rate_hz)        # the prewarped cutoff
        k = math.sqrt(2.0) * w                              # 2 cos(pi/4) w
        c = 1.0 + k + w * w
        b0 = w * w / c
        self._b = (b0, 2.0 * b0, b0)
        self._a = a1, a2 = (2.0 * (w * w - 1.0) / c, (1.0 - k + w * w) / c)
        for i in range(3):
            self._d1[i] = self._d2[i] = self._y[i] / (1.0 + a1 + a2)

    def apply(self, sample) -> tuple[float, float, float]:
        """One sample (3,) in, the filtered sample out."""
        if not self.active:
            self._y = (float(sample[0]), float(sample[1]), float(sample[2]))
            return self._y
        b0, b1, b2 = self._b
        a1, a2 = self._a
        d1, d2 = self._d1, self._d2
        out = [0.0, 0.0, 0.0]
        for i in range(3):
            d0 = sample[i] - d1[i] * a1 - d2[i] * a2
            out[i] = d0 * b0 + d1[i] * b1 + d2[i] * b2
            d2[i] = d1[i]
            d1[i] = d0
        self._y = (out[0], out[1], out[2])
        return self._y
