"""The envelope of a lost motor: the spinning ("relaxed hover") equilibria of an airframe with one
or two motors at 0 %, solved on the simulator's own rotor and rigid-body model (CasADi + IPOPT).

After Mueller and D'Andrea (ICRA 2014, IJRR 2016), a relaxed hover is a periodic solution: the
body spins at a constant rate w about a body-fixed unit axis n (the primary axis), n constant in
the world frame, the actuators constant in the body frame. With the plant of sil_vehicle
(rigid_body.derivative: Euler's equations, no aerodynamic moment; rotors.body_wrench: thrust,
reaction torque, tilts) the conditions are, for the body wrench (F, M) of the rotors:

    M = w^2 n x (J n)              Euler's equations with omega = w n constant in the body frame
    F . n = |N|                    the thrust along n balances the mean force needed,
    N = m g up + k |v_rel| v_rel   gravity and the mean drag of the air-relative velocity
                                   v_rel = (0, 0, v_down) - wind (position held, or a steady
                                   descent)

n in the world is N's direction (the body's orientation about it is free: it rotates). The part of
F normal to n rotates with the body and moves the centre of mass on a circle of radius about
|F_perp| / (m w^2); it averages to zero. J is diagonal with Ixx = Iyy, so (n x J n)_z = 0: the body
yaw torque must vanish. The plant has no aerodynamic yaw damping, so nothing balances a net rotor
reaction torque but the tilts (or, on a fixed-rotor airframe, the throttles): the spin rate is not
set by a torque balance, as in Mueller and D'Andrea, but is a free parameter of a family of
equilibria, and both spin directions are equilibria (w enters squared). What the tilts' yaw torque
does is move the vehicle along the family: dw/dt = Mz / Izz.

The control margin of an equilibrium is the smallest distance of a live actuator from a limit, as a
fraction of its range (throttle idle..100 %, tilt min..max): 0.5 is every actuator mid-range, a
negative value is how far outside its limits the best equilibrium lies (no equilibrium within the
limits: the relaxed problem is solved from several starts and its best is reported).

Pure functions of their inputs; `simulate` runs the plant (sil_vehicle.vehicle.Vehicle) from an
equilibrium on constant commands. Figures: docs/decisions/2026-12-05-lost-motor-envelope.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import casadi as ca
import numpy as np

from sil_vehicle.config import VehicleParams
from sil_vehicle.frames import wind_from_to_ned

# The default largest spin rate searched: a +-2000 deg/s gyro's full scale (the common MEMS range,
# e.g. the ICM-42688-P's and the BMI088's largest), a choice for the estimator's sake.
GYRO_FULL_SCALE_RAD_S = math.radians(2000.0)
# The largest orbit of the centre of mass accepted at a low spin rate (a choice).
MAX_ORBIT_RADIUS_M = 1.0
_OPTS = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 500}


@dataclass(frozen=True)
class SpinEquilibrium:
    """One relaxed-hover (or steady relaxed-descent) solution. Body FRD; angles in degrees."""
    vehicle: str
    motor_factors: tuple[float, ...]
    wind_m_s: float
    wind_from_deg: float
    objective: str
    feasible: bool                          # an equilibrium with every actuator within its limits
    margin: float                           # fraction of range (see the module docstring)
    descent_m_s: float                      # 0: position held; > 0: the slowest steady descent
    spin_rad_s: float                       # w (either sign is an equilibrium)
    axis_frd: tuple[float, float, float]    # n, the primary axis (world up), body FRD
    axis_from_body_up_deg: float            # angle between n and -z body (the body's cone)
    axis_lean_deg: float                    # angle of n from the world vertical (wind, descent)
    throttle_pct: tuple[float, ...]         # the commands (a dead motor's is irrelevant)
    tilt_rad: tuple[float, ...]
    thrust_N: tuple[float, ...]             # per rotor, as the plant produces it
    wrench_frd: tuple[float, ...]           # Fx, Fy, Fz (N), Mx, My, Mz (N m) of the rotors
    thrust_along_axis_N: float              # F . n
    force_normal_N: float                   # |F_perp|
    orbit_radius_m: float                   # the centre of mass's circle (no drag)
    residual: tuple[float, ...]             # the equilibrium equations in the plant's own wrench

    @property
    def tilt_deg(self) -> tuple[float, ...]:
        return tuple(math.degrees(a) for a in self.tilt_rad)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["tilt_deg"] = [round(a, 3) for a in self.tilt_deg]
        return d


# --- the model (CasADi, the plant's arithmetic) ---------------------------------------------------

def _curve(c, z):
    """A rotor curve clamped at zero below its root, as config.Quadratic does."""
    return ca.fmax(c.c2 * z ** 2 + c.c1 * z + c.c0, 0.0)


def _polynomial(c, z):
    """A rotor curve as its quadratic, unclamped."""
    return c.c2 * z ** 2 + c.c1 * z + c.c0


def rotor_wrench_expr(alpha, zeta, factors, vp: VehicleParams, *, curve=_polynomial, sym=ca.MX,
                skip_dead: bool = False):
    """Body FRD wrench (6) as a CasADi expression in `sym` (MX or SX): motor i produces
    factors[i] * zeta[i] through `curve` (by default the thrust and torque quadratics without
    the idle clamp: the throttle is kept above idle, where the curve is positive); with
    `skip_dead`, a motor whose factor is 0 gives nothing (a lost motor). The one wrench of both
    envelopes (trq_lab.analysis.envelope's static trims, this module's spinning equilibria)."""
    f_total = sym.zeros(3)
    m_total = sym.zeros(3)
    for i, rotor in enumerate(vp.rotors):
        if skip_dead and factors[i] == 0.0:
            continue
        z = zeta[i] * factors[i]
        f = curve(vp.thrust_N, z)
        tau = curve(vp.torque_Nm, z) * rotor.spin
        ax, ay, _ = rotor.tilt_axis_frd
        n = ca.vertcat(-ay * ca.sin(alpha[i]), ax * ca.sin(alpha[i]), -ca.cos(alpha[i]))
        r = ca.DM(rotor.position_frd_m)
        f_total += f * n
        m_total += ca.cross(r, f * n) - tau * n
    return ca.vertcat(f_total, m_total)


def wrench_expr(zeta, alpha, factors, vp: VehicleParams):
    """Body FRD wrench (6) of the rotors as rotors.body_wrench computes it, for throttle commands
    `zeta` (%) and tilts `alpha` (rad): motor i produces factors[i] * zeta[i] (the plant clamps the
    command to idle..100 before the factor; the solver keeps it there, the relaxed problem
    aside); the curves clamped at zero, a dead motor giving nothing (`rotor_wrench_expr`)."""
    return rotor_wrench_expr(alpha, zeta, factors, vp, curve=_curve, sym=ca.SX, skip_dead=True)


def needed_force_ned(vp: VehicleParams, wind_ned, descent_m_s):
    """The mean force (NED, N) the rotors must supply: -(gravity + mean drag), the drag of the
    air-relative velocity of a vehicle holding its horizontal position while descending at
    `descent_m_s` (the drag of the orbit's own small velocity left out: it averages to second
    order). Works on floats and on CasADi expressions."""
    rel = [-wind_ned[0], -wind_ned[1], descent_m_s - wind_ned[2]]
    speed = ca.sqrt(rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2 + 1e-12)
    k = vp.drag_N_s2_m2
    return ca.vertcat(k * speed * rel[0], k * speed * rel[1],
                      -vp.mass_kg * vp.gravity_m_s2 + k * speed * rel[2])


def _margin_terms(zeta, alpha, factors, vp: VehicleParams):
    """Each live actuator's distance from each limit, as a fraction of its range."""
    span_z = 100.0 - vp.idle_pct
    terms = []
    for i in range(4):
        if factors[i] == 0.0:
            continue
        terms += [(100.0 - zeta[i]) / span_z, (zeta[i] - vp.idle_pct) / span_z]
        if not vp.tilt_locked:
            span_a = vp.tilt_max_rad - vp.tilt_min_rad
            terms += [(vp.tilt_max_rad - alpha[i]) / span_a, (alpha[i] - vp.tilt_min_rad) / span_a]
    return terms


@dataclass(frozen=True)
class _Problem:
    x: ca.SX
    zeta: ca.SX
    alpha: ca.SX
    n: ca.SX
    w: ca.SX
    vd: ca.SX
    t: ca.SX
    wrench: ca.SX
    eq: ca.SX           # the equilibrium equations (= 0)
    ineq: ca.SX         # >= 0
    power: ca.SX
    tilt_reg: ca.SX


def _problem(vp: VehicleParams, factors, wind_ned, max_cone_rad: float, max_orbit_m: float,
             static: bool = False) -> _Problem:
    """The NLP's pieces; `static` (the spin held at 0): no orbit, the whole force along n (its x
    and y components normal to n vanish: enough, n being within the cone of -z body)."""
    zeta, alpha, n = ca.SX.sym("zeta", 4), ca.SX.sym("alpha", 4), ca.SX.sym("n", 3)
    w, vd, t = ca.SX.sym("w"), ca.SX.sym("vd"), ca.SX.sym("t")
    x = ca.vertcat(zeta, alpha, n, w, vd, t)
    wr = wrench_expr(zeta, alpha, factors, vp)
    f, m = wr[0:3], wr[3:6]
    jn = ca.DM(np.diag(vp.inertia_kg_m2)) @ n
    need = needed_force_ned(vp, wind_ned, vd)
    fn = ca.dot(f, n)
    f_perp = f - fn * n
    eq = ca.vertcat(m - w ** 2 * ca.cross(n, jn), fn - ca.norm_2(need), ca.dot(n, n) - 1.0)
    cone = -n[2] - math.cos(max_cone_rad)                          # n within the cone of -z body
    if static:
        eq = ca.vertcat(eq, f_perp[0], f_perp[1])
        orbit = []
    else:
        orbit = [(max_orbit_m * vp.mass_kg) ** 2 * w ** 4 - ca.sumsqr(f_perp)]
    ineq = ca.vertcat(*[term - t for term in _margin_terms(zeta, alpha, factors, vp)], cone, *orbit)
    power = 0
    for i in range(4):
        if factors[i] != 0.0:
            power += ca.fmax(_curve(vp.thrust_N, zeta[i] * factors[i]), 1e-9) ** 1.5
    live = [i for i in range(4) if factors[i] != 0.0]
    tilt_reg = ca.sumsqr(ca.vertcat(*[alpha[i] for i in live])) if not vp.tilt_locked else 0
    return _Problem(x, zeta, alpha, n, w, vd, t, wr, eq, ineq, power, tilt_reg)


def _bounds(vp: VehicleParams, factors, *, relaxed: bool, spin, descent: bool, max_spin: float):
    """lbx, ubx of x = (zeta 4, alpha 4, n 3, w, vd, t). Relaxed: the actuators may leave their
    limits (the margin t measures by how much)."""
    lo_z, hi_z = (0.0, 200.0) if relaxed else (vp.idle_pct, 100.0)
    lo_a, hi_a = (-1.5, 1.5) if relaxed else (vp.tilt_min_rad, vp.tilt_max_rad)
    lbx, ubx = [], []
    for i in range(4):
        fixed = factors[i] == 0.0
        lbx.append(vp.idle_pct if fixed else lo_z)
        ubx.append(vp.idle_pct if fixed else hi_z)
    for i in range(4):
        fixed = factors[i] == 0.0 or vp.tilt_locked
        lbx.append(0.0 if fixed else lo_a)
        ubx.append(0.0 if fixed else hi_a)
    lbx += [-1.0] * 3
    ubx += [1.0] * 3
    if spin is None:
        lbx.append(0.0)
        ubx.append(max_spin)
    else:
        lbx.append(float(spin))
        ubx.append(float(spin))
    lbx.append(0.0)
    ubx.append(100.0 if descent else 0.0)
    lbx.append(-10.0)
    ubx.append(0.5)
    return lbx, ubx


def _starts(vp: VehicleParams, factors, spin, max_spin: float):
    """Initial guesses: the primary axis at a few cone angles and azimuths, a few spin rates."""
    z0 = min(95.0, vp.hover_throttle_pct * 4 / max(1e-9, sum(1 for f in factors if f > 0)))
    if spin is not None:
        spins = [spin]
    else:
        spins = [s for s in (8.0, 20.0, 30.0) if s <= max_spin] or [max_spin]
    out = []
    for cone in (15.0, 35.0):
        for az in range(0, 360, 90):
            c, a = math.radians(cone), math.radians(az + 45)
            n0 = [math.sin(c) * math.cos(a), math.sin(c) * math.sin(a), -math.cos(c)]
            for s in spins:
                out.append([z0] * 4 + [0.0] * 4 + n0 + [float(s), 0.0, 0.0])
    return out


def _solve(vp, factors, wind_ned, *, objective: str, relaxed: bool, spin, descent: bool,
           max_spin: float, max_cone_rad: float, max_orbit_m: float, x0s=None,
           min_margin: float = 0.0):
    p = _problem(vp, factors, wind_ned, max_cone_rad, max_orbit_m,
                 static=spin is not None and float(spin) == 0.0)
    reg = 1e-4 * p.tilt_reg
    if descent:
        f = p.vd + reg
    elif objective == "min_spin":
        f = p.w + reg
    elif objective == "power" and not relaxed:
        f = 1e-2 * p.power + reg
    else:
        f = -p.t + reg
    nlp = {"x": p.x, "f": f, "g": ca.vertcat(p.eq, p.ineq)}
    solver = ca.nlpsol("spin", "ipopt", nlp, _OPTS)
    lbx, ubx = _bounds(vp, factors, relaxed=relaxed, spin=spin, descent=descent, max_spin=max_spin)
    if not relaxed:
        lbx[-1] = min_margin            # within the limits: t >= 0 (or a margin kept)
        if objective in ("power", "min_spin") or descent:
            ubx[-1] = min_margin        # t is then only the lower bound of the margin terms
    n_eq, n_ineq = p.eq.shape[0], p.ineq.shape[0]
    lbg = [0.0] * n_eq + [0.0] * n_ineq
    ubg = [0.0] * n_eq + [ca.inf] * n_ineq
    best = None
    for x0 in (x0s or _starts(vp, factors, spin, max_spin)):
        x0 = [min(max(v, lo), hi) for v, lo, hi in zip(x0, lbx, ubx)]
        r = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        if not solver.stats()["success"]:
            continue
        xs = np.array(r["x"]).ravel()
        g = np.array(r["g"]).ravel()
        if np.max(np.abs(g[:n_eq])) > 1e-6:
            continue
        if best is None or float(r["f"]) < best[0] - 1e-9:
            best = (float(r["f"]), xs)
    return p, best


def _equilibrium(vp, factors, wind_speed, wind_from_deg, objective, xs,
                 feasible) -> SpinEquilibrium:
    from sil_vehicle.dynamics.rotors import body_wrench
    zeta, alpha, n = xs[0:4], xs[4:8], xs[8:11]
    w, vd = float(xs[11]), float(xs[12])
    motors = [min(max(z, vp.idle_pct), 100.0) * fct for z, fct in zip(zeta, factors)]
    wr = np.array(body_wrench(motors, list(alpha), vp))
    wind = wind_from_to_ned(wind_speed, wind_from_deg)
    need = np.array(needed_force_ned(vp, wind, vd)).ravel()
    res = residual(vp, motors, alpha, n, w, need)
    fn = float(wr[0:3] @ n)
    f_perp = float(np.linalg.norm(wr[0:3] - fn * n))
    margins = [float(v) for v in _margin_terms(zeta, alpha, factors, vp)]
    return SpinEquilibrium(
        vehicle=vp.name, motor_factors=tuple(factors), wind_m_s=wind_speed,
        wind_from_deg=wind_from_deg, objective=objective, feasible=feasible,
        margin=min(margins), descent_m_s=vd, spin_rad_s=w,
        axis_frd=tuple(float(v) for v in n),
        axis_from_body_up_deg=math.degrees(math.acos(max(-1.0, min(1.0, -n[2])))),
        axis_lean_deg=math.degrees(math.acos(max(-1.0, min(1.0, -need[2] / np.linalg.norm(need))))),
        throttle_pct=tuple(float(z) for z in zeta), tilt_rad=tuple(float(a) for a in alpha),
        thrust_N=tuple(vp.thrust_N(m) for m in motors), wrench_frd=tuple(float(v) for v in wr),
        thrust_along_axis_N=fn, force_normal_N=f_perp,
        orbit_radius_m=(f_perp / (vp.mass_kg * w * w) if w > 0
                        else 0.0 if f_perp < 1e-3 else math.inf),
        residual=tuple(float(v) for v in res))


def residual(vp: VehicleParams, motor_pct, tilt_rad, axis_frd, spin_rad_s: float, need_ned):
    """The equilibrium equations evaluated with the plant's own body_wrench on the motors' actual
    throttles (after fault and clamp): M - w^2 n x J n (3, N m), F . n - |N| (N), |n| - 1."""
    from sil_vehicle.dynamics.rotors import body_wrench
    wr = np.array(body_wrench(list(motor_pct), list(tilt_rad), vp))
    n = np.asarray(axis_frd, float)
    jn = np.asarray(vp.inertia_kg_m2) * n
    return np.concatenate([wr[3:6] - spin_rad_s ** 2 * np.cross(n, jn),
                           [wr[0:3] @ n - np.linalg.norm(need_ned), np.linalg.norm(n) - 1.0]])


def solve(vp: VehicleParams, factors, wind_speed: float = 0.0, wind_from_deg: float = 0.0, *,
          objective: str = "margin", spin_rad_s: float | None = None,
          max_spin_rad_s: float = GYRO_FULL_SCALE_RAD_S, max_cone_deg: float = 89.0,
          max_orbit_m: float = MAX_ORBIT_RADIUS_M, descend: bool = True,
          descent_margin: float = 0.0) -> SpinEquilibrium:
    """The best relaxed hover: largest margin ("margin") or least ideal induced power ("power",
    sum of thrust^1.5, momentum theory), at a given spin rate or the best in 0..max_spin_rad_s.
    With no hover within the limits: the best relaxed one is found (negative margin: by how much
    the limits are missed) and, with `descend`, the slowest steady descent within the limits
    (descent_m_s > 0) is returned instead when one exists, keeping every live actuator at least
    `descent_margin` (fraction of its range) from its limits. RuntimeError: no equilibrium at all
    (not even outside the limits: e.g. too slow a spin for the gyroscopic moment needed)."""
    if objective not in ("margin", "power"):
        raise ValueError(f"spin envelope: objective {objective!r}, expected 'margin' or 'power'")
    factors = [float(f) for f in factors]
    wind = wind_from_to_ned(wind_speed, wind_from_deg)
    kw = dict(spin=spin_rad_s, max_spin=max_spin_rad_s, max_cone_rad=math.radians(max_cone_deg),
              max_orbit_m=max_orbit_m)
    # 1) relaxed: the largest margin, which may be negative (no hover within the limits)
    _, relaxed = _solve(vp, factors, wind, objective="margin", relaxed=True, descent=False, **kw)
    if relaxed is not None and relaxed[1][-1] >= 0.0:
        xs = relaxed[1]
        if objective == "power":
            _, best = _solve(vp, factors, wind, objective="power", relaxed=False, descent=False,
                             x0s=[list(xs)], **kw)
            xs = best[1] if best is not None else xs
        else:                           # polish within the true limits from the relaxed optimum
            _, best = _solve(vp, factors, wind, objective="margin", relaxed=False, descent=False,
                             x0s=[list(xs)], **kw)
            xs = best[1] if best is not None else xs
        return _equilibrium(vp, factors, wind_speed, wind_from_deg, objective, xs, True)
    if descend:
        starts = _starts(vp, factors, spin_rad_s, max_spin_rad_s)
        for x0 in starts:
            x0[12] = 10.0                   # a descent of the order of the drag's speeds
        if relaxed is not None:
            starts.insert(0, list(relaxed[1][:12]) + [10.0, 0.0])
        _, best = _solve(vp, factors, wind, objective="margin", relaxed=False, descent=True,
                         min_margin=descent_margin, x0s=starts, **kw)
        if best is not None:
            return _equilibrium(vp, factors, wind_speed, wind_from_deg, "descent", best[1], False)
    if relaxed is None:
        raise RuntimeError("spin envelope: IPOPT found no solution of the relaxed problem")
    return _equilibrium(vp, factors, wind_speed, wind_from_deg, objective, relaxed[1], False)


def max_axis_thrust_N(vp: VehicleParams, factors) -> float:
    """An upper bound on any hover's mean vertical force: the sum of the live rotors' largest
    thrusts (|mean force| <= F . n <= |F| <= sum f_i)."""
    return sum(vp.thrust_N(100.0 * f) for f in factors)


# --- margins for control at an equilibrium -------------------------------------------------------

def control_margins(vp: VehicleParams, eq: SpinEquilibrium) -> dict[str, float | None]:
    """How far the live actuators, within their limits, can push one quantity while the others
    that keep the equilibrium are held: the thrust along the primary axis ("Fn", N; Mx, My, Mz
    held), the body roll and pitch torques ("Mx", "My", N m; the other torques and Fn held), and
    the yaw torque ("Mz", N m; Mx, My, Fn held: the normal force only moves the small orbit).
    None: not reachable (that quantity cannot move alone)."""
    factors = list(eq.motor_factors)
    zeta, alpha = ca.SX.sym("zeta", 4), ca.SX.sym("alpha", 4)
    wr = wrench_expr(zeta, alpha, factors, vp)
    n = ca.DM(eq.axis_frd)
    fn = ca.dot(wr[0:3], n)
    q = {"Fn": fn, "Mx": wr[3], "My": wr[4], "Mz": wr[5]}
    trim = {"Fn": eq.thrust_along_axis_N, "Mx": eq.wrench_frd[3], "My": eq.wrench_frd[4],
            "Mz": eq.wrench_frd[5]}
    lbx, ubx = _bounds(vp, factors, relaxed=False, spin=0.0, descent=False, max_spin=0.0)
    lbx, ubx = lbx[0:8], ubx[0:8]
    x = ca.vertcat(zeta, alpha)
    x0 = list(eq.throttle_pct) + list(eq.tilt_rad)
    out: dict[str, float | None] = {}
    for key in q:
        held = [k for k in q if k != key]
        g = ca.vertcat(*[q[k] - trim[k] for k in held])
        for sign in (+1, -1):
            solver = ca.nlpsol("m", "ipopt", {"x": x, "f": -sign * q[key], "g": g}, _OPTS)
            r = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=0, ubg=0)
            name = f"{'+' if sign > 0 else '-'}{key}"
            if solver.stats()["success"]:      # >= 0: the equilibrium itself is a candidate
                out[name] = max(0.0, round(sign * (-sign * float(r["f"]) - trim[key]), 4))
            else:
                out[name] = None
    return out


# --- the periodic orbit, its linearisation and the plant ----------------------------------------

def _rotation_to(a, b) -> np.ndarray:
    """The rotation matrix turning unit vector a onto unit vector b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    v, c = np.cross(a, b), float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _dcm_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """Scalar-first quaternion of a body-to-world rotation matrix."""
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    return (w, x, y, z)


def initial_state(vp: VehicleParams, eq: SpinEquilibrium, *, down_m: float = -50.0):
    """The plant's 13-state on the periodic orbit at phase 0: the attitude turning n onto the needed
    force's direction, the body rates w n, the velocity of the orbit (the periodic solution of
    m dv/dt = R(t) F_perp - the drag linearised about the mean air-relative velocity) plus the
    steady descent."""
    n = np.asarray(eq.axis_frd)
    wind = np.asarray(wind_from_to_ned(eq.wind_m_s, eq.wind_from_deg))
    need = np.array(needed_force_ned(vp, wind, eq.descent_m_s)).ravel()
    rot = _rotation_to(n, need / np.linalg.norm(need))          # body -> world
    nw = rot @ n
    f_w = rot @ np.asarray(eq.wrench_frd[0:3])
    f_perp = f_w - (f_w @ nw) * nw
    v_mean = np.array([0.0, 0.0, eq.descent_m_s])
    rel = v_mean - wind
    speed = float(np.linalg.norm(rel))
    k = vp.drag_N_s2_m2
    jd = -k * (speed * np.eye(3) + (np.outer(rel, rel) / speed if speed > 1e-9 else 0.0))
    w = eq.spin_rad_s
    f_c = f_perp - 1j * np.cross(nw, f_perp)                     # R(t) F_perp = Re(f_c e^{iwt})
    v_c = np.linalg.solve(1j * w * vp.mass_kg * np.eye(3) - jd, f_c) if w > 0 else np.zeros(3)
    v0 = v_mean + v_c.real
    omega = w * n
    return (0.0, 0.0, down_m, *v0.tolist(), *_dcm_to_quat(rot), *omega.tolist())


def floquet_exponents(vp: VehicleParams, eq: SpinEquilibrium) -> np.ndarray:
    """Eigenvalues of the plant's dynamics linearised about the periodic orbit, in calm air:
    written in the body frame (velocity v_b, the world's down direction g_b, the rates omega) the
    orbit is a fixed point of an autonomous system; its Jacobian's eigenvalues are the orbit's
    Floquet exponents (position, a pure integrator, and the rotation about the vertical left out;
    g_b's length gives one more zero)."""
    if eq.wind_m_s != 0.0:
        raise ValueError("floquet_exponents: calm air only (the wind breaks the symmetry about the "
                         "vertical that makes the orbit a fixed point in the body frame)")
    v, g, om = ca.SX.sym("v", 3), ca.SX.sym("g", 3), ca.SX.sym("om", 3)
    f = ca.DM(eq.wrench_frd[0:3])
    m = ca.DM(eq.wrench_frd[3:6])
    jm = ca.DM(np.diag(vp.inertia_kg_m2))
    speed = ca.sqrt(ca.sumsqr(v) + 1e-16)
    vdot = f / vp.mass_kg + vp.gravity_m_s2 * g - vp.drag_N_s2_m2 * speed * v / vp.mass_kg \
        - ca.cross(om, v)
    gdot = -ca.cross(om, g)
    omdot = ca.solve(jm, m - ca.cross(om, jm @ om))
    s = ca.vertcat(v, g, om)
    jac = ca.Function("j", [s], [ca.jacobian(ca.vertcat(vdot, gdot, omdot), s)])
    x0 = initial_state(vp, eq)
    rot_q = x0[6:10]
    from sil_vehicle.frames import quat_to_dcm
    r = np.array(quat_to_dcm(*rot_q))
    v_b = r.T @ np.asarray(x0[3:6])
    g_b = r.T @ np.array([0.0, 0.0, 1.0])
    a = np.array(jac(np.concatenate([v_b, g_b, x0[10:13]])))
    return np.linalg.eigvals(a)


@dataclass(frozen=True)
class PlantRun:
    """The plant flown from an equilibrium on its constant commands."""
    seconds: float
    crashed: bool
    spin_rad_s_end: float             # |omega| at the end
    spin_change_rad_s: float          # largest | |omega| - w | over the run
    rates_error_rad_s: float          # largest |omega - w n| (body) over the run
    axis_lean_deg_max: float          # largest angle of the body's n from the expected world axis
    drift_m: float                    # distance of the orbit's centre (1-period mean) from start
    descent_error_m_s: float          # mean vertical speed minus the expected (last period)
    drift_times_s: tuple[float, ...]
    drift_m_at: tuple[float, ...]     # the orbit centre's distance at those times


def simulate(sim, eq: SpinEquilibrium, seconds: float = 2.0, *,
             perturb_rad_s: float = 0.0) -> PlantRun:
    """Fly the plant (sil_vehicle's Vehicle, the Python reference tick) from `eq` on constant
    commands, motors with factor 0 switched off, the wind of `eq` (no gusts), optionally the body
    rates perturbed (rad/s, about body x). `sim`: SimParams (its vehicle is the one analysed)."""
    from sil_vehicle.faults import Faults
    from sil_vehicle.frames import quat_to_dcm
    from sil_vehicle.vehicle import ActuatorCommand, Vehicle, VehicleState

    vp = sim.vehicle
    sim = sim.with_changes(physics_core="python", wind_speed_m_s=eq.wind_m_s,
                           wind_from_deg=eq.wind_from_deg, gusts_enabled=False)
    veh = Vehicle(sim, np.random.default_rng(0))
    faults = Faults()
    for i, f in enumerate(eq.motor_factors):
        if f == 0.0:
            faults = faults.with_motor(i, off=True)
        elif f != 1.0:
            faults = faults.with_motor(i, effectiveness=f)
    veh.faults = faults
    x0 = list(initial_state(vp, eq))
    x0[10] += perturb_rad_s
    motors = tuple(min(max(z, vp.idle_pct), 100.0) * f
                   for z, f in zip(eq.throttle_pct, eq.motor_factors))
    veh.command = ActuatorCommand(tuple(eq.throttle_pct), tuple(eq.tilt_rad))
    veh.armed = True
    veh.state = VehicleState(0, tuple(x0), motors, tuple(eq.tilt_rad),
                             tuple(wind_from_to_ned(eq.wind_m_s, eq.wind_from_deg)), True, False,
                             False, "")
    n = np.asarray(eq.axis_frd)
    wind = np.asarray(wind_from_to_ned(eq.wind_m_s, eq.wind_from_deg))
    need = np.array(needed_force_ned(vp, wind, eq.descent_m_s)).ravel()
    nw = need / np.linalg.norm(need)
    w = eq.spin_rad_s
    ticks = int(round(seconds / (sim.dt_us * 1e-6)))
    period = max(1, int(round((2 * math.pi / w if w > 0 else 0.1) / (sim.dt_us * 1e-6))))
    pos, vel = [], []
    spin_change = rates_err = lean = 0.0
    for _ in range(ticks):
        s = veh.step()
        om = np.asarray(s.x[10:13])
        spin_change = max(spin_change, abs(np.linalg.norm(om) - abs(w)))
        rates_err = max(rates_err, float(np.linalg.norm(om - w * n)))
        r = np.array(quat_to_dcm(*s.x[6:10]))
        lean = max(lean, math.degrees(math.acos(max(-1.0, min(1.0, float((r @ n) @ nw))))))
        pos.append(s.x[0:3])
        vel.append(s.x[3:6])
        if s.crashed:
            break
    pos = np.asarray(pos)
    vel = np.asarray(vel)
    # the orbit's centre: the mean over one period, against the first period's centre moved on
    # by the expected steady descent
    dt = sim.dt_us * 1e-6
    first = pos[:period].mean(axis=0) if len(pos) >= period else pos[0]
    times, drifts = [], []
    for frac in (0.25, 0.5, 0.75, 1.0):
        end = int(frac * len(pos))
        if end < 2 * period:
            continue
        centre = pos[end - period:end].mean(axis=0)
        expected = first + np.array([0.0, 0.0, eq.descent_m_s]) * (end - period) * dt
        times.append(round(end * dt, 3))
        drifts.append(float(np.linalg.norm(centre - expected)))
    last = vel[-period:, 2].mean() if len(vel) >= period else vel[:, 2].mean()
    return PlantRun(seconds=len(pos) * sim.dt_us * 1e-6, crashed=veh.state.crashed,
                    spin_rad_s_end=float(np.linalg.norm(veh.state.x[10:13])),
                    spin_change_rad_s=spin_change, rates_error_rad_s=rates_err,
                    axis_lean_deg_max=lean, drift_m=drifts[-1] if drifts else math.nan,
                    descent_error_m_s=float(last - eq.descent_m_s), drift_times_s=tuple(times),
                    drift_m_at=tuple(drifts))


def slowest_spin_rad_s(vp: VehicleParams, factors, wind_speed: float = 0.0,
                       wind_from_deg: float = 0.0, max_spin_rad_s: float = GYRO_FULL_SCALE_RAD_S,
                       max_cone_deg: float = 89.0) -> float | None:
    """The slowest spin of a relaxed hover within the actuators' limits (None: there is none up
    to max_spin_rad_s)."""
    wind = wind_from_to_ned(wind_speed, wind_from_deg)
    _, best = _solve(vp, [float(f) for f in factors], wind, objective="min_spin", relaxed=False,
                     descent=False, spin=None, max_spin=max_spin_rad_s,
                     max_cone_rad=math.radians(max_cone_deg), max_orbit_m=MAX_ORBIT_RADIUS_M)
    return None if best is None else float(best[1][11])


def sweep(vp: VehicleParams, factors, rates_rad_s, wind_speed: float = 0.0,
          wind_from_deg: float = 0.0) -> list[SpinEquilibrium | None]:
    """The largest-margin equilibrium at each spin rate (the family the tilts move along), or the
    slowest steady descent where no hover is within the limits; None: no equilibrium at all."""
    out: list[SpinEquilibrium | None] = []
    for w in rates_rad_s:
        try:
            out.append(solve(vp, factors, wind_speed, wind_from_deg, spin_rad_s=float(w)))
        except RuntimeError:
            out.append(None)
    return out


# --- the command (trq-envelope --spin) -----------------------------------------------------------

SWEEP_RATES_RAD_S = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, GYRO_FULL_SCALE_RAD_S)


def _line(eq: SpinEquilibrium) -> str:
    return (f"spin {eq.spin_rad_s:6.2f} rad/s, axis {eq.axis_from_body_up_deg:5.2f} deg from body "
            f"up, margin {eq.margin:+.3f}, descent {eq.descent_m_s:.2f} m/s, throttle "
            f"{[round(z, 1) for z in eq.throttle_pct]} %, tilt "
            f"{[round(a, 1) for a in eq.tilt_deg]} deg")


def main_spin(vp: VehicleParams, factors: list[float], args) -> int:
    """trq-envelope --spin: print (and with --json write) the relaxed-hover envelope. Exit 0: a
    hover within the limits exists; 1: none (the slowest steady descent is reported)."""
    import json
    import sys
    max_spin = args.max_spin if args.max_spin is not None else GYRO_FULL_SCALE_RAD_S
    if max_spin <= 0 or (args.spin_rate is not None and not 0 <= args.spin_rate <= max_spin):
        print(f"envelope: --spin-rate {args.spin_rate} and --max-spin {max_spin}: expected "
              "0 <= spin rate <= max spin, max spin > 0", file=sys.stderr)
        return 2
    if not 0.0 <= args.descent_margin < 0.5:
        print(f"envelope: --descent-margin {args.descent_margin}: expected 0 <= margin < 0.5",
              file=sys.stderr)
        return 2
    try:
        eq = solve(vp, factors, args.wind, args.wind_dir, objective=args.objective,
                   spin_rad_s=args.spin_rate, max_spin_rad_s=max_spin,
                   descent_margin=args.descent_margin)
    except RuntimeError as exc:
        print(f"envelope: {exc}", file=sys.stderr)
        return 1
    out = {"equilibrium": eq.as_dict(),
           "max_axis_thrust_N": max_axis_thrust_N(vp, factors),
           "weight_N": vp.mass_kg * vp.gravity_m_s2,
           "slowest_spin_rad_s": slowest_spin_rad_s(vp, factors, args.wind, args.wind_dir,
                                                    max_spin) if eq.feasible else None,
           "control_margins": (control_margins(vp, eq) if eq.feasible or eq.descent_m_s > 0
                               else {})}
    print(f"spinning envelope of {vp.name}: motor factors {factors}, wind {args.wind:g} m/s from "
          f"{args.wind_dir:g} deg ({args.objective})")
    kind = "hover" if eq.feasible else ("steady descent" if eq.descent_m_s > 0 else "NONE")
    print(f"  {kind}: {_line(eq)}")
    print(f"  thrust along the axis {eq.thrust_along_axis_N:.3f} N of at most "
          f"{out['max_axis_thrust_N']:.3f} N (weight {out['weight_N']:.3f} N), orbit radius "
          f"{eq.orbit_radius_m * 1000:.2f} mm, axis lean {eq.axis_lean_deg:.2f} deg; residual "
          f"{max(abs(r) for r in eq.residual):.1e}")
    if out["slowest_spin_rad_s"] is not None:
        print(f"  hover spin rates: {out['slowest_spin_rad_s']:.2f} .. {max_spin:.2f} rad/s "
              "(no upper bound in the plant but the search's)")
    cm = out["control_margins"]
    print("  control margins: " + ", ".join(
        f"{k} {'none' if v is None else f'{v:.3f}'}" for k, v in cm.items()))
    if cm.get("+Mz") is not None and cm.get("-Mz") is not None:
        izz = vp.inertia_kg_m2[2]
        print(f"  the tilts' yaw torque: +{cm['+Mz']:.3f} / -{cm['-Mz']:.3f} N m, the spin's "
              f"acceleration +{cm['+Mz'] / izz:.0f} / -{cm['-Mz'] / izz:.0f} rad/s^2")
    if eq.wind_m_s == 0.0 and eq.spin_rad_s > 0:
        ev = floquet_exponents(vp, eq)
        out["floquet_exponents"] = [[float(e.real), float(e.imag)] for e in ev]
        print(f"  linearised about the orbit: largest real part {max(e.real for e in ev):.2e} /s")
    if args.sweep:
        found = sweep(vp, factors, SWEEP_RATES_RAD_S, args.wind, args.wind_dir)
        out["sweep"] = [None if e is None else e.as_dict() for e in found]
        for w, e in zip(SWEEP_RATES_RAD_S, found):
            print(f"  sweep: spin {w:6.2f} rad/s: " + ("no equilibrium" if e is None else
                  f"{'hover' if e.feasible else 'descent'} {e.descent_m_s:.2f} m/s, margin "
                  f"{e.margin:+.3f}, axis {e.axis_from_body_up_deg:5.2f} deg, throttle "
                  f"{[round(z, 1) for z in e.throttle_pct]} %, tilt "
                  f"{[round(a, 1) for a in e.tilt_deg]} deg"))
    if args.simulate > 0:
        from sil_vehicle.config import load_sim
        import trq_params
        sim = load_sim(trq_params.resolve("sim", "default")).with_changes(vehicle=vp)
        run = simulate(sim, eq, args.simulate)
        out["plant"] = asdict(run)
        print(f"  plant, {run.seconds:g} s on constant commands: crashed {run.crashed}, |omega| "
              f"within {run.spin_change_rad_s:.2e} rad/s, rates within {run.rates_error_rad_s:.2e} "
              f"rad/s, axis within {run.axis_lean_deg_max:.3f} deg, orbit centre drift "
              f"{run.drift_m * 1000:.3f} mm")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2, default=float) + "\n")
    return 0 if eq.feasible else 1
