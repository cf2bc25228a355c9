"""The NLP solvers on ocp.py's whole-horizon NLP (behind nmpc/base.py's `Solver`), the test
oracles and the latency bound's solver; the real-time default is rti.py's RtiSolver.

    SqpSolver    (kind "sqp") a hand-written SQP (full steps) with a structured QP solver (HPIPM
                 through casadi.conic, no code generation); Hessian either Gauss-Newton (the
                 constant Hessian of the quadratic cost: always convex, cheapest) or exact
                 (cost + constraint curvature with the QP multipliers); a few iterations per
                 step, warm-started from the caller's guess.
    IpoptSolver  (kind "ipopt") the converged reference: the same NLP solved by IPOPT to tight
                 tolerance.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from trq_offboard.config import ControllerConfig
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc.base import Solver, conic_line, conic_qp, plan_of
from trq_offboard.nmpc.ocp import Ocp
from trq_offboard.records import SolveInfo, SolveStatus

__all__ = ["SqpSolver", "IpoptSolver"]


class _NlpSolver(Solver):
    """A solver of the whole-horizon NLP (Ocp.nlp): the bounds and the packed guess."""

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


class SqpSolver(_NlpSolver):
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
        self._qp = conic_qp("qp", sc.qp_solver, h_sp, a_sp, sc.qp_max_iterations)
        self._lam = np.zeros(g.shape[0])
        self._fg = ca.Function("fg", [w, p], [f, g])

    def describe(self) -> str:
        """What solves the NMPC, for logs and benchmarks."""
        return conic_line("sqp", self.hessian, self.cfg.solver.qp_solver)

    def zero_multipliers(self) -> None:
        self._lam[:] = 0.0

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


class IpoptSolver(_NlpSolver):
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
