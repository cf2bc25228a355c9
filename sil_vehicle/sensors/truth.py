"""What the plant knows at a tick, as the sensors read it: a small immutable record.

The vehicle builds one per physics tick (`Sitl._sense`); the sensor models never see the vehicle
itself. The record holds plain tuples of floats (`pos`, `vel`, `quat`, `rates`, `force`,
`motors`): building it is the vehicle's per-tick cost, so it converts nothing, and the models
read their floats from it directly. The same quantities as float64 arrays, under the names the
readings use (`pos_ned_m`, ..., shapes in the comments), are built on access, a new array each
time (for the models that do array arithmetic at a sensor's own rate, and for tests).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from sil_vehicle.sensors.noise import rotate_to_body

__all__ = ["Truth", "specific_force_frd", "imu_truth", "STANDARD_GRAVITY_M_S2"]

STANDARD_GRAVITY_M_S2 = 9.80665


def _floats(seq) -> tuple[float, ...]:
    return tuple(np.asarray(seq, float).tolist())


class Truth(NamedTuple):
    t_us: int
    pos: tuple[float, ...]        # (3,) NED position, m
    vel: tuple[float, ...]        # (3,) NED velocity, m/s
    quat: tuple[float, ...]       # (4,) body FRD -> world NED, scalar first
    rates: tuple[float, ...]      # (3,) body FRD rates, rad/s
    force: tuple[float, ...]      # (3,) what an accelerometer reads: (a - g) in body FRD, m/s^2
    motors: tuple[float, ...]     # (n_motors,) throttle the motors produce, 0..100 %

    @classmethod
    def of(cls, t_us: int, pos_ned_m: Sequence[float], vel_ned_m_s: Sequence[float],
           quat_wxyz: Sequence[float], rates_frd_rad_s: Sequence[float],
           specific_force_frd_m_s2: Sequence[float], motor_pct: Sequence[float]) -> "Truth":
        """From any sequences (arrays, tuples of the vehicle's state), as tuples of floats."""
        f = _floats
        return cls(int(t_us), f(pos_ned_m), f(vel_ned_m_s), f(quat_wxyz), f(rates_frd_rad_s),
                   f(specific_force_frd_m_s2), f(motor_pct))

    @classmethod
    def at_rest(cls, t_us: int = 0, gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
                quat_wxyz=(1.0, 0.0, 0.0, 0.0), motor_pct=(0.0, 0.0, 0.0, 0.0)) -> "Truth":
        """A vehicle standing still at the origin (tests, the first tick)."""
        q = np.asarray(quat_wxyz, float)
        return cls.of(t_us, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), q, (0.0, 0.0, 0.0),
                      specific_force_frd(q, np.zeros(3), gravity_m_s2), motor_pct)

    # the same as float64 arrays (a new one per access)
    @property
    def pos_ned_m(self) -> np.ndarray:                  # (3,)
        return np.array(self.pos)

    @property
    def vel_ned_m_s(self) -> np.ndarray:                # (3,)
        return np.array(self.vel)

    @property
    def quat_wxyz(self) -> np.ndarray:                  # (4,)
        return np.array(self.quat)

    @property
    def rates_frd_rad_s(self) -> np.ndarray:            # (3,)
        return np.array(self.rates)

    @property
    def specific_force_frd_m_s2(self) -> np.ndarray:    # (3,)
        return np.array(self.force)

    @property
    def motor_pct(self) -> np.ndarray:                  # (n_motors,)
        return np.array(self.motors, dtype=float)


def specific_force_frd(quat_wxyz: np.ndarray, accel_ned_m_s2: np.ndarray,
                       gravity_m_s2: float) -> np.ndarray:
    """f = R^T (a - g) with g = (0, 0, +gravity) in NED: a level vehicle at rest reads
    (0, 0, -gravity) in FRD."""
    g = np.array((0.0, 0.0, gravity_m_s2))
    return rotate_to_body(np.asarray(quat_wxyz, float), np.asarray(accel_ned_m_s2, float) - g)



def imu_truth(q0: Sequence[float], q1: Sequence[float], v0: Sequence[float],
              v1: Sequence[float], dt_s: float, gravity_m_s2: float
              ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(rates, specific force) in body FRD that an integrating IMU reads over a tick in which the
    attitude (body FRD -> NED, scalar first) went from q0 to q1 and the NED velocity from v0 to
    v1. The rates: the rotation vector of q0^* q1 (the tick's delta angle) over dt. The specific
    force: the mean acceleration over the tick less gravity, a - g with a = (v1 - v0) / dt,
    rotated into the body frame at the tick's middle attitude q0 exp(delta / 2), where an
    integrating accelerometer's delta velocity sits (and where the estimator's sculling
    correction expects it). Every change of attitude and velocity reaches the IMU this way, the
    plant's touchdown (which stops and levels the vehicle within one tick) included. Plain
    floats: this runs every physics tick."""
    aw, ax, ay, az = q0
    bw, bx, by, bz = q1
    w = aw * bw + ax * bx + ay * by + az * bz          # q0^* q1
    x = aw * bx - ax * bw - ay * bz + az * by
    y = aw * by + ax * bz - ay * bw - az * bx
    z = aw * bz - ax * by + ay * bx - az * bw
    if w < 0.0:                                       # the shorter way round
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    half = math.atan2(n, w)                           # half the tick's rotation angle
    k = 2.0 * half / n if n > 1e-9 else 2.0 / w       # rotation vector = k (x, y, z)
    rates = (k * x / dt_s, k * y / dt_s, k * z / dt_s)
    # the middle attitude: q0 times the quarter-angle rotation about the same axis
    c, sn = math.cos(0.5 * half), (math.sin(0.5 * half) / n if n > 1e-9 else 0.25 * k)
    hx, hy, hz = sn * x, sn * y, sn * z
    qw = aw * c - ax * hx - ay * hy - az * hz
    qx = aw * hx + ax * c + ay * hz - az * hy
    qy = aw * hy - ax * hz + ay * c + az * hx
    qz = aw * hz + ax * hy - ay * hx + az * c
    an, ae = (v1[0] - v0[0]) / dt_s, (v1[1] - v0[1]) / dt_s
    ad = (v1[2] - v0[2]) / dt_s - gravity_m_s2
    # R^T (a - g), R's entries spelled as frames.quat_to_dcm spells them
    force = ((1 - 2 * (qy * qy + qz * qz)) * an + 2 * (qx * qy + qw * qz) * ae
             + 2 * (qx * qz - qw * qy) * ad,
             2 * (qx * qy - qw * qz) * an + (1 - 2 * (qx * qx + qz * qz)) * ae
             + 2 * (qy * qz + qw * qx) * ad,
             2 * (qx * qz + qw * qy) * an + 2 * (qy * qz - qw * qx) * ae
             + (1 - 2 * (qx * qx + qy * qy)) * ad)
    return rates, force
