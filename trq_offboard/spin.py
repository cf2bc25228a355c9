"""The lost-motor controller: a spinning "relaxed hover" on three rotors (issue 40 item 3).

With one motor at 0 % the TRQ has no static trim, but a family of spinning equilibria (Mueller and
D'Andrea's relaxed hover): the body turns at a constant rate w about a body-fixed primary axis n
that stays fixed in the world, the live actuators constant in the body frame
(docs/decisions/2026-12-05-lost-motor-envelope.md). This module flies that orbit:

    equilibrium(vehicle, motor, spin_rad_s) -> SpinTrim      the orbit (IPOPT, once)
    SpinController(config, vehicle, motor)                    built once (trim, LQR gain)
        .reset(estimate, *, command=None, hold_pos_ned_m=None, ground_down_m=0.0)
        .step(estimate, reference) -> ActuatorCommand         pure arithmetic, no I/O
        .info -> SpinInfo                                     what the last step did
    landing_reference(t_s, start_pos_ned_m, landing, ground_down_m) -> ReferenceSample
    load_spin_config(controller_yaml) -> SpinConfig           the controller file's `spin:`

The design (docs/decisions/2026-12-05-lost-motor-spin-controller.md says why, and what it does in
the plant): a cascade.

- Outside, a position loop (PID on the world NED position and velocity) asks for a force vector
  T = m (a_des - g) + drag(v): its direction is the direction the primary axis must take in the
  world, n_des (leaning at most max_lean_deg), its size the force along the axis, f_des.
- Inside, a discrete LQR about the orbit written in the body frame, where the orbit is a fixed
  point: the body rates omega (3; the orbit has omega = w n), the desired axis seen from the body
  s = R^T n_des (2, in a basis normal to n: s moves as ds/dt = -omega x s), and the six live
  actuators' outputs (3 throttles, 3 tilts) through their first-order lags (the controller
  integrates its own commands through the vehicle file's lags and rate limits: no measurement of
  them is needed). Its inputs are the six live commands; the dead rotor's throttle is 0 and its
  tilt 0. The force along the axis enters as an output weighted in the cost; the operating point
  moves with f_des along the linearised family of equilibria (the torque balance held). Yaw is
  given up; the spin rate is a state regulated to spin_rate_rad_s through the tilts' yaw torque
  (the plant has no yaw damping: without it the spin would drift along the family).

The inner loop may instead be an NMPC on the same body-frame model kept nonlinear, the actuators'
bounds as constraints, this LQR's Riccati solution as its terminal cost (`inner: nmpc`,
spin_nmpc.py; the LQR flies a period whose QP fails).

Units: throttles in percent on the wire and in the trim, as fractions (percent / 100) inside the
LQR; tilts in rad; world NED, body FRD, as the rest of trq_offboard.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from trq_params import loader, schema

from trq_offboard.config import VehicleModel, load_vehicle_model
from trq_offboard.frames import rotation_ned_frd
from trq_offboard.records import ActuatorCommand, ReferenceSample, StateEstimate
from trq_offboard.spin_nmpc import SpinNmpc, SpinReference, geometry, live_wrench

__all__ = ["SpinWeights", "SpinPosition", "SpinLanding", "SpinConfig", "SpinTrim", "SpinInfo",
           "equilibrium", "SpinController", "landing_reference", "load_spin_config", "spin_config",
           "load_for_vehicle", "spin_sense"]

_IPOPT = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 500}


# --- parameters -------------------------------------------------------------------------------

@dataclass(frozen=True)
class SpinWeights:
    rates: tuple[float, float]          # (rad/s)^-2, the two rates normal to the axis
    spin: float                         # (rad/s)^-2, the spin rate's error
    axis: float                         # rad^-2, the axis' direction error
    force: float                        # N^-2, the force along the axis
    actuator: tuple[float, float]       # throttle (fraction)^-2, tilt rad^-2: lagged outputs
    input: tuple[float, float]          # the same, the commands


@dataclass(frozen=True)
class SpinPosition:
    kp_s2: tuple[float, float]          # horizontal, vertical (m/s^2 per m)
    kd_s: tuple[float, float]           # (m/s^2 per m/s)
    ki_s3: tuple[float, float]          # (m/s^2 per m s)
    max_lean_rad: float
    climb_force_N: float
    sink_force_N: float
    max_integral_m_s2: float


@dataclass(frozen=True)
class SpinLanding:
    hold_s: float
    descent_speed_m_s: float
    final_height_m: float
    final_speed_m_s: float
    contact_height_m: float
    contact_speed_m_s: float
    final_spin_rate_rad_s: float        # the spin below final_height_m (a smaller cone)


@dataclass(frozen=True)
class SpinConfig:
    file: str
    spin_rate_rad_s: float
    control_rate_hz: int
    weights: SpinWeights
    position: SpinPosition
    landing: SpinLanding
    vehicle_file: str
    inner: str = "lqr"                  # the inner loop: "lqr", or "nmpc" (spin_nmpc.py)
    horizon_steps: int = 20             # the NMPC's horizon, in control periods
    observer_lowpass_s: float | None = None   # the observer's estimate fed forward through a
                                              # low-pass of this time constant (None: not used)
    observer_settle_s: float = 0.1            # not taken for this long after the switch

    @property
    def dt_s(self) -> float:
        return 1.0 / self.control_rate_hz


def spin_config(s: schema.Spin, file: str, vehicle_file: str) -> SpinConfig:
    """The record of a validated `spin:` section."""
    w, p, la = s.weights, s.position, s.landing
    return SpinConfig(
        file, s.spin_rate_rad_s, s.control_rate_hz,
        SpinWeights(tuple(w.rates), w.spin, w.axis, w.force, tuple(w.actuator), tuple(w.input)),
        SpinPosition(tuple(p.kp_s2), tuple(p.kd_s), tuple(p.ki_s3), math.radians(p.max_lean_deg),
                     p.climb_force_N, p.sink_force_N, p.max_integral_m_s2),
        SpinLanding(la.hold_s, la.descent_speed_m_s, la.final_height_m, la.final_speed_m_s,
                    la.contact_height_m, la.contact_speed_m_s, la.final_spin_rate_rad_s),
        vehicle_file, s.inner, s.horizon_steps, s.observer_lowpass_s, s.observer_settle_s)


def load_spin_config(path: Path | str) -> SpinConfig:
    """The `spin:` section of a controller file (ConfigError, the loader's, if it is missing or
    invalid; the message names the file and the key)."""
    path = Path(path).resolve()
    c = loader.load(path, schema.ControllerFile)
    if c.spin is None:
        raise loader.ConfigError(f"{path}: spin: missing (the lost-motor controller's section, "
                                 "expected a mapping: see params/controller/trq_nmpc_eso.yaml)")
    return spin_config(c.spin, str(path), str((path.parent / c.vehicle).resolve()))


# --- the rotors' wrench (CasADi; the prediction model's arithmetic, live rotors only) ---------

def _wrench(vm: VehicleModel, live, zeta_pct, alpha_rad):
    """Body FRD force and torque of the live rotors (lists of SX/floats, 4 each, the dead
    rotor's ignored): spin_nmpc.live_wrench on their geometry."""
    return live_wrench(vm, ca.DM(geometry(vm, live)), [zeta_pct[i] for i in live],
                       [alpha_rad[i] for i in live])


@dataclass(frozen=True)
class SpinTrim:
    """One relaxed hover of the controller's model: the commands (the dead motor's 0), the
    primary axis n (body FRD, pointing up: the mean force's direction), the spin rate, the
    margin (the live actuators' least distance from a limit, a fraction of their range)."""
    motor: int                              # the dead motor, 1..4
    spin_rad_s: float
    axis_frd: tuple[float, float, float]
    throttle_pct: tuple[float, float, float, float]
    tilt_rad: tuple[float, float, float, float]
    force_along_axis_N: float
    margin: float


# the trims solved in this process (vehicle, motor, spin rate): a controller builds one spinning
# controller per motor and per sense of the spin, and the trim does not depend on the sense
_TRIMS: dict[tuple, SpinTrim] = {}


def equilibrium(vm: VehicleModel, motor: int, spin_rad_s: float) -> SpinTrim:
    """The largest-margin relaxed hover at `spin_rad_s` with motor `motor` (1..4) dead, in calm
    air (IPOPT from eight starts, as trq_lab's spin envelope; ValueError if none is found).
    Solved once per process for each vehicle, motor and rate (a pure function of them)."""
    key = (repr(vm), motor, float(spin_rad_s))
    if key not in _TRIMS:
        _TRIMS[key] = _equilibrium(vm, motor, spin_rad_s)
    return _TRIMS[key]


def _equilibrium(vm: VehicleModel, motor: int, spin_rad_s: float) -> SpinTrim:
    if motor not in (1, 2, 3, 4):
        raise ValueError(f"spin: motor {motor!r}, expected 1..4 (PX4 quad X numbering)")
    if vm.tilt_locked:
        raise ValueError(f"spin: vehicle {vm.name!r} has its tilts locked: no relaxed hover "
                         "(docs/decisions/2026-12-05-lost-motor-envelope.md)")
    live = [i for i in range(4) if i != motor - 1]
    z, a, n, t = ca.SX.sym("z", 3), ca.SX.sym("a", 3), ca.SX.sym("n", 3), ca.SX.sym("t")
    zeta, alpha = [0.0] * 4, [0.0] * 4
    for k, i in enumerate(live):
        zeta[i], alpha[i] = z[k], a[k]
    f, m = _wrench(vm, live, zeta, alpha)
    jn = ca.DM(np.diag(vm.inertia_kg_m2)) @ n
    weight = vm.mass_kg * vm.gravity_m_s2
    g_eq = ca.vertcat(m - spin_rad_s ** 2 * ca.cross(n, jn), ca.dot(f, n) - weight,
                      ca.dot(n, n) - 1.0)
    span_z, span_a = 100.0 - vm.idle_pct, vm.tilt_max_rad - vm.tilt_min_rad
    terms = []
    for k in range(3):
        terms += [(100.0 - z[k]) / span_z - t, (z[k] - vm.idle_pct) / span_z - t,
                  (vm.tilt_max_rad - a[k]) / span_a - t, (a[k] - vm.tilt_min_rad) / span_a - t]
    g_in = ca.vertcat(*terms, -n[2] - math.cos(math.radians(89.0)))
    x = ca.vertcat(z, a, n, t)
    solver = ca.nlpsol("spin_trim", "ipopt",
                       {"x": x, "f": -t + 1e-4 * ca.sumsqr(a), "g": ca.vertcat(g_eq, g_in)},
                       _IPOPT)
    lbx = [vm.idle_pct] * 3 + [vm.tilt_min_rad] * 3 + [-1.0] * 3 + [-1.0]
    ubx = [100.0] * 3 + [vm.tilt_max_rad] * 3 + [1.0] * 3 + [0.5]
    n_eq = 5
    lbg = [0.0] * (n_eq + g_in.shape[0])
    ubg = [0.0] * n_eq + [ca.inf] * g_in.shape[0]
    best = None
    for cone in (15.0, 35.0):
        for az in range(0, 360, 90):
            c, b = math.radians(cone), math.radians(az + 45)
            x0 = [90.0] * 3 + [0.0] * 3 + [math.sin(c) * math.cos(b), math.sin(c) * math.sin(b),
                                           -math.cos(c), 0.0]
            r = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
            g = np.array(r["g"]).ravel()
            if not solver.stats()["success"] or np.max(np.abs(g[:n_eq])) > 1e-6:
                continue
            if best is None or float(r["f"]) < best[0] - 1e-9:
                best = (float(r["f"]), np.array(r["x"]).ravel())
    if best is None:
        raise ValueError(f"spin: no relaxed hover of {vm.name} with motor {motor} dead at "
                         f"{spin_rad_s:g} rad/s within the actuators' limits (the envelope: "
                         "docs/decisions/2026-12-05-lost-motor-envelope.md)")
    xs = best[1]
    thr, til = [0.0] * 4, [0.0] * 4
    for k, i in enumerate(live):
        thr[i], til[i] = float(xs[k]), float(xs[3 + k])
    return SpinTrim(motor, float(spin_rad_s), tuple(float(v) for v in xs[6:9]), tuple(thr),
                    tuple(til), weight, float(xs[9]))


# --- the linear model about the orbit and its LQR -----------------------------------------------

def _basis(n: np.ndarray) -> np.ndarray:
    """Two unit vectors (3x2) normal to n and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(n, e1)])


@dataclass(frozen=True)
class _Linear:
    a: np.ndarray          # 11x11 continuous: (omega 3, axis 2, actuators 6)
    b: np.ndarray          # 11x6
    c_force: np.ndarray    # 1x11: the force along the axis
    m_act: np.ndarray      # 3x6: the torque's sensitivity to the actuators
    f_act: np.ndarray      # 1x6: the force along n's


def _linearise(vm: VehicleModel, trim: SpinTrim, live, basis: np.ndarray,
               direction: int = 1) -> _Linear:
    om, s, act = ca.SX.sym("om", 3), ca.SX.sym("s", 3), ca.SX.sym("act", 6)
    zeta, alpha = [0.0] * 4, [0.0] * 4
    for k, i in enumerate(live):
        zeta[i], alpha[i] = 100.0 * act[k], act[3 + k]        # throttles as fractions here
    f, m = _wrench(vm, live, zeta, alpha)
    jm = np.diag(vm.inertia_kg_m2)
    om_dot = ca.solve(ca.DM(jm), m - ca.cross(om, ca.DM(jm) @ om))
    s_dot = -ca.cross(om, s)
    f_n = ca.dot(f, s)
    out = ca.vertcat(om_dot, s_dot, f_n, m)
    jac = ca.Function("spin_linear", [om, s, act], [ca.jacobian(out, ca.vertcat(om, s, act))])
    n = np.asarray(trim.axis_frd)
    a0 = np.array([trim.throttle_pct[i] / 100.0 for i in live]
                  + [trim.tilt_rad[i] for i in live])
    j = np.array(jac(direction * trim.spin_rad_s * n, n, a0))  # 10 x 12
    e = basis
    a = np.zeros((11, 11))
    a[0:3, 0:3] = j[0:3, 0:3]
    a[0:3, 3:5] = j[0:3, 3:6] @ e
    a[0:3, 5:11] = j[0:3, 6:12]
    a[3:5, 0:3] = e.T @ j[3:6, 0:3]
    a[3:5, 3:5] = e.T @ j[3:6, 3:6] @ e
    tau = np.array([vm.motor_time_constant_s] * 3 + [vm.servo_time_constant_s] * 3)
    tau = np.maximum(tau, 1e-3)
    a[5:11, 5:11] = -np.diag(1.0 / tau)
    b = np.zeros((11, 6))
    b[5:11, :] = np.diag(1.0 / tau)
    c_force = np.concatenate([j[6, 0:3], j[6, 3:6] @ e, j[6, 6:12]])[None, :]
    return _Linear(a, b, c_force, j[7:10, 6:12], j[6:7, 6:12])


def _expm(m: np.ndarray) -> np.ndarray:
    """The matrix exponential: scaling and squaring of an 18-term Taylor series (the matrices here
    are small, their norm times the step well below 10; numpy only, the package's dependency)."""
    norm = float(np.max(np.sum(np.abs(m), axis=1)))
    k = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    a = m / (2.0 ** k)
    term = np.eye(len(m))
    out = term.copy()
    for i in range(1, 19):
        term = term @ a / i
        out = out + term
    for _ in range(k):
        out = out @ out
    return out


def _dare(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The stabilising solution P of the discrete algebraic Riccati equation
    P = A'PA - A'PB (R + B'PB)^-1 B'PA + Q, by the structured doubling algorithm (quadratic
    convergence; numpy only). ValueError if it does not converge."""
    n = len(a)
    ak, gk, hk = a.copy(), b @ np.linalg.solve(r, b.T), q.copy()
    for _ in range(100):
        w = np.linalg.inv(np.eye(n) + gk @ hk)
        a_next = ak @ w @ ak
        g_next = gk + ak @ w @ gk @ ak.T
        h_next = hk + ak.T @ hk @ w @ ak
        done = np.max(np.abs(h_next - hk)) <= 1e-12 * max(1.0, np.max(np.abs(h_next)))
        ak, gk, hk = a_next, 0.5 * (g_next + g_next.T), 0.5 * (h_next + h_next.T)
        if done:
            return hk
    raise ValueError("spin: the LQR's Riccati equation did not converge (weights: "
                     "docs/decisions/2026-12-05-lost-motor-spin-controller.md)")


def _zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    nx, nu = b.shape
    blk = np.zeros((nx + nu, nx + nu))
    blk[:nx, :nx], blk[:nx, nx:] = a, b
    e = _expm(blk * dt)
    return e[:nx, :nx], e[:nx, nx:]


def _lqr_gain(lin: _Linear, cfg: SpinConfig, n: np.ndarray, basis: np.ndarray,
              delay_steps: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The discrete LQR gain (6 x (11 + 6 delay_steps)) on the state (omega, axis, actuators)
    and, with a delay of `delay_steps` control periods between a command and its effect, the
    commands still in flight (oldest first); and the Riccati solution P it comes from."""
    w = cfg.weights
    q = np.zeros((11, 11))
    q[0:3, 0:3] = w.spin * np.outer(n, n) + basis @ np.diag(w.rates) @ basis.T
    q[3:5, 3:5] = w.axis * np.eye(2)
    q[5:11, 5:11] = np.diag([w.actuator[0]] * 3 + [w.actuator[1]] * 3)
    q += w.force * lin.c_force.T @ lin.c_force
    r = np.diag([w.input[0]] * 3 + [w.input[1]] * 3)
    ad, bd = _zoh(lin.a, lin.b, cfg.dt_s)
    if delay_steps:
        nx, nu, d = 11, 6, delay_steps
        na = nx + nu * d
        a_aug = np.zeros((na, na))
        b_aug = np.zeros((na, nu))
        a_aug[:nx, :nx] = ad
        a_aug[:nx, nx:nx + nu] = bd                 # the oldest command in flight acts now
        for j in range(d - 1):                      # the buffer shifts by one period
            a_aug[nx + j * nu:nx + (j + 1) * nu, nx + (j + 1) * nu:nx + (j + 2) * nu] = np.eye(nu)
        b_aug[nx + (d - 1) * nu:, :] = np.eye(nu)   # this period's command enters last
        q_aug = np.zeros((na, na))
        q_aug[:nx, :nx] = q
        ad, bd, q = a_aug, b_aug, q_aug
    p = _dare(ad, bd, q, r)
    return np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad), p


# --- the controller ------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Stage:
    """One spin rate's trim and LQR."""
    trim: SpinTrim
    axis: np.ndarray                   # n, body FRD
    basis: np.ndarray                  # 3x2 normal to n
    gain: np.ndarray                   # 6 x (11 + 6 d)
    a0: np.ndarray                     # the live actuators at the trim (fractions, rad)
    per_newton: np.ndarray             # their move per newton along the axis
    per_torque: np.ndarray             # 6x3: their move per N m of body torque, the force held
    p_term: np.ndarray | None = None   # inner nmpc: the delay-free LQR's P (11x11), its terminal
    t_term: np.ndarray | None = None   # cost, on x = t_term (z - z_ref) (11 x 12)


@dataclass(frozen=True)
class SpinInfo:
    """What the last step did (for the log and the tests)."""
    spin_rad_s: float                  # the body rates' component along the trim's axis
    axis_error_rad: float              # the angle of the body's axis from the one asked for
    force_N: float                     # the force along the axis asked for
    saturated: int                     # live commands clipped at a limit
    landed: bool                       # touchdown seen: the motors are off
    fallback: bool = False             # a non-finite estimate: the trim commanded, the state kept
    qp_status: int = -1                # inner nmpc: HPIPM's status (-1: no QP solved, the LQR)
    qp_iterations: int = 0


class SpinController:
    """The lost-motor controller for motor `motor` (1..4) dead. Build once (the trim's IPOPT and
    the LQR's Riccati equation: about a second), then `reset` at the switch and `step` every
    1 / config.control_rate_hz s. No clock, no I/O: the caller owns time."""

    def __init__(self, config: SpinConfig, vehicle: VehicleModel, motor: int,
                 delay_s: float = 0.0, direction: int | None = None) -> None:
        """`delay_s`: the time from the state a command answers to the command's effect (the
        controller file's applied_delay_s: 0 in lockstep), rounded up to whole control periods
        and carried in the LQR's state as the commands in flight. `direction`: the spin's sense
        about the primary axis (omega = direction w n; both are equilibria); None: the sense the
        live rotors' reaction torques push the body at equal throttles (the one the body starts
        turning in after the failure)."""
        if not 0.0 <= delay_s <= 0.2:
            raise ValueError(f"spin: delay_s {delay_s!r}, expected 0..0.2 s")
        if direction not in (None, 1, -1):
            raise ValueError(f"spin: direction {direction!r}, expected 1, -1 or None")
        self.config, self.vehicle, self.motor = config, vehicle, motor
        if direction is None:
            # a ccw rotor's reaction pushes the body +z (FRD); n points up (-z): omega = w n
            # turns the body -z, so the live rotors' net push -z asks direction +1
            push = sum(r.spin for i, r in enumerate(vehicle.rotors) if i != motor - 1)
            direction = 1 if push < 0 else -1
        self.direction = direction
        self.delay_steps = int(math.ceil(delay_s / config.dt_s - 1e-9))
        self._live = [i for i in range(4) if i != motor - 1]
        if config.inner not in ("lqr", "nmpc"):
            raise ValueError(f"spin: inner {config.inner!r}, expected 'lqr' or 'nmpc'")
        self._stages = [self._stage(config.spin_rate_rad_s)]
        if config.landing.final_spin_rate_rad_s != config.spin_rate_rad_s:
            self._stages.append(self._stage(config.landing.final_spin_rate_rad_s))
        self._use(0)
        self._lo = np.array([vehicle.idle_pct / 100.0] * 3 + [vehicle.tilt_min_rad] * 3)
        self._hi = np.array([1.0] * 3 + [vehicle.tilt_max_rad] * 3)
        dt = config.dt_s
        tau = np.array([vehicle.motor_time_constant_s] * 3 + [vehicle.servo_time_constant_s] * 3)
        self._lag = 1.0 - np.exp(-dt / np.maximum(tau, 1e-9))
        self._rate = np.array([vehicle.motor_rate_limit_pct_s / 100.0] * 3
                              + [vehicle.servo_rate_limit_rad_s] * 3) * dt
        # the dead rotor at idle, tilt 0 (as the controller commands it while spinning): its
        # body force and torque in the nominal model the observer runs on, which the spinning
        # model leaves out (the observer's d carries them negated: `_disturbance`)
        dead = motor - 1
        f_idle, m_idle = live_wrench(vehicle, ca.DM(geometry(vehicle, [dead])),
                                     [vehicle.idle_pct], [0.0])
        self._idle_force = np.array(ca.DM(f_idle)).ravel()
        self._idle_torque = np.array(ca.DM(m_idle)).ravel()
        self._inertia = np.asarray(vehicle.inertia_kg_m2, float)
        self._nmpc = None
        if config.inner == "nmpc":
            self._nmpc = SpinNmpc(vehicle, self._live, dt, config.horizon_steps, config.weights,
                                  self._lo, self._hi)
        self.reset(None)

    def _stage(self, spin_rad_s: float) -> _Stage:
        """The trim at `spin_rad_s`, its LQR gain and its family's slope (built once)."""
        trim = equilibrium(self.vehicle, self.motor, spin_rad_s)
        live = self._live
        n = np.asarray(trim.axis_frd)
        e = _basis(n)
        lin = _linearise(self.vehicle, trim, live, e, self.direction)
        gain, p = _lqr_gain(lin, self.config, n, e, self.delay_steps)  # 6 x (11 + 6 d)
        p_term = t_term = None
        if self.config.inner == "nmpc":
            # the NMPC's terminal cost: the delay-free LQR's P (the NMPC carries the commands in
            # flight by predicting through them), on x = [omega - w n, E' s, y - a_op]; without
            # a delay the gain's own
            p_term = p if self.delay_steps == 0 else _lqr_gain(lin, self.config, n, e, 0)[1]
            t_term = np.zeros((11, 12))
            t_term[0:3, 0:3] = np.eye(3)
            t_term[3:5, 3:6] = e.T
            t_term[5:11, 6:12] = np.eye(6)
        a0 = np.array([trim.throttle_pct[i] / 100.0 for i in live]
                      + [trim.tilt_rad[i] for i in live])
        # the operating point's move per newton of force along the axis with the torque held
        # (the least change in scaled units): the linearised family of equilibria
        sens_inv = np.linalg.pinv(np.vstack([lin.m_act, lin.f_act]))    # 6 x 4
        return _Stage(trim, n, e, gain, a0, sens_inv[:, 3], sens_inv[:, 0:3], p_term, t_term)

    def _use(self, i: int) -> None:
        st = self._stages[i]
        self._stage_index = i
        self.trim, self._n, self._e, self.gain = st.trim, st.axis, st.basis, st.gain
        self._a0, self._per_newton, self._per_torque = st.a0, st.per_newton, st.per_torque
        self._p_term, self._t_term = st.p_term, st.t_term

    # --- the switch ----------------------------------------------------------------------------
    def reset(self, estimate: StateEstimate | None, *, command: ActuatorCommand | None = None,
              hold_pos_ned_m=None, ground_down_m: float = 0.0, integral_m_s2=None,
              disturbance_m_s2=None) -> None:
        """Start afresh: `command` is the last command sent (the actuators' outputs are taken to
        be there: the lag states start from it; None: from the trim); `hold_pos_ned_m` the point
        to hold (None: the estimate's position); `ground_down_m` the ground's NED down;
        `integral_m_s2` the position loop's integral to start from (world NED, m/s^2, bounded by
        max_integral_m_s2; None: zero): the acceleration the wind asks, which the observer
        flying before the switch has learnt (its d negated); `disturbance_m_s2` the observer's
        NED acceleration to start its low-pass from (observer_lowpass_s set; None: zero): the
        same wind, which the observer's estimate at the switch does not give (`_disturbance`)."""
        if command is None:
            self._act = self._a0.copy()
        else:
            self._act = np.array([command.throttle_pct[i] / 100.0 for i in self._live]
                                 + [command.tilt_rad[i] for i in self._live])
        self._act = np.clip(self._act, self._lo, self._hi)
        self._in_flight = [self._act.copy() for _ in range(self.delay_steps)]   # oldest first
        if self._nmpc is not None:
            self._nmpc.reset()
        lim = self.config.position.max_integral_m_s2
        self._integral = (np.zeros(3) if integral_m_s2 is None
                          else np.clip(np.asarray(integral_m_s2, float), -lim, lim))
        self._ground = float(ground_down_m)
        if hold_pos_ned_m is None and estimate is not None:
            hold_pos_ned_m = estimate.pos_ned_m
        self.hold_pos_ned_m = None if hold_pos_ned_m is None else tuple(map(float, hold_pos_ned_m))
        self._landed = False
        self._d = np.zeros(6)               # the observer's estimate, low-passed
        if disturbance_m_s2 is not None:
            self._d[0:3] = np.asarray(disturbance_m_s2, float)
        self._periods = 0                   # steps since the switch
        self._use(0)
        self.info = SpinInfo(0.0, 0.0, self.trim.force_along_axis_N, 0, False)

    # --- one control period --------------------------------------------------------------------
    def step(self, estimate: StateEstimate, reference: ReferenceSample,
             disturbance=None) -> ActuatorCommand:
        """The command for this period from the estimate (world NED position and velocity, ZYX
        Euler angles, body FRD rates) and the reference (position and velocity, NED; its yaw is
        ignored: yaw is given up; phase "land" lets the touchdown switch the motors off).
        `disturbance` (6, or None: none this period): the observer's estimate of what the
        controller's nominal model misses, that model flying the dead rotor at idle and tilt 0
        (the NED acceleration, m/s^2, then the body FRD angular acceleration, rad/s^2); used
        when the file's observer_lowpass_s is set (`_disturbance`)."""
        cfg, vm, pos = self.config, self.vehicle, self.config.position
        p = np.asarray(estimate.pos_ned_m, float)
        v = np.asarray(estimate.vel_ned_m_s, float)
        om = np.asarray(estimate.rates_frd_rad_s, float)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v)) and np.all(np.isfinite(om))
                and all(math.isfinite(a) for a in estimate.euler_rad)):
            self.info = SpinInfo(math.nan, math.nan, self.trim.force_along_axis_N, 0,
                                 self._landed, True)
            if self._landed:
                return ActuatorCommand((0.0,) * 4, (0.0,) * 4)
            return ActuatorCommand(self.trim.throttle_pct, self.trim.tilt_rad)
        if self._landed or (reference.phase == "land"
                            and p[2] >= self._ground - cfg.landing.contact_height_m
                            and abs(v[2]) <= cfg.landing.contact_speed_m_s):
            self._landed = True
            self.info = SpinInfo(float(om @ self._n), 0.0, 0.0, 0, True)
            return ActuatorCommand((0.0,) * 4, (0.0,) * 4)
        if (len(self._stages) > 1 and self._stage_index == 0 and reference.phase == "land"
                and p[2] >= self._ground - cfg.landing.final_height_m):
            self._use(1)                     # the final descent at the faster spin: less cone
        rot = rotation_ned_frd(*estimate.euler_rad)
        fed = self._disturbance(disturbance, rot)      # None: the option is off
        # the position loop: the force vector asked for (world NED), the observer's acceleration
        # taken out (what the rotors must add to the loop's for it)
        e_p = np.asarray(reference.pos_ned_m, float) - p
        e_v = np.asarray(reference.vel_ned_m_s, float) - v
        kp = np.array([pos.kp_s2[0]] * 2 + [pos.kp_s2[1]])
        kd = np.array([pos.kd_s[0]] * 2 + [pos.kd_s[1]])
        ki = np.array([pos.ki_s3[0]] * 2 + [pos.ki_s3[1]])
        self._integral = np.clip(self._integral + ki * e_p * cfg.dt_s, -pos.max_integral_m_s2,
                                 pos.max_integral_m_s2)
        acc = kp * e_p + kd * e_v + self._integral
        if fed is not None:
            acc = acc - fed[0]
        force = vm.mass_kg * (acc - np.array([0.0, 0.0, vm.gravity_m_s2])) \
            + vm.drag_N_s2_m2 * np.linalg.norm(v) * v
        f_up = max(-force[2], 1e-6)
        horiz = force[0:2]
        h = float(np.linalg.norm(horiz))
        if h > f_up * math.tan(pos.max_lean_rad):
            horiz = horiz * (f_up * math.tan(pos.max_lean_rad) / h)
        n_des = np.array([horiz[0], horiz[1], -f_up])
        f_des = float(np.linalg.norm(n_des))
        n_des /= f_des
        f0 = self.trim.force_along_axis_N
        f_des = min(max(f_des, f0 - pos.sink_force_N), f0 + pos.climb_force_N)
        # the inner LQR about the orbit
        s = rot.T @ n_des
        # the operating point for that force, and for the torque that cancels the observer's
        # angular acceleration (the family of equilibria, linearised: the least move)
        a_op = self._a0 + self._per_newton * (f_des - f0)
        d_ang = None
        if fed is not None:
            d_ang = fed[1]
            a_op = a_op - self._per_torque @ (self._inertia * d_ang)
        x = np.concatenate([om - self.direction * self.trim.spin_rad_s * self._n, self._e.T @ s,
                            self._act - a_op, *(u - a_op for u in self._in_flight)])
        u_raw = a_op - self.gain @ x
        u = np.clip(u_raw, self._lo, self._hi)
        saturated = int(np.sum(np.abs(u - u_raw) > 1e-12))
        qp = (-1, 0)
        if self._nmpc is not None:
            u, saturated, qp = self._nmpc_command(om, s, a_op, f_des, u, saturated, d_ang)
        # the actuators' outputs over this period, as the vehicle file's lags and rate limits
        # make them from the command that acts now (the oldest in flight, or this one)
        acting = u
        if self._in_flight:
            acting = self._in_flight.pop(0)
            self._in_flight.append(u)
        self._act = self._act + np.clip(self._lag * (acting - self._act), -self._rate, self._rate)
        body_axis = rot @ self._n
        self.info = SpinInfo(float(om @ self._n),
                             math.acos(max(-1.0, min(1.0, float(body_axis @ n_des)))), f_des,
                             saturated, False, qp_status=qp[0], qp_iterations=qp[1])
        thr, til = [0.0] * 4, [0.0] * 4
        for k, i in enumerate(self._live):
            thr[i], til[i] = float(100.0 * u[k]), float(u[3 + k])
        return ActuatorCommand(tuple(thr), tuple(til))

    def _nmpc_command(self, om, s, a_op, f_des, u_lqr, saturated_lqr, d_ang):
        """Inner nmpc: this period's command from the plan (spin_nmpc.py), the state carried
        through the commands still in flight, the observer's angular acceleration d_ang (None:
        none) in its model; the LQR's (clipped) when the QP fails. Returns (command, live
        commands at a bound, (QP status, QP iterations))."""
        z0 = self._nmpc.predict(np.concatenate([om, s, self._act]), self._in_flight, d_ang)
        sw = self.direction * self.trim.spin_rad_s
        ref = (SpinReference(self._n, self._e, sw, a_op, f_des) if d_ang is None
               else SpinReference(self._n, self._e, sw, a_op, f_des, d_ang))
        u, info = self._nmpc.solve(z0, ref, self._p_term, self._t_term, guess=u_lqr)
        if u is None:
            return u_lqr, saturated_lqr, (info.status, info.iterations)
        at_bound = (u <= self._lo + 1e-9) | (u >= self._hi - 1e-9)
        return u, int(np.sum(at_bound)), (info.status, info.iterations)

    def _disturbance(self, d, rot: np.ndarray):
        """The observer's estimate as the spinning model misses it, low-passed: (NED
        acceleration, body FRD angular acceleration); None when the file does not use it.
        The observer's model flies the dead rotor at idle, which the spinning model leaves
        out: its share, which the observer's d carries negated, is added back. Until
        observer_settle_s after the switch, and in a period without an estimate (None,
        non-finite), the low-pass holds."""
        tau = self.config.observer_lowpass_s
        if tau is None:
            return None
        self._periods += 1
        settled = self._periods * self.config.dt_s > self.config.observer_settle_s + 1e-9
        if d is not None and settled:
            d = np.asarray(d, float)
            if d.shape == (6,) and np.all(np.isfinite(d)):
                own = np.concatenate([d[0:3] + rot @ self._idle_force / self.vehicle.mass_kg,
                                      d[3:6] + self._idle_torque / self._inertia])
                k = 1.0 - math.exp(-self.config.dt_s / tau) if tau > 0.0 else 1.0
                self._d = self._d + k * (own - self._d)
        return self._d[0:3], self._d[3:6]


# --- the spin's sense at the switch ----------------------------------------------------------

def spin_sense(rates_frd_rad_s, axis_frd) -> int:
    """The sense of the spin to fly from a switch (omega = sense w n, n the trim's axis, body FRD,
    pointing up): the way the body already yaws, its rate about body z (r) as it projects on the
    axis, r n_z (+1 if none). Not the whole rate's projection, omega . n: at the detection the
    body tumbles towards the dead rotor at 2-4 rad/s about an axis in its x-y plane, whose share
    along the tilted axis n (up to 1.5 rad/s) is no spin and, where the yaw rate is small, picked
    the sense opposite the yaw's and a spin-up through no spin at all (the record:
    docs/decisions/2026-12-05-lost-motor-axes.md)."""
    r = float(np.asarray(rates_frd_rad_s, float)[2])
    return 1 if r * float(axis_frd[2]) >= 0.0 else -1


# --- the descent -------------------------------------------------------------------------------

def landing_reference(t_s: float, start_pos_ned_m, landing: SpinLanding,
                      ground_down_m: float = 0.0) -> ReferenceSample:
    """The reference `t_s` after the switch: the start held for hold_s, then a descent at
    descent_speed_m_s down to final_height_m above the ground, then final_speed_m_s to the ground
    (phase "hold", then "land")."""
    n, e, d0 = (float(v) for v in start_pos_ned_m)
    if t_s < landing.hold_s:
        return ReferenceSample((n, e, d0), (0.0, 0.0, 0.0), 0.0, "hold")
    t = t_s - landing.hold_s
    knee = ground_down_m - landing.final_height_m            # NED down of the slower part's start
    fast = max(0.0, knee - d0)
    if t * landing.descent_speed_m_s < fast:
        return ReferenceSample((n, e, d0 + t * landing.descent_speed_m_s),
                               (0.0, 0.0, landing.descent_speed_m_s), 0.0, "land")
    t_slow = t - fast / landing.descent_speed_m_s
    d = max(d0, knee) + t_slow * landing.final_speed_m_s
    if d >= ground_down_m:
        return ReferenceSample((n, e, ground_down_m), (0.0, 0.0, landing.final_speed_m_s), 0.0,
                               "land")
    return ReferenceSample((n, e, d), (0.0, 0.0, landing.final_speed_m_s), 0.0, "land")


def load_for_vehicle(path: Path | str, motor: int) -> SpinController:
    """The controller of a controller file's `spin:` section, on its own vehicle file."""
    cfg = load_spin_config(path)
    return SpinController(cfg, load_vehicle_model(cfg.vehicle_file), motor)
