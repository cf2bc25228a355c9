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

`sample` is what the estimator calls per IMU sample: `propagate` with the filter's bias
estimates (`set_biases`), and the sample added to the filter period's delta angle and delta
velocity (the downsampler's sums, `take_sums` at the period's end; they are kept here so that
one compiled call does both). `NativeOutputPredictor` runs `sample` as C (predictor.c, built once
with the system's C compiler and cached like the physics tick, called through ctypes on one
array that holds the whole state): the same operations in the same order, built without fused
multiply-add, so the same numbers bit for bit; `native_predictor` gives it, or the Python
reference when no compiler is found.
"""

from __future__ import annotations

import ctypes
import math
import warnings
from collections import deque
from functools import lru_cache
from pathlib import Path

import numpy as np

from trq_wire.cache import cached_library, find_compiler

__all__ = ["OutputPredictor", "NativeOutputPredictor", "native_predictor", "quat_exp",
           "quat_mul", "rotate"]

SOURCE = Path(__file__).with_name("predictor.c")
# as the physics tick's (sil_vehicle.compiled): no fused multiply-add, never fast-math
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
# predictor.c's state array (enum S_*)
S_DT, S_G, S_Q, S_V, S_P, S_CANG, S_BG, S_BA, S_DA, S_DV, S_GYRO, S_ACCEL, S_SIZE = (
    0, 1, 2, 6, 9, 12, 15, 18, 21, 24, 27, 30, 33)


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
        self._dt_imu = self._dt_nominal = imu_period_us * 1e-6
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
        self._bg = self._ba = (0.0, 0.0, 0.0)      # the filter's bias estimates (set_biases)
        self._dA = [0.0, 0.0, 0.0]                  # the filter period's sums (take_sums)
        self._dV = [0.0, 0.0, 0.0]

    def reset(self, t_us: int, q, v, p) -> None:
        """The output state set to the filter's (at alignment); no record, no correction, the
        period's sums zero."""
        self.t_us = t_us
        self.q, self.v, self.p = tuple(q), tuple(v), tuple(p)
        self._record.clear()
        self._c_ang = (0.0, 0.0, 0.0)
        self._i_v = [0.0, 0.0, 0.0]
        self._i_p = [0.0, 0.0, 0.0]
        self._zero_sums()

    def set_biases(self, bg, ba) -> None:
        """The filter's gyro and accelerometer bias estimates, which `sample` removes."""
        self._bg, self._ba = tuple(bg), tuple(ba)

    def sample(self, t_us: int, gyro, accel, dt_s: float | None = None) -> None:
        """One IMU sample (as `propagate`, with the biases of `set_biases`), added to the
        period's sums too. `dt_s`: the sample's own interval (EKF2's delta_ang_dt), kept for
        the samples after it; None: the last one (at first the IMU's nominal period)."""
        if dt_s is not None:
            self._dt_imu = dt_s
        self.propagate(t_us, gyro, accel, self._bg, self._ba)
        self._sum(gyro, accel)

    def _sum(self, g, f) -> None:
        """The delta angle and delta velocity over the filter period, the velocity rotated into
        the frame at the start of the period with the first-order sculling term
        dV += dv + (dA_acc + dA / 2) x dv."""
        dt = self._dt_imu
        ax, ay, az = (g[0] * dt, g[1] * dt, g[2] * dt)
        vx, vy, vz = (f[0] * dt, f[1] * dt, f[2] * dt)
        A, V = self._dA, self._dV
        rx, ry, rz = A[0] + 0.5 * ax, A[1] + 0.5 * ay, A[2] + 0.5 * az
        V[0] += vx + ry * vz - rz * vy
        V[1] += vy + rz * vx - rx * vz
        V[2] += vz + rx * vy - ry * vx
        A[0] += ax
        A[1] += ay
        A[2] += az

    def take_sums(self) -> tuple[np.ndarray, np.ndarray]:
        """(dA (3,), dV (3,)) of the samples since the last call (or reset), then zeroed."""
        out = np.array(self._dA), np.array(self._dV)
        self._zero_sums()
        return out

    def _zero_sums(self) -> None:
        self._dA, self._dV = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]

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
        record = self._record
        while record and record[0][0] < t_delayed_us:
            record.popleft()
        if not record or record[0][0] != t_delayed_us:
            return
        _, q_o, v_o, p_o = record[0]
        # qe = conj(q_o) (x) q (quat_mul inlined)
        aw, ax, ay, az = q_o[0], -q_o[1], -q_o[2], -q_o[3]
        bw, bx, by, bz = q
        qw = aw * bw - ax * bx - ay * by - az * bz
        qx = aw * bx + ax * bw + ay * bz - az * by
        qy = aw * by - ax * bz + ay * bw + az * bx
        qz = aw * bz + ax * by - ay * bx + az * bw
        s = 2.0 if qw >= 0.0 else -2.0
        gain = 0.5 * self._dt_nominal / max((self.t_us - t_delayed_us) * 1e-6, self._dt_f)
        self._c_ang = (s * qx * gain, s * qy * gain, s * qz * gain)
        ev0, ev1, ev2 = v[0] - v_o[0], v[1] - v_o[1], v[2] - v_o[2]
        ep0, ep1, ep2 = p[0] - p_o[0], p[1] - p_o[1], p[2] - p_o[2]
        # the sums as sum() adds them (from 0, in order)
        self.tracking_error = (abs(s) * math.sqrt(qx ** 2 + qy ** 2 + qz ** 2),
                               math.sqrt(0 + ev0 * ev0 + ev1 * ev1 + ev2 * ev2),
                               math.sqrt(0 + ep0 * ep0 + ep1 * ep1 + ep2 * ep2))
        kv, kp = self._k_v, self._k_p
        i_v, i_p = self._i_v, self._i_p
        i_v[0] += ev0
        i_v[1] += ev1
        i_v[2] += ev2
        i_p[0] += ep0
        i_p[1] += ep1
        i_p[2] += ep2
        self.shift((kv * ev0 + 0.1 * kv * kv * i_v[0], kv * ev1 + 0.1 * kv * kv * i_v[1],
                    kv * ev2 + 0.1 * kv * kv * i_v[2]),
                   (kp * ep0 + 0.1 * kp * kp * i_p[0], kp * ep1 + 0.1 * kp * kp * i_p[1],
                    kp * ep2 + 0.1 * kp * kp * i_p[2]))

    def shift(self, dv, dp) -> None:
        """Add dv, dp to the current output state and to every recorded one."""
        d0, d1, d2 = dv
        e0, e1, e2 = dp
        self._record = deque(((t, q, (v[0] + d0, v[1] + d1, v[2] + d2),
                               (p[0] + e0, p[1] + e1, p[2] + e2)) for t, q, v, p in self._record),
                             maxlen=self._record.maxlen)
        v, p = self.v, self.p
        self.v = (v[0] + d0, v[1] + d1, v[2] + d2)
        self.p = (p[0] + e0, p[1] + e1, p[2] + e2)

class NativeOutputPredictor(OutputPredictor):
    """The output predictor with `sample` in C (predictor.c) on one ctypes array that holds
    its state; everything else is the Python reference's code, reading and writing the state
    through the properties below."""

    def __init__(self, lib: ctypes.CDLL, **kw) -> None:
        self._s = (ctypes.c_double * S_SIZE)()
        self._c = lib.trq_imu_sample
        self._c.argtypes = (ctypes.c_double * S_SIZE,)
        self._c.restype = None
        super().__init__(**kw)
        self._s[S_DT] = self._dt_imu
        self._s[S_G] = self._g

    def sample(self, t_us: int, gyro, accel, dt_s: float | None = None) -> None:
        s = self._s
        if dt_s is not None:
            s[S_DT] = dt_s
        s[S_GYRO:S_GYRO + 3] = gyro
        s[S_ACCEL:S_ACCEL + 3] = accel
        self._c(s)
        self.t_us = t_us

    def propagate(self, t_us: int, gyro, accel, bg, ba) -> None:
        s = self._s
        kept = s[S_BG:S_DV + 3]                 # the biases set and the sums: as they were
        s[S_BG:S_BG + 3], s[S_BA:S_BA + 3] = bg, ba
        self.sample(t_us, gyro, accel)
        s[S_BG:S_DV + 3] = kept

    def set_biases(self, bg, ba) -> None:
        self._s[S_BG:S_BG + 3], self._s[S_BA:S_BA + 3] = bg, ba

    def take_sums(self) -> tuple[np.ndarray, np.ndarray]:
        s = self._s
        out = np.array(s[S_DA:S_DA + 3]), np.array(s[S_DV:S_DV + 3])
        self._zero_sums()
        return out

    def _zero_sums(self) -> None:
        self._s[S_DA:S_DA + 6] = (0.0,) * 6

    def _get(i: int, n: int):        # noqa: N805 (a property factory, used in the class body)
        def get(self) -> tuple[float, ...]:
            return tuple(self._s[i:i + n])

        def put(self, value) -> None:
            self._s[i:i + n] = value
        return property(get, put)

    q = _get(S_Q, 4)
    v = _get(S_V, 3)
    p = _get(S_P, 3)
    _c_ang = _get(S_CANG, 3)
    del _get


def _build(cc: str) -> Path:
    return cached_library(cc, list(CFLAGS), SOURCE, "sil_predictor", ["-lm"])


@lru_cache(maxsize=1)
def _library() -> ctypes.CDLL | None:
    cc = find_compiler()
    if cc is None:
        warnings.warn("no C compiler found (tried $CC, gcc, cc, clang): the estimator's output "
                      "predictor runs in Python (the same results, slower)", RuntimeWarning,
                      stacklevel=3)
        return None
    try:
        lib = ctypes.CDLL(str(_build(cc)))
        if lib.trq_imu_sample_size() != S_SIZE:
            raise RuntimeError(f"predictor.c's state has {lib.trq_imu_sample_size()} entries, "
                               f"predictor.py's {S_SIZE}")
        return lib
    except (OSError, RuntimeError) as exc:
        warnings.warn(f"the compiled output predictor is unavailable ({exc}): it runs in "
                      "Python", RuntimeWarning, stacklevel=3)
        return None


def native_predictor(**kw) -> OutputPredictor:
    """A NativeOutputPredictor (the library built and cached on first use), or the Python
    OutputPredictor with a RuntimeWarning when no C compiler is found or the build fails."""
    lib = _library()
    return OutputPredictor(**kw) if lib is None else NativeOutputPredictor(lib, **kw)
