"""NMPC solvers behind one interface: `Solver.solve(x0, x_ref, d, u_prev, guess) -> (u, x, info)`.

    RtiSolver    (rti.py, kind "rti", the default) the real-time iteration on per-stage C
                 compiled once and cached, with a preparation / feedback split (`prepare`).
    SqpSolver    (kind "sqp") a hand-written SQP (full steps) on the NLP of ocp.py with a
                 structured QP solver (HPIPM through casadi.conic, no code generation); Hessian
                 either Gauss-Newton (the constant Hessian of the quadratic cost: always convex,
                 cheapest) or exact (cost + constraint curvature with the QP multipliers);
                 a few iterations per step, warm-started from the caller's guess.
    IpoptSolver  the converged reference: the same NLP solved by IPOPT to tight tolerance.

Both never return NaN: on a failure (exception, non-finite iterate, status) they return the
guess (finite) with `SolveInfo.status == FAILED`; the caller decides what to fly. Each solve
measures its wall time with time.perf_counter (a measurement, returned in SolveInfo).
"""

from __future__ import annotations

import time
from typing import Callable, Protocol, Union

import casadi as ca
import numpy as np

from trq_offboard.config import ControllerConfig
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc import hpipm
from trq_offboard.nmpc.ocp import Ocp
from trq_offboard.records import SolveInfo, SolveStatus

__all__ = ["Solver", "SqpSolver", "IpoptSolver", "make_solver", "Plan", "Guess", "plan_of",
           "conic_line"]

Plan = tuple[np.ndarray, np.ndarray]      # (u (N, nu) physical, x (N+1, 12))
# a plan, or a function making one: called only if the solver needs it (a real-time iteration
# that was prepared needs it only to fail with)
Guess = Union[Plan, Callable[[], Plan]]


def plan_of(guess: Guess) -> Plan:
    """The plan of a Guess (calling it if it is a function)."""
    return guess() if callable(guess) else guess


class Solver(Protocol):
    ocp: Ocp

    def solve(self, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, u_prev: np.ndarray,
              guess: Guess, y0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray,
                                                                 SolveInfo]:
        """x0 (12) measured state, x_ref (N+1, 12) reference states, d (6) disturbance held
        over the horizon, u_prev (nu) the command applied now (its tilts bound the first tilt
        step), guess an initial plan (u, x) or a function making one (plan_of), y0 (nu,
        physical; only with actuator lag states, default u_prev) the actuators' outputs when
        the plan starts. Returns the plan (u (N, nu) physical [alpha, zeta] or [zeta]: the
        commands, x (N+1, 12)) and a SolveInfo."""
        ...


class _Base:
    def __init__(self, cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray):
        self.cfg = cfg
        self.ocp = Ocp.build(cfg, model)
        self.u_trim = np.asarray(u_trim, float)

    def _setup(self, x0, x_ref, d, u_prev, guess, y0=None):
        ocp = self.ocp
        x0 = np.asarray(x0, float).reshape(12)
        a_prev = np.asarray(u_prev, float)[0:4] if ocp.tilting else np.zeros(0)
        if ocp.n_lag and y0 is None:
            y0 = u_prev                    # actuators settled at the applied command
        p = ocp.params(x_ref, self.u_trim, d)
        lbw, ubw = ocp.bounds(x0, a_prev, y0)
        w0 = ocp.pack(guess[1], guess[0], a_prev if ocp.tilting else None, y0)
        w0 = np.clip(w0, lbw, ubw)
        return p, lbw, ubw, w0

    def _failed(self, guess, t0, iters, msg) -> tuple[np.ndarray, np.ndarray, SolveInfo]:
        u, x = (np.nan_to_num(np.asarray(a, float)) for a in guess)
        return u, x, SolveInfo(SolveStatus.FAILED, iters, time.perf_counter() - t0,
                               float("nan"), msg)


def conic_line(kind: str, hessian: str, qp_solver: str) -> str:
    """describe() of a solver whose QP goes through casadi.conic (whose hpipm plugin is always
    the libhpipm CasADi ships)."""
    return f"{kind} {hessian}, {qp_solver} conic" + (
        ", libhpipm CasADi's" if qp_solver == "hpipm" else "")


class SqpSolver(_Base):
    """Full-step SQP with HPIPM (or another casadi conic plugin) and a fixed iteration budget."""

    def __init__(self, cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray,
                 hessian: str = "gauss_newton"):
        super().__init__(cfg, model, u_trim)
        sc = cfg.solver
        self.max_iterations = sc.max_iterations
        self.tolerance = sc.tolerance
        self.hessian = hessian
        # Largest shooting gap of an accepted plan. The budget iterate is accepted even when not
        # converged (after a fault the gaps close over several control steps; rejecting it there
        # lost the vehicle in the wind + motor-fault flight); only nonsense is rejected.
        self.max_gap = 10.0
        nlp = self.ocp.nlp
        w, p, g, f = nlp["x"], nlp["p"], nlp["g"], nlp["f"]
        lam = ca.SX.sym("lam", g.shape[0])
        fopts = {"cse": True}
        self._lin = ca.Function("lin", [w, p], [g, ca.jacobian(g, w), ca.gradient(f, w), f],
                                fopts)
        h_cost = ca.hessian(f, w)[0]
        reg = sc.regularization * ca.DM.eye(w.shape[0])
        if hessian == "exact":
            h = ca.hessian(f + ca.dot(lam, g), w)[0] + reg
            self._hess = ca.Function("hess_lag", [w, p, lam], [h], fopts)
            h_sp = self._hess.sparsity_out(0)
        else:
            hf = ca.Function("hcost", [w, p], [h_cost + reg])
            self._h_const = hf(np.zeros(w.shape[0]), np.zeros(p.shape[0]))
            h_sp = self._h_const.sparsity()
        a_sp = self._lin.sparsity_out(1)
        qp_opts = {"error_on_fail": False, "print_time": False}
        if sc.qp_solver == "hpipm":
            hpipm.check_conic()
            qp_opts["hpipm"] = {"iter_max": sc.qp_max_iterations, "warm_start": 0}
        elif sc.qp_solver == "qrqp":
            qp_opts.update({"print_iter": False, "print_header": False, "print_info": False})
        elif sc.qp_solver == "osqp":
            qp_opts["osqp"] = {"verbose": False, "eps_abs": 1e-8, "eps_rel": 1e-8,
                               "polish": True}
        self._qp = ca.conic("qp", sc.qp_solver, {"h": h_sp, "a": a_sp}, qp_opts)
        self._lam = np.zeros(g.shape[0])
        self._fg = ca.Function("fg", [w, p], [f, g])

    def describe(self) -> str:
        """What solves the NMPC, for logs and benchmarks."""
        return conic_line("sqp", self.hessian, self.cfg.solver.qp_solver)

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        t0 = time.perf_counter()
        ocp, guess = self.ocp, plan_of(guess)
        try:
            p, lbw, ubw, w = self._setup(x0, x_ref, d, u_prev, guess, y0)
            lam = self._lam
            it = 0
            step = np.inf
            for it in range(1, self.max_iterations + 1):
                g, jac, grad, _ = self._lin(w, p)
                g = np.asarray(g).ravel()
                h = self._hess(w, p, lam) if self.hessian == "exact" else self._h_const
                res = self._qp(h=h, g=grad, a=jac, lba=ocp.lbg - g, uba=ocp.ubg - g,
                               lbx=lbw - w, ubx=ubw - w)
                if not self._qp.stats().get("success", False):
                    dw_try = np.asarray(res["x"]).ravel()
                    if not np.all(np.isfinite(dw_try)):
                        return self._failed(guess, t0, it, "QP failed")
                dw = np.asarray(res["x"]).ravel()
                lam_new = np.asarray(res["lam_a"]).ravel()
                if not (np.all(np.isfinite(dw)) and np.all(np.isfinite(lam_new))):
                    return self._failed(guess, t0, it, "non-finite QP step")
                w = np.clip(w + dw, lbw, ubw)
                lam = lam_new
                step = float(np.max(np.abs(dw)))
                if step < self.tolerance:
                    break
            f, g = self._fg(w, p)
            cost = float(f)
            gap = float(np.max(np.abs(np.asarray(g).ravel()))) if g.numel() else 0.0
            if not np.isfinite(cost) or not np.all(np.isfinite(w)) or gap > self.max_gap:
                return self._failed(guess, t0, it, f"diverged (gap {gap:.3g})")
            self._lam = lam
            u, x = ocp.unpack(w)
            msg = "converged" if step < self.tolerance else f"budget (step {step:.2g})"
            return u, x, SolveInfo(SolveStatus.OK, it, time.perf_counter() - t0, cost, msg)
        except RuntimeError as exc:     # casadi evaluation errors
            return self._failed(guess, t0, 0, f"exception: {exc}")


class IpoptSolver(_Base):
    """IPOPT on the same NLP to a tight tolerance: the reference for tests, not for real time."""

    def __init__(self, cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray,
                 tol: float = 1e-10):
        super().__init__(cfg, model, u_trim)
        self._nlp = ca.nlpsol("ipopt", "ipopt", self.ocp.nlp, {
            "expand": True, "print_time": False, "error_on_fail": False,
            "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": tol,
            "ipopt.max_iter": cfg.solver.ipopt_max_iterations})

    def describe(self) -> str:
        """What solves the NMPC, for logs and benchmarks."""
        return "ipopt"

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        t0 = time.perf_counter()
        ocp, guess = self.ocp, plan_of(guess)
        try:
            p, lbw, ubw, w0 = self._setup(x0, x_ref, d, u_prev, guess, y0)
            r = self._nlp(x0=w0, p=p, lbx=lbw, ubx=ubw, lbg=ocp.lbg, ubg=ocp.ubg)
        except RuntimeError as exc:
            return self._failed(guess, t0, 0, f"exception: {exc}")
        st = self._nlp.stats()
        w = np.asarray(r["x"]).ravel()
        if not st["success"] or not np.all(np.isfinite(w)):
            return self._failed(guess, t0, st.get("iter_count", 0), st["return_status"])
        u, x = ocp.unpack(w)
        return u, x, SolveInfo(SolveStatus.OK, st["iter_count"], time.perf_counter() - t0,
                               float(r["f"]), st["return_status"])


def make_solver(cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray) -> Solver:
    if cfg.solver.kind == "ipopt":
        return IpoptSolver(cfg, model, u_trim)
    if cfg.solver.kind == "rti":
        from trq_offboard.nmpc.rti import RtiSolver
        return RtiSolver(cfg, model, u_trim, cfg.solver.hessian)
    return SqpSolver(cfg, model, u_trim, cfg.solver.hessian)
