"""The fused filter (issue 34): the companion's own estimate of position and velocity, from the
motion capture pose, the raw accelerometer and the controller's own model with the observer's
disturbance as a known input.

A linear Kalman filter in world NED on x = [p (3) m, v (3) m/s, a_r (3) m/s^2, b (3) m/s^2]
(12 states: issue 34's nine and the accelerometer's bias, which the nine alone would read as
the vehicle's acceleration), advanced once per control period h by `FusedFilter.step`:

    process      p' = v,  v' = a_k + a_r + w_v,  a_r' = w_r
                 a_k: the known input, held over the period: the acceleration the controller's
                 model gives for the commands in effect (the observer's b0) plus, by
                 `disturbance_input`, the observer's translational disturbance estimate
                 ("observer"), or only the motors' share of it that the effectiveness
                 observer explains ("motors": the model flown with the motors' estimated
                 effectiveness), so that a fault seen does not reach the filter as a surprise,
                 or nothing ("none");
                 a_r: what both miss (a random walk);
                 w_v, w_r white, of densities `model_acc_density` and `residual_walk_density`;
                 b' = w_b, the accelerometer's bias in NED (a slow random walk of density
                 `accel_bias_walk_density`, `accel_bias_std` at the start: the vehicle flies
                 near level, so the body bias seen in NED changes only with the yaw)
    accelerometer  z = R(eta) f_frd + g e_z  measures a_k + a_r + b (each period: the mean of
                 the samples received, variance accel_std^2 / n); the position fixes what the
                 total acceleration is, so the slow difference is the sensor's bias
    position     z = p at the pose's time of validity (ATT_POS_MOCAP's time_usec, about one
                 control period before it arrives): the filter keeps its last `history` periods
                 (posterior, known input, accelerometer measurement), goes back to the period
                 before that time, predicts to it, fuses the pose and predicts forward again
                 through the kept periods. A pose whose innovation test ratio (its normalised
                 squared innovation over the chi-square gate `pose_gate`) exceeds 1 is
                 rejected, except after a dropout (a gate would then lock the poses out for
                 good); one older than the history is dropped. The same for a GNSS fix
                 (`position_source: gnss`: GPS_RAW_INT in NED around home, its time_usec the
                 time of validity, the receiver's delay behind its arrival; its own noise per
                 axis, an input of the pose's kernel): the history is then sized to cover that
                 delay (config.py).
    velocity     optional (`autopilot_vel_std_m_s` > 0): the autopilot's velocity, fused as a
                 measurement of v at the period's end (its IMU-integrated velocity blended with
                 the model's)

Without a pose for `dropout_s` the filter dead-reckons on the model, the observer's disturbance
and the accelerometer, and says so (`Health.dead_reckoning`; `HealthReport` turns the changes
into STATUSTEXT messages). Its health per period: the last pose's test ratio and the position's
variance (trace / 3, m^2), for controller.csv.

The arithmetic is written once, over an array module (`_NUMPY` or `_CASADI`: `_transition`,
`_predict`, `_accel_update`, `_update`, `_pose_fusion`): NumPy runs it as it is (the pure path,
`codegen` off or no C compiler), and with `codegen` it is built as two CasADi functions, the
period's advance (predict over dt, then the accelerometer update when there is one: the
posterior at the period's end, also each step of the re-prediction after a delayed pose) and
the pose's fusion (predict to its time of validity, innovation, test ratio, Joseph update, and
the posterior carried on through the period the pose lies in: the re-prediction's first step,
for a pose one period late its only one; the gate stays in Python), generated as C and compiled
once through nmpc/cache.py with the filter's constants baked in as literals and dt an input.
Sizes come from N_STATES and the measurement matrices.
tests/unit/trq_offboard/test_fused_compiled.py holds the two paths equal.

Pure: integer microseconds of the vehicle's clock in, no clock read, no I/O, no randomness.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.records import EstimatorHealth as Health

__all__ = ["FusedConfig", "FusedFilter", "Health", "HealthReport", "rotation_ned_frd"]

_I3 = np.eye(3)


class _NUMPY:
    """The array module of the pure path: the formulas below run on NumPy arrays."""
    array = staticmethod(np.array)
    block = staticmethod(np.block)
    kron = staticmethod(np.kron)
    eye = staticmethod(np.eye)
    diag = staticmethod(np.diag)
    inv = staticmethod(np.linalg.inv)
    solve = staticmethod(np.linalg.solve)

    @staticmethod
    def zeros(rows: int, cols: int) -> np.ndarray:
        return np.zeros((rows, cols))

    @staticmethod
    def const(a: np.ndarray) -> np.ndarray:
        return a


class _CASADI:
    """The same operations on CasADi SX (the compiled kernels); constants as sparse DM, so
    that the measurement matrices' and the transition's zeros cost nothing."""
    array = staticmethod(ca.blockcat)
    block = staticmethod(ca.blockcat)
    kron = staticmethod(ca.kron)
    inv = staticmethod(ca.inv)
    solve = staticmethod(ca.solve)

    diag = staticmethod(ca.diag)

    @staticmethod
    def eye(n: int):
        return ca.DM.eye(n)

    @staticmethod
    def zeros(rows: int, cols: int):
        return ca.DM(rows, cols)

    @staticmethod
    def const(a: np.ndarray):
        return ca.sparsify(ca.DM(a))


@dataclass(frozen=True)
class FusedConfig:
    """The fused filter's parameters (controller key `estimator`, kind fused)."""
    mocap_std_m: float                    # the pose's position noise, 1 sigma per axis
    accel_std_m_s2: float                 # one HIGHRES_IMU accelerometer's noise, 1 sigma
    model_acc_density: float              # w_v: the model's white acceleration error, m/s^2/rtHz
    residual_walk_density: float          # w_r: a_r's random walk, m/s^3/rtHz
    accel_bias_std: float                 # b at the start, 1 sigma per axis, m/s^2
    accel_bias_walk_density: float        # w_b: b's random walk, m/s^3/rtHz
    pose_gate: float                      # chi-square (3 dof) gate of a pose's innovation
    dropout_s: float                      # no pose this long: dead reckoning
    imu_rate_hz: int                      # HIGHRES_IMU asked of the vehicle
    mocap_rate_hz: int                    # ATT_POS_MOCAP asked of the vehicle
    history: int = 8                      # control periods kept for the delayed pose
    disturbance_input: str = "motors"     # added to b0: "motors", "observer" (its d), "none"
    autopilot_vel_std_m_s: float = 0.0    # the autopilot's velocity as a measurement (0: not)
    # the position source: "mocap" (ATT_POS_MOCAP, noise mocap_std_m) or "gnss" (GPS_RAW_INT in
    # NED, trq_offboard/link/gnss.py; noise gnss_std_m (h, v), 0: each fix's own)
    position_source: str = "mocap"
    gnss_rate_hz: int = 10                # GPS_RAW_INT asked of the vehicle
    gnss_std_m: tuple[float, float] = (0.0, 0.0)
    gnss_delay_s: float = 0.11            # GPS_RAW_INT's stamp less this: its time of validity


def rotation_ned_frd(euler_rad) -> np.ndarray:
    """R taking body FRD vectors to world NED, ZYX Euler angles (roll, pitch, yaw); the NumPy
    twin of trq_offboard.model.dynamics.rotation_ned_frd."""
    roll, pitch, yaw = euler_rad
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def _transition(dt, cfg: FusedConfig, xp=_NUMPY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F (12x12), G (12x3) of the known input, Q (12x12)) over dt s; per axis the constant-
    acceleration triple and the bias, the axes independent (Kronecker products with I3)."""
    f1 = xp.array([[1.0, dt, 0.5 * dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    g1 = xp.array([[0.5 * dt * dt], [dt], [0.0]])
    qr = cfg.residual_walk_density ** 2
    qv = cfg.model_acc_density ** 2
    d2, d3, d4, d5 = dt ** 2, dt ** 3, dt ** 4, dt ** 5
    q1 = qr * xp.array([[d5 / 20, d4 / 8, d3 / 6], [d4 / 8, d3 / 3, d2 / 2], [d3 / 6, d2 / 2, dt]])
    q1 += qv * xp.array([[d3 / 3, d2 / 2, 0.0], [d2 / 2, dt, 0.0], [0.0, 0.0, 0.0]])
    z31, z13 = xp.zeros(3, 1), xp.zeros(1, 3)
    f4 = xp.block([[f1, z31], [z13, xp.eye(1)]])
    g4 = xp.block([[g1], [xp.zeros(1, 1)]])
    q4 = xp.block([[q1, z31], [z13, xp.array([[cfg.accel_bias_walk_density ** 2 * dt]])]])
    i3 = xp.eye(3)
    return xp.kron(f4, i3), xp.kron(g4, i3), xp.kron(q4, i3)


N_STATES = 12
_H_POS = np.hstack([_I3, np.zeros((3, 9))])
_H_ACC = np.hstack([np.zeros((3, 6)), _I3, _I3])
_H_VEL = np.hstack([np.zeros((3, 3)), _I3, np.zeros((3, 6))])


def _update(x, P, H, z_minus_hx, R, xp=_NUMPY):
    """Kalman update (Joseph form): (x, P, normalised squared innovation)."""
    H = xp.const(H)
    S = H @ P @ H.T + R
    S_inv = xp.inv(S)
    K = P @ H.T @ S_inv
    x = x + K @ z_minus_hx
    A = xp.eye(P.shape[0]) - K @ H
    P = A @ P @ A.T + K @ R @ K.T
    return x, 0.5 * (P + P.T), z_minus_hx.T @ S_inv @ z_minus_hx


def _predict(x, P, F, G, Q, a_known):
    """The prior over one transition under the known input held over it."""
    return F @ x + G @ a_known, F @ P @ F.T + Q


def _accel_update(x, P, a_known, z, var, xp=_NUMPY):
    """The accelerometer's mean z (variance var per axis) as a measurement of a_k + a_r + b."""
    x, P, _ = _update(x, P, _H_ACC, z - a_known - x[6:9] - x[9:12], var * xp.eye(3), xp)
    return x, P


def _pose_fusion(x, P, pos, r_pos, cfg: FusedConfig, xp=_NUMPY):
    """A pose at the prior's time, its variances per axis r_pos (3): (test ratio, x, P
    updated); the gate is the caller's."""
    r = xp.diag(r_pos)
    innovation = pos - x[0:3]
    S = P[0:3, 0:3] + r
    ratio = innovation.T @ xp.solve(S, innovation) / cfg.pose_gate
    x, P, _ = _update(x, P, _H_POS, innovation, r, xp)
    return ratio, x, P


@functools.lru_cache(maxsize=8)
def _kernels(cfg: FusedConfig) -> tuple[ca.Function, ca.Function] | None:
    """The period's advance and the pose's fusion as compiled functions (module docstring), or
    None without a C compiler or when a build fails (then the NumPy path runs):
        advance (x, P, dt, a_known, z_acc, var_acc, has_acc) -> (x, P)
        pose    (x, P, dt, a_known, pos, dt_rest, z_acc, var_acc, has_acc, r_pos)
                -> (test ratio, x, P, x_next, P_next)
    dt in s (the pose's 0 at a kept period's end); P dense, CasADi's column-major order;
    has_acc 0 or 1: without, the predicted (x, P) exactly. The pose lies in the period after
    (x, P), under its a_known; the pose's kernel also carries its posterior on to that period's
    end (dt_rest later, with that period's accelerometer): the first step of the re-prediction,
    most often the only one (a pose one period late), in the same call. Kept per process (one
    build a configuration); each filter wraps them in its own buffers."""
    from trq_offboard.nmpc.cache import compiled_many, find_compiler

    if find_compiler() is None:
        return None
    n, m = N_STATES, _H_ACC.shape[0]
    x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
    dt, a, z, var, has = (ca.SX.sym(name, k) for name, k in
                          (("dt", 1), ("a_known", m), ("z_acc", m), ("var_acc", 1),
                           ("has_acc", 1)))
    pos, rest = ca.SX.sym("pos", _H_POS.shape[0]), ca.SX.sym("dt_rest")
    r_pos = ca.SX.sym("r_pos", _H_POS.shape[0])
    F, G, Q = _transition(dt, cfg, _CASADI)
    xp_, Pp = _predict(x, P, F, G, Q, a)
    xa, Pa = _accel_update(xp_, Pp, a, z, var, _CASADI)
    advance = ca.Function(f"fused_advance_{n}", [x, P, dt, a, z, var, has],
                          [ca.if_else(has, xa, xp_), ca.if_else(has, Pa, Pp)])
    ratio, xu, Pu = _pose_fusion(xp_, Pp, pos, r_pos, cfg, _CASADI)
    x_next, P_next = advance(xu, Pu, rest, a, z, var, has)
    pose = ca.Function(f"fused_pose_{n}", [x, P, dt, a, pos, rest, z, var, has, r_pos],
                       [ratio, xu, Pu, x_next, P_next])
    built = compiled_many([advance, pose])
    if any(how == "interpreted" for _, how in built):
        return None
    return built[0][0], built[1][0]


_ZERO3 = np.zeros(3)


class _Kernel:
    """A compiled kernel evaluated in place (casadi.Function.buffer, as
    model.dynamics.NumpyFunction, which this module cannot import: config imports it): the
    caller writes `args` (flat, column-major; P through `p_in`, the second input seen as a
    matrix whose transpose receives P), calls `evaluate` and copies from `results`."""

    def __init__(self, fn: ca.Function) -> None:
        self._buf, self.evaluate = fn.buffer()
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.results = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        for i, a in enumerate(self.args):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self.results):
            self._buf.set_res(i, memoryview(a))
        n = math.isqrt(self.args[1].size)
        self.p_in = self.args[1].reshape(n, n).T


def _matrix(flat: np.ndarray) -> np.ndarray:
    """A kernel's square matrix output (flat, column-major) as a NumPy array of its own (in
    Fortran order: the copy is flat, and the next kernel reads it back flat)."""
    n = math.isqrt(flat.size)
    return flat.copy().reshape(n, n).T


@dataclass
class _Period:
    """One kept control period: its end time, the known input over it, the accelerometer's
    measurement at its end (mean, variance) or None, and the posterior at its end."""
    t_us: int
    a_known: np.ndarray
    acc: tuple[np.ndarray, float] | None
    x: np.ndarray
    P: np.ndarray


class FusedFilter:
    """The filter (module docstring): reset, then per control period `add_imu` / `add_pose`
    for the samples received and `step` to the period's end. `codegen`: the compiled kernels
    (when a C compiler is found), else the NumPy path (`compiled` says which runs)."""

    def __init__(self, cfg: FusedConfig, gravity_m_s2: float, codegen: bool = True) -> None:
        self.cfg = cfg
        self.g = gravity_m_s2
        self._trans: dict[int, tuple] = {}
        kernels = _kernels(cfg) if codegen else None
        self._advance_fn, self._pose_fn = ((_Kernel(kernels[0]), _Kernel(kernels[1]))
                                           if kernels is not None else (None, None))
        self._periods: list[_Period] = []
        self._imu: list[np.ndarray] = []          # total accelerations (NED) this period
        self._poses: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.last_pose_us: int | None = None
        self.test_ratio = math.nan
        self.rejected = 0
        self.dropped = 0
        self._regaining = False          # taking poses back after dead reckoning

    def _f(self, dt_us: int):
        got = self._trans.get(dt_us)
        if got is None:
            got = _transition(dt_us * 1e-6, self.cfg)
            if len(self._trans) < 64:
                self._trans[dt_us] = got
        return got

    def reset(self, t_us: int, pos_ned_m, vel_ned_m_s, pos_std_m: float | None = None) -> None:
        """Start from a position and velocity (the autopilot's), a_r = 0 and b = 0, with the
        pose's variance on position (or pos_std_m's), generous ones on velocity and a_r,
        accel_bias_std on b."""
        cfg = self.cfg
        x = np.concatenate([np.asarray(pos_ned_m, float), np.asarray(vel_ned_m_s, float),
                            np.zeros(6)])
        std = cfg.mocap_std_m if pos_std_m is None else pos_std_m
        P = np.diag([std ** 2] * 3 + [0.1 ** 2] * 3 + [1.0] * 3
                    + [cfg.accel_bias_std ** 2] * 3)
        self._periods = [_Period(int(t_us), np.zeros(3), None, x, P)]
        self._imu.clear()
        self._poses.clear()
        self.last_pose_us = int(t_us)
        self.test_ratio = math.nan
        self.rejected = 0
        self.dropped = 0
        self._regaining = False

    @property
    def compiled(self) -> bool:
        """The compiled kernels run (else the NumPy path)."""
        return self._advance_fn is not None

    @property
    def t_us(self) -> int:
        return self._periods[-1].t_us

    @property
    def x(self) -> np.ndarray:
        return self._periods[-1].x

    @property
    def P(self) -> np.ndarray:
        return self._periods[-1].P

    def add_imu(self, specific_force_frd_m_s2, euler_rad) -> None:
        """One accelerometer sample (specific force, body FRD) with the attitude it was taken
        at: kept as a total acceleration in NED for the period's end."""
        f = np.asarray(specific_force_frd_m_s2, float)
        if np.all(np.isfinite(f)):
            self._imu.append(rotation_ned_frd(euler_rad) @ f + np.array([0.0, 0.0, self.g]))

    def add_pose(self, t_us: int, pos_ned_m, std_ned_m=None) -> None:
        """One position (motion capture, or a GNSS fix in NED) at its time of validity, with
        its 1-sigma errors per axis (None: mocap_std_m), fused at the next `step`."""
        p = np.asarray(pos_ned_m, float)
        std = (np.full(3, self.cfg.mocap_std_m) if std_ned_m is None
               else np.asarray(std_ned_m, float))
        if np.all(np.isfinite(p)) and np.all(np.isfinite(std)) and np.all(std > 0.0):
            self._poses.append((int(t_us), p, std * std))

    def step(self, t_us: int, a_known_ned: np.ndarray, vel_ned_m_s=None) -> Health:
        """Advance to t_us (> the last period's end) under the known input a_known (m/s^2 NED,
        held over the period); fuse this period's accelerometer mean and then the poses received
        at their times of validity; with autopilot_vel_std_m_s, `vel_ned_m_s` (the
        autopilot's velocity now) is fused last as a measurement of v."""
        last = self._periods[-1]
        dt_us = int(t_us) - last.t_us
        if dt_us <= 0:
            return self.health(t_us)
        a_known = np.asarray(a_known_ned, float).copy()
        acc = None
        if self._imu:
            n = len(self._imu)
            acc = (np.mean(self._imu, axis=0), self.cfg.accel_std_m_s2 ** 2 / n)
            self._imu.clear()
        x, P = self._advance(last.x, last.P, dt_us, a_known, acc)
        self._periods.append(_Period(int(t_us), a_known, acc, x, P))
        del self._periods[:-self.cfg.history]
        for t_pose, pos, r_pos in sorted(self._poses, key=lambda s: s[0]):
            self._fuse_pose(min(t_pose, int(t_us)), pos, r_pos)
        self._poses.clear()
        std = self.cfg.autopilot_vel_std_m_s
        if std > 0.0 and vel_ned_m_s is not None:
            top = self._periods[-1]
            v = np.asarray(vel_ned_m_s, float)
            top.x, top.P, _ = _update(top.x, top.P, _H_VEL, v - top.x[3:6], std * std * _I3)
        return self.health(t_us)

    def _advance(self, x, P, dt_us: int, a_known, acc):
        fn = self._advance_fn
        if fn is not None:
            args, p_in, res = fn.args, fn.p_in, fn.results
            args[0][:], p_in[:], args[2][0], args[3][:] = x, P, dt_us * 1e-6, a_known
            if acc is None:
                args[6][0] = 0.0
            else:
                args[4][:], args[5][0], args[6][0] = acc[0], acc[1], 1.0
            fn.evaluate()
            return res[0].copy(), _matrix(res[1])
        x, P = _predict(x, P, *self._f(dt_us), a_known)
        if acc is not None:
            x, P = _accel_update(x, P, a_known, *acc)
        return x, P

    def _pose(self, base: _Period, t_pose: int, pos, r_pos, nxt: _Period | None):
        """The pose at t_pose (variances per axis r_pos) fused into the posterior of the kept
        period `base`, predicted to
        it under the input of the period after (`nxt`; None: the pose is at the last period's
        end): (test ratio, x, P updated, and the compiled kernel's posterior carried on to
        nxt's end, else None)."""
        x, P, dt_us = base.x, base.P, t_pose - base.t_us
        a_known = _ZERO3 if nxt is None else nxt.a_known
        fn = self._pose_fn
        if fn is not None:
            args, p_in, res = fn.args, fn.p_in, fn.results
            args[0][:], p_in[:], args[2][0], args[3][:], args[4][:] = \
                x, P, dt_us * 1e-6, a_known, pos
            args[5][0] = 0.0 if nxt is None else (nxt.t_us - t_pose) * 1e-6
            if nxt is None or nxt.acc is None:
                args[8][0] = 0.0
            else:
                args[6][:], args[7][0], args[8][0] = nxt.acc[0], nxt.acc[1], 1.0
            args[9][:] = r_pos
            fn.evaluate()
            ahead = None if nxt is None else (res[3].copy(), _matrix(res[4]))
            return float(res[0][0]), res[1].copy(), _matrix(res[2]), ahead
        if dt_us > 0:
            F, G, Q = self._f(dt_us)
            x, P = _predict(x, P, F, G, Q, a_known)
        ratio, x, P = _pose_fusion(x, P, pos, r_pos, self.cfg)
        return float(ratio), x, P, None

    def _fuse_pose(self, t_pose: int, pos: np.ndarray, r_pos: np.ndarray) -> None:
        """The pose at its time of validity: back to the kept period before it, forward to it,
        the update, then forward again through the later periods."""
        periods = self._periods
        k = len(periods) - 1
        while k >= 0 and periods[k].t_us > t_pose:
            k -= 1
        if k < 0:
            self.dropped += 1
            return
        base = periods[k]
        # forward to the pose under the next period's input (none: the pose is at base's end)
        nxt = periods[k + 1] if k + 1 < len(periods) else None
        ratio, x, P, ahead = self._pose(base, t_pose, pos, r_pos, nxt)
        self.test_ratio = ratio
        # past the gate: rejected, unless the filter has been without a pose for dropout_s
        # (then the estimate is what is in doubt, and a gate would lock the poses out for good),
        # or is still taking them back after that: the gate closes again only once a pose
        # falls inside it (a first pose after an outage may correct only part of the drift)
        if ratio > 1.0 and not self.dead_reckoning(t_pose) and not self._regaining:
            self.rejected += 1
            return
        self._regaining = ratio > 1.0
        self.last_pose_us = max(self.last_pose_us or t_pose, t_pose)
        t = t_pose
        if t_pose == base.t_us:
            base.x, base.P = x, P
        for j in range(k + 1, len(periods)):
            p = periods[j]
            x, P = (ahead if j == k + 1 and ahead is not None       # the pose kernel's
                    else self._advance(x, P, p.t_us - t, p.a_known, p.acc))
            p.x, p.P = x, P
            t = p.t_us

    def dead_reckoning(self, t_us: int) -> bool:
        return self.last_pose_us is None or \
            t_us - self.last_pose_us > round(self.cfg.dropout_s * 1e6)

    def health(self, t_us: int) -> Health:
        x = self.x
        return Health(tuple(x[0:3].tolist()), tuple(x[3:6].tolist()), self.test_ratio,
                      float(np.trace(self.P[0:3, 0:3]) / 3.0), self.dead_reckoning(t_us),
                      self.rejected)


class HealthReport:
    """The filter's health for the ground station, as STATUSTEXT: WARNING "fused filter: no
    pose, dead reckoning" when dead reckoning starts, NOTICE "fused filter: pose back" when it
    ends (once per change); WARNING "fused filter: pose rejected (R x gate)" when its
    gate starts rejecting (once per run of periods with a rejection: the innovation test, the
    filter's divergence test; rejected for dropout_s, it dead-reckons and takes the source back
    past the gate). `what` names the position source's sample: "pose", "gnss fix". Pure: the
    same healths give the same messages."""

    def __init__(self, what: str = "pose") -> None:
        self._dead = False
        self._rejected: int | None = None     # the count last seen
        self._rejecting = False
        self.what = what

    def messages(self, health: Health) -> list:
        out = []
        new = self._rejected is not None and health.rejected > self._rejected
        self._rejected = health.rejected
        if new and not self._rejecting:
            # within STATUSTEXT's 50 characters: the test ratio to 3 digits
            text = f"fused filter: {self.what} rejected ({health.test_ratio:.3g} x gate)"
            out.append(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING,
                                                          text.encode("ascii")))
        self._rejecting = new
        if health.dead_reckoning != self._dead:
            self._dead = health.dead_reckoning
            severity, text = ((mavlink.MAV_SEVERITY_WARNING,
                               f"fused filter: no {self.what}, dead reckoning")
                              if self._dead else (mavlink.MAV_SEVERITY_NOTICE,
                                                  f"fused filter: {self.what} back"))
            out.append(mavlink.MAVLink_statustext_message(severity, text.encode("ascii")))
        return out
