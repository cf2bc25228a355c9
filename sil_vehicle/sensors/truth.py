"""What the plant knows at a tick, as the sensors read it: a small frozen record.

The vehicle builds one per physics tick (the next step wires it); the sensor models never see
the vehicle itself. Arrays are float64, shapes in the comments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sil_vehicle.sensors.noise import rotate_to_body

__all__ = ["Truth", "specific_force_frd", "STANDARD_GRAVITY_M_S2"]

STANDARD_GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class Truth:
    t_us: int
    pos_ned_m: np.ndarray                 # (3,)
    vel_ned_m_s: np.ndarray               # (3,)
    quat_wxyz: np.ndarray                 # (4,) body FRD -> world NED, scalar first
    rates_frd_rad_s: np.ndarray           # (3,)
    specific_force_frd_m_s2: np.ndarray   # (3,) what an accelerometer reads: (a - g) in body
    motor_pct: np.ndarray                 # (n_motors,) throttle the motors produce, 0..100

    @classmethod
    def of(cls, t_us: int, pos_ned_m, vel_ned_m_s, quat_wxyz, rates_frd_rad_s,
           specific_force_frd_m_s2, motor_pct) -> "Truth":
        """From any sequences (tuples of the vehicle's state), as float arrays."""
        f = np.asarray
        return cls(int(t_us), f(pos_ned_m, float), f(vel_ned_m_s, float), f(quat_wxyz, float),
                   f(rates_frd_rad_s, float), f(specific_force_frd_m_s2, float),
                   f(motor_pct, float))

    @classmethod
    def at_rest(cls, t_us: int = 0, gravity_m_s2: float = STANDARD_GRAVITY_M_S2,
                quat_wxyz=(1.0, 0.0, 0.0, 0.0), motor_pct=(0.0, 0.0, 0.0, 0.0)) -> "Truth":
        """A vehicle standing still at the origin (tests, the first tick)."""
        q = np.asarray(quat_wxyz, float)
        return cls.of(t_us, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), q, (0.0, 0.0, 0.0),
                      specific_force_frd(q, np.zeros(3), gravity_m_s2), motor_pct)


def specific_force_frd(quat_wxyz: np.ndarray, accel_ned_m_s2: np.ndarray,
                       gravity_m_s2: float) -> np.ndarray:
    """f = R^T (a - g) with g = (0, 0, +gravity) in NED: a level vehicle at rest reads
    (0, 0, -gravity) in FRD."""
    g = np.array((0.0, 0.0, gravity_m_s2))
    return rotate_to_body(np.asarray(quat_wxyz, float), np.asarray(accel_ned_m_s2, float) - g)
