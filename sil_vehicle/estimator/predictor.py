"""The output predictor: the filter's delayed state carried forward to `now` at IMU rate, kept
on the filter's track by a complementary correction (PX4 EKF2, OutputPredictor::
calculateOutputStates and correctOutputStates; Paul Riseborough's "output observer").

Per IMU sample (dA, dV over dt, the filter's bias estimates bg, ba at the delayed horizon):

    q   <- q (x) exp(dA - bg dt + c_ang)            c_ang: the attitude correction (below)
    v'  =  v + R(q_old) (dV - ba dt) + (0, 0, g) dt
    p   <- p + (v + v') dt / 2,   v <- v'

At the end of each filter period the output state is recorded in a buffer of the horizon's
length. When the filter has processed the period ending at t_d (now - horizon), the output
state recorded at t_d is compared with the filter's state at t_d (EKF2's gains):

    dtheta  = 2 vec(q_out(t_d)^-1 (x) q_filter) (sign of the scalar part)
    c_ang   = dtheta * 0.5 dt_imu / max(now - t_d, dt_filter)    applied on every IMU sample
              (EKF2 floors the delay at one IMU period; floored at the filter period, over which
              the correction is applied until the next fit, it corrects at most half the error
              per fit, so a horizon of zero stays stable)
    e_v     = v_filter - v_out(t_d),  I_v += e_v,  k_v = dt_filter / clip(tau_vel, dt_filter, 10)
    c_v     = k_v e_v + 0.1 k_v^2 I_v      (PD-like, about 5 % overshoot; likewise c_p with tau_pos)

and c_v, c_p are added to every recorded output state and to the current one. A reset of the
filter's state (the first position measurement) is applied to the output states as a jump.

Plain Python floats: a handful of multiplications per IMU sample, no array allocation.
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["OutputPredictor", "quat_exp", "quat_mul", "rotate"]


def quat_mul(a, b) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def quat_exp(vx: float, vy: float, vz: float) -> tuple[float, float, float, float]:
    """exp(v / 2), the series of sil_vehicle.estimator.derivation.quat_exp."""
    t2 = vx * vx + vy * vy + vz * vz
    c = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    s = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
    return (c, s * vx, s * vy, s * vz)


def normalised(q) -> tuple[float, float, float, float]:
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def rotate(q, x: float, y: float, z: float) -> tuple[float, float, float]:
    """R(q) (x, y, z): body FRD to NED."""
    w, a, b, c = q
    return ((1 - 2 * (b * b + c * c)) * x + 2 * (a * b - w * c) * y + 2 * (a * c + w * b) * z,
            2 * (a * b + w * c) * x + (1 - 2 * (a * a + c * c)) * y + 2 * (b * c - w * a) * z,
            2 * (a * c - w * b) * x + 2 * (b * c + w * a) * y + (1 - 2 * (a * a + b * b)) * z)


class OutputPredictor:
    """The output state (t_us, q, v, p) at IMU rate and its record at filter-period ends."""

    def __init__(self, *, gravity_m_s2: float, imu_period_us: int, filter_period_us: int,
                 tau_vel_s: float, tau_pos_s: float, capacity: int) -> None:
        self._g = gravity_m_s2
        self._dt_imu = imu_period_us * 1e-6
        self._dt_f = dt_f = filter_period_us * 1e-6
        self._k_v = dt_f / min(max(tau_vel_s, dt_f), 10.0)
        self._k_p = dt_f / min(max(tau_pos_s, dt_f), 10.0)
        self._record: deque = deque(maxlen=capacity)
        self.t_us = 0
        self.q = (1.0, 0.0, 0.0, 0.0)
        self.v = (0.0, 0.0, 0.0)
        self.p = (0.0, 0.0, 0.0)
        self._c_ang = (0.0, 0.0, 0.0)
        self._i_v = [0.0, 0.0, 0.0]
        self._i_p = [0.0, 0.0, 0.0]
        self.tracking_error = (0.0, 0.0, 0.0)     # |dtheta| (rad), |e_v|, |e_p| at the last fit

    def reset(self, t_us: int, q, v, p) -> None:
        self.t_us = t_us
        self.q, self.v, self.p = tuple(q), tuple(v), tuple(p)
        self._record.clear()
        self._c_ang = (0.0, 0.0, 0.0)
        self._i_v = [0.0, 0.0, 0.0]
        self._i_p = [0.0, 0.0, 0.0]

    def propagate(self, t_us: int, gyro, accel, bg, ba) -> None:
        """One IMU sample at t_us: rates `gyro` (rad/s) and specific force `accel` (m/s^2),
        body FRD, held over the IMU period that ends at t_us."""
        dt = self._dt_imu
        c = self._c_ang
        # q <- q (x) exp(dA - bg dt + c_ang), normalised (quat_mul, quat_exp and rotate inlined)
        vx = (gyro[0] - bg[0]) * dt + c[0]
        vy = (gyro[1] - bg[1]) * dt + c[1]
        vz = (gyro[2] - bg[2]) * dt + c[2]
        t2 = vx * vx + vy * vy + vz * vz
        bw = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
        sn = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
        bx, by, bz = sn * vx, sn * vy, sn * vz
        aw, ax, ay, az = self.q
        qw = aw * bw - ax * bx - ay * by - az * bz
        qx = aw * bx + ax * bw + ay * bz - az * by
        qy = aw * by - ax * bz + ay * bw + az * bx
        qz = aw * bz + ax * by - ay * bx + az * bw
        n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        self.q = (qw / n, qx / n, qy / n, qz / n)
        # v' = v + R(q_old) (dV - ba dt) + g dt,  p <- p + (v + v') dt / 2
        x = (accel[0] - ba[0]) * dt
        y = (accel[1] - ba[1]) * dt
        z = (accel[2] - ba[2]) * dt
        w, a, b, c2 = aw, ax, ay, az
        dvx = (1 - 2 * (b * b + c2 * c2)) * x + 2 * (a * b - w * c2) * y + 2 * (a * c2 + w * b) * z
        dvy = 2 * (a * b + w * c2) * x + (1 - 2 * (a * a + c2 * c2)) * y + 2 * (b * c2 - w * a) * z
        dvz = 2 * (a * c2 - w * b) * x + 2 * (b * c2 + w * a) * y + (1 - 2 * (a * a + b * b)) * z
        v0, p0 = self.v, self.p
        v = (v0[0] + dvx, v0[1] + dvy, v0[2] + dvz + self._g * dt)
        h = 0.5 * dt
        self.p = (p0[0] + (v0[0] + v[0]) * h, p0[1] + (v0[1] + v[1]) * h,
                  p0[2] + (v0[2] + v[2]) * h)
        self.v = v
        self.t_us = t_us

    def record(self) -> None:
        """Keep the current output state (at a filter-period end) for the later fit."""
        self._record.append((self.t_us, self.q, self.v, self.p))

    def correct(self, t_delayed_us: int, q, v, p) -> None:
        """Fit the output track to the filter's state (q, v, p) at t_delayed_us."""
        while self._record and self._record[0][0] < t_delayed_us:
            self._record.popleft()
        if not self._record or self._record[0][0] != t_delayed_us:
            return
        _, q_o, v_o, p_o = self._record[0]
        qe = quat_mul((q_o[0], -q_o[1], -q_o[2], -q_o[3]), tuple(q))
        s = 2.0 if qe[0] >= 0.0 else -2.0
        gain = 0.5 * self._dt_imu / max((self.t_us - t_delayed_us) * 1e-6, self._dt_f)
        self._c_ang = (s * qe[1] * gain, s * qe[2] * gain, s * qe[3] * gain)
        e_v = [v[i] - v_o[i] for i in range(3)]
        e_p = [p[i] - p_o[i] for i in range(3)]
        self.tracking_error = (abs(s) * math.sqrt(qe[1] ** 2 + qe[2] ** 2 + qe[3] ** 2),
                               math.sqrt(sum(e * e for e in e_v)),
                               math.sqrt(sum(e * e for e in e_p)))
        kv, kp = self._k_v, self._k_p
        c_v, c_p = [0.0] * 3, [0.0] * 3
        for i in range(3):
            self._i_v[i] += e_v[i]
            self._i_p[i] += e_p[i]
            c_v[i] = kv * e_v[i] + 0.1 * kv * kv * self._i_v[i]
            c_p[i] = kp * e_p[i] + 0.1 * kp * kp * self._i_p[i]
        self.shift(c_v, c_p)

    def shift(self, dv, dp) -> None:
        """Add dv, dp to the current output state and to every recorded one."""
        def add(a, d):
            return (a[0] + d[0], a[1] + d[1], a[2] + d[2])
        self._record = deque(((t, q, add(v, dv), add(p, dp)) for t, q, v, p in self._record),
                             maxlen=self._record.maxlen)
        self.v, self.p = add(self.v, dv), add(self.p, dp)
