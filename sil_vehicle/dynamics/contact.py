"""Ground contact: a spring-damper normal force and regularised Coulomb friction at each of the
landing gear's contact points, on a flat ground plane (docs/simulator.md, "Ground contact").

For each contact point r (body FRD, from the centre of mass) below the plane (depth d > 0, its
world velocity u = v + R (omega x r)):

    normal  N   = max(0, k d + c u_down)                       (pushes up, never pulls)
    tangent F_t = -u_t * min(c_stick, mu N / |u_t|)            (u_t: the point's N, E velocity)

so a point slides with Coulomb friction mu N, and below the speed mu N / c_stick it sticks
through a viscous term c_stick (the regularisation: a vehicle with no sideways force rests
without creeping; under a sideways force F below breakaway it creeps at F / (n c_stick)). The
forces act in world NED, their moments about the centre of mass in body FRD; both are added to
the rotors' wrench inside every RK4 stage (sil_vehicle.dynamics.rigid_body.derivative), so the
rigid body settles on its gear under the same integration as in flight. No levelling, no state
reset: the ground is only a force.

The plane's height is chosen so that the vehicle at rest, level, on its lowest contact points,
has its centre of mass at down = 0 (the NED origin is home on the ground: PROTOCOL.md), which
keeps every user of "z = 0 on the ground" right at rest.

Plain floats and one fixed order of operations: dynamics/tick.c repeats this function operation
for operation (the two stay bit-identical: tests/consistency/test_compiled_core.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

__all__ = ["Gear", "contact_wrench", "touching", "resting_plane_down_m", "tip_over_rad"]


@dataclass(frozen=True)
class Gear:
    """The landing gear as the contact model uses it (built by sil_vehicle.config)."""
    points_frd_m: tuple[tuple[float, float, float], ...]
    stiffness_N_m: float           # per point
    damping_N_s_m: float           # per point
    friction: float                # Coulomb coefficient mu
    stick_damping_N_s_m: float     # per point, the viscous stick region
    ground_down_m: float           # the plane, world down
    reach_down_m: float            # the centre of mass below this: a point may touch


def resting_plane_down_m(points_frd_m: Sequence[Sequence[float]], stiffness_N_m: float,
                         weight_N: float) -> float:
    """The plane on which the level vehicle rests with its centre of mass at down = 0: the
    lowest points (largest body z) share the weight, each compressed by weight / (n k)."""
    low = max(p[2] for p in points_frd_m)
    n = sum(1 for p in points_frd_m if p[2] == low)
    return low - weight_N / (n * stiffness_N_m)


def tip_over_rad(points_frd_m: Sequence[Sequence[float]]) -> float:
    """The tilt at which the centre of mass passes over the edge of the support polygon of the
    lowest points (a vehicle tilted further while touching falls over): atan(a / h), a the
    shortest distance from the centre of mass's foot to the polygon's edges, h the points'
    depth below the centre of mass."""
    low = max(p[2] for p in points_frd_m)
    feet = sorted((p for p in points_frd_m if p[2] == low), key=lambda p: math.atan2(p[1], p[0]))
    if len(feet) < 3:
        return 0.0
    a = math.inf
    for (x1, y1, _), (x2, y2, _) in zip(feet, feet[1:] + feet[:1]):
        edge = math.hypot(x2 - x1, y2 - y1)
        a = min(a, (x1 * y2 - x2 * y1) / edge)       # signed: > 0 when the origin is inside
    return math.atan2(a, low) if a > 0.0 else 0.0


def contact_wrench(x: Sequence[float], gear: Gear) -> tuple[float, float, float, float, float,
                                                            float]:
    """The ground's force (world NED, N) and moment about the centre of mass (body FRD, N m)."""
    pd, vn, ve, vd, qw, qx, qy, qz, p, q, r = x[2:13]
    r00 = 1 - 2 * (qy * qy + qz * qz)
    r01 = 2 * (qx * qy - qw * qz)
    r02 = 2 * (qx * qz + qw * qy)
    r10 = 2 * (qx * qy + qw * qz)
    r11 = 1 - 2 * (qx * qx + qz * qz)
    r12 = 2 * (qy * qz - qw * qx)
    r20 = 2 * (qx * qz - qw * qy)
    r21 = 2 * (qy * qz + qw * qx)
    r22 = 1 - 2 * (qx * qx + qy * qy)
    k, c, mu, cs = gear.stiffness_N_m, gear.damping_N_s_m, gear.friction, gear.stick_damping_N_s_m
    ground = gear.ground_down_m
    f_n = f_e = f_d = m_x = m_y = m_z = 0.0
    for px, py, pz in gear.points_frd_m:
        depth = pd + r20 * px + r21 * py + r22 * pz - ground
        if depth <= 0.0:
            continue
        ux = q * pz - r * py
        uy = r * px - p * pz
        uz = p * py - q * px
        un = vn + r00 * ux + r01 * uy + r02 * uz
        ue = ve + r10 * ux + r11 * uy + r12 * uz
        ud = vd + r20 * ux + r21 * uy + r22 * uz
        normal = k * depth + c * ud
        if normal <= 0.0:
            continue
        speed = math.sqrt(un * un + ue * ue)
        slip = mu * normal
        s = cs if speed * cs <= slip else slip / speed
        gn = -s * un
        ge = -s * ue
        gd = -normal
        f_n += gn
        f_e += ge
        f_d += gd
        bx = r00 * gn + r10 * ge + r20 * gd
        by = r01 * gn + r11 * ge + r21 * gd
        bz = r02 * gn + r12 * ge + r22 * gd
        m_x += py * bz - pz * by
        m_y += pz * bx - px * bz
        m_z += px * by - py * bx
    return (f_n, f_e, f_d, m_x, m_y, m_z)


def touching(x: Sequence[float], gear: Gear) -> int:
    """How many contact points are below the plane (0 when the centre of mass is out of reach)."""
    if not x[2] > gear.reach_down_m:
        return 0
    qw, qx, qy = x[6], x[7], x[8]
    r20 = 2 * (x[7] * x[9] - qw * qy)
    r21 = 2 * (qy * x[9] + qw * qx)
    r22 = 1 - 2 * (qx * qx + qy * qy)
    return sum(1 for px, py, pz in gear.points_frd_m
               if x[2] + r20 * px + r21 * py + r22 * pz - gear.ground_down_m > 0.0)
