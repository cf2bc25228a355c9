"""Rigid-body dynamics of the TRQ with the rotor wrench of its tilted rotors (CasADi).

    dp/dt     = v
    dv/dt     = (R(eta) F_B - k |v| v) / m + g e_z + d[0:3]       (NED; drag on ground velocity)
    deta/dt   = W(eta) omega                                     (ZYX Euler kinematics)
    domega/dt = I^-1 (tau_B - omega x I omega) + d[3:6]          (body FRD)

Rotor i (arm axis a_i, position l a_i, spin s_i = +1 ccw) tilted by alpha_i about its arm has the
thrust direction n_i = (-a_y sin alpha, a_x sin alpha, -cos alpha); it adds F_i n_i to the force
and l a_i x F_i n_i - s_i tau_i n_i to the torque. F and tau are the quadratic curves of the YAML
in throttle percent, *without* the plant's clamp at zero (smooth for the NLP): the NMPC keeps the
throttle above idle, where the thrust curve is positive. (The torque curve is negative between
idle, 10 %, and 11.1 %, by at most 6e-4 N m; the plant clamps it there. The NMPC never goes near
idle in practice; the consistency test uses throttles above 12 %.)

The wind is unknown to the model: its effect, the actuator lags and the faults are what the
generalised disturbance d stands for (estimated by the ESO).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from trq_params.schema import throttle_curve

from trq_offboard.config import VehicleModel
from trq_offboard.frames import rotation_ned_frd

NX, ND = 12, 6


def euler_rate_matrix(roll, pitch):
    """W with deta/dt = W omega (ZYX); singular at pitch = +-90 deg."""
    cr, sr = ca.cos(roll), ca.sin(roll)
    cp, tp = ca.cos(pitch), ca.tan(pitch)
    return ca.vertcat(ca.horzcat(1, sr * tp, cr * tp),
                      ca.horzcat(0, cr, -sr),
                      ca.horzcat(0, sr / cp, cr / cp))


class PredictionModel:
    """Symbolic model of one airframe, built once; all members are casadi Functions.

    f(x, u, d) -> dx/dt (12)             wrench(u) -> [F_B (N), tau_B (N m)] body FRD (6)
    accel(x, u) -> [dv/dt, domega/dt] without d
    b0(x, u) -> [dv/dt, d^2 eta/dt^2, domega/dt] without d (NumPy; the ESO's b0)
    motor_jacobian(x, u) -> d[dv_z/dt, domega/dt] / d zeta (4x4 column-major flat, NumPy)
    euler_accel(x, u, d) -> d^2 eta / dt^2 (3)
    discrete(dt, substeps) -> F(x, u, d) -> x_next   (RK4, input and d held)
    """

    def __init__(self, vehicle: VehicleModel) -> None:
        self.vehicle = vm = vehicle
        self.nx, self.nd = NX, ND
        self.nu = vm.n_inputs
        self.tilting = not vm.tilt_locked
        x = ca.SX.sym("x", NX)
        u = ca.SX.sym("u", self.nu)
        d = ca.SX.sym("d", ND)
        w = self._wrench(u)
        self.wrench = ca.Function("wrench", [u], [w], ["u"], ["wrench_frd"])
        acc = self._accel(x, w)
        self.accel = ca.Function("accel", [x, u], [acc], ["x", "u"], ["acc"])
        W = euler_rate_matrix(x[6], x[7])
        xdot = ca.vertcat(x[3:6], acc[0:3] + d[0:3], W @ x[9:12], acc[3:6] + d[3:6])
        self._x, self._u, self._d, self._xdot = x, u, d, xdot
        self.f = ca.Function("f", [x, u, d], [xdot], ["x", "u", "d"], ["xdot"])
        eta_dot = W @ x[9:12]
        # d/dt (W(eta) omega) = dW/deta * eta_dot * omega + W omega_dot
        eta_acc = ca.jtimes(eta_dot, x, xdot)
        self.euler_accel = ca.Function("euler_accel", [x, u, d], [eta_acc],
                                       ["x", "u", "d"], ["eta_ddot"])
        # the observer's b0(x, u) with d = 0, one call from NumPy: linear (NED), Euler and body
        # angular accelerations (9; ExtendedStateObserver.b0_of picks what its channels need)
        b0 = ca.vertcat(acc[0:3], ca.substitute(eta_acc, d, ca.DM.zeros(ND)), acc[3:6])
        self.b0 = NumpyFunction(ca.Function("b0", [x, u], [b0], ["x", "u"], ["b0"]))
        # the sensitivity of the vertical (NED z) and the body angular accelerations to each
        # motor's throttle (%), 4x4 (the motor effectiveness observer's J; NumPy, column-major)
        zeta = u[4:8] if self.tilting else u[0:4]
        self.motor_jacobian = NumpyFunction(ca.Function(
            "motor_jacobian", [x, u], [ca.densify(ca.jacobian(acc[2:6], zeta))], ["x", "u"],
            ["J"]))

    # --- inputs -------------------------------------------------------------------------------
    def split(self, u):
        """(alpha (4), zeta (4)) of an input vector; tilts are 0 for a locked airframe."""
        if self.tilting:
            return u[0:4], u[4:8]
        return ca.DM.zeros(4) if isinstance(u, ca.DM) else 0 * u[0:4], u[0:4]

    def _wrench(self, u):
        vm = self.vehicle
        alpha, zeta = self.split(u)
        force = ca.SX.zeros(3)
        torque = ca.SX.zeros(3)
        th, tq = vm.thrust_N, vm.torque_Nm
        for i, rotor in enumerate(vm.rotors):
            ax, ay, _ = rotor.arm_frd
            z = zeta[i]
            f_i = throttle_curve(th.c2, th.c1, th.c0, z)
            tau_i = throttle_curve(tq.c2, tq.c1, tq.c0, z)
            n = ca.vertcat(-ay * ca.sin(alpha[i]), ax * ca.sin(alpha[i]), -ca.cos(alpha[i]))
            r = ca.DM(rotor.position_frd_m)
            force += f_i * n
            torque += ca.cross(r, f_i * n) - rotor.spin * tau_i * n
        return ca.vertcat(force, torque)

    def _accel(self, x, wrench):
        vm = self.vehicle
        v, omega = x[3:6], x[9:12]
        R = rotation_ned_frd(x[6], x[7], x[8])
        speed = ca.sqrt(ca.sumsqr(v) + 1e-12)   # smooth |v| (the offset is 1e-6 m/s)
        acc_lin = (R @ wrench[0:3] - vm.drag_N_s2_m2 * speed * v) / vm.mass_kg \
            + ca.vertcat(0, 0, vm.gravity_m_s2)
        ixx, iyy, izz = vm.inertia_kg_m2
        acc_ang = ca.vertcat((wrench[3] - (izz - iyy) * omega[1] * omega[2]) / ixx,
                             (wrench[4] - (ixx - izz) * omega[2] * omega[0]) / iyy,
                             (wrench[5] - (iyy - ixx) * omega[0] * omega[1]) / izz)
        return ca.vertcat(acc_lin, acc_ang)

    # --- discretisation -------------------------------------------------------------------------
    def discrete(self, dt_s: float, substeps: int = 1) -> ca.Function:
        """RK4 with `substeps` equal steps over dt_s; u and d are held (zero-order hold)."""
        x, u, d = self._x, self._u, self._d
        h = dt_s / substeps
        xk = x
        for _ in range(substeps):
            xk = self._rk4(xk, u, d, h)
        return ca.Function("F", [x, u, d], [xk], ["x", "u", "d"], ["x_next"])

    def discrete_dt(self) -> ca.Function:
        """One RK4 step over a step length given at call time: F(x, u, d, dt) (the controller's
        delay predictor, whose segments follow the stamps of the commands in flight)."""
        x, u, d = self._x, self._u, self._d
        h = ca.SX.sym("dt")
        return ca.Function("F_dt", [x, u, d, h], [self._rk4(x, u, d, h)], ["x", "u", "d", "dt"],
                           ["x_next"])

    def discrete_varying(self, dt_s: float) -> ca.Function:
        """One RK4 step over dt_s with the input given at the step's start, midpoint and end:
        F(x, u0, u_mid, u_end, d) -> x_next (d held). The NMPC's actuator lag states drive the
        model through it with the lag's exact values at the three RK4 times."""
        x, d = self._x, self._d
        u0, um, ue = (ca.SX.sym(n, self.nu) for n in ("u0", "u_mid", "u_end"))
        return ca.Function("F_varying", [x, u0, um, ue, d],
                           [self._rk4(x, u0, d, dt_s, um, ue)],
                           ["x", "u0", "u_mid", "u_end", "d"], ["x_next"])

    def _rk4(self, x, u, d, h, u_mid=None, u_end=None):
        """One RK4 step of length h with d held and u held (or u at the start, u_mid at the
        midpoint and u_end at the end of the step)."""
        um = u if u_mid is None else u_mid
        ue = u if u_end is None else u_end
        k1 = self.f(x, u, d)
        k2 = self.f(x + 0.5 * h * k1, um, d)
        k3 = self.f(x + 0.5 * h * k2, um, d)
        k4 = self.f(x + h * k3, ue, d)
        return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


class NumpyFunction:
    """A CasADi Function called with NumPy arrays (each read flat, in CasADi's column-major
    order) and evaluated into persistent buffers (casadi.Function.buffer): no DM conversion,
    about a microsecond of overhead instead of about fifty. Inputs and outputs must be dense.
    Calling it returns a copy of the first output; `outputs` returns copies of all of them."""

    def __init__(self, fn: ca.Function) -> None:
        self.fn = fn
        self._buf, self._eval = fn.buffer()
        self._in = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self._outs = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._out = self._outs[0]
        for i, a in enumerate(self._in):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self._outs):
            self._buf.set_res(i, memoryview(a))

    def _run(self, args) -> None:
        for dst, src in zip(self._in, args):
            # an array's own ravel: np.ravel's Python wrapper costs more than the copy, some
            # twenty inputs a control period
            dst[:] = src.ravel() if type(src) is np.ndarray else np.ravel(src)
        self._eval()

    def __call__(self, *args) -> np.ndarray:
        self._run(args)
        return self._out.copy()

    def outputs(self, *args) -> list[np.ndarray]:
        self._run(args)
        return [a.copy() for a in self._outs]

    def outputs_in_place(self, *args) -> list[np.ndarray]:
        """`outputs` without the copies: the result buffers themselves, which the next
        evaluation overwrites (for a caller that is done with them by then)."""
        self._run(args)
        return self._outs

    # in place: the caller writes the inputs into `args` (flat, column-major), calls
    # `evaluate` and reads the outputs from `results` before the next evaluation
    @property
    def args(self) -> list[np.ndarray]:
        return self._in

    @property
    def results(self) -> list[np.ndarray]:
        return self._outs

    def evaluate(self) -> None:
        self._eval()
