"""The vehicle's own low-level controller, used when the offboard link is lost: hold attitude
(level, yaw where it was) and altitude, then descend, touch down and disarm, as the autopilot of
a real prototype would.

It knows the airframe (geometry and rotor curves) but not the faults: integral terms on the
attitude and the climb rate absorb a weak motor. The wrench it asks for is allocated to the
actuators by the pseudo-inverse of the effectiveness in the virtual inputs
(F_i cos alpha_i, F_i sin alpha_i), in which the body wrench is linear (the rotor drag torque
taken as kappa F_i, kappa the torque-to-thrust ratio at hover); then alpha_i = atan2, F_i = norm,
and the throttle from the inverted thrust curve. A fixed-rotor airframe uses the thrusts alone.
Deterministic: its state is its integrators and its phase, advanced by `update`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sil_vehicle.config import VehicleParams
from sil_vehicle.frames import quat_to_euler, wrap_pi
from sil_vehicle.vehicle import ActuatorCommand, VehicleState


@dataclass(frozen=True)
class FailsafeGains:
    hold_s: float = 2.0            # hold altitude before descending
    descent_m_s: float = 0.5       # descent rate above the last metre (a choice)
    # in the last metre: PX4's MPC_LAND_CRWL default. PX4 keeps it above its land detector's
    # vertical-speed bound (LNDMC_Z_VEL_MAX <= crawl / 1.2, land_detector.Z_VEL_MAX_M_S), so
    # that a vehicle resting on its gear reads as a descent that stopped; slower, an estimate
    # sinking on the gear satisfies the descent and the thrust never lets go of the weight
    crawl_m_s: float = 0.3
    kp_att: float = 432.0          # rad/s^2 per rad (a triple pole at 12 rad/s)
    kd_att: float = 36.0           # rad/s^2 per rad/s
    ki_att: float = 1728.0         # rad/s^2 per rad s
    kp_vz: float = 4.0             # m/s^2 per m/s
    ki_vz: float = 2.0             # m/s^2 per m
    kp_z: float = 1.5              # m/s per m (altitude hold)
    i_limit_att: float = 0.2       # |integral| bound, rad s
    i_limit_vz: float = 5.0        # |integral| bound, m


def effectiveness(vp: VehicleParams) -> np.ndarray:
    """6 x 8 map from virtual inputs [c_1..4, s_1..4] (N) to the body wrench (N, N m)."""
    kappa = vp.torque_Nm(vp.hover_throttle_pct) / vp.thrust_N(vp.hover_throttle_pct)
    cols_c, cols_s = [], []
    for rotor in vp.rotors:
        ax, ay, _ = rotor.tilt_axis_frd
        r = np.array(rotor.position_frd_m)
        for direction, cols in (((0.0, 0.0, -1.0), cols_c), ((-ay, ax, 0.0), cols_s)):
            d = np.array(direction)
            cols.append(np.concatenate([d, np.cross(r, d) - rotor.spin * kappa * d]))
    return np.column_stack(cols_c + cols_s)


class FailsafeLander:
    def __init__(self, vp: VehicleParams, gains: FailsafeGains = FailsafeGains()) -> None:
        self.vp = vp
        self.g = gains
        a = effectiveness(vp)
        if vp.tilt_locked:
            self._rows = [2, 3, 4, 5]                     # Fz, Mx, My, Mz from the 4 thrusts
            self._pinv = np.linalg.pinv(a[np.ix_(self._rows, range(4))])
        else:
            self._rows = list(range(6))
            self._pinv = np.linalg.pinv(a)
        self.active = False
        self.engaged_us = 0

    def engage(self, state: VehicleState) -> None:
        self.active = True
        self._t0_us = self.engaged_us = state.t_us
        self._yaw = quat_to_euler(*state.x[6:10])[2]
        self._z_hold = state.x[2]
        self._i_att = np.zeros(3)
        self._i_vz = 0.0

    def update(self, state: VehicleState, dt_s: float) -> ActuatorCommand:
        """One tick of the hold-then-land controller (engaged at `engage`)."""
        g, vp = self.g, self.vp
        roll, pitch, yaw = quat_to_euler(*state.x[6:10])
        rates = np.array(state.x[10:13])
        z, vz = state.x[2], state.x[5]
        t = (state.t_us - self._t0_us) * 1e-6
        # vertical: hold, then descend (slower near the ground)
        if t < g.hold_s:
            vz_sp = g.kp_z * (self._z_hold - z)
        else:
            vz_sp = g.descent_m_s if z < -1.0 else g.crawl_m_s
        e_vz = vz_sp - vz
        self._i_vz = float(np.clip(self._i_vz + e_vz * dt_s, -g.i_limit_vz, g.i_limit_vz))
        az = g.kp_vz * e_vz + g.ki_vz * self._i_vz              # down-positive acceleration
        tilt = max(math.cos(roll) * math.cos(pitch), 0.5)
        fz = -vp.mass_kg * (vp.gravity_m_s2 - az) / tilt        # body z force (negative: up)
        fz = min(fz, 0.0)
        # attitude: level, yaw held
        e_att = np.array([-roll, -pitch, wrap_pi(self._yaw - yaw)])
        self._i_att = np.clip(self._i_att + e_att * dt_s, -g.i_limit_att, g.i_limit_att)
        acc = g.kp_att * e_att - g.kd_att * rates + g.ki_att * self._i_att
        torque = np.array(vp.inertia_kg_m2) * acc
        wrench = np.concatenate([[0.0, 0.0, fz], torque])[self._rows]
        v = self._pinv @ wrench
        if vp.tilt_locked:
            thrusts, tilts = np.maximum(v, 0.0), np.zeros(4)
        else:
            c, s = v[0:4], v[4:8]
            thrusts = np.hypot(c, s)
            tilts = np.clip(np.arctan2(s, np.maximum(c, 1e-6)), vp.tilt_min_rad, vp.tilt_max_rad)
        throttle = [min(100.0, max(vp.idle_pct, vp.thrust_N.inverse(float(f)))) for f in thrusts]
        return ActuatorCommand(tuple(throttle), tuple(float(a) for a in tilts))
