"""Can anything keep the body upright with two adjacent motors lost? A trajectory optimisation over
the first second after the failure (CasADi + IPOPT, direct multiple shooting, 10 ms RK4 steps):
motors 1 and 3 (the front pair) stop at t = 0 from a level hover (their outputs decaying through
the plant's motor lag and rate limit), the live rotors 2 and 4 commanded from t = 0 itself (an
oracle's detection: the best case), throttles idle..100 %, tilts -30..30 deg through the servos'
lag and rate limit, the plant's rigid body, drag and rotor curves (sil_vehicle's parameters). It
maximises s, the smallest cosine of the tilt from vertical over the horizon: s < 0 means the body
passes 90 deg (the plant's tumble) within it whatever the inputs, at the local optimum found
from each start. A fall from 5 m lasts at least 1.04 s (the drag's free fall), so a horizon of
1.0 s ends in the air. Prints each start's optimum. The record:
docs/decisions/2026-12-05-lost-motor-on-seeds.md.

    python docs/results/lost_motor_pairs/adjacent_upright.py > adjacent_upright.txt
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

import trq_params
from sil_vehicle.config import load_sim

DT = 0.01
LIVE = (1, 3)                  # motors 2 and 4 (0-based)
DEAD = (0, 2)                  # motors 1 and 3


def _curve(c, z):
    return c.c2 * z * z + c.c1 * z + c.c0


def model(vp) -> ca.Function:
    """f(x, u, y_dead) -> (dx/dt, the cosine of the tilt from vertical, the live outputs' and
    tilts' rates): x = v (3, NED), quaternion wxyz (4), omega (3, body FRD), the live rotors'
    outputs (2, %), their tilts (2, rad); u = their throttles (2) and tilts (2) commanded; y_dead
    the dead rotors' output (%). The plant's rigid body, drag and rotor curves."""
    m, g, k = vp.mass_kg, vp.gravity_m_s2, vp.drag_N_s2_m2
    J = np.diag(vp.inertia_kg_m2)
    Tm, Ts = vp.motor_time_constant_s, vp.servo_time_constant_s

    def f_thrust(z):
        return ca.fmax(0.0, _curve(vp.thrust_N, z))

    def f_torque(z):
        return ca.fmax(0.0, _curve(vp.torque_Nm, z))

    def deriv(x, u, y_dead):
        # x: v (3), quaternion wxyz (4), omega (3), live outputs (2), live tilts (2)
        v, q, w = x[0:3], x[3:7], x[7:10]
        yl, al = x[10:12], x[12:14]
        zeta = [y_dead, yl[0], y_dead, yl[1]]
        alpha = [0.0, al[0], 0.0, al[1]]
        F, M = ca.SX.zeros(3), ca.SX.zeros(3)
        for i, rotor in enumerate(vp.rotors):
            ax, ay, _ = rotor.tilt_axis_frd
            nvec = ca.vertcat(-ay * ca.sin(alpha[i]), ax * ca.sin(alpha[i]), -ca.cos(alpha[i]))
            f, tau = f_thrust(zeta[i]), f_torque(zeta[i]) * rotor.spin
            F += f * nvec
            M += ca.cross(ca.DM(rotor.position_frd_m), f * nvec) - tau * nvec
        qw, qx, qy, qz = q[0], q[1], q[2], q[3]
        R = ca.vertcat(
            ca.horzcat(1 - 2 * (qy**2 + qz**2), 2 * (qx*qy - qw*qz), 2 * (qx*qz + qw*qy)),
            ca.horzcat(2 * (qx*qy + qw*qz), 1 - 2 * (qx**2 + qz**2), 2 * (qy*qz - qw*qx)),
            ca.horzcat(2 * (qx*qz - qw*qy), 2 * (qy*qz + qw*qx), 1 - 2 * (qx**2 + qy**2)))
        speed = ca.sqrt(ca.dot(v, v) + 1e-9)
        vdot = (R @ F) / m + ca.vertcat(0, 0, g) - k * speed * v / m
        Jw = ca.DM(J) @ w
        wdot = ca.solve(ca.DM(J), M - ca.cross(w, Jw))
        qdot = 0.5 * ca.vertcat(-qx*w[0] - qy*w[1] - qz*w[2], qw*w[0] + qy*w[2] - qz*w[1],
                                qw*w[1] - qx*w[2] + qz*w[0], qw*w[2] + qx*w[1] - qy*w[0])
        ydot = (u[0:2] - yl) / Tm
        adot = (u[2:4] - al) / Ts
        return ca.vertcat(vdot, qdot, wdot, ydot, adot), R[2, 2], ydot, adot

    xs, us, yd = ca.SX.sym("x", 14), ca.SX.sym("u", 4), ca.SX.sym("yd")
    return ca.Function("f", [xs, us, yd], list(deriv(xs, us, yd)))


def solve(horizon_s: float, start: str, vp) -> dict:
    n = int(round(horizon_s / DT))
    m, g = vp.mass_kg, vp.gravity_m_s2
    Tm, rate_m = vp.motor_time_constant_s, vp.motor_rate_limit_pct_s
    Ts, rate_s = vp.servo_time_constant_s, vp.servo_rate_limit_rad_s
    hover = vp.thrust_N.inverse(m * g / 4.0)
    # the dead motors' outputs: the plant's lag and rate limit towards 0 (1 ms steps)
    y, dead = hover, []
    for i in range(n * 10 + 1):
        if i % 10 == 0:
            dead.append(y)
        y += max(-rate_m * 1e-3, (0.0 - y) * (1.0 - math.exp(-1e-3 / Tm)))

    f = model(vp)
    opti = ca.Opti()
    X = opti.variable(14, n + 1)
    U = opti.variable(4, n)
    s = opti.variable()
    x0 = np.concatenate([[0, 0, 0], [1, 0, 0, 0], [0, 0, 0], [hover, hover], [0, 0]])
    opti.subject_to(X[:, 0] == x0)
    lo_t, hi_t = vp.tilt_min_rad, vp.tilt_max_rad
    for i in range(n):
        xi, ui = X[:, i], U[:, i]
        k1 = f(xi, ui, dead[i])[0]
        k2 = f(xi + DT / 2 * k1, ui, 0.5 * (dead[i] + dead[i + 1]))[0]
        k3 = f(xi + DT / 2 * k2, ui, 0.5 * (dead[i] + dead[i + 1]))[0]
        k4 = f(xi + DT * k3, ui, dead[i + 1])[0]
        opti.subject_to(X[:, i + 1] == xi + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4))
        _, _, yd_i, ad_i = f(xi, ui, dead[i])
        opti.subject_to(opti.bounded(-rate_m, yd_i, rate_m))
        opti.subject_to(opti.bounded(-rate_s, ad_i, rate_s))
        opti.subject_to(opti.bounded(vp.idle_pct, ui[0:2], 100.0))
        opti.subject_to(opti.bounded(lo_t, ui[2:4], hi_t))
    for i in range(1, n + 1):
        opti.subject_to(f(X[:, i], U[:, min(i, n - 1)], dead[i])[1] >= s)
    opti.minimize(-s)
    # starts: thrust cut; the tilts' spin-up one way or the other, at full thrust or half
    t = np.arange(n) / n
    guesses = {"cut": (10.0, 0.0), "spin+ full": (100.0, hi_t), "spin- full": (100.0, lo_t),
               "spin+ half": (55.0, hi_t), "spin- half": (55.0, lo_t)}
    thr, til = guesses[start]
    opti.set_initial(U[0:2, :], thr)
    opti.set_initial(U[2, :], til)
    opti.set_initial(U[3, :], -til)
    # the states of the guess: its inputs rolled out through the same steps (a consistent start)
    u_guess = np.vstack([np.full(n, thr), np.full(n, thr), np.full(n, til), np.full(n, -til)])
    x_guess = np.zeros((14, n + 1))
    x_guess[:, 0] = x0
    c_min = 1.0
    for i in range(n):
        xi = x_guess[:, i]
        # the guess's commands kept within the motors' and servos' rate limits
        u_guess[0:2, i] = np.clip(u_guess[0:2, i], xi[10:12] - 0.999 * rate_m * Tm,
                                  xi[10:12] + 0.999 * rate_m * Tm)
        u_guess[2:4, i] = np.clip(u_guess[2:4, i], xi[12:14] - 0.999 * rate_s * Ts,
                                  xi[12:14] + 0.999 * rate_s * Ts)
        ui = u_guess[:, i]
        k1 = np.asarray(f(xi, ui, dead[i])[0]).ravel()
        k2 = np.asarray(f(xi + DT / 2 * k1, ui, 0.5 * (dead[i] + dead[i + 1]))[0]).ravel()
        k3 = np.asarray(f(xi + DT / 2 * k2, ui, 0.5 * (dead[i] + dead[i + 1]))[0]).ravel()
        k4 = np.asarray(f(xi + DT * k3, ui, dead[i + 1])[0]).ravel()
        x_guess[:, i + 1] = xi + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x_guess[3:7, i + 1] /= np.linalg.norm(x_guess[3:7, i + 1])
        c_min = min(c_min, float(f(x_guess[:, i + 1], ui, dead[i + 1])[1]))
    opti.set_initial(U, u_guess)
    opti.set_initial(X, x_guess)
    opti.set_initial(s, c_min)
    # a start near the guess (it is feasible): small barrier and bound push, so that the solver
    # does not leave it for a worse point while it restores the interior
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "max_iter": 1500,
                                                 "tol": 1e-6, "mu_init": 1e-5,
                                                 "bound_push": 1e-8, "bound_frac": 1e-8})
    try:
        sol = opti.solve()
        ok, sv, Xv, Uv = True, float(sol.value(s)), sol.value(X), sol.value(U)
    except RuntimeError:
        ok, sv, Xv, Uv = False, float(opti.debug.value(s)), opti.debug.value(X), \
            opti.debug.value(U)
    wz = Xv[7:10, :]
    return {"horizon_s": horizon_s, "start": start, "start_min_cos": round(c_min, 4),
            "converged": ok,
            "min_cos_tilt": round(sv, 4),
            "max_tilt_deg": round(math.degrees(math.acos(max(-1.0, min(1.0, sv)))), 1),
            "fall_m": round(_fall(Xv), 2),
            "max_spin_rad_s": round(float(np.max(np.abs(wz[2, :]))), 1),
            "mean_throttle_pct": round(float(np.mean(Uv[0:2, :])), 1)}


def _fall(Xv) -> float:
    """Height lost over the horizon (m): the vertical velocity integrated."""
    return float(np.sum(0.5 * (Xv[2, 1:] + Xv[2, :-1])) * DT)


def main() -> None:
    vp = load_sim(trq_params.DIR / "sim" / "default.yaml").vehicle
    for horizon_s in (0.5, 1.0):
        for start in ("cut", "spin+ full", "spin- full", "spin+ half", "spin- half"):
            print(solve(horizon_s, start, vp), flush=True)


if __name__ == "__main__":
    main()
