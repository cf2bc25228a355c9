"""Rotor forces: the body wrench of four tilted rotors, from throttle (percent) and tilt (rad).

Rotor i sits at r_i = l * a_i, a_i = (cos az_i, sin az_i, 0) its arm axis in body FRD. Its thrust
direction, tilted by alpha_i about the arm, is n_i = (-a_y sin alpha, a_x sin alpha, -cos alpha).
Force F_i n_i; torque r_i x F_i n_i - spin_i tau_i n_i (a ccw rotor, spin +1, yaws the body right).
"""

from __future__ import annotations

import math
from typing import Sequence

from sil_vehicle.config import VehicleParams


def thrust_direction_frd(axis: Sequence[float], tilt_rad: float) -> tuple[float, float, float]:
    s, c = math.sin(tilt_rad), math.cos(tilt_rad)
    return (-axis[1] * s, axis[0] * s, -c)


def body_wrench(throttle_pct: Sequence[float], tilt_rad: Sequence[float],
                vp: VehicleParams) -> tuple[float, float, float, float, float, float]:
    """(Fx, Fy, Fz, Mx, My, Mz) in body FRD, N and N m, for the actual actuator outputs."""
    fx = fy = fz = mx = my = mz = 0.0
    thrust, torque = vp.thrust_N, vp.torque_Nm
    for rotor, zeta, alpha in zip(vp.rotors, throttle_pct, tilt_rad):
        f = thrust(zeta)
        tau = torque(zeta) * rotor.spin
        nx, ny, nz = thrust_direction_frd(rotor.tilt_axis_frd, alpha)
        px, py, pz = rotor.position_frd_m
        fx += f * nx
        fy += f * ny
        fz += f * nz
        mx += f * (py * nz - pz * ny) - tau * nx
        my += f * (pz * nx - px * nz) - tau * ny
        mz += f * (px * ny - py * nx) - tau * nz
    return fx, fy, fz, mx, my, mz
