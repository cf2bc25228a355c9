"""The slowest fall possible with two opposite motors lost from a 5 m hover, in calm air and
in the paper's 8 m/s wind: the two live rotors at full thrust from the instant of the failure,
the body level, the plant's quadratic drag on the air-relative velocity (F = -k |v_rel| v_rel);
either holding the point against the wind (the thrust's horizontal part balancing the drag) or
drifting with it (all thrust vertical). Prints the touchdown speed (the lower bound of any
controller's) and the time to the ground. The vehicle's figures from params/vehicle/trq.yaml.
The record: docs/decisions/2026-12-05-lost-motor-axes.md.

    python docs/results/lost_motor_pairs_wind/bound.py > bound.txt
"""

from __future__ import annotations

import math

import trq_params
from trq_offboard.config import load_vehicle_model

DT_S = 1e-4             # explicit Euler step (the figures move below 1 mm/s from 1e-3 to 1e-4)


def fall(wind_m_s: float, hold: bool, height_m: float = 5.0) -> tuple[float, float, float]:
    """(touchdown speed m/s, horizontal ground speed m/s at touchdown, time s)."""
    vm = load_vehicle_model(trq_params.DIR / "vehicle" / "trq.yaml")
    th = vm.thrust_N
    thrust = 2.0 * ((th.c2 * 100.0 + th.c1) * 100.0 + th.c0)       # both live rotors at 100 %
    m, g, k = vm.mass_kg, vm.gravity_m_s2, vm.drag_N_s2_m2
    v = vh = t = 0.0
    h = height_m
    while h > 0.0:
        air_h = wind_m_s - vh                                         # air past the body
        air = math.hypot(air_h, v)
        if hold:
            f_h = k * air * air_h                                    # the drag the thrust holds
            t_v, a_h = math.sqrt(max(thrust ** 2 - f_h ** 2, 0.0)), 0.0
        else:
            t_v, a_h = thrust, k * air * air_h / m
        v += (g - t_v / m - k * air * v / m) * DT_S
        vh += a_h * DT_S
        h -= v * DT_S
        t += DT_S
    return v, vh, t


if __name__ == "__main__":
    print("wind m/s | horizontally | touchdown m/s | ground speed m/s | time s")
    for wind in (0.0, 8.0):
        for hold in (True, False):
            v, vh, t = fall(wind, hold)
            print(f"{wind:.0f} | {'holds the point' if hold else 'drifts'} | {v:.2f} | {vh:.2f} | "
                  f"{t:.2f}")
