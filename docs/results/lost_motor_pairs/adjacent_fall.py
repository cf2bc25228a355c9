"""Two adjacent motors lost (1 and 3, the front pair) from a level hover at 5 m, in the plant
alone (sil_vehicle's Vehicle, 1 kHz, calm air, no controller): the hover commands held for
`switch_s` (the detection's delay), then the two live rear rotors (2, 4) cut to idle, tilts 0: an
upright free fall if anything is. With `burst_m` the live rotors go to full thrust again below that
height (a last burst that slows the fall at the price of the nose-down pitch they add). Prints, per
case, the body's largest tilt before the ground, the touchdown's speed and tilt, and the plant's
crash. The record: docs/decisions/2026-12-05-lost-motor-on-seeds.md.

    python docs/results/lost_motor_pairs/adjacent_fall.py > adjacent_fall.txt
"""

from __future__ import annotations

import math

import numpy as np

import trq_params
from sil_vehicle.config import load_sim
from sil_vehicle.faults import Faults
from sil_vehicle.frames import quat_to_dcm
from sil_vehicle.vehicle import ActuatorCommand, Vehicle, VehicleState

SIM_FILE = trq_params.DIR / "sim" / "default.yaml"


def fall(switch_s: float, burst_m: float | None = None, altitude_m: float = 5.0) -> dict:
    sim = load_sim(SIM_FILE).with_changes(wind_speed_m_s=0.0, gusts_enabled=False)
    vp = sim.vehicle
    veh = Vehicle(sim, np.random.default_rng(0))
    veh.faults = Faults().with_motor(0, off=True).with_motor(2, off=True)
    veh.armed = True
    hover = vp.thrust_N.inverse(vp.mass_kg * vp.gravity_m_s2 / 4.0)
    x0 = [0.0, 0.0, -altitude_m, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    veh.state = VehicleState(0, tuple(x0), (hover,) * 4, (0.0,) * 4, (0.0, 0.0, 0.0), True,
                             False, False, "")
    veh.command = ActuatorCommand((hover,) * 4, (0.0,) * 4)
    dt = sim.dt_us * 1e-6
    tilt_max = 0.0
    for k in range(int(round(4.0 / dt))):
        s = veh.state
        t = k * dt
        if s.on_ground and t > 0.05 or s.crashed:
            break
        height = -s.x[2]
        if t >= switch_s:
            full = burst_m is not None and height <= burst_m
            veh.command = ActuatorCommand((0.0, 100.0 if full else 0.0, 0.0,
                                           100.0 if full else 0.0), (0.0,) * 4)
        up = -np.asarray(quat_to_dcm(*s.x[6:10]))[:, 2]          # body -z in the world (NED)
        tilt_max = max(tilt_max, math.degrees(math.acos(max(-1.0, min(1.0, -up[2])))))
        veh.step()
    s = veh.state
    return {"switch_s": switch_s, "burst_m": burst_m, "t_s": round(s.t_us * 1e-6, 3),
            "tilt_max_deg": round(tilt_max, 1), "crashed": s.crashed,
            "crash_reason": s.crash_reason,
            "touchdown_speed_m_s": round(s.touchdown_speed_m_s, 2),
            "touchdown_tilt_deg": round(math.degrees(s.touchdown_tilt_rad), 1)}


def main() -> None:
    for switch_s in (0.0, 0.01, 0.02, 0.04, 0.11):
        print(fall(switch_s))
    for burst_m in (0.5, 1.0, 1.5):
        print(fall(0.0, burst_m))


if __name__ == "__main__":
    main()
