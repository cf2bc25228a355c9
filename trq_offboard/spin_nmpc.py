"""The lost-motor controller's NMPC: the spinning orbit's body-frame model, nonlinear, its actuator
limits as constraints (issue 40 item 3; spin.py's `inner: nmpc`).

    nmpc = SpinNmpc(vehicle, live, dt_s, horizon_steps, weights, lo, hi)    # build once
    u0, info = nmpc.solve(z0, ref, p_term, t_term, guess)   # one real-time iteration a period
    nmpc.reset()                                   # at the switch: the next plan from its guess

The model is the one spin.py's LQR linearises, kept nonlinear: in the body frame, where the
relaxed hover is a fixed point,

    z = [omega (3, body FRD rad/s), s (3: R^T n_des, the direction asked for the primary axis,
         seen from the body), y (6: the live actuators' outputs, 3 throttles / 100, 3 tilts rad)]
    u = the six live commands (same units)
    d omega/dt = J^-1 (M(y) - omega x J omega) + d_w  M: the live rotors' torque (`live_wrench`:
    d s/dt     = -omega x s                           the prediction model's arithmetic); d_w
                                                      the observer's estimate of what the model
                                                      misses (body FRD rad/s^2), held over the
                                                      horizon (0: none)
    d y/dt     = (u - y) / T                         T: the vehicle file's motor and servo lags

(the rate limits are left out, as in the project's OCP and the LQR), discretised by one RK4
step per control period (at 20-30 rad/s a step turns the body 0.2-0.3 rad:
RK4's error is of the order of that to the fifth power). The attitude is reduced (s): yaw is given
up, as the orbit gives it up; the spin rate is a state and the tilts' yaw torque governs it.

Cost (Gauss-Newton on residuals, the LQR's own weights, so that near the orbit and away from the
limits the two controllers ask the same):

    sum_k |r(z_k, u_k)|^2 + (z_N - z_ref)' T' P T (z_N - z_ref)
    r = [sqrt(w_spin) (omega . n - sigma w), sqrt(w_rates) E' omega, sqrt(w_axis) E' s,
         sqrt(w_act) (y - a_op), sqrt(w_force) (F(y) . s - f_des), sqrt(w_input) (u - a_op)]

n the trim's primary axis, E (3x2) a basis normal to it, sigma w the signed spin rate, a_op the
operating point for the force asked for f_des (spin.py's family of equilibria), F(y) the live
rotors' body force. The terminal weight is the LQR's own Riccati solution P on the LQR's state
x = T (z - z_ref) = [omega - sigma w n, E' s, y - a_op]: with the model linear and no bound
active the NMPC's first move is the LQR's, at any horizon (a unit test checks it). What the NMPC
adds: the throttles and tilts bounded in the plan (the LQR clips its answer), and the nonlinear
model over the horizon (a large axis error, a spin far from the orbit's rate).

Solver: one SQP step a control period (real-time iteration). The previous plan, shifted by one
period, is rolled out from z0 (single shooting: no gaps); the rollout, the stage Jacobians and
residuals come from one compiled CasADi function (nmpc/cache.py); the structured QP in the
increments goes to HPIPM (nmpc/hpipm.py's OcpQp; box bounds on the inputs only). A QP that
fails (HPIPM status 3, non-finite) returns None: the caller flies its LQR that period.

Pure arithmetic on its inputs (no clock, no I/O); `info` carries the QP's status and iterations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from trq_offboard.config import VehicleModel
from trq_offboard.model.dynamics import NumpyFunction
from trq_offboard.nmpc import hpipm
from trq_offboard.nmpc.cache import compiled

__all__ = ["SpinNmpc", "SpinReference", "SpinNmpcInfo", "NZ", "NU", "geometry", "live_wrench"]

NZ, NU, NR = 12, 6, 18                 # state, input, residuals
_NG = 18                               # the live rotors' geometry (`geometry`)
_NM = 3 + _NG                          # the model's parameter: d_w, geometry
_NP = 3 + 6 + 1 + 6 + 1 + _NM          # n, E (column-major), sigma w, a_op, f_des, d_w, geometry
# the compiled functions, built once per process for each vehicle, step, horizon and weights (the
# live rotors are a parameter): a flight's controller builds one SpinController per motor and sense
_FUNCTIONS: dict[tuple, tuple] = {}
_REG = 1e-9                            # on the QP Hessian's diagonal (its s block is singular
                                       # along n: nothing weighs the axis' own component)


@dataclass(frozen=True)
class SpinReference:
    """What one period's plan aims at (spin.py builds it from its stage and the position loop)."""
    axis: np.ndarray                   # n (3), body FRD
    basis: np.ndarray                  # E (3x2)
    spin_rad_s: float                  # sigma w: signed (omega = sigma w n on the orbit)
    a_op: np.ndarray                   # the live actuators' operating point (6)
    force_N: float                     # f_des, along s
    disturbance: np.ndarray = field(default_factory=lambda: np.zeros(3))   # d_w (body FRD
                                       # rad/s^2), held over the horizon

    def params(self) -> np.ndarray:
        return np.concatenate([self.axis, self.basis.ravel(order="F"), [self.spin_rad_s],
                               self.a_op, [self.force_N], self.disturbance])

    def z_ref(self) -> np.ndarray:
        return np.concatenate([self.spin_rad_s * self.axis, self.axis, self.a_op])


@dataclass(frozen=True)
class SpinNmpcInfo:
    status: int                        # HPIPM's: 0 converged, 1 iteration limit, 2 min step, 3 NaN
    iterations: int
    cost: float                        # the linearised plan's model cost at the rollout (before
                                       # the step)


def geometry(vm: VehicleModel, live) -> np.ndarray:
    """The three live rotors' geometry as the model's parameter (_NG): per rotor its position
    (body FRD, 3), its tilt arm's x and y (2) and its spin sign (1)."""
    return np.concatenate([[*vm.rotors[i].position_frd_m, vm.rotors[i].arm_frd[0],
                            vm.rotors[i].arm_frd[1], vm.rotors[i].spin] for i in live])


def live_wrench(vm: VehicleModel, g, zeta_pct, alpha_rad):
    """Body FRD force and torque (CasADi SX) of the rotors of geometry `g` (`geometry`: the
    three live ones, or any others) at throttles `zeta_pct` (%) and tilts `alpha_rad` (one each):
    the prediction model's arithmetic, the rotors' curves and tilt axes. spin.py's trim, LQR and
    the dead rotor's idle wrench use it too."""
    force, torque = ca.SX.zeros(3), ca.SX.zeros(3)
    th, tq = vm.thrust_N, vm.torque_Nm
    for k in range(len(zeta_pct)):
        pos, ax, ay, spin = g[6 * k:6 * k + 3], g[6 * k + 3], g[6 * k + 4], g[6 * k + 5]
        z, a = zeta_pct[k], alpha_rad[k]
        f = (th.c2 * z + th.c1) * z + th.c0
        t = (tq.c2 * z + tq.c1) * z + tq.c0
        n = ca.vertcat(-ay * ca.sin(a), ax * ca.sin(a), -ca.cos(a))
        force += f * n
        torque += ca.cross(pos, f * n) - spin * t * n
    return force, torque


def _model(vm: VehicleModel, dt_s: float):
    """(z, u, g) -> z after dt_s (RK4), and the live rotors' body force at y (CasADi SX); g the
    model's parameter (_NM): d_w, then the live rotors' `geometry`, a parameter, so that one
    compiled function serves every motor lost; the wrench `live_wrench`."""
    z, u, g = ca.SX.sym("z", NZ), ca.SX.sym("u", NU), ca.SX.sym("g", _NM)
    d_w, geo = g[0:3], g[3:_NM]
    tau = np.maximum(np.array([vm.motor_time_constant_s] * 3 + [vm.servo_time_constant_s] * 3),
                     1e-3)
    jm = ca.DM(np.diag(vm.inertia_kg_m2))

    def wrench(y):
        return live_wrench(vm, geo, [100.0 * y[k] for k in range(3)],
                           [y[3 + k] for k in range(3)])

    def rhs(x):
        om, s, y = x[0:3], x[3:6], x[6:12]
        _, m = wrench(y)
        om_dot = ca.solve(jm, m - ca.cross(om, jm @ om)) + d_w
        return ca.vertcat(om_dot, -ca.cross(om, s), (u - y) / ca.DM(tau))

    k1 = rhs(z)
    k2 = rhs(z + dt_s / 2 * k1)
    k3 = rhs(z + dt_s / 2 * k2)
    k4 = rhs(z + dt_s * k3)
    z_next = z + dt_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    force, _ = wrench(z[6:12])
    return z, u, g, z_next, force


class SpinNmpc:
    """One lost motor's NMPC (the module docstring). `live`: the three live rotors' indices
    (0..3); `weights`: spin.py's SpinWeights; `lo`, `hi`: the six commands' bounds."""

    def __init__(self, vm: VehicleModel, live, dt_s: float, horizon_steps: int, weights,
                 lo, hi, qp_iter_max: int = 30, qp_mode: str = "speed") -> None:
        if horizon_steps < 1:
            raise ValueError(f"spin nmpc: horizon_steps {horizon_steps!r}, expected >= 1")
        self.N, self.dt_s = int(horizon_steps), float(dt_s)
        self._lo, self._hi = np.asarray(lo, float), np.asarray(hi, float)
        self._geometry = geometry(vm, live)
        key = (repr(vm), self.dt_s, self.N, repr(weights))
        if key not in _FUNCTIONS:
            _FUNCTIONS[key] = self._functions(vm, weights)
        self._fn, self._step, self.how = _FUNCTIONS[key]
        self._qp = hpipm.OcpQp(NZ, NU, self.N, np.zeros(0, np.int32), mode=qp_mode,
                               iter_max=qp_iter_max)
        self._empty = np.zeros((self.N + 1, 0))
        self.iterations = 1                 # SQP steps a period (1: the real-time iteration)
        self.reset()

    def _functions(self, vm, weights):
        """The compiled period function (NumpyFunction), the one-step model, how it was built."""
        z, u, g, z_next, force = _model(vm, self.dt_s)
        p = ca.SX.sym("p", _NP)
        n, e, sw, a_op, f_des = p[0:3], ca.reshape(p[3:9], 3, 2), p[9], p[10:16], p[16]
        z_next, force = (ca.substitute(v, g, p[17:17 + _NM]) for v in (z_next, force))
        w = weights
        sq = np.sqrt
        r = ca.vertcat(sq(w.spin) * (ca.dot(z[0:3], n) - sw),
                       ca.diag(ca.DM(sq(np.asarray(w.rates, float)))) @ (e.T @ z[0:3]),
                       sq(w.axis) * (e.T @ z[3:6]),
                       ca.DM(sq([w.actuator[0]] * 3 + [w.actuator[1]] * 3)) * (z[6:12] - a_op),
                       sq(w.force) * (ca.dot(force, z[3:6]) - f_des),
                       ca.DM(sq([w.input[0]] * 3 + [w.input[1]] * 3)) * (u - a_op))
        step = ca.Function("spin_step", [z, u, p], [z_next])
        stage = ca.Function("spin_stage", [z, u, p],
                            [ca.jacobian(z_next, z), ca.jacobian(z_next, u), r,
                             ca.jacobian(r, z), ca.jacobian(r, u)])
        # one function for the whole period: the rollout of U from z0 and every stage's
        # linearisation along it (N from the argument shapes: one compiled function per N)
        z0 = ca.SX.sym("z0", NZ)
        us = ca.SX.sym("U", NU, self.N)
        roll = step.mapaccum("spin_roll", self.N)
        zs = roll(z0, us, ca.repmat(p, 1, self.N))            # NZ x N: z_1..z_N
        z_all = ca.horzcat(z0, zs)
        a, b, res, jz, ju = stage.map(self.N)(z_all[:, 0:self.N], us, ca.repmat(p, 1, self.N))
        fn = ca.Function(f"spin_rti_{self.N}", [z0, us, p],
                         [ca.densify(o) for o in (z_all, a, b, res, jz, ju)])
        compiled_fn, how = compiled(fn)
        return NumpyFunction(compiled_fn), NumpyFunction(step), how

    def reset(self) -> None:
        """Forget the plan: the next solve starts afresh from its guess."""
        self._plan = None

    def predict(self, z0, commands, disturbance=None) -> np.ndarray:
        """z0 carried through `commands` (each one control period, oldest first) under the
        disturbance d_w (3, None: 0): the state a plan starts from when commands are still in
        flight."""
        z = np.asarray(z0, float)
        d_w = np.zeros(3) if disturbance is None else np.asarray(disturbance, float)
        p = np.concatenate([np.zeros(17), d_w, self._geometry])   # the step reads d_w, geometry
        for c in commands:
            z = self._step(z, c, p)
        return z

    def solve(self, z0, ref: SpinReference, p_term: np.ndarray, t_term: np.ndarray,
              guess=None) -> tuple[np.ndarray | None, SpinNmpcInfo]:
        """The first command of this period's plan from z0 (NZ), or None when the QP failed.
        `p_term`: the LQR's Riccati solution (11x11) on its state x = t_term (z - z_ref),
        `t_term` (11 x NZ). With no plan yet (the first period after `reset`, or after a failed
        QP) the plan starts from `guess` (6: the LQR's command) held over the horizon (None: the
        operating point): from the last command sent, in a tumble, one SQP step can land on the
        wrong side of the axis and flip the vehicle (the record)."""
        N = self.N
        if self._plan is None:
            plan = np.tile(ref.a_op if guess is None else np.asarray(guess, float), (N, 1))
        else:
            plan = self._plan
        plan = np.clip(plan, self._lo, self._hi)
        for _ in range(self.iterations):
            plan, info = self._sqp_step(z0, plan, ref, p_term, t_term)
            if plan is None:
                self._plan = None
                return None, info
        self._plan = np.vstack([plan[1:], plan[-1:]])         # next period's guess: shifted
        return plan[0].copy(), info

    def _sqp_step(self, z0, plan, ref, p_term, t_term):
        N = self.N
        params = np.concatenate([ref.params(), self._geometry])
        zs, a, b, res, jz, ju = self._fn.outputs_in_place(z0, plan, params)

        def mat(flat, rows, cols):          # a flat column-major output as [rows, k, cols]:
            return flat.reshape(N, cols, rows).transpose(2, 0, 1)   # map() puts stage k's
                                                                    # matrix in columns k*cols..
        zs = zs.reshape(N + 1, NZ).T                          # NZ x (N+1)
        res = res.reshape(N, NR).T                            # NR x N, stage k in column k
        jz, ju = mat(jz, NR, NZ), mat(ju, NR, NU)             # d r_k / d z_k, d r_k / d u_k
        a, b = mat(a, NZ, NZ), mat(b, NZ, NU)
        jac = np.concatenate([jz, ju], axis=2)                # NR x N x (NZ + NU)
        hess = np.einsum("rki,rkj->kij", jac, jac)
        hess[:, range(NZ + NU), range(NZ + NU)] += _REG
        grad = np.einsum("rki,rk->ki", jac, res)
        pt = t_term.T @ p_term @ t_term
        x_n = zs[:, N] - ref.z_ref()
        hn = pt + _REG * np.eye(NZ)
        q = np.zeros((N + 1, NZ))
        q[1:N] = grad[1:, :NZ]
        q[N] = pt @ x_n
        self._qp.set_hessian(hess, hn)
        at = a.transpose(1, 2, 0)                             # (N, NZ cols, NZ rows): A_k'
        bt = b.transpose(1, 2, 0)                             # (N, NU, NZ): B_k'
        lbu, ubu = self._lo - plan, self._hi - plan
        _, du, _ = self._qp.solve(at, bt, np.zeros((N, NZ)), q, grad[:, NZ:], self._empty,
                                  self._empty, lbu, ubu)
        cost = float(np.sum(res ** 2) + x_n @ pt @ x_n)
        info = SpinNmpcInfo(int(self._qp.status), int(self._qp.iterations), cost)
        if self._qp.status == 3 or not np.all(np.isfinite(du)):
            return None, info
        return np.clip(plan + du, self._lo, self._hi), info
