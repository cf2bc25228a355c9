"""Extended state observers (paper eq. 10-11): one third-order observer per channel, or one
order lower on a measured rate.

Channels: x, y, z position (NED, m) and roll, pitch, yaw (ZYX Euler angles, rad). Per channel
    e    = y - x1                      (angles: wrapped to (-pi, pi])
    x1' = x2 + beta1 g1(e)
    x2' = x3 + beta2 g2(e) + b0(u)
    x3' =      beta3 g3(e)
x1 estimates the output, x2 its rate, x3 the total disturbance on its second derivative.
b0(u) is the nominal model's second derivative of the output for the applied command at the
measured state (model/dynamics.py, d = 0): dv/dt for the position channels and d^2 eta/dt^2
for the angle channels.

Reduced channels (EsoChannelGains.output velocity / rates): the group measures its output's
rate instead (NED velocity, body FRD rates), one order lower:
    e    = y - x1                      (y: the measured rate)
    x1' = x3 + b0(u) + beta1 g1(e)
    x3' =              beta3 g2(e)     (beta1 = 2 w, beta3 = w^2: both poles at -w; the
                                        nonlinear observer scales them by delta^(1 - alpha_i)
                                        as below, with g1, g2 its first two fal corrections)
x2 is kept as x3 + b0 (the rate's derivative); b0 is then the body angular acceleration, and
d[3:6] = x3 with no conversion. A fault is a step in an acceleration, which the measured rate
shows one integration sooner than the position or angle: the observer can be several times
faster (params/controller/eso.yaml).

Observers
    nonlinear (Han): g_i = fal(e, alpha_i, delta) = e / delta^(1 - alpha_i) for |e| <= delta,
                     |e|^alpha_i sgn(e) outside; beta_i = c_i w^i delta^(1 - alpha_i) with
                     c = (3, 3, 1), so inside the band it equals the linear observer below and
                     outside its gains fall off (less peaking on large errors).
    linear:          g_i(e) = e, beta = (3 w, 3 w^2, w^3): all poles at -w (bandwidth w).

Disturbance handed to the prediction model (ocp.py): d[0:3] = x3 of the position channels (an
NED acceleration, exactly the model's d); the angle channels estimate an Euler-angle
acceleration, and since d^2 eta/dt^2 = (nominal) + W(eta) d_omega, d[3:6] = W(eta)^-1 x3 (body
FRD angular acceleration). |d| is clamped per group (EsoConfig.max_disturbance).

Integration: at each control step the observer ODE is integrated over the control period with
`substeps` explicit Euler steps; b0 is held, the measurement is interpolated linearly between the
previous and the current sample (first-order hold: holding the newest sample instead biases x3 in
proportion to the velocity, about 30 % after 1 s in the double-integrator test).

The update over one control period (`substeps` steps, the usual case) is also built as one
CasADi function of (z, y_prev, y, b0, dt), generated as C and compiled once through
nmpc/cache.py (`codegen`; without a compiler CasADi's interpreter runs it): the same arithmetic
in the same order as the NumPy loop (the wrap as NumPy's floor modulo, the clip as min and max),
which serves any other gap (lost samples) and the pure path.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from trq_offboard.config import EsoConfig

__all__ = ["fal", "ExtendedStateObserver"]


def fal(e: np.ndarray, alpha: float | np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Han's fal: linear with slope delta^(alpha-1) inside |e| <= delta, |e|^alpha sgn(e) out."""
    e = np.asarray(e, float)
    inside = np.abs(e) <= delta
    return np.where(inside, e / np.power(delta, 1.0 - alpha),
                    np.sign(e) * np.power(np.abs(e), alpha))


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class ExtendedStateObserver:
    """Six third-order observers advanced together (vectorised over channels)."""

    def __init__(self, cfg: EsoConfig, control_dt_s: float, codegen: bool = True) -> None:
        self.cfg = cfg
        self.dt = control_dt_s
        self.h = control_dt_s / cfg.substeps
        groups = (cfg.translational, cfg.rotational)
        w = np.concatenate([np.broadcast_to(np.asarray(g.omega_o_rad_s, float), 3)
                            for g in groups])
        self.delta = np.repeat([g.delta for g in groups], 3)
        # channels one order lower, on the measured rate (velocity, body rates)
        velocity, rates = cfg.translational.output == "velocity", cfg.rotational.output == "rates"
        self.reduced = np.repeat([velocity, rates], 3)
        self._angles = np.array([False] * 3 + [not rates] * 3)
        self._rates = rates
        # where each channel's output sits in the state vector (12: position, velocity NED, Euler
        # angles, body rates) and its b0 in the model's accelerations (9: NED, Euler, body)
        lin, ang = (3 if velocity else 0), (9 if rates else 6)
        self._y_index = np.r_[lin:lin + 3, ang:ang + 3]
        self._b0_index = np.r_[0:3, (6 if rates else 3) + np.arange(3)]
        c = (3.0, 3.0, 1.0)
        self.linear = cfg.kind == "linear"
        self.alpha = (1.0, 1.0, 1.0) if self.linear else cfg.alpha
        scale = [1.0 if self.linear else self.delta ** (1.0 - self.alpha[i]) for i in range(3)]
        self.beta = [c[i] * w ** (i + 1) * scale[i] for i in range(3)]
        # reduced channels: x1' = x3 + b0 + 2 w g1(e), x3' = w^2 g2(e) (both poles at -w)
        self._b1 = np.where(self.reduced, 2.0 * w * scale[0], self.beta[0])
        self._b3 = np.where(self.reduced, w ** 2 * scale[1], self.beta[2])
        self.z = np.zeros((3, 6))      # rows x1, x2, x3; columns x y z roll pitch yaw
        self._y_prev = np.zeros(6)
        lim_t, lim_r = cfg.max_disturbance
        self._lim = np.array([lim_t] * 3 + [lim_r] * 3)
        self._neg_lim = -self._lim
        self._any_angle = bool(self._angles.any())
        self._acol = np.array(self.alpha, float).reshape(3, 1)   # fal's exponent per row
        self._period_fn = self._build_period(codegen)

    def _build_period(self, codegen: bool):
        """update() over one control period as a compiled function (see the module docstring),
        built once per process for a configuration and period."""
        from trq_offboard.model.dynamics import NumpyFunction
        from trq_offboard.nmpc.cache import compiled_once

        return NumpyFunction(compiled_once(("eso period", self.cfg, self.dt),
                                           self._period_function, codegen))

    def _period_function(self) -> ca.Function:
        """(z (3x6 row-major), y_prev, y, b0, dt) -> z (3x6 row-major)."""
        n = self.cfg.substeps
        zs, yp, ys, bs, dts = (ca.SX.sym(name, k) for name, k in
                               (("z", 18), ("y_prev", 6), ("y", 6), ("b0", 6), ("dt", 1)))
        two_pi = 2.0 * math.pi

        def wrap(a):                      # NumPy's (a + pi) % (2 pi) - pi: a floor modulo
            m = ca.fmod(a + math.pi, two_pi)
            return ca.if_else(m < 0, m + two_pi, m) - math.pi

        # fal's constants as NumPy computes them (delta^(1 - alpha) per row and channel)
        inner = np.power(self.delta, 1.0 - self._acol)          # (3, 6)
        h = dts[0] / n
        b2 = self.beta[1]
        z1 = [zs[j] for j in range(6)]
        z2 = [zs[6 + j] for j in range(6)]
        z3 = [zs[12 + j] for j in range(6)]
        ang = self._angles
        step = [ys[j] - yp[j] for j in range(6)]
        step = [wrap(step[j]) if ang[j] else step[j] for j in range(6)]
        for i in range(n):
            frac = (i + 1) / n
            n1, n2, n3 = [], [], []
            for j in range(6):
                e = yp[j] + frac * step[j] - z1[j]
                if ang[j]:
                    e = wrap(e)
                if self.linear:
                    g = [e, e, e]
                else:
                    g = [ca.if_else(ca.fabs(e) <= self.delta[j], e / inner[r, j],
                                    ca.sign(e) * ca.power(ca.fabs(e), self.alpha[r]))
                         for r in range(3)]
                red = bool(self.reduced[j])
                dz1 = (z3[j] + bs[j] if red else z2[j]) + self._b1[j] * g[0]
                dz2 = z3[j] + b2[j] * g[1] + bs[j]
                dz3 = self._b3[j] * (g[1] if red else g[2])
                n1.append(z1[j] + h * dz1)
                n2.append(z2[j] + h * dz2)
                n3.append(z3[j] + h * dz3)
            z1, z2, z3 = n1, n2, n3
        z1 = [wrap(z1[j]) if ang[j] else z1[j] for j in range(6)]
        z3 = [ca.fmin(ca.fmax(z3[j], -self._lim[j]), self._lim[j]) for j in range(6)]
        z2 = [z3[j] + bs[j] if self.reduced[j] else z2[j] for j in range(6)]
        return ca.Function(f"eso_period_{n}", [zs, yp, ys, bs, dts],
                           [ca.vertcat(*z1, *z2, *z3)])

    def measurement(self, x: np.ndarray) -> np.ndarray:
        """The channels' measured outputs (6) from a state vector (12: position, velocity NED,
        Euler angles, body rates): position or velocity, angles or body rates."""
        return np.asarray(x, float)[self._y_index]

    def b0_of(self, acc: np.ndarray) -> np.ndarray:
        """The channels' b0 (6) from the model's accelerations (9: NED linear, Euler, body
        angular; PredictionModel.b0): the second derivative of a full channel's output, the
        first of a reduced one's, which is the same linear acceleration for both."""
        return np.asarray(acc, float)[self._b0_index]

    def reset(self, y: np.ndarray, y_rate: np.ndarray, disturbance: np.ndarray | None = None
              ) -> None:
        """Start at the measured output and its rate (ignored on reduced channels, whose x2
        is the output's rate x3 + b0); x3 from a known disturbance or zero."""
        self.z[0] = y
        self.z[1] = np.where(self.reduced, 0.0, y_rate)
        self._y_prev = np.array(y, float)
        self.z[2] = 0.0 if disturbance is None else disturbance

    def _g3(self, e: np.ndarray) -> np.ndarray:
        """(3, 6): the correction of each row x1, x2, x3, fal(e, alpha_i, delta) broadcast over
        the rows (with alpha 1, fal is e to rounding); e itself for the linear observer."""
        if self.linear:
            return np.broadcast_to(e, (3, 6))
        return fal(e, self._acol, self.delta)

    def substeps_for(self, dt_s: float) -> int:
        """The Euler substeps `update` takes over a gap of dt_s: each at most a control period
        over `substeps`."""
        return max(1, int(math.ceil(self.cfg.substeps * dt_s / self.dt - 1e-9)))

    def takes_period(self, dt_s: float) -> bool:
        """Whether `update` over dt_s is one call of the compiled period."""
        return self._period_fn is not None and self.substeps_for(dt_s) == self.cfg.substeps

    def update(self, y: np.ndarray, b0: np.ndarray, dt_s: float | None = None) -> None:
        """Advance by dt_s (default one control period) to the measured output y (6,
        `measurement`), with b0 (6, `b0_of`) held. A longer gap (a lost or skipped sample) is
        integrated over its true length, with proportionally more substeps so that each stays
        as short."""
        z1, z2, z3 = self.z
        y = np.asarray(y, float)
        b0 = np.asarray(b0, float)
        dt = self.dt if dt_s is None else float(dt_s)
        n = self.substeps_for(dt)
        if n == self.cfg.substeps and self._period_fn is not None:   # one control period
            self.z = self._period_fn(self.z, self._y_prev, y, b0, dt).reshape(3, 6)
            self._y_prev = y.copy()
            return
        h = dt / n
        b2 = self.beta[1]
        red, ang = self.reduced, self._angles
        step = y - self._y_prev
        step[ang] = _wrap(step[ang])
        for i in range(n):
            e = self._y_prev + ((i + 1) / n) * step - z1
            e[ang] = _wrap(e[ang])
            g = self._g3(e)
            dz1 = np.where(red, z3 + b0, z2) + self._b1 * g[0]
            dz2 = z3 + b2 * g[1] + b0
            dz3 = self._b3 * np.where(red, g[1], g[2])
            z1 = z1 + h * dz1
            z2 = z2 + h * dz2
            z3 = z3 + h * dz3
        z1[ang] = _wrap(z1[ang])
        self._y_prev = y.copy()
        z3 = np.clip(z3, -self._lim, self._lim)
        self.z = np.vstack([z1, np.where(red, z3 + b0, z2), z3])

    @property
    def output_estimate(self) -> np.ndarray:
        return self.z[0].copy()

    def output_error(self, y: np.ndarray) -> float:
        """(y_hat - y)^T (y_hat - y) of the current estimate (angles wrapped)."""
        e = self.z[0] - np.asarray(y, float)
        if self._any_angle:
            e[self._angles] = _wrap(e[self._angles])
        return float(e @ e)

    def disturbance(self, euler_rad: np.ndarray) -> np.ndarray:
        """d (6) for the prediction model: NED acceleration, body angular acceleration."""
        if self._rates:                                     # x3 is already a body acceleration
            return np.minimum(np.maximum(self.z[2], self._neg_lim), self._lim)   # np.clip's
        roll, pitch = float(euler_rad[0]), float(euler_rad[1])
        sr, cr = math.sin(roll), math.cos(roll)
        sp, cp = math.sin(pitch), math.cos(pitch)
        # W^-1 (eta_dot -> omega), ZYX
        w_inv = np.array([[1.0, 0.0, -sp], [0.0, cr, sr * cp], [0.0, -sr, cr * cp]])
        d = np.concatenate([self.z[2, 0:3], w_inv @ self.z[2, 3:6]])
        return np.minimum(np.maximum(d, self._neg_lim), self._lim)
