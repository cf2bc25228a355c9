"""Control allocation by direct inversion (paper eq. 9): body wrench -> throttles and tilts.

Effectiveness. With the virtual inputs of rotor i
    c_i = F_i cos(alpha_i),   s_i = F_i sin(alpha_i)          (F_i thrust, N)
and the drag torque written as tau_i = kappa_i F_i, the body wrench of the four tilted rotors is
linear in v = [c_1..c_4, s_1..s_4]:
    force  += c_i (0, 0, -1) + s_i (-a_y, a_x, 0)
    torque += c_i (-l a_y, l a_x, spin_i kappa_i) + s_i (spin_i kappa_i a_y, -spin_i kappa_i a_x, l)
(a_i the arm axis, l the arm length; see model/dynamics.py for the geometry). For a locked
(fixed-rotor) airframe s_i = 0 and only the rows (F_z, M_x, M_y, M_z) are controllable: a 4x4 map.

Allocation. v = pinv(B) w (minimum norm), then alpha_i = atan2(s_i, c_i), F_i = |(c_i, s_i)|,
throttle from the inverted thrust curve; finally saturation to the tilt limits and idle..100 %.

Drag torque. kappa_i = tau(zeta_i) / F(zeta_i) is not constant. The first pass uses kappa at the
hover throttle for all rotors; `refine_iterations` fixed-point passes then recompute kappa_i from
the throttle just found and re-solve. The map stays linear at every pass, so when the fixed point
is reached the exact curves reproduce the wrench exactly; the TRQ contracts faster than the quad
(whose yaw torque comes from the drag torque alone). Default: 12 passes (the measured errors per
pass: docs/decisions/2026-12-02-figures-from-comments.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from trq_offboard.config import VehicleModel
from trq_offboard.records import ActuatorCommand

__all__ = ["Allocator", "Allocation", "rotor_wrench"]


def rotor_wrench(vehicle: VehicleModel, throttle_pct, tilt_rad) -> np.ndarray:
    """Exact body wrench (6, FRD) of the rotors with the unclamped curves (NumPy)."""
    out = np.zeros(6)
    for rotor, zeta, alpha in zip(vehicle.rotors, throttle_pct, tilt_rad):
        f = vehicle.thrust_N.value(zeta)
        tau = vehicle.torque_Nm.value(zeta)
        ax, ay, _ = rotor.arm_frd
        n = np.array([-ay * math.sin(alpha), ax * math.sin(alpha), -math.cos(alpha)])
        out[0:3] += f * n
        out[3:6] += np.cross(rotor.position_frd_m, f * n) - rotor.spin * tau * n
    return out


@dataclass(frozen=True)
class Allocation:
    command: ActuatorCommand
    thrust_N: tuple[float, ...]
    saturated: bool                     # some value was clipped to its limit
    wrench_error: float                 # |B u - w| (inf-norm) of the result, exact curves


class Allocator:
    """Direct-inversion allocator of one airframe (built once; `allocate` is cheap)."""

    def __init__(self, vehicle: VehicleModel, refine_iterations: int = 12) -> None:
        self.vehicle = vehicle
        self.refine_iterations = refine_iterations
        zh = vehicle.hover_throttle_pct
        self.kappa_hover = vehicle.torque_Nm.value(zh) / vehicle.thrust_N.value(zh)
        self._rows = slice(0, 6) if not vehicle.tilt_locked else [2, 3, 4, 5]

    def effectiveness(self, kappa) -> np.ndarray:
        """B: wrench (6) = B v, v = [c_1..4, s_1..4] (TRQ); rows (Fz, Mx, My, Mz) of the
        thrusts (4) for a locked airframe."""
        vm = self.vehicle
        kappa = np.broadcast_to(np.asarray(kappa, dtype=float), (4,))
        B = np.zeros((6, 8))
        l = vm.arm_length_m
        for i, rotor in enumerate(vm.rotors):
            ax, ay, _ = rotor.arm_frd
            sk = rotor.spin * kappa[i]
            B[:, i] = (0.0, 0.0, -1.0, -l * ay, l * ax, sk)
            B[:, 4 + i] = (-ay, ax, 0.0, sk * ay, -sk * ax, l)
        if vm.tilt_locked:
            return B[np.ix_([2, 3, 4, 5], range(4))]
        return B

    def allocate(self, wrench_frd) -> Allocation:
        """Throttles and tilts producing the body wrench (FRD, N and N m), then saturated."""
        vm = self.vehicle
        w = np.asarray(wrench_frd, dtype=float).reshape(6)
        target = w[self._rows]
        kappa = np.full(4, self.kappa_hover)
        zeta = np.zeros(4)
        alpha = np.zeros(4)
        for _ in range(1 + self.refine_iterations):
            v = np.linalg.pinv(self.effectiveness(kappa)) @ target
            if vm.tilt_locked:
                c, s = v, np.zeros(4)
            else:
                c, s = v[0:4], v[4:8]
            force = np.hypot(c, s)
            alpha = np.arctan2(s, c)
            f_idle = vm.thrust_N.value(vm.idle_pct)
            zeta = np.array([vm.thrust_N.solve(max(f, f_idle)) for f in force])
            kappa = np.array([vm.torque_Nm.value(z) / vm.thrust_N.value(z) for z in zeta])
        zeta_sat = np.clip(zeta, vm.idle_pct, 100.0)
        alpha_sat = np.zeros(4) if vm.tilt_locked else np.clip(alpha, vm.tilt_min_rad,
                                                                  vm.tilt_max_rad)
        saturated = bool(np.any(zeta_sat != zeta) or np.any(alpha_sat != alpha))
        achieved = rotor_wrench(vm, zeta_sat, alpha_sat)
        err = float(np.max(np.abs(achieved[self._rows] - target)))
        cmd = ActuatorCommand(tuple(float(z) for z in zeta_sat),
                              tuple(float(a) for a in alpha_sat))
        thrust = tuple(float(vm.thrust_N.value(z)) for z in zeta_sat)
        return Allocation(cmd, thrust, saturated, err)

    def hover(self, roll_rad: float = 0.0, pitch_rad: float = 0.0) -> ActuatorCommand:
        """Command that holds the weight (world) at the given attitude with zero moments."""
        vm = self.vehicle
        cr, sr = math.cos(roll_rad), math.sin(roll_rad)
        cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
        weight = vm.mass_kg * vm.gravity_m_s2
        # body components of the world force (0, 0, -m g): R^T (0, 0, -mg), yaw-independent
        f_body = -weight * np.array([-sp, sr * cp, cr * cp])
        if vm.tilt_locked:   # only body z is available: keep the vertical component
            f_body = np.array([0.0, 0.0, -weight / max(cr * cp, 0.5)])
        return self.allocate(np.concatenate([f_body, np.zeros(3)])).command

    def command_vector(self, cmd: ActuatorCommand) -> np.ndarray:
        """Model input u of a command: [alpha(4), zeta(4)] (TRQ) or [zeta(4)] (locked)."""
        if self.vehicle.tilt_locked:
            return np.array(cmd.throttle_pct, dtype=float)
        return np.array([*cmd.tilt_rad, *cmd.throttle_pct], dtype=float)

    def command_of(self, u) -> ActuatorCommand:
        u = np.asarray(u, dtype=float).reshape(-1).tolist()         # Python floats
        if self.vehicle.tilt_locked:
            return ActuatorCommand(tuple(u[0:4]), (0.0, 0.0, 0.0, 0.0))
        return ActuatorCommand(tuple(u[4:8]), tuple(u[0:4]))
