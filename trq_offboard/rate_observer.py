"""The body-rate observer that knows the published rates are low-passed.

PX4 publishes its body rates (ODOMETRY's, ATTITUDE's) through a 2-pole low-pass at
IMU_GYRO_CUTOFF (sil_vehicle/estimator/lowpass.py is the vehicle's side). An extended state
observer that compares that signal with its own rate estimate reads the filter's lag as a
disturbance (docs/decisions/2026-12-05-lossy-link-rates-lowpass.md). This observer carries the
filter in its output instead, per body axis:

    state    s = (f, f', w, d)       f: the published (filtered) rate, w: the body rate,
                                     d: the total disturbance on its derivative
    model    f'' = wc^2 (w - f) - 2 zeta wc f'      (the filter: Butterworth, zeta = 1/sqrt 2)
             w'  = d + b0                           (b0: the nominal model's angular
             d'  = 0                                 acceleration under the applied input)
    output   y = f
    observer s' = A s + B b0 + L (y - f)

L places the error dynamics' poles at the filter's own pair and a double pole at -omega_o (the
ESO's bandwidth): the filter's modes are as well known as the filter, and the disturbance's are
what the bandwidth governs. Integrated by explicit Euler substeps over a control period with the
measurement interpolated linearly between samples (first-order hold), as trq_offboard/eso.py.

    ro = RateObserver(cutoff_hz, omega_o_rad_s, control_dt_s, substeps)
    ro.reset(rates)                                 # at rest on the measured rates
    ro.update(rates_measured, b0_angular, dt_s)     # one control period
    ro.rates, ro.disturbance                        # the present body rate and d (3 each)

Pure: no clock, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["RateObserver", "observer_gain"]

ZETA = 1.0 / math.sqrt(2.0)


def _model(cutoff_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    wc = 2.0 * math.pi * cutoff_hz
    a = np.array([[0.0, 1.0, 0.0, 0.0],
                  [-wc * wc, -2.0 * ZETA * wc, wc * wc, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, 0.0, 0.0, 0.0]])
    b = np.array([0.0, 0.0, 1.0, 0.0])
    c = np.array([1.0, 0.0, 0.0, 0.0])
    return a, b, c


def observer_gain(cutoff_hz: float, omega_o_rad_s: float) -> np.ndarray:
    """L (4,) placing A - L C's poles at the filter's pair and a double pole at -omega_o
    (Ackermann's formula on the observable pair (A, C))."""
    if not cutoff_hz > 0.0 or not omega_o_rad_s > 0.0:
        raise ValueError(f"RateObserver: cutoff_hz {cutoff_hz} and omega_o_rad_s "
                         f"{omega_o_rad_s} must be > 0")
    a, _, c = _model(cutoff_hz)
    wc = 2.0 * math.pi * cutoff_hz
    # desired characteristic polynomial (s^2 + 2 zeta wc s + wc^2)(s + w)^2
    poly = np.polymul([1.0, 2.0 * ZETA * wc, wc * wc], [1.0, 2.0 * omega_o_rad_s,
                                                       omega_o_rad_s ** 2])
    phi = sum(coef * np.linalg.matrix_power(a, 4 - i) for i, coef in enumerate(poly))
    obs = np.vstack([c @ np.linalg.matrix_power(a, i) for i in range(4)])
    return phi @ np.linalg.solve(obs, np.array([0.0, 0.0, 0.0, 1.0]))


class RateObserver:
    """Three body axes, each the 4-state observer above."""

    def __init__(self, cutoff_hz: float, omega_o_rad_s: float, control_dt_s: float,
                 substeps: int, max_disturbance: float = math.inf) -> None:
        self.a, self.b, self.c = _model(cutoff_hz)
        self.l = observer_gain(cutoff_hz, omega_o_rad_s)
        self.dt = control_dt_s
        self.substeps = int(substeps)
        self.lim = max_disturbance
        self.s = np.zeros((4, 3))           # rows f, f', w, d; columns the body axes
        self._y_prev = np.zeros(3)

    def reset(self, rates: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        y = np.asarray(rates, float)
        self.s = np.vstack([y, np.zeros(3), y,
                            np.zeros(3) if disturbance is None else np.asarray(disturbance)])
        self._y_prev = y.copy()

    def update(self, rates: np.ndarray, b0: np.ndarray, dt_s: float | None = None) -> None:
        """Advance by dt_s (default one control period) to the measured (filtered) rates,
        with the angular acceleration b0 (3) held."""
        y = np.asarray(rates, float)
        dt = self.dt if dt_s is None else float(dt_s)
        n = max(1, int(math.ceil(self.substeps * dt / self.dt - 1e-9)))
        h = dt / n
        s = self.s
        y_prev = self._y_prev
        # the measurement at each substep's end (first-order hold), all substeps at once; the
        # input's term B b0 and the gain as a column formed once: the same figures as forming
        # them every substep, in fewer NumPy calls
        # (docs/decisions/2026-12-05-fused-filter-period-cut.md)
        ys = y_prev + (np.arange(1, n + 1) / n)[:, None] * (y - y_prev)
        a, l_col = self.a, self.l[:, None]
        bb = np.outer(self.b, np.asarray(b0, float))
        for y_i in ys:
            ds = a @ s + bb + l_col * (y_i - s[0])
            s = s + h * ds
        s[3] = np.clip(s[3], -self.lim, self.lim)
        self.s = s
        self._y_prev = y.copy()

    @property
    def rates(self) -> np.ndarray:
        """The body rates now (the filter's lag removed)."""
        return self.s[2].copy()

    @property
    def disturbance(self) -> np.ndarray:
        return self.s[3].copy()
