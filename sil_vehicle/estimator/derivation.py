"""The filter's equations, derived symbolically with CasADi SX and built once into
casadi.Function objects (PX4 derives EKF2's the same way with SymForce:
PX4-Autopilot src/modules/ekf2/EKF/python/ekf_derivation/derivation.py).

Nominal state x (20), in this order:

    p     (3)  position NED (m)
    v     (3)  velocity NED (m/s)
    q     (4)  attitude, body FRD -> NED, scalar first
    bg    (3)  gyro bias FRD (rad/s)
    ba    (3)  accelerometer bias FRD (m/s^2)
    bn    (3)  GNSS position error NED (m): the receiver's slowly wandering (Gauss-Markov) error
    bb    (1)  barometer offset (m): pressure altitude AMSL + p_d (home altitude plus drift)

The one state table: every index into x or dx anywhere comes from the slices and indices
below (P_, V_, Q_, BG, BA, BN, BB; DP, DV, DTH, DBG, DBA, DBN, DBB; the single ones such as
P_D, BN_D, BB_I, DP_D, DBN_D, DBB_I), as EKF2's State struct (name, index, length).

Error state dx (19): dp, dv, dtheta, dbg, dba, dbn, dbb. The attitude error dtheta is a
rotation vector in the BODY frame (local): q_true = q (x) exp(dtheta), the other states add.
The last four are EKF2's 15 states plus what the sensing models say is correlated (the GNSS
error and the baro drift): fused as white noise, they would make the filter overconfident.

Discrete nominal propagation over one filter period dt, from the accumulated delta angle dA
and delta velocity dV (dV expressed in the body frame at the start of the period):

    dA_c = dA - bg dt,   dV_c = dV - ba dt
    q+   = q (x) exp(dA_c) / |.|
    v+   = v + R(q) dV_c + (0, 0, g) dt
    p+   = p + (v + v+) dt / 2
    bn+  = a_gnss bn, a_gnss = exp(-dt / tau_gnss)
    bb+  = bb_ref + a_baro (bb - bb_ref), a_baro = exp(-dt / tau_baro): the barometer's drift
           a Gauss-Markov about the offset taken at initialisation, bb_ref (the sensor's model,
           sil_vehicle.sensors.baro); a_baro = 1 a walk (EKF2's bias estimate)
    bg, ba constant

The error-state Jacobians are obtained by composition (Sola 2017, "Quaternion kinematics for the
error-state Kalman filter", sections 5.3 and 6.1, and 7.2 for the measurement Jacobian
H = dh/dx . dx/d(dx)): with inject(x, dx) the true state and diff(x_ref, x) the inverse
(dtheta = 2 vec(q_ref^-1 (x) q)),

    F = d diff(f(x, u), f(inject(x, dx), u)) / d dx       at dx = 0
    G = d diff(f(x, u), f(x, u + n)) / d n                 at n = 0  (n: noise on dA, dV)
    H = d h(inject(x, dx)) / d dx                          at dx = 0

exp of a rotation vector is its Taylor series to the 4th power (exact to 1e-9 for the 0.2 rad a
10 ms period sees at 20 rad/s), smooth at zero, so derivatives through it are well defined.

Measurements h(x) (each function returns h and H (m x 19)):

    mocap_pos  p                               mocap position (m)
    gnss_pos   p + bn                          GNSS position (m)
    gnss_vel   v                               GNSS velocity (m/s)
    mocap_att  2 vec(q_ref^-1 (x) q)           the attitude as a 3-vector error about q_ref
                                               (the filter passes its own q: h = 0, H = [0 0 I])
    baro       -p_d + bb                       pressure altitude AMSL (m)
    ev_yaw     yaw(q) (ZYX Euler)              the vision system's heading (rad); fused as
                                               EKF2 fuses vision yaw: z is the measured
                                               quaternion, y = wrap(yaw(z) - yaw(q))
    mag        R(q)^T m_ned                    the earth's field in body axes (gauss)

Each fusion, `fuse_<name>(x, P, z, r, m_ned)`, is generated whole (the filter's 100 Hz step runs
in compiled code, not in NumPy): with y = z - h(x) (for mocap_att z is the measured quaternion
and y = 2 vec(q^-1 (x) z), its sign that of the scalar part), S = H P H^T + diag(r),
K = P H^T S^-1, it returns y, diag(S), x (+) K y and the Joseph-form
(I - K H) P (I - K H)^T + K diag(r) K^T, symmetrised; the caller gates on y and diag(S) and keeps
the update or drops it.

`predict(x, P, dA, dV, dt, a, qd)` returns (x+, P+ = F P F^T + G Qn G^T + Qd) with
a = (a_gnss, a_baro, bb_ref) and qd = (var dA, var dV x, y, z, var dbg, var dba, var dbn north
and east, var dbn down, var dbb), per period (dV's per axis: EKF2 raises a clipped axis's).

The evaluator is CasADi: the functions are generated as C and compiled once by
sil_vehicle.estimator.codegen (cached, never committed); without a compiler the same Functions run
in CasADi's interpreter. There is no NumPy-only path of these equations.
"""

from __future__ import annotations

from functools import lru_cache

import casadi as ca

__all__ = ["MEASUREMENTS", "NDX", "NX", "NQD", "dcm", "functions", "quat_exp", "quat_mul",
           "P_", "V_", "Q_", "BG", "BA", "BN", "BB", "DP", "DV", "DTH", "DBG", "DBA", "DBN",
           "DBB", "P_D", "BN_D", "BB_I", "DP_D", "DBN_D", "DBB_I"]

NX, NDX = 20, 19
P_, V_, Q_, BG, BA, BN, BB = (slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13),
                              slice(13, 16), slice(16, 19), slice(19, 20))
# error-state slices
DP, DV, DTH, DBG, DBA, DBN, DBB = (slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12),
                                   slice(12, 15), slice(15, 18), slice(18, 19))
# single entries: the down position, the receiver's down error, the barometer's offset
P_D, BN_D, BB_I = P_.start + 2, BN.start + 2, BB.start
DP_D, DBN_D, DBB_I = DP.start + 2, DBN.start + 2, DBB.start
NQD = 9         # predict's qd: var dA, var dV (x, y, z), var dbg, var dba, var dbn ne, d, var dbb
MEASUREMENTS = ("mocap_pos", "gnss_pos", "gnss_vel", "mocap_att", "baro", "mag", "ev_yaw")


def quat_mul(a, b):
    """Hamilton product a (x) b, scalar first (works on SX and on sequences of floats)."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def quat_exp(v):
    """exp(v / 2) of a rotation vector v (rad), as a 4th-order Taylor series (see above)."""
    t2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    c = 1.0 - t2 / 8.0 + t2 * t2 / 384.0
    s = 0.5 - t2 / 48.0 + t2 * t2 / 3840.0
    return (c, s * v[0], s * v[1], s * v[2])


def dcm(q):
    """R(q), body FRD -> NED (sil_vehicle.frames.quat_to_dcm), as an SX matrix."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def _vec(t) -> ca.SX:
    return ca.vertcat(*t)


def inject(x: ca.SX, dx: ca.SX) -> ca.SX:
    """The true state of nominal x and error dx (Sola 2017, eq. 283)."""
    q = _vec(quat_mul(x[Q_], quat_exp(dx[DTH])))
    return ca.vertcat(x[P_] + dx[DP], x[V_] + dx[DV], q, x[BG] + dx[DBG], x[BA] + dx[DBA],
                      x[BN] + dx[DBN], x[BB] + dx[DBB])


def diff(x_ref: ca.SX, x: ca.SX) -> ca.SX:
    """The error dx with inject(x_ref, dx) = x, to first order in the attitude."""
    qr = x_ref[Q_]
    qe = quat_mul((qr[0], -qr[1], -qr[2], -qr[3]), x[Q_])
    return ca.vertcat(x[P_] - x_ref[P_], x[V_] - x_ref[V_], 2 * _vec(qe[1:]),
                      x[BG] - x_ref[BG], x[BA] - x_ref[BA], x[BN] - x_ref[BN],
                      x[BB] - x_ref[BB])


def nominal(x: ca.SX, dA: ca.SX, dV: ca.SX, dt: ca.SX, a: ca.SX, g: float) -> ca.SX:
    dA_c = dA - x[BG] * dt
    dV_c = dV - x[BA] * dt
    q = _vec(quat_mul(x[Q_], quat_exp(dA_c)))
    q = q / ca.norm_2(q)
    v = x[V_] + dcm(x[Q_]) @ dV_c + ca.vertcat(0, 0, g) * dt
    p = x[P_] + (x[V_] + v) * dt / 2
    bb = a[2] + a[1] * (x[BB] - a[2])
    return ca.vertcat(p, v, q, x[BG], x[BA], a[0] * x[BN], bb)


def _measurements(x: ca.SX, q_ref: ca.SX, m_ned: ca.SX) -> dict[str, ca.SX]:
    qe = quat_mul((q_ref[0], -q_ref[1], -q_ref[2], -q_ref[3]), x[Q_])
    return {"mocap_pos": x[P_], "gnss_pos": x[P_] + x[BN], "gnss_vel": x[V_],
            "mocap_att": 2 * _vec(qe[1:]), "baro": -x[2] + x[BB],
            "mag": dcm(x[Q_]).T @ m_ned, "ev_yaw": _yaw(x[Q_])}


def _yaw(q) -> ca.SX:
    """The ZYX Euler yaw of q (sil_vehicle.frames.quat_to_euler's)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@lru_cache(maxsize=4)
def functions(gravity_m_s2: float) -> dict[str, ca.Function]:
    """Every function of the filter, built once per gravity:

    nominal(x, dA, dV, dt, a) -> x+          the nominal propagation
    transition(x, dA, dV, dt, a) -> (F, G)   error-state transition and noise Jacobians
    predict(x, P, dA, dV, dt, a, qd) -> (x+, P+)
    inject(x, dx) -> x                            the error folded into the nominal state
    h_<name>(x, q_ref, m_ned) -> (h, H)           each measurement of MEASUREMENTS
    fuse_<name>(x, P, z, r, m_ned) -> (y, s, x+, P+)   its fusion (see the module's docstring)
    """
    x, dx = ca.SX.sym("x", NX), ca.SX.sym("dx", NDX)
    dA, dV, n = ca.SX.sym("dA", 3), ca.SX.sym("dV", 3), ca.SX.sym("n", 6)
    dt, a_in = ca.SX.sym("dt"), ca.SX.sym("a", 3)
    P, qd = ca.SX.sym("P", NDX, NDX), ca.SX.sym("qd", NQD)
    q_ref, m_ned = ca.SX.sym("q_ref", 4), ca.SX.sym("m_ned", 3)
    zero_dx, zero_n = ca.DM.zeros(NDX), ca.DM.zeros(6)

    x_next = nominal(x, dA, dV, dt, a_in, gravity_m_s2)
    err_x = diff(x_next, nominal(inject(x, dx), dA, dV, dt, a_in, gravity_m_s2))
    err_n = diff(x_next, nominal(x, dA + n[:3], dV + n[3:], dt, a_in, gravity_m_s2))
    F = ca.substitute(ca.jacobian(err_x, dx), dx, zero_dx)
    G = ca.substitute(ca.jacobian(err_n, n), n, zero_n)
    Qn = ca.diag(ca.vertcat(qd[0], qd[0], qd[0], qd[1], qd[2], qd[3]))
    Qd = ca.diag(ca.vertcat(ca.SX.zeros(9), qd[4] * ca.DM.ones(3), qd[5] * ca.DM.ones(3),
                            qd[6], qd[6], qd[7], qd[8]))
    P_next = F @ P @ F.T + G @ Qn @ G.T + Qd
    P_next = (P_next + P_next.T) / 2

    u_names = ["x", "dA", "dV", "dt", "a"]
    fns = {
        "nominal": ca.Function("eskf_nominal", [x, dA, dV, dt, a_in], [x_next], u_names,
                               ["x_next"]),
        "transition": ca.Function("eskf_transition", [x, dA, dV, dt, a_in], [F, G], u_names,
                                  ["F", "G"]),
        "predict": ca.Function("eskf_predict", [x, P, dA, dV, dt, a_in, qd], [x_next, P_next],
                               ["x", "P", "dA", "dV", "dt", "a", "qd"], ["x_next", "P_next"]),
        "inject": ca.Function("eskf_inject", [x, dx], [inject(x, dx)], ["x", "dx"], ["x_true"]),
    }
    h_at = _measurements(x, q_ref, m_ned)
    h_err = _measurements(inject(x, dx), q_ref, m_ned)
    for name in MEASUREMENTS:
        H = ca.substitute(ca.jacobian(h_err[name], dx), dx, zero_dx)
        fns[f"h_{name}"] = ca.Function(f"eskf_h_{name}", [x, q_ref, m_ned], [h_at[name], H],
                                       ["x", "q_ref", "m_ned"], ["h", "H"])
        fns[f"fuse_{name}"] = _fusion(name, fns[f"h_{name}"], x, P, m_ned)
    return fns


def _fusion(name: str, h_fn: ca.Function, x: ca.SX, P: ca.SX, m_ned: ca.SX) -> ca.Function:
    h, H = h_fn(x, x[Q_], m_ned)
    m = h.numel()
    r = ca.SX.sym("r", m)
    if name == "ev_yaw":
        z = ca.SX.sym("z", 4)
        d = _yaw(z) - h
        y = ca.atan2(ca.sin(d), ca.cos(d))
    elif name == "mocap_att":
        z = ca.SX.sym("z", 4)
        qx = x[Q_]
        qe = quat_mul((qx[0], -qx[1], -qx[2], -qx[3]), z)
        y = ca.if_else(qe[0] >= 0, 2, -2) * _vec(qe[1:]) - h
    else:
        z = ca.SX.sym("z", m)
        y = z - h
    PHt = P @ H.T
    S = H @ PHt + ca.diag(r)
    K = PHt @ ca.inv(S)
    ikh = ca.DM.eye(NDX) - K @ H
    P_next = ikh @ P @ ikh.T + K @ ca.diag(r) @ K.T
    x_next = inject(x, K @ y)
    x_next[Q_] = x_next[Q_] / ca.norm_2(x_next[Q_])
    return ca.Function(f"eskf_fuse_{name}", [x, P, z, r, m_ned],
                       [y, ca.diag(S), x_next, (P_next + P_next.T) / 2],
                       ["x", "P", "z", "r", "m_ned"], ["y", "s", "x_next", "P_next"])
