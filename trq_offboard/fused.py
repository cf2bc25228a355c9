"""The fused filter (issues 34 and 39): the companion's own estimate of position and velocity,
from the motion capture pose (or a GNSS fix), the raw accelerometer and the controller's own
model with the observer's disturbance as a known input.

A linear Kalman filter in world NED on x = [p (3) m, v (3) m/s, a_r (3) m/s^2, b (3) m/s^2]
(12 states: issue 34's nine and the accelerometer's bias, which the nine alone would read as
the vehicle's acceleration), kept as a history of control periods (t_prev, t] and advanced by
`FusedFilter.step` to each state's time:

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
    accelerometer  each HIGHRES_IMU message is the mean specific force over the interval since
                 the message before it, [previous time_usec, time_usec] (at most
                 IMU_MAX_SPAN_INTERVALS of the requested interval; a repeated or older stamp
                 dropped): its interval is split over the periods it covers, each piece
                 rotated with the attitude of its own time (the attitude interpolated between
                 the period's ends, which `step` and `reset` are given: two rotations a period,
                 whatever the number of samples) and weighted by its length. A period's mean,
                 z = R f + g e_z over the time its pieces cover, measures a_k + a_r + b with
                 variance accel_std^2 / (covered s x imu_rate_hz); it is taken unless its
                 normalised squared innovation exceeds `accel_gate` (a touchdown's impulse, a
                 clipped sample), except after `accel_reject_max` periods rejected in a row (a
                 gate must not lock a real change out). The position fixes what the total
                 acceleration is, so the slow difference is the sensor's bias.
    position     z = p at the pose's time of validity (ATT_POS_MOCAP's time_usec, about one
                 control period before it arrives), kept in the period it lies in. A pose whose
                 innovation test ratio (its normalised squared innovation over the chi-square
                 gate `pose_gate`) exceeds 1 is rejected. Dead reckoning (no pose fused for
                 `dropout_s`), a pose past the gate is held as a candidate: `regain_poses` in a
                 row whose innovations lie on one straight line in time (each three
                 consecutive, within pose_gate: a drifted track is off by a position and a
                 velocity, which a line absorbs; a glitch is not on it) reset the position to
                 the last and the velocity by the line's slope, as EKF2 resets to a
                 measurement, counted in `resets`; a pose within the gate is fused as ever.
                 One older than the history is dropped. The same for a GNSS fix
                 (`position_source: gnss`: GPS_RAW_INT in NED around home, its time_usec the
                 time of validity, the receiver's delay behind its arrival; its own noise per
                 axis): the history is then sized to cover that delay (config.py).
    velocity     optional (`autopilot_vel_std_m_s` > 0): the autopilot's velocity, kept with
                 its period and fused at the period's end. It is not independent of the
                 position: the autopilot fuses the same fixes (or its own copy of the pose), so
                 the two are fused by covariance intersection with equal weights, each
                 variance doubled (consistent whatever their correlation).

Every period keeps what it holds (known input, attitude, accelerometer pieces, poses and what
became of them, velocity) and its posterior. A sample that lands in a closed period (a pose's
time of validity, a HIGHRES_IMU interval straddling a period's end) runs the kept periods again
from the posterior before it, each with all it holds: nothing fused before is lost and nothing
counted twice, and a late sample gives what the same sample on time gives.

Without a pose for `dropout_s` the filter dead-reckons on the model, the observer's disturbance
and the accelerometer, and says so (`Health.dead_reckoning`; `HealthReport` turns the changes
into STATUSTEXT messages). Its health per period: the last pose's test ratio, the position's
variance (trace / 3, m^2), the rejections, resets and accelerometer rejections, for
controller.csv.

The arithmetic is written once, over an array module (`_NUMPY` or `_CASADI`: `_transition`,
`_predict`, `_accel_update`, `_update`, `_pose_fusion`): NumPy runs it as it is (the pure path,
`codegen` off or no C compiler), and with `codegen` a stretch of a period (predict to a pose,
fuse it, predict on to the stretch's end, there the gated accelerometer and the velocity) is one
CasADi function generated as C and compiled once through nmpc/cache.py with the filter's
constants baked in as literals and the times inputs: a period is one call, one more per extra
pose; the usual step, which runs the period before again (a HIGHRES_IMU interval straddling its
end) and then the new one, is one call of the two stretches chained (the same arithmetic: the
same figures to the bit). The gates' decisions stay in Python.
tests/unit/trq_offboard/test_fused_compiled.py holds the paths equal.

Pure: integer microseconds of the vehicle's clock in, no clock read, no I/O, no randomness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.frames import rotation_rows
from trq_offboard.records import EstimatorHealth as Health

__all__ = ["FusedConfig", "FusedFilter", "Health", "HealthReport"]

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


# the filter's sizes (the C core's arrays, trq_offboard/fused_core.c, and this path's lists
# alike): periods kept, candidates after a dropout (regain_poses), poses a period holds, IMU
# messages and poses received between two steps (more than a period or a step holds are
# counted dropped: `dropped`, `imu_dropped`). Choices: far above what a flight sends (one or
# two of each a period).
HISTORY_MAX, CANDIDATES_MAX, POSES_MAX, IMU_PENDING_MAX, POSES_PENDING_MAX = 256, 16, 16, 64, 64


@dataclass(frozen=True, kw_only=True)
class FusedConfig:
    """The fused filter's parameters (controller key `estimator`, kind fused), by name."""
    mocap_std_m: float                    # the pose's position noise, 1 sigma per axis
    # one HIGHRES_IMU accelerometer message's noise, 1 sigma, at imu_rate_hz (a message
    # covering a longer or shorter interval counts in proportion: the noise of a mean)
    accel_std_m_s2: float
    model_acc_density: float              # w_v: the model's white acceleration error, m/s^2/rtHz
    residual_walk_density: float          # w_r: a_r's random walk, m/s^3/rtHz
    accel_bias_std: float                 # b at the start, 1 sigma per axis, m/s^2
    accel_bias_walk_density: float        # w_b: b's random walk, m/s^3/rtHz
    pose_gate: float                      # chi-square (3 dof) gate of a pose's innovation
    dropout_s: float                      # no pose this long: dead reckoning
    imu_rate_hz: int                      # HIGHRES_IMU asked of the vehicle
    mocap_rate_hz: int                    # ATT_POS_MOCAP asked of the vehicle
    history: int = 8                      # control periods kept (delayed poses and IMU samples)
    disturbance_input: str = "motors"     # added to b0: "motors", "observer" (its d), "none"
    autopilot_vel_std_m_s: float = 0.0    # the autopilot's velocity as a measurement (0: not)
    # the position source: "mocap" (ATT_POS_MOCAP, noise mocap_std_m) or "gnss" (GPS_RAW_INT in
    # NED, trq_offboard/link/gnss.py; noise gnss_std_m (h, v), 0: each fix's own)
    position_source: str = "mocap"
    gnss_rate_hz: int = 10                # GPS_RAW_INT asked of the vehicle
    gnss_std_m: tuple[float, float] = (0.0, 0.0)
    gnss_delay_s: float = 0.11            # GPS_RAW_INT's stamp less this: its time of validity
    accel_gate: float = 100.0             # chi-square (3 dof) gate of a period's accelerometer
    accel_reject_max: int = 3             # periods rejected in a row: the next one taken
    regain_poses: int = 3                 # after a dropout: mutually consistent poses to reset

    def __post_init__(self) -> None:
        for name, low, high in (("imu_rate_hz", 1, None), ("mocap_rate_hz", 1, None),
                                ("history", 2, HISTORY_MAX),
                                ("regain_poses", 3, CANDIDATES_MAX),
                                ("accel_reject_max", 1, None)):
            value = int(getattr(self, name))
            if value < low or (high is not None and value > high):
                raise ValueError(f"FusedConfig.{name} = {getattr(self, name)}: expected an "
                                 f"integer >= {low}" + ("" if high is None else
                                                        f" and <= {high}"))
        for name in ("accel_gate", "pose_gate"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"FusedConfig.{name} = {getattr(self, name)}: expected > 0")


# a HIGHRES_IMU message covers the interval since the one before it, at most this many of the
# requested intervals (a choice: a longer gap is a lost message or an IMU dropout, and the mean
# a message carries then covers less than the gap)
IMU_MAX_SPAN_INTERVALS = 2


def _transition(dt, cfg: FusedConfig, xp=_NUMPY) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F (12x12), G (12x3) of the known input, Q (12x12)) over dt s; per axis the constant-
    acceleration triple and the bias, the axes independent (Kronecker products with I3). The
    discretisation is exact: two transitions over dt1 and dt2 make the one over dt1 + dt2."""
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
    """The accelerometer's mean z (variance var per axis) as a measurement of a_k + a_r + b:
    (x, P updated, its normalised squared innovation; the gate is the caller's)."""
    return _update(x, P, _H_ACC, z - a_known - x[6:9] - x[9:12], var * xp.eye(3), xp)


def _pose_fusion(x, P, pos, r_pos, cfg: FusedConfig, xp=_NUMPY):
    """A pose at the prior's time, its variances per axis r_pos (3): (test ratio, x, P
    updated); the gate is the caller's."""
    r = xp.diag(r_pos)
    innovation = pos - x[0:3]
    S = P[0:3, 0:3] + r
    ratio = innovation.T @ xp.solve(S, innovation) / cfg.pose_gate
    x, P, _ = _update(x, P, _H_POS, innovation, r, xp)
    return ratio, x, P


def _period_end(x, P, dt, a_known, z_acc, var_acc, has_acc, gate, z_vel, var_vel, has_vel,
                cfg: FusedConfig, xp):
    """Predicted over dt, then at the end the accelerometer's mean (taken when has_acc and its
    normalised squared innovation is within `gate`) and the autopilot's velocity (has_vel):
    (x, P, the accelerometer's normalised squared innovation, taken 0/1). CasADi only."""
    F, G, Q = _transition(dt, cfg, xp)
    x, P = _predict(x, P, F, G, Q, a_known)
    xa, Pa, nis = _accel_update(x, P, a_known, z_acc, var_acc, xp)
    take = ca.logic_and(has_acc, nis <= gate)
    x, P = ca.if_else(take, xa, x), ca.if_else(take, Pa, P)
    xv, Pv, _ = _update(x, P, _H_VEL, z_vel - x[3:6], var_vel * xp.eye(3), xp)
    return ca.if_else(has_vel, xv, x), ca.if_else(has_vel, Pv, P), nis, take


def _stretch_symbols(cfg: FusedConfig, x, P, suffix: str = ""):
    """One stretch's inputs after x and P (dt1, a_known, pos, r_pos, has_pos, dt2, z_acc,
    var_acc, has_acc, gate, z_vel, var_vel, has_vel) as SX symbols, and the function of them
    that returns the stretch's outputs (`_kernel`) for a gate given as an expression."""
    sym = ca.SX.sym
    m = 3
    ins = [sym("dt1" + suffix), sym("a_known" + suffix, m), sym("pos" + suffix, m),
           sym("r_pos" + suffix, m), sym("has_pos" + suffix), sym("dt2" + suffix),
           sym("z_acc" + suffix, m), sym("var_acc" + suffix), sym("has_acc" + suffix),
           sym("gate" + suffix), sym("z_vel" + suffix, m), sym("var_vel" + suffix),
           sym("has_vel" + suffix)]

    def stretch(x, P, gate):
        dt1, a, pos, r_pos, has_pos, dt2, z, var, has_acc, _, zv, varv, has_vel = ins
        F, G, Q = _transition(dt1, cfg, _CASADI)
        xp_, Pp = _predict(x, P, F, G, Q, a)
        ratio, xu, Pu = _pose_fusion(xp_, Pp, pos, r_pos, cfg, _CASADI)
        xs, Ps = ca.if_else(has_pos, xu, xp_), ca.if_else(has_pos, Pu, Pp)
        xe, Pe, nis, take = _period_end(xs, Ps, dt2, a, z, var, has_acc, gate, zv, varv,
                                        has_vel, cfg, _CASADI)
        return xe, Pe, ratio, nis, take, xp_, Pp

    return ins, stretch


def _kernels(cfg: FusedConfig) -> tuple[ca.Function, ca.Function] | None:
    """The compiled kernels (`_kernel` and `_kernel_two`), built together once a process for a
    configuration (trq_wire.cache.built_once, as the controller's other compiled parts), or None
    without a C compiler or when a build fails (then the NumPy path runs)."""
    from trq_offboard.nmpc.cache import compiled_many, find_compiler
    from trq_wire.cache import built_once

    def build() -> tuple[ca.Function, ca.Function] | None:
        if find_compiler() is None:
            return None
        built = compiled_many([_kernel(cfg), _kernel_two(cfg)])
        if any(how == "interpreted" for _, how in built):
            return None
        return built[0][0], built[1][0]

    return built_once(("fused kernels", cfg), build)[0]


def _kernel(cfg: FusedConfig) -> ca.Function:
    """One stretch of a period as a CasADi function (module docstring), compiled by
    `_kernels`:
        period (x, P, dt1, a_known, pos, r_pos, has_pos, dt2, z_acc, var_acc, has_acc, gate,
                z_vel, var_vel, has_vel)
               -> (x_end, P_end, pose test ratio, accel NIS, accel taken, x_prior, P_prior)
    predicted dt1 to the pose (the prior), the pose fused when has_pos, predicted dt2 on to
    the stretch's end, there the accelerometer's mean (if has_acc and within `gate`; inf:
    taken whatever it says) and the autopilot's velocity (has_vel). dt in s; P dense,
    CasADi's column-major order. Compiled once a process a configuration (`_kernels`); each
    filter wraps it in its own buffers."""
    n = N_STATES
    x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
    ins, stretch = _stretch_symbols(cfg, x, P)
    return ca.Function(f"fused_period_{n}", [x, P, *ins], list(stretch(x, P, ins[9])))


def _kernel_two(cfg: FusedConfig) -> ca.Function:
    """Two periods' stretches in one function, the second from the first's end: the same
    arithmetic as two calls of `_kernel` (the first's outputs are the second's inputs), so
    the same figures to the bit, for the usual step that runs the period before again (a
    HIGHRES_IMU interval straddling its end) and then the new one (`FusedFilter._run_two`):
        two (x, P, <the first stretch's inputs after P>, <the second's, its gate the one
             that holds when the first period's accelerometer was rejected>, gate_taken)
            -> (x1, P1, nis1, taken1, x2, P2, ratio2, nis2, taken2, x2_prior, P2_prior)
    The second's gate is gate_taken when the first period's accelerometer was taken (or it
    had none), as `FusedFilter._gate` has it. One call from Python where two would cost two
    calls' Python; fused_core.c calls `_kernel` twice instead (the same figures, half the
    straight-line code to read a period: docs/decisions/2026-12-07-period-paced.md)."""
    n = N_STATES
    x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
    ins1, stretch1 = _stretch_symbols(cfg, x, P)
    ins2, stretch2 = _stretch_symbols(cfg, x, P, "_2")
    gate_taken = ca.SX.sym("gate_taken")
    x1, P1, _, nis1, take1, _, _ = stretch1(x, P, ins1[9])
    taken1 = ca.logic_or(ca.logic_not(ins1[8]), take1)
    x2, P2, ratio2, nis2, take2, xp2, Pp2 = stretch2(x1, P1, ca.if_else(taken1, gate_taken,
                                                                         ins2[9]))
    return ca.Function(f"fused_two_{n}", [x, P, *ins1, *ins2, gate_taken],
                       [x1, P1, nis1, take1, x2, P2, ratio2, nis2, take2, xp2, Pp2])


def pose_variances(cfg: FusedConfig, std_ned_m=None) -> tuple[float, float, float] | None:
    """The variances per axis the filter gives a pose of 1-sigma errors std_ned_m (None:
    mocap_std_m on each), doubled with the autopilot's velocity as a measurement (covariance
    intersection: the two are not independent); None when the errors are not finite and > 0
    (the pose is dropped)."""
    s = (cfg.mocap_std_m,) * 3 if std_ned_m is None else tuple(float(v) for v in std_ned_m)
    if not (math.isfinite(s[0] + s[1] + s[2]) and min(s) > 0.0):
        return None
    k = 2.0 if cfg.autopilot_vel_std_m_s > 0.0 else 1.0
    return k * (s[0] * s[0]), k * (s[1] * s[1]), k * (s[2] * s[2])


def start_state(cfg: FusedConfig, pos_ned_m, vel_ned_m_s, pos_std_m: float | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """`FusedFilter.reset`'s x and P: the position and velocity given, a_r = 0 and b = 0; the
    pose's variance on position (or pos_std_m's), generous ones on velocity and a_r,
    accel_bias_std on b."""
    x = np.concatenate([np.asarray(pos_ned_m, float), np.asarray(vel_ned_m_s, float),
                        np.zeros(6)])
    std = cfg.mocap_std_m if pos_std_m is None else pos_std_m
    P = np.diag([std ** 2] * 3 + [0.1 ** 2] * 3 + [1.0] * 3 + [cfg.accel_bias_std ** 2] * 3)
    return x, P


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


# what became of a position sample: fused; rejected by the gate; held (a candidate after a
# dropout, not fused); the position reset to it (after regain_poses consistent candidates)
_NEW, _FUSED, _REJECTED, _HELD, _RESET = range(5)


@dataclass
class _Pose:
    t_us: int
    pos: np.ndarray
    r_pos: np.ndarray          # variances per axis
    kind: int = _NEW
    vel_shift: np.ndarray | None = None      # a reset's: the velocity's correction
    vel_var: np.ndarray | None = None        # and its variance per axis


@dataclass
class _Period:
    """One kept control period (t_prev, t_us]: the known input over it, the attitude at its
    end, the accelerometer samples integrated into it (weighted toward its start and end
    attitudes, body FRD), its position samples, the autopilot's velocity at its end (or None),
    and the posterior at its end."""
    t_us: int
    a_known: np.ndarray
    rot: tuple                           # R (NED from FRD) at t_us, its rows (rotation_rows)
    x: np.ndarray
    P: np.ndarray
    w0: np.ndarray = None                # sum of dt (1 - s) f over its samples' pieces
    w1: np.ndarray = None                # sum of dt s f (s: the piece's midpoint, 0..1)
    covered_s: float = 0.0               # the time its samples cover
    poses: list = None
    vel: np.ndarray | None = None
    acc_taken: bool = True               # its accelerometer mean passed the gate (or none)
    acc: tuple | None = None             # its accelerometer measurement (`_acc`), once formed

    def __post_init__(self) -> None:
        if self.w0 is None:
            self.w0, self.w1, self.poses = np.zeros(3), np.zeros(3), []


class FusedFilter:
    """The filter (module docstring): reset, then per control period `add_imu` / `add_pose`
    for the samples received and `step` to the period's end. `codegen`: the compiled kernel
    (when a C compiler is found), else the NumPy path (`compiled` says which runs)."""

    def __init__(self, cfg: FusedConfig, gravity_m_s2: float, codegen: bool = True) -> None:
        self.cfg = cfg
        self.g = gravity_m_s2
        self._g_ned = np.array([0.0, 0.0, gravity_m_s2])
        self._trans: dict[int, tuple] = {}
        kernels = _kernels(cfg) if codegen else None
        self._fn = _Kernel(kernels[0]) if kernels is not None else None
        self._fn2 = _Kernel(kernels[1]) if kernels is not None else None
        self._periods: list[_Period] = []
        self._imu: list[tuple[int, np.ndarray]] = []       # (time_usec, f FRD) not yet placed
        self._poses: list[_Pose] = []
        self._imu_last_us: int | None = None
        self._imu_nominal_us = round(1e6 / cfg.imu_rate_hz)
        # the variances a pose of the default noise carries, formed once (None: the noise not
        # finite and > 0, every such pose dropped, as `add_pose` drops one)
        r = pose_variances(cfg)
        self._mocap_r = None if r is None else np.array(r)
        self._dropout_us = round(cfg.dropout_s * 1e6)
        self._candidates: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        self.last_pose_us: int | None = None
        self._zero_health()

    def _zero_health(self) -> None:
        """The health figures a (re)start clears: the last test ratio and the counters."""
        self.test_ratio = math.nan
        self.rejected = 0
        self.dropped = 0
        self.imu_dropped = 0
        self.accel_rejected = 0
        self.resets = 0

    def _f(self, dt_us: int):
        got = self._trans.get(dt_us)
        if got is None:
            got = _transition(dt_us * 1e-6, self.cfg)
            if len(self._trans) < 64:
                self._trans[dt_us] = got
        return got

    def reset(self, t_us: int, pos_ned_m, vel_ned_m_s, pos_std_m: float | None = None,
              euler_rad=(0.0, 0.0, 0.0)) -> None:
        """Start from a position and velocity (the autopilot's) and the attitude at t_us,
        a_r = 0 and b = 0, with the pose's variance on position (or pos_std_m's), generous
        ones on velocity and a_r, accel_bias_std on b."""
        x, P = start_state(self.cfg, pos_ned_m, vel_ned_m_s, pos_std_m)
        self._periods = [_Period(int(t_us), np.zeros(3), rotation_rows(*euler_rad), x, P)]
        self._imu.clear()
        self._poses.clear()
        self._candidates.clear()
        self._imu_last_us = None
        self.last_pose_us = int(t_us)
        self._zero_health()

    @property
    def compiled(self) -> bool:
        """The compiled kernel runs (else the NumPy path)."""
        return self._fn is not None

    @property
    def t_us(self) -> int:
        return self._periods[-1].t_us

    @property
    def x(self) -> np.ndarray:
        return self._periods[-1].x

    @property
    def P(self) -> np.ndarray:
        return self._periods[-1].P

    def add_imu(self, t_us: int, specific_force_frd_m_s2) -> None:
        """One HIGHRES_IMU accelerometer message: the mean specific force (body FRD) over the
        interval since the message before it, ending at its time of validity t_us (time_usec);
        placed at the next `step` in the periods that interval covers."""
        f = np.array(specific_force_frd_m_s2, float)
        if math.isfinite(f[0] + f[1] + f[2]):
            if len(self._imu) >= IMU_PENDING_MAX:
                self.imu_dropped += 1
                return
            self._imu.append((int(t_us), f))

    def add_pose(self, t_us: int, pos_ned_m, std_ned_m=None) -> None:
        """One position (motion capture, or a GNSS fix in NED) at its time of validity, with
        its 1-sigma errors per axis (None: mocap_std_m), fused at the next `step`."""
        if std_ned_m is None:          # the default noise: its variances formed once
            r = self._mocap_r
            if r is not None and math.isfinite(pos_ned_m[0] + pos_ned_m[1] + pos_ned_m[2]):
                self._keep_pose(_Pose(int(t_us), np.array(pos_ned_m, float), r))
            return
        p = np.array(pos_ned_m, float)
        r = pose_variances(self.cfg, std_ned_m)
        if r is not None and math.isfinite(p[0] + p[1] + p[2]):
            self._keep_pose(_Pose(int(t_us), p, np.array(r)))

    def _keep_pose(self, pose: _Pose) -> None:
        if len(self._poses) >= POSES_PENDING_MAX:
            self.dropped += 1
        else:
            self._poses.append(pose)

    def step(self, t_us: int, a_known_ned: np.ndarray, euler_rad=None,
             vel_ned_m_s=None) -> Health:
        """Advance to t_us (> the last period's end) under the known input a_known (m/s^2 NED,
        held over the period), the attitude at t_us `euler_rad` (None: the last period's);
        place the accelerometer messages received in the periods they cover and the poses at
        their times of validity, and run the kept periods again from the earliest one either
        touched (each with all it holds); with autopilot_vel_std_m_s, `vel_ned_m_s` (the
        autopilot's velocity now) is kept with the period and fused at its end."""
        periods = self._periods
        last = periods[-1]
        t_us = int(t_us)
        if t_us <= last.t_us:
            return self.health(t_us)
        # (the angles as Python floats: the same products as NumPy scalars', cheaper)
        rot = last.rot if euler_rad is None else \
            rotation_rows(*np.asarray(euler_rad, float).tolist())
        period = _Period(t_us, np.asarray(a_known_ned, float).copy(), rot, last.x, last.P)
        std = self.cfg.autopilot_vel_std_m_s
        if std > 0.0 and vel_ned_m_s is not None:
            v = np.asarray(vel_ned_m_s, float)
            period.vel = v.copy() if np.all(np.isfinite(v)) else None
        periods.append(period)
        del periods[:-self.cfg.history]
        first = len(periods) - 1
        if self._imu:
            first = min(first, self._place_imu(t_us))
        if self._poses:
            first = min(first, self._place_poses(t_us))
        self._run(first)
        return self.health(t_us)

    def _place_imu(self, t_us: int) -> int:
        """The accelerometer messages up to t_us into the periods their intervals cover:
        the earliest period touched (len(periods) - 1 if none)."""
        periods = self._periods
        first = len(periods) - 1
        later = []
        span_max = IMU_MAX_SPAN_INTERVALS * self._imu_nominal_us
        imu = self._imu if len(self._imu) < 2 else sorted(self._imu, key=lambda s: s[0])
        for t, f in imu:
            if t > t_us:                       # after this state: the next period's
                later.append((t, f))
                continue
            prev = self._imu_last_us
            if prev is not None and t <= prev:     # a repeat or out of order
                self.imu_dropped += 1
                continue
            self._imu_last_us = t
            a = t - self._imu_nominal_us if prev is None else max(prev, t - span_max)
            placed = False
            for k in range(len(periods) - 1, 0, -1):
                end, start = periods[k].t_us, periods[k - 1].t_us
                if start >= t:
                    continue
                if end <= a:
                    break
                lo, hi = max(a, start), min(t, end)
                dt = (hi - lo) * 1e-6
                s = (0.5 * (lo + hi) - start) / (end - start)
                p = periods[k]
                p.w0 += (dt * (1.0 - s)) * f
                p.w1 += (dt * s) * f
                p.covered_s += dt
                p.acc = None
                placed = True
                first = min(first, k)
            if not placed:
                self.imu_dropped += 1
        self._imu = later
        return first

    def _place_poses(self, t_us: int) -> int:
        """The poses received into the periods of their times of validity, [start, end)
        but the newest's end (a pose one period late, at a period's end, goes to the start of
        the next: the posterior kept at that end stays without it, and the newest period alone
        runs); one after t_us taken at t_us, one older than the history dropped: the earliest
        period touched."""
        periods = self._periods
        first = len(periods) - 1
        for pose in self._poses:
            pose.t_us = min(pose.t_us, t_us)
            k = len(periods) - 1
            while k > 0 and periods[k - 1].t_us > pose.t_us:
                k -= 1
            if k == 0 or periods[k - 1].t_us > pose.t_us or len(periods[k].poses) >= POSES_MAX:
                self.dropped += 1
                continue
            kept = periods[k].poses
            kept.append(pose)
            if len(kept) > 1:
                kept.sort(key=lambda p: p.t_us)
            first = min(first, k)
        self._poses.clear()
        return first

    def _acc(self, k: int):
        """Period k's accelerometer measurement (total acceleration NED, variance per axis),
        or None: its samples rotated with the attitudes at its start and end, each weighted
        by where in the period it lies (the attitude interpolated linearly between the two:
        exact to second order in the rotation over a period)."""
        p = self._periods[k]
        if p.covered_s <= 0.0:
            return None
        if p.acc is None:               # formed once, until a sample is added to the period
            # the products written out in a fixed order (NumPy's go through BLAS, whose order
            # and fused multiply-adds depend on the CPU), as the C core repeats them
            a, b = self._periods[k - 1].rot, p.rot
            u, v = p.w0.tolist(), p.w1.tolist()
            z = np.array([(r[0] * u[0] + r[1] * u[1] + r[2] * u[2])
                          + (q[0] * v[0] + q[1] * v[1] + q[2] * v[2]) for r, q in zip(a, b)]) \
                / p.covered_s + self._g_ned
            p.acc = z, self.cfg.accel_std_m_s2 ** 2 / (p.covered_s * self.cfg.imu_rate_hz)
        return p.acc

    def _gate(self, k: int) -> float:
        """Period k's accelerometer gate: accel_gate, or none (inf) after accel_reject_max
        periods rejected in a row (a gate must not lock the accelerometer out)."""
        if self._periods[k - 1].acc_taken:
            return self.cfg.accel_gate
        m = self.cfg.accel_reject_max
        prev = self._periods[max(1, k - m):k]
        if len(prev) == m and not any(p.acc_taken for p in prev):
            return math.inf
        return self.cfg.accel_gate

    def _run(self, first: int) -> None:
        """The kept periods from `first` on run again from the posterior before it, each with
        its poses (the new ones gated here), accelerometer mean and velocity."""
        periods = self._periods
        newest = len(periods) - 1
        first = max(first, 1)
        if first == newest - 1 and self._fn2 is not None and self._run_two(newest):
            return
        for k in range(first, newest + 1):
            self._run_period(k, newest)

    def _run_two(self, k: int) -> bool:
        """Periods k - 1 and k (the newest) in one call of the two-period kernel (the usual
        step: a HIGHRES_IMU interval straddled k - 1's end), when k - 1 holds at most one pose,
        already fused, and k at most one, new: the same figures and decisions as running each
        (`_run_period`). A new pose past its gate runs period k again the usual way (its prior
        and the decision's bookkeeping). False, nothing done, when the periods hold more."""
        periods = self._periods
        p0, p1, p2 = periods[k - 2], periods[k - 1], periods[k]
        q1 = q2 = None
        if p1.poses:
            active = [q for q in p1.poses if q.kind in (_NEW, _FUSED, _RESET)]
            if len(active) > 1 or (active and active[0].kind != _FUSED):
                return False
            q1 = active[0] if active else None
        if p2.poses:
            if len(p2.poses) > 1 or p2.poses[0].kind != _NEW:
                return False
            q2 = p2.poses[0]
        cfg = self.cfg
        acc1, acc2 = self._acc(k - 1), self._acc(k)
        gate1 = cfg.accel_gate if p0.acc_taken else self._gate(k - 1)
        # period k's gate when k - 1's accelerometer is rejected (`_gate` with it rejected)
        m = cfg.accel_reject_max
        prev = periods[max(1, k - m):k]
        gate2_not = math.inf if len(prev) == m and not any(p.acc_taken for p in prev[:-1]) \
            else cfg.accel_gate
        fn = self._fn2
        args, res = fn.args, fn.results
        args[0][:], fn.p_in[:] = p0.x, p0.P
        t = p0.t_us
        if q1 is None:
            self._set_stretch(args, 2, p1.t_us - t, p1.a_known, None, 0, acc1, gate1, p1.vel)
        else:
            self._set_stretch(args, 2, q1.t_us - t, p1.a_known, q1, p1.t_us - q1.t_us, acc1,
                              gate1, p1.vel)
        t = p1.t_us
        if q2 is None:
            self._set_stretch(args, 15, p2.t_us - t, p2.a_known, None, 0, acc2, gate2_not,
                              p2.vel)
        else:
            self._set_stretch(args, 15, q2.t_us - t, p2.a_known, q2, p2.t_us - q2.t_us, acc2,
                              gate2_not, p2.vel)
        args[28][0] = cfg.accel_gate
        fn.evaluate()
        p1.x, p1.P = res[0].copy(), _matrix(res[1])
        self._acc_result(k - 1, acc1, res[2][0], res[3][0] > 0.0, k)
        if q2 is not None:
            ratio = res[6][0]
            if not ratio <= 1.0:            # past the gate (or not a number): the usual way
                self._run_period(k, k)
                return True
            self._decide(q2, ratio, None)
        p2.x, p2.P = res[4].copy(), _matrix(res[5])
        self._acc_result(k, acc2, res[7][0], res[8][0] > 0.0, k)
        return True

    def _run_period(self, k: int, newest: int) -> None:
        """Period k run again from the posterior before it, with its poses (the new ones
        gated here), accelerometer mean and velocity."""
        periods = self._periods
        prev, p = periods[k - 1], periods[k]
        acc = self._acc(k)
        gate = self.cfg.accel_gate if prev.acc_taken else self._gate(k)
        vel = p.vel
        x, P, t = prev.x, prev.P, prev.t_us
        active = [q for q in p.poses if q.kind in (_NEW, _FUSED, _RESET)] if p.poses else ()
        done = False
        for i, q in enumerate(active):
            last = i == len(active) - 1
            out = self._stretch(x, P, q.t_us - t, p.a_known, q, p.t_us - q.t_us if last
                                else 0, acc if last else None, gate, vel if last else None)
            x_end, P_end, ratio, nis, taken = out
            prior = None
            if q.kind == _NEW:
                if ratio > 1.0:
                    prior = self._prior()
                self._decide(q, ratio, prior)
            if q.kind in (_RESET, _REJECTED, _HELD) and prior is None:
                prior = self._prior()
            if q.kind == _FUSED:
                if last:
                    x, P, done = x_end, P_end, True
                    self._acc_result(k, acc, nis, taken, newest)
                else:
                    x, P = x_end, P_end
            elif q.kind == _RESET:
                x, P = self._reset_to(q, *prior)
            else:                               # rejected or held: the prior goes on
                x, P = prior
            t = q.t_us
        if not done:
            x, P, _, nis, taken = self._stretch(x, P, p.t_us - t, p.a_known, None, 0, acc,
                                                gate, vel)
            self._acc_result(k, acc, nis, taken, newest)
        p.x, p.P = x, P

    def _acc_result(self, k: int, acc, nis: float, taken: bool, newest: int) -> None:
        p = self._periods[k]
        p.acc_taken = acc is None or taken
        if k == newest and not p.acc_taken:
            self.accel_rejected += 1

    def _decide(self, q: _Pose, ratio: float, prior) -> None:
        """A new pose's fate from its test ratio against the prior at its time: fused within
        the gate; outside it rejected, or, dead reckoning (no pose fused for dropout_s), held
        as a candidate. `regain_poses` candidates in a row that are mutually consistent (each
        three consecutive ones: their innovations against the dead-reckoned track on one
        straight line, within pose_gate: the track's position and velocity errors are what a
        line absorbs, a glitch is not) reset the position to the last and the velocity by the
        line's slope (as EKF2 resets to a measurement), counted in `resets`."""
        self.test_ratio = ratio
        if ratio <= 1.0:
            q.kind = _FUSED
            self._candidates.clear()
            self.last_pose_us = max(self.last_pose_us or q.t_us, q.t_us)
            return
        if not self.dead_reckoning(q.t_us):
            q.kind = _REJECTED
            self.rejected += 1
            return
        x_prior, P_prior = prior
        run = self._candidates
        run.append((q.t_us, q.pos - x_prior[0:3], q.r_pos, np.diag(P_prior)[6:9].copy()))
        if len(run) >= 3 and not self._on_a_line(run[-3:]):
            del run[:-2]                 # one of them off the line: the last two go on
        if len(run) >= self.cfg.regain_poses:
            q.kind = _RESET
            t1, nu1, r1, _ = run[0]
            span = (q.t_us - t1) * 1e-6
            q.vel_shift = (run[-1][1] - nu1) / span
            q.vel_var = (r1 + q.r_pos) / (span * span)
            run.clear()
            self.resets += 1
            self.last_pose_us = max(self.last_pose_us or q.t_us, q.t_us)
        else:
            q.kind = _HELD
            self.rejected += 1

    def _on_a_line(self, three) -> bool:
        """Three candidates' innovations on one straight line in time: the middle one's
        distance from the line through the other two, against its variance (the poses' noise
        and the acceleration error the prior carries, P_aa, over the spacing), within
        pose_gate (chi-square, 3 dof)."""
        (t1, n1, r1, _), (t2, n2, r2, paa), (t3, n3, r3, _) = three
        w = (t2 - t1) / (t3 - t1)
        d = n2 - ((1.0 - w) * n1 + w * n3)
        lever = 0.5 * (t2 - t1) * (t3 - t2) * 1e-12
        var = r2 + (1.0 - w) ** 2 * r1 + w * w * r3 + lever * lever * paa
        return float(np.sum(d * d / var)) <= self.cfg.pose_gate

    @staticmethod
    def _reset_to(q: _Pose, x, P):
        """The position reset to the pose (its value and variance) and the velocity shifted by
        the candidates' slope (its variance theirs), no correlation of either left."""
        x = x.copy()
        P = np.array(P)
        x[0:3] = q.pos
        x[3:6] = x[3:6] + q.vel_shift
        P[0:6, :] = 0.0
        P[:, 0:6] = 0.0
        P[0:3, 0:3] = np.diag(q.r_pos)
        P[3:6, 3:6] = np.diag(q.vel_var)
        return x, P

    def _stretch(self, x, P, dt1_us: int, a_known, pose: _Pose | None, dt2_us: int, acc,
                 gate: float, vel):
        """Predicted dt1 to the pose (if any) and fused, predicted dt2 on, then the
        accelerometer (gated) and the velocity: (x_end, P_end, the pose's test ratio, the
        accelerometer's NIS, taken; the prior at the pose: `_prior`)."""
        fn = self._fn
        if fn is not None:
            res = fn.results
            fn.args[0][:], fn.p_in[:] = x, P
            self._set_stretch(fn.args, 2, dt1_us, a_known, pose, dt2_us, acc, gate, vel)
            fn.evaluate()
            return (res[0].copy(), _matrix(res[1]), res[2][0], res[3][0], res[4][0] > 0.0)
        ratio, nis, taken = math.nan, math.nan, False
        x, P = _predict(x, P, *self._f(dt1_us), a_known)
        self._numpy_prior = x, P
        if pose is not None:
            ratio, x, P = _pose_fusion(x, P, pose.pos, pose.r_pos, self.cfg)
            ratio = float(ratio)
        if dt2_us:
            x, P = _predict(x, P, *self._f(dt2_us), a_known)
        if acc is not None:
            xa, Pa, nis = _accel_update(x, P, a_known, *acc)
            nis = float(nis)
            taken = nis <= gate
            if taken:
                x, P = xa, Pa
        if vel is not None:
            std = self.cfg.autopilot_vel_std_m_s
            x, P, _ = _update(x, P, _H_VEL, vel - x[3:6], 2.0 * std * std * _I3)
        return x, P, ratio, nis, taken

    def _set_stretch(self, args, i: int, dt1_us: int, a_known, pose: _Pose | None,
                     dt2_us: int, acc, gate: float, vel) -> None:
        """A stretch's inputs after x and P into a kernel's args from index i on (`_kernel`'s
        order: dt1, a_known, pos, r_pos, has_pos, dt2, z_acc, var_acc, has_acc, gate, z_vel,
        var_vel, has_vel)."""
        args[i][0], args[i + 1][:] = dt1_us * 1e-6, a_known
        if pose is None:
            args[i + 4][0] = 0.0
        else:
            args[i + 2][:], args[i + 3][:], args[i + 4][0] = pose.pos, pose.r_pos, 1.0
        args[i + 5][0] = dt2_us * 1e-6
        if acc is None:
            args[i + 8][0] = 0.0
        else:
            args[i + 6][:], args[i + 7][0], args[i + 8][0], args[i + 9][0] = \
                acc[0], acc[1], 1.0, gate
        if vel is None:
            args[i + 12][0] = 0.0
        else:
            std = self.cfg.autopilot_vel_std_m_s
            args[i + 10][:], args[i + 11][0], args[i + 12][0] = vel, 2.0 * std * std, 1.0

    def _prior(self):
        """The prior at the pose of the last `_stretch` with one: (x, P)."""
        fn = self._fn
        if fn is not None:
            return fn.results[5].copy(), _matrix(fn.results[6])
        return self._numpy_prior

    def dead_reckoning(self, t_us: int) -> bool:
        return self.last_pose_us is None or \
            t_us - self.last_pose_us > self._dropout_us

    def health(self, t_us: int) -> Health:
        x, P = self.x.tolist(), self.P
        return Health(tuple(x[0:3]), tuple(x[3:6]), self.test_ratio,
                      float(P[0, 0] + P[1, 1] + P[2, 2]) / 3.0, self.dead_reckoning(t_us),
                      self.rejected, self.resets, self.accel_rejected)


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
        self._resets = 0
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
        if health.resets > self._resets:
            text = f"fused filter: position reset to {self.what}"
            out.append(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_NOTICE,
                                                          text.encode("ascii")))
        self._resets = health.resets
        if health.dead_reckoning != self._dead:
            self._dead = health.dead_reckoning
            severity, text = ((mavlink.MAV_SEVERITY_WARNING,
                               f"fused filter: no {self.what}, dead reckoning")
                              if self._dead else (mavlink.MAV_SEVERITY_NOTICE,
                                                  f"fused filter: {self.what} back"))
            out.append(mavlink.MAVLink_statustext_message(severity, text.encode("ascii")))
        return out
