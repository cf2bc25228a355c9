"""6-DoF rigid body (Newton-Euler) and its fixed-step RK4 integration.

State x (13 floats, a tuple):
    0-2   position NED (m)           3-5   velocity NED (m/s)
    6-9   attitude quaternion (w, x, y, z), body FRD to world NED
    10-12 body rates FRD p, q, r (rad/s)
Over one step the body wrench of the rotors is held (zero-order hold of the actuator outputs);
drag is re-evaluated at each RK4 stage since it depends on the velocity, and so is the ground's
contact wrench (sil_vehicle.dynamics.contact, given `gear`), which depends on the whole state.

    m dv/dt = R(q) F_B + m g e_z + F_drag(v - w)
    I dw/dt = tau_B - w x I w
    dq/dt   = 1/2 q (x) (0, w)
Written with scalars: this is the simulator's inner loop (about 4,000 RK4 stages per simulated
second) and plain floats are several times faster than NumPy on arrays of three.
"""

from __future__ import annotations

import math
from typing import Sequence

from sil_vehicle.dynamics.contact import Gear, contact_wrench

State = tuple[float, ...]

N_STATE = 13


def derivative(x: Sequence[float], wrench_frd: Sequence[float], wind_ned: Sequence[float],
               mass_kg: float, inertia: Sequence[float], gravity: float,
               drag_k: float, gear: Gear | None = None,
               anchors_ne_m: Sequence[float] = ()) -> State:
    _, _, _, vn, ve, vd, qw, qx, qy, qz, p, q, r = x
    fx, fy, fz, mx, my, mz = wrench_frd
    # body force to world
    fn = (1 - 2 * (qy * qy + qz * qz)) * fx + 2 * (qx * qy - qw * qz) * fy + 2 * (qx * qz + qw * qy) * fz
    fe = 2 * (qx * qy + qw * qz) * fx + (1 - 2 * (qx * qx + qz * qz)) * fy + 2 * (qy * qz - qw * qx) * fz
    fdn = 2 * (qx * qz - qw * qy) * fx + 2 * (qy * qz + qw * qx) * fy + (1 - 2 * (qx * qx + qy * qy)) * fz
    if gear is not None and x[2] > gear.reach_down_m:     # the ground within reach
        cn, ce, cd, cx, cy, cz = contact_wrench(x, gear, anchors_ne_m)
        fn = fn + cn
        fe = fe + ce
        fdn = fdn + cd
        mx = mx + cx
        my = my + cy
        mz = mz + cz
    rx, ry, rz = vn - wind_ned[0], ve - wind_ned[1], vd - wind_ned[2]
    s = -drag_k * math.sqrt(rx * rx + ry * ry + rz * rz)
    inv_m = 1.0 / mass_kg
    ixx, iyy, izz = inertia
    return (vn, ve, vd,
            (fn + s * rx) * inv_m, (fe + s * ry) * inv_m, (fdn + s * rz) * inv_m + gravity,
            0.5 * (-qx * p - qy * q - qz * r), 0.5 * (qw * p + qy * r - qz * q),
            0.5 * (qw * q - qx * r + qz * p), 0.5 * (qw * r + qx * q - qy * p),
            (mx - (izz - iyy) * q * r) / ixx, (my - (ixx - izz) * r * p) / iyy,
            (mz - (iyy - ixx) * p * q) / izz)


def rk4_step(x: Sequence[float], dt: float, wrench_frd: Sequence[float],
             wind_ned: Sequence[float], mass_kg: float, inertia: Sequence[float],
             gravity: float, drag_k: float, gear: Gear | None = None,
             anchors_ne_m: Sequence[float] = ()) -> State:
    """One RK4 step; the quaternion is renormalised afterwards. `gear`: the ground's contact
    (none: no ground), with its points' stick anchors (held over the step)."""
    args = (wrench_frd, wind_ned, mass_kg, inertia, gravity, drag_k, gear, anchors_ne_m)
    h = 0.5 * dt
    k1 = derivative(x, *args)
    k2 = derivative([a + h * b for a, b in zip(x, k1)], *args)
    k3 = derivative([a + h * b for a, b in zip(x, k2)], *args)
    k4 = derivative([a + dt * b for a, b in zip(x, k3)], *args)
    d6 = dt / 6.0
    y = [a + d6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
    n = 1.0 / math.sqrt(y[6] * y[6] + y[7] * y[7] + y[8] * y[8] + y[9] * y[9])
    y[6] *= n
    y[7] *= n
    y[8] *= n
    y[9] *= n
    return tuple(y)
