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
Each substep is written out per row (f' + l0 e; (a10 f + a11 f' + a12 w) + l1 e; (d + b0) +
l2 e; l3 e), the same arithmetic in the same order on both paths: the update over one control
period (`substeps` steps, the usual case) is also one CasADi function of (s, y_prev, y, b0, dt),
generated as C and compiled once through nmpc/cache.py (`codegen`, as the ESO's; without a
compiler CasADi's interpreter runs it), and the NumPy loop serves any other gap (lost samples)
and the pure path (docs/decisions/2026-12-05-fused-filter-period-cut.md).

    ro = RateObserver(cutoff_hz, omega_o_rad_s, control_dt_s, substeps, codegen=True)
    ro.reset(rates)                                 # at rest on the measured rates
    ro.update(rates_measured, b0_angular, dt_s)     # one control period
    ro.rates, ro.disturbance                        # the present body rate and d (3 each)

Pure: no clock, no I/O.
"""

from __future__ import annotations

import math

import casadi as ca
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


def _substep(rows, y_i, b0, h: float, a1: tuple, gain: tuple):
    """One explicit Euler substep of the observer (module docstring) to the measurement y_i:
    the rows (f, f', w, d) of the next state, each a list over the axes, worked per axis (CasADi
    SX scalars for the kernel, Python floats for the pure path): both paths do the same
    arithmetic in the same order."""
    f, fd, w, d = rows
    if isinstance(f, list):                 # per axis (CasADi scalars, or floats)
        return [list(r) for r in zip(*(_substep((f[j], fd[j], w[j], d[j]), y_i[j], b0[j], h,
                                                a1, gain) for j in range(len(f))))]
    e = y_i - f
    return [f + h * (fd + gain[0] * e),
            fd + h * (a1[0] * f + a1[1] * fd + a1[2] * w + gain[1] * e),
            w + h * (d + b0 + gain[2] * e),
            d + h * (gain[3] * e)]


class RateObserver:
    """Three body axes, each the 4-state observer above."""

    def __init__(self, cutoff_hz: float, omega_o_rad_s: float, control_dt_s: float,
                 substeps: int, max_disturbance: float = math.inf, codegen: bool = False
                 ) -> None:
        self._key = (cutoff_hz, omega_o_rad_s, control_dt_s, substeps, max_disturbance)
        self.a, self.b, self.c = _model(cutoff_hz)
        self.l = observer_gain(cutoff_hz, omega_o_rad_s)
        self.dt = control_dt_s
        self.substeps = int(substeps)
        self.lim = max_disturbance
        self.s = np.zeros((4, 3))           # rows f, f', w, d; columns the body axes
        self._y_prev = np.zeros(3)
        # the filter row's coefficients (A's second row) and the gain, as plain floats
        self._a1 = tuple(float(v) for v in self.a[1, 0:3])
        self._l = tuple(float(v) for v in self.l)
        self._period_fn = self._build_period() if codegen else None

    def _build_period(self):
        """update() over one control period as a compiled function (module docstring), built
        once per process for the observer's figures."""
        from trq_offboard.model.dynamics import NumpyFunction
        from trq_offboard.nmpc.cache import compiled_once

        return NumpyFunction(compiled_once(("rate observer period", self._key),
                                           self._period_function))

    def _period_function(self) -> ca.Function:
        """(s (4x3 row-major), y_prev, y, b0, dt) -> s (4x3 row-major)."""
        n = self.substeps
        ss, yp, ys, bs, dts = (ca.SX.sym(name, k) for name, k in
                               (("s", 12), ("y_prev", 3), ("y", 3), ("b0", 3), ("dt", 1)))
        h = dts[0] / n
        rows = [[ss[3 * r + j] for j in range(3)] for r in range(4)]
        step = [ys[j] - yp[j] for j in range(3)]
        for i in range(n):
            frac = (i + 1) / n
            # the last substep's end is the sample itself (CasADi simplifies yp + 1 (y - yp)
            # to y: the NumPy loop does the same)
            y_i = [ys[j] if i == n - 1 else yp[j] + frac * step[j] for j in range(3)]
            rows = _substep(rows, y_i, bs, h, self._a1, self._l)
        lim = self.lim
        rows[3] = [ca.fmin(ca.fmax(v, -lim), lim) for v in rows[3]]
        return ca.Function(f"rate_observer_period_{n}", [ss, yp, ys, bs, dts],
                           [ca.vertcat(*(v for row in rows for v in row))])

    def reset(self, rates: np.ndarray, disturbance: np.ndarray | None = None) -> None:
        y = np.asarray(rates, float)
        self.s = np.vstack([y, np.zeros(3), y,
                            np.zeros(3) if disturbance is None else np.asarray(disturbance)])
        self._y_prev = y.copy()

    def substeps_for(self, dt_s: float) -> int:
        """The Euler substeps `update` takes over a gap of dt_s: each at most a control period
        over `substeps`."""
        return max(1, int(math.ceil(self.substeps * dt_s / self.dt - 1e-9)))

    def takes_period(self, dt_s: float) -> bool:
        """Whether `update` over dt_s is one call of the compiled period."""
        return self._period_fn is not None and self.substeps_for(dt_s) == self.substeps

    def update(self, rates: np.ndarray, b0: np.ndarray, dt_s: float | None = None) -> None:
        """Advance by dt_s (default one control period) to the measured (filtered) rates,
        with the angular acceleration b0 (3) held."""
        y = np.asarray(rates, float)
        b0 = np.asarray(b0, float)
        dt = self.dt if dt_s is None else float(dt_s)
        n = self.substeps_for(dt)
        if n == self.substeps and self._period_fn is not None:     # one control period
            self.s = self._period_fn(self.s, self._y_prev, y, b0, dt).reshape(4, 3)
            self._y_prev = y.copy()
            return
        # per axis in Python floats: the same operations as NumPy's on 3-vectors, cheaper
        h = dt / n
        yp, yn, b = self._y_prev.tolist(), y.tolist(), b0.tolist()
        step = [yn[j] - yp[j] for j in range(3)]
        rows = self.s.tolist()
        for i in range(n):
            frac = (i + 1) / n
            y_i = yn if i == n - 1 else [yp[j] + frac * step[j] for j in range(3)]
            rows = _substep(rows, y_i, b, h, self._a1, self._l)
        lim = self.lim
        rows[3] = [min(max(v, -lim), lim) for v in rows[3]]
        self.s = np.array(rows)
        self._y_prev = y.copy()

    @property
    def rates(self) -> np.ndarray:
        """The body rates now (the filter's lag removed)."""
        return self.s[2].copy()

    @property
    def disturbance(self) -> np.ndarray:
        return self.s[3].copy()
