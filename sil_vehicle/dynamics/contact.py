"""Ground contact: a spring-damper normal force and regularised Coulomb friction at each of the
landing gear's contact points, on a flat ground plane (docs/simulator.md, "Ground contact").

For each contact point r (body FRD, from the centre of mass) below the plane (depth d > 0, its
world velocity u = v + R (omega x r)):

    normal  N   = max(0, k d + c u_down)                       (pushes up, never pulls)
    tangent F_t = -k_t (p_t - a) - c_t u_t, capped at |F_t| <= mu N

with p_t the point's north, east position, u_t its velocity and a its stick anchor: where the
point stuck to the ground. Sticking, the point is held by a stiff spring-damper to its anchor (a
regularised stick: a sideways force below breakaway, the wind's drag on a vehicle at rest,
stretches it by F / (n k_t) and no more, it does not creep); past mu N the force is Coulomb's and
the anchor is dragged along after the tick (`update_anchors`: the spring kept at its breakaway
stretch). A point out of contact has its anchor where it is. The forces act in world NED, their
moments about the centre of mass in body FRD; both are added to the rotors' wrench inside every
RK4 stage (sil_vehicle.dynamics.rigid_body.derivative; the anchors are held over a tick, as the
rotors' wrench is), so the rigid body settles on its gear under the same integration as in
flight. No levelling, no state reset: the ground is only a force.

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

__all__ = ["Gear", "contact_wrench", "touching", "update_anchors", "feet_ne_m",
           "resting_plane_down_m", "tip_over_rad"]


@dataclass(frozen=True)
class Gear:
    """The landing gear as the contact model uses it (built by sil_vehicle.config)."""
    points_frd_m: tuple[tuple[float, float, float], ...]
    stiffness_N_m: float           # per point
    damping_N_s_m: float           # per point
    friction: float                # Coulomb coefficient mu
    stick_stiffness_N_m: float     # per point, k_t: the spring to the stick anchor
    stick_damping_N_s_m: float     # per point, c_t
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


def _dcm(qw: float, qx: float, qy: float, qz: float) -> tuple[float, ...]:
    """The rotation body FRD -> world NED of a unit quaternion, row by row (9 entries), in the
    arithmetic tick.c repeats (bit-identical cores)."""
    return (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
            2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
            2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy))


def contact_wrench(x: Sequence[float], gear: Gear,
                   anchors_ne_m: Sequence[float]) -> tuple[float, float, float, float, float,
                                                           float]:
    """The ground's force (world NED, N) and moment about the centre of mass (body FRD, N m);
    `anchors_ne_m`: each point's stick anchor, north and east (2 per point)."""
    pn0, pe0, pd, vn, ve, vd, qw, qx, qy, qz, p, q, r = x[0:13]
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _dcm(qw, qx, qy, qz)
    k, c, mu = gear.stiffness_N_m, gear.damping_N_s_m, gear.friction
    kt, ct = gear.stick_stiffness_N_m, gear.stick_damping_N_s_m
    ground = gear.ground_down_m
    f_n = f_e = f_d = m_x = m_y = m_z = 0.0
    for i, (px, py, pz) in enumerate(gear.points_frd_m):
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
        fn = pn0 + r00 * px + r01 * py + r02 * pz
        fe = pe0 + r10 * px + r11 * py + r12 * pz
        gn = -kt * (fn - anchors_ne_m[2 * i]) - ct * un
        ge = -kt * (fe - anchors_ne_m[2 * i + 1]) - ct * ue
        slip = mu * normal
        t2 = gn * gn + ge * ge
        if t2 > slip * slip:                         # sliding: Coulomb's mu N
            s = slip / math.sqrt(t2)
            gn = gn * s
            ge = ge * s
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


def feet_ne_m(x: Sequence[float], gear: Gear) -> tuple[float, ...]:
    """Each point's north and east position (2 per point): the anchors of a vehicle set down."""
    pn, pe, _, _, _, _, qw, qx, qy, qz = x[0:10]
    r00, r01, r02, r10, r11, r12 = _dcm(qw, qx, qy, qz)[0:6]
    out: list[float] = []
    for px, py, pz in gear.points_frd_m:
        out += (pn + r00 * px + r01 * py + r02 * pz, pe + r10 * px + r11 * py + r12 * pz)
    return tuple(out)


def update_anchors(x: Sequence[float], gear: Gear,
                   anchors_ne_m: Sequence[float]) -> tuple[float, ...]:
    """The anchors after a tick ending in state x: a point out of contact (or pressing with no
    force) anchors where it is; one whose spring stretches past breakaway (mu N / k_t) drags its
    anchor along, the stretch kept at breakaway; the others keep theirs. No anchors (the tick
    began out of the ground's reach, where the tick takes them where the points are): the same,
    from the points where they are now (a fast fall can reach into the ground in one tick)."""
    feet = feet_ne_m(x, gear)
    if len(anchors_ne_m) != len(feet):
        anchors_ne_m = feet
    pd, vn, ve, vd, qw, qx, qy, qz, p, q, r = x[2:13]
    r20 = 2 * (qx * qz - qw * qy)
    r21 = 2 * (qy * qz + qw * qx)
    r22 = 1 - 2 * (qx * qx + qy * qy)
    out: list[float] = []
    for i, (px, py, pz) in enumerate(gear.points_frd_m):
        fn, fe = feet[2 * i], feet[2 * i + 1]
        depth = pd + r20 * px + r21 * py + r22 * pz - gear.ground_down_m
        ud = vd + r20 * (q * pz - r * py) + r21 * (r * px - p * pz) + r22 * (p * py - q * px)
        normal = gear.stiffness_N_m * depth + gear.damping_N_s_m * ud
        if depth <= 0.0 or normal <= 0.0:
            out += (fn, fe)
            continue
        dn, de = fn - anchors_ne_m[2 * i], fe - anchors_ne_m[2 * i + 1]
        stretch = math.sqrt(dn * dn + de * de)
        limit = gear.friction * normal / gear.stick_stiffness_N_m
        if stretch > limit:
            out += (fn - dn * limit / stretch, fe - de * limit / stretch)
        else:
            out += (anchors_ne_m[2 * i], anchors_ne_m[2 * i + 1])
    return tuple(out)


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
