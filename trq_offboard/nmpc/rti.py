"""Real-time iteration (RTI) of the NMPC: one SQP step per control step, split into a preparation
and a feedback phase, on per-stage functions compiled once (acados' structure, in CasADi).

    solver = RtiSolver(cfg, model, u_trim, hessian="gauss_newton")   # build once (cached C)
    u, x, info = solver.solve(x0, x_ref, d, u_prev, guess)           # feedback (+ preparation
                                                                     #   if none is pending)
    solver.prepare(x_ref_next, d, u_cmd, guess_next)                 # after sending the command

Preparation (before the new state is known): at the linearisation point w (the caller's guess,
normally the previous plan shifted by one control period) evaluate, for every stage k,

    phi_k = F(s_k, v_k, d)   A_k, B_k = dF/d(s, v)   D_k = dF/dd   grad l_k   [H_k]

with ONE call of a per-stage function mapped over the horizon, and assemble the structured QP in
the increments dw:

    min 1/2 dw' H dw + grad' dw   s.t.  gaps + J dw = 0,   lbw - w <= dw <= ubw - w

With HPIPM called directly the whole preparation (the stage function, its map, the gaps, the
gradient's assembly, the outputs written dense) is generated as one C function and compiled once
for its horizon (`cache.py`); on the conic path the stage function is compiled apart, serving
every horizon length, and CasADi runs the rest.

H is the constant Hessian of the quadratic cost (Gauss-Newton: exact here, since the cost is
quadratic in w) or, for hessian="exact", the Hessian of the Lagrangian with the multipliers of the
previous QP; plus `regularization` on the diagonal.
Feedback (when x0 arrives): embed s_0 = [x0, alpha_prev (, y0)] as equal bounds on ds_0, correct the
gaps to first order for the change of d since the preparation (D_k (d - d_prep)) and the cost
gradient exactly for the change of the reference (the cost is quadratic), solve the QP (HPIPM:
Riccati-based, exploits the stage structure; called directly through nmpc/hpipm.py with ds_0
eliminated, or through casadi.conic: solver key hpipm_interface) and take the full step.

SolveInfo of solve(): solve_time_s is the time of solve() itself (the feedback phase, or
preparation + feedback when no preparation was pending); `last_prepare_s` holds the time of the
last preparation. iterations counts SQP steps (1 per control step); `qp_iterations` the QP's.
The cost reported is the model cost of the returned plan (exact: the cost is quadratic).
Never returns NaN: a failure returns the (finite) guess with status FAILED.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import casadi as ca
import numpy as np

from trq_offboard.config import ControllerConfig
from trq_offboard.model import PredictionModel
from trq_offboard.model.dynamics import NumpyFunction
from trq_offboard.nmpc import feedback, guess_core, hpipm
from trq_offboard.nmpc.base import Solver, conic_line, conic_qp, plan_of
from trq_offboard.nmpc.cache import compiled, compiled_many
from trq_offboard.nmpc.ocp import Ocp, Stage
from trq_offboard.records import SolveInfo, SolveStatus

__all__ = ["RtiSolver", "HPIPM_AUTO"]

# hpipm_mode auto: HPIPM's mode and arguments per Hessian. Gauss-Newton: speed_abs (no residuals
# computed), a small initial barrier mu0 (an iteration less) and a tight complementarity tolerance
# (speed_abs stops on it alone). Exact: speed at HPIPM's defaults (the next Hessian needs the
# multipliers, which speed_abs does not compute to tolerance; mu0 0.1 left its QPs at the
# iteration limit). Measurements in params/controller/nmpc.yaml.
HPIPM_AUTO = {"gauss_newton": ("speed_abs", {"mu0": 0.1, "tol_comp": 1e-10}),
              "exact": ("speed", {})}


@dataclass
class _Prepared:
    w: np.ndarray            # linearisation point (nw)
    a: ca.DM | np.ndarray    # conic: constraint Jacobian (sparse); direct: [A_k B_k]' (N, nz, ns)
    h: ca.DM | np.ndarray | None   # conic: Hessian (sparse); direct: stage blocks (exact) or None
    gaps: np.ndarray         # F(s_k, v_k) - s_{k+1}, stage-major (N ns)
    grad: np.ndarray         # cost gradient (nw)
    jd: np.ndarray           # (N, ns, 6) dF/dd per stage
    d: np.ndarray            # d and the reference the preparation used
    xr_w: np.ndarray         # x_ref placed at the state positions of w (nw)


class RtiSolver(Solver):
    """One SQP step per control step on compiled per-stage functions; HPIPM QP."""

    prepares = True

    def __init__(self, cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray,
                 hessian: str = "gauss_newton", ocp=None):
        t_build = time.perf_counter()
        self.cfg = cfg
        self.ocp = ocp if ocp is not None else Ocp.build(cfg, model)
        self.u_trim = np.asarray(u_trim, float)
        self.hessian = hessian
        sc = cfg.solver
        self.max_iterations = sc.max_iterations
        o = self.ocp
        N, ns, nv, nx, nu = o.n_steps, o.ns, o.nv, o.nx, o.nu
        nz, nw = ns + nv, o.lbw.size
        self._N, self._ns, self._nv, self._nx = N, ns, nv, nx
        stage = Stage.build(cfg, model)

        enabled = sc.codegen == "auto"
        # HPIPM called directly (nmpc/hpipm.py) or through casadi.conic
        self.qp_interface = "conic"
        if sc.qp_solver == "hpipm" and sc.hpipm_interface == "direct":
            ok, why = hpipm.available()
            if ok:
                self.qp_interface = "direct"
            else:
                warnings.warn(f"HPIPM could not be called directly ({why}): the RTI uses "
                              "casadi.conic('hpipm') instead (slower)", RuntimeWarning,
                              stacklevel=2)
        direct = self.qp_interface == "direct"
        # the direct preparation is compiled whole below, its stage functions inlined: no
        # CasADi virtual machine around them a period (its indexing, its map, the outputs'
        # densification); the conic path calls them compiled apart
        whole = direct and enabled
        # inlined, the stage functions write their Jacobians and Hessian dense (their structural
        # zeros as zeros): the preparation's densification of them is then no copy at all
        dense = ca.densify if whole else (lambda e: e)

        # --- per-stage functions (SX: inlined in the preparation, or compiled apart) -----------
        s, v = ca.SX.sym("s", ns), ca.SX.sym("v", nv)
        xr, ut, d = ca.SX.sym("x_ref", nx), ca.SX.sym("u_trim", nu), ca.SX.sym("d", 6)
        lam = ca.SX.sym("lam", ns)
        z = ca.vertcat(s, v)
        phi = stage.dynamics(s, v, d)
        l_k = stage.cost(s, v, xr, ut)
        tag = "trq" if o.tilting else "quad"
        fns = [ca.Function(f"rti_lin_{tag}", [s, v, xr, ut, d],
                           [phi, dense(ca.jacobian(phi, z)), dense(ca.gradient(l_k, z)),
                            dense(ca.jacobian(phi, d))], {"cse": True})]
        if hessian == "exact":
            fns.append(ca.Function(f"rti_hess_{tag}", [s, v, d, lam],
                                   [dense(ca.hessian(ca.dot(lam, phi), z)[0])], {"cse": True}))
        # the NLP's cost (logged with every solve), the Ocp's own expression compiled
        w_sym, p_sym = ca.SX.sym("w", nw), ca.SX.sym("p", o.n_params)
        fns.append(ca.Function(f"rti_cost_{tag}_{N}", [w_sym, p_sym], [o.cost_fn(w_sym, p_sym)]))
        built = compiled_many(fns[-1:] if whole else fns, enabled)
        self._cost_fn = NumpyFunction(built[-1][0])
        self._cost_fn.args[1][(N + 1) * nx:(N + 1) * nx + nu] = self.u_trim / o.u_scale
        self.build_mode = built[0][1]                  # compiled | cached | interpreted
        lin = (fns[0] if whole else built[0][0]).map(N)
        # constant cost Hessians (stage and terminal)
        zero = [np.zeros(ns), np.zeros(nv), np.zeros(nx), np.zeros(nu)]
        hc = np.asarray(ca.Function("hc", [s, v, xr, ut], [ca.hessian(l_k, z)[0]])(*zero))
        lN = stage.terminal_cost(s, xr)
        hcN = np.asarray(ca.Function("hcN", [s, xr], [ca.hessian(lN, s)[0]])(zero[0], zero[2]))
        gN = ca.Function("gN", [s, xr], [ca.gradient(lN, s)])
        reg = sc.regularization

        # --- the preparation as one MX function: mapped stage calls + QP assembly --------------
        W = ca.MX.sym("w", nw)
        XR = ca.MX.sym("x_ref", nx, N + 1)
        UT = ca.MX.sym("u_trim", nu)
        D = ca.MX.sym("d", 6)
        LAM = ca.MX.sym("lam", N * ns)
        s_idx, v_idx = o.s_index, o.v_index
        S = ca.reshape(W[s_idx[:N].ravel().tolist()], ns, N)
        V = ca.reshape(W[v_idx.ravel().tolist()], nv, N)
        PHI, JZ, GZ, JD = lin(S, V, XR[:, 0:N], UT, D)
        gaps = ca.vec(PHI) - W[s_idx[1:].ravel().tolist()]
        z_idx = np.hstack([s_idx[:N], v_idx])                     # (N, nz): w-positions of z_k
        # gradient: stage parts from GZ, terminal from gN, placed in w order
        grad_src = ca.vertcat(ca.vec(GZ), gN(W[s_idx[N].tolist()], XR[:, N]))
        pos = np.concatenate([z_idx.ravel(), s_idx[N]])
        grad = grad_src[np.argsort(pos).tolist()]
        self._hc = hc + reg * np.eye(nz)               # constant stage Hessian (GN part)
        self._hcN = hcN + reg * np.eye(ns)
        HL = None
        if hessian == "exact":
            hess = (fns[1] if whole else built[1][0]).map(N)
            HL = ca.densify(hess(S, V, D, ca.reshape(LAM, ns, N)))   # (nz, nz N)
        if direct:
            # the stage Jacobians [A_k B_k] dense (column-major: one block per stage), all
            # outputs dense and evaluated into NumPy buffers (no DM conversion, which cost
            # time a step: docs/decisions/2026-12-02-figures-from-comments.md)
            outs = [ca.densify(JZ), ca.densify(gaps), ca.densify(grad), ca.densify(ca.vec(JD))]
            if HL is not None:
                outs.append(HL)
        else:
            # constraint Jacobian: [A_k B_k] at (stage rows, z_k), -I at (stage rows, s_{k+1})
            jsp = fns[0].sparsity_out(1)
            jr, jc = np.array(jsp.get_triplet()[0]), np.array(jsp.get_triplet()[1])
            nnz_j = jr.size
            rows, cols, src = [], [], []
            for k in range(N):
                rows += [k * ns + jr, k * ns + np.arange(ns)]
                cols += [z_idx[k][jc], s_idx[k + 1]]
                src += [k * nnz_j + np.arange(nnz_j), np.full(ns, N * nnz_j)]    # -1 sentinel
            a_sp, a_src = self._assemble(N * ns, nw, rows, cols, src)
            A = ca.MX(a_sp, ca.vertcat(JZ.nz[:], -1)[a_src.tolist()])
            outs = [A, gaps, grad, ca.vec(JD)]
            # Hessian: block diagonal, stage blocks hc (+ Lagrangian term) and terminal hcN
            rows, cols, src = [], [], []
            for k in range(N):
                rows.append(np.repeat(z_idx[k], nz))
                cols.append(np.tile(z_idx[k], nz))
                src.append(k * nz * nz + np.arange(nz * nz))
            rows.append(np.repeat(s_idx[N], ns))
            cols.append(np.tile(s_idx[N], ns))
            src.append(N * nz * nz + np.arange(ns * ns))
            h_sp, h_src = self._assemble(nw, nw, rows, cols, src)
            base = np.concatenate([np.tile(self._hc.ravel(order="F"), N),
                                   self._hcN.ravel(order="F")])
            if HL is not None:
                hsrc = ca.vertcat(ca.vec(HL), ca.DM.zeros(ns * ns)) + ca.DM(base)
                outs.append(ca.MX(h_sp, hsrc[h_src.tolist()]))
            else:
                self._h_const = ca.DM(h_sp, ca.DM(base[h_src]))
        self._prep = ca.Function(f"rti_prep_{tag}_{N}", [W, XR, UT, D, LAM], outs)
        if whole:
            self._prep, self.build_mode = compiled(self._prep)
        if direct:
            self._prep_np = NumpyFunction(self._prep)
            # state boxes: the finite bounds of s_k (the same for k >= 1); inputs all boxed
            self._idxbx = np.flatnonzero(np.abs(o.lbw[s_idx[1]]) < 1e19)
            self._sbx = s_idx[:, self._idxbx]
            mode, opts = sc.hpipm_mode, dict(sc.hpipm_options)
            if mode == "auto":       # measured presets (params/controller/nmpc.yaml)
                mode, preset = HPIPM_AUTO[hessian]
                opts = {**preset, **opts}
            self.hpipm_mode, self.hpipm_options = mode, opts
        else:
            self._qp = conic_qp("rti_qp", sc.qp_solver, h_sp, a_sp, sc.qp_max_iterations)
        # feedback helpers (NumPy)
        self._lam = np.zeros(N * ns)
        wts = cfg.weights
        q2 = 2.0 * np.array([*wts.position, *wts.velocity, *wts.euler, *wts.rates])
        self._x_pos = s_idx[:, 0:nx]                                # (N+1, nx)
        # x_0's places in w: a slice where w is stage-major (a view, no fancy index a period)
        x0p = self._x_pos[0]
        self._x0_pos = (slice(int(x0p[0]), int(x0p[0]) + nx)
                        if np.array_equal(x0p, np.arange(x0p[0], x0p[0] + nx)) else x0p)
        self._q2_w = np.zeros(nw)
        self._q2_w[self._x_pos[:N]] = q2
        self._q2_w[self._x_pos[N]] = wts.terminal_factor * q2
        self._kernel = None
        self._guess = None
        if direct:
            # the direct interface's HPIPM QP with this solver's mode, options and Hessian, and
            # the feedback in one compiled call, which holds the QP's handles, where it can be
            # built (else the NumPy feedback serves)
            self._hqp = hpipm.OcpQp(ns, nv, N, self._idxbx, mode=self.hpipm_mode,
                                    iter_max=sc.qp_max_iterations, options=self.hpipm_options,
                                    shim=enabled)
            if hessian != "exact":
                self._hqp.set_hessian(self._hc, self._hcN)
            if enabled and self._hqp.uses_shim and feedback.available():
                self._kernel = feedback.FeedbackKernel(o, self._hqp, self._q2_w,
                                                       self._prep_np.results[0:4])
                self._s0_hess = np.ascontiguousarray(self._hc[ns:, :ns])
            if enabled and guess_core.available():
                # the next linearisation point in one compiled call, straight into the
                # preparation's inputs (prepare_plan)
                args = self._prep_np.args
                self._guess = guess_core.GuessKernel(o, args[0], args[1])
                self.prepares_plans = True
            # the preparation's outputs as the QP reads them: views of its buffers, made once
            res = self._prep_np.results
            self._prep_views = (res[0].reshape(N, nz, ns), res[1], res[2],
                                res[3].reshape(N, 6, ns).transpose(0, 2, 1))
        self._prepared: _Prepared | None = None
        self.last_prepare_s = 0.0
        self.qp_iterations = 0
        self.build_s = time.perf_counter() - t_build

    def describe(self) -> str:
        """The QP path this solver took, for logs and benchmarks: the interface, HPIPM's mode and
        arguments, the per-solve loop (compiled shim or ctypes), the feedback
        (one compiled call or NumPy) and which libhpipm (a flight is replayed bit for bit only
        on the same library: BLASFEO's kernels round differently)."""
        if self.qp_interface != "direct":
            return conic_line("rti", self.hessian, self.cfg.solver.qp_solver)
        opts = "".join(f" {k} {v:g}" for k, v in self.hpipm_options.items())
        loop = "shim" if self._hqp.uses_shim else "ctypes loop"
        fb = "compiled feedback" if self._kernel is not None else "numpy feedback"
        lib = hpipm.loaded_library()
        which = "-" if lib is None else (
            f"{lib} (CasADi's)" if lib == hpipm.bundled_path() else f"{lib} (${hpipm.LIBRARY_ENV})")
        return (f"rti {self.hessian}, hpipm direct {self.hpipm_mode}{opts}, {loop}, {fb}, "
                f"libhpipm {which}")

    @staticmethod
    def _assemble(nr, nc, rows, cols, src):
        rows, cols, src = (np.concatenate(a).astype(int) for a in (rows, cols, src))
        order = np.lexsort((rows, cols))                 # column-major (CCS) order
        sp = ca.Sparsity.triplet(nr, nc, rows[order].tolist(), cols[order].tolist())
        assert sp.nnz() == rows.size, "duplicate entries in the QP structure"
        return sp, src[order]

    # --- phases --------------------------------------------------------------------------------
    def prepare(self, x_ref, d, u_prev, guess, y0=None) -> None:
        """Linearise at `guess` (u (N, nu), x (N+1, 12): the plan expected at the next step) and
        assemble the QP; the next solve() only embeds its x0 and solves it. y0 (with actuator
        lag states): the actuators' outputs expected when that plan starts (default u_prev)."""
        t0 = time.perf_counter()
        o = self.ocp
        a_prev = np.asarray(u_prev, float)[0:4] if o.tilting else None
        if o.n_lag and y0 is None:
            y0 = u_prev
        w = o.pack(guess[1], guess[0], a_prev, y0).clip(o.lbw, o.ubw)     # np.clip's ufunc
        x_ref = np.asarray(x_ref, float).reshape(self._N + 1, self._nx)
        d = np.asarray(d, float).reshape(6)
        xr_w = np.zeros(w.size)
        xr_w[self._x_pos] = x_ref
        if self.qp_interface == "direct":
            # x_ref (N+1, nx) row-major is the (nx, N+1) input column-major; the outputs are
            # the buffers themselves: a preparation is consumed by the feedback before the
            # next one evaluates (solve() prepares again only after its feedback)
            self._prep_np.outputs_in_place(w, x_ref, self.u_trim / o.u_scale, d, self._lam)
            self._prepared = self._direct_prepared(w, d, xr_w)
        else:
            out = self._prep(w, x_ref.T, self.u_trim / o.u_scale, d, self._lam)
            a, h = out[0], (out[4] if self.hessian == "exact" else self._h_const)
            self._prepared = _Prepared(
                w, a, h, np.asarray(out[1]).ravel(), np.asarray(out[2]).ravel(),
                np.asarray(out[3]).reshape(self._N, 6, self._ns).transpose(0, 2, 1), d, xr_w)
        self.last_prepare_s = time.perf_counter() - t0

    def prepare_plan(self, plan, elapsed_s, h_s, pv, yaw_ref, d, u_prev, y0=None) -> None:
        """Solver.prepare_plan: the next linearisation point and the reference states formed
        by the compiled guess (guess_core.py) in the preparation's input buffers, then the
        preparation evaluated there; the same preparation as the controller's NumPy path
        (Controller._prepare) to the bit (tests/consistency/test_rti_guess.py)."""
        t0 = time.perf_counter()
        g = self._guess
        if g is None:
            raise RuntimeError("this RTI solver has no compiled guess (prepares_plans False)")
        g(plan, elapsed_s, h_s, pv, yaw_ref, u_prev, y0)
        d = np.asarray(d, float).reshape(6)
        args = self._prep_np.args
        args[2][:] = self.u_trim / self.ocp.u_scale
        args[3][:] = d
        args[4][:] = self._lam
        self._prep_np.evaluate()
        self._prepared = self._direct_prepared(g.w, d, g.xr_w)
        self.last_prepare_s = time.perf_counter() - t0

    def _direct_prepared(self, w, d, xr_w) -> _Prepared:
        """The direct interface's preparation, its outputs where it evaluated them: [A_k B_k]'
        per stage (N, nz, ns; A_k column-major), the gaps, the gradient, dF/dd (N, ns, 6) and
        (exact Hessian) the stage blocks, (nz, nz N) column-major read as (N, nz, nz), plus the
        cost's."""
        a, gaps, grad, jd = self._prep_views
        h = None
        if self.hessian == "exact":
            N, nz = self._N, self._ns + self._nv
            h = self._prep_np.results[4].reshape(N, nz, nz).transpose(0, 2, 1) + self._hc
        return _Prepared(w, a, h, gaps, grad, jd, d, xr_w)

    def discard(self) -> None:
        """Forget a pending preparation (the controller was reset)."""
        self._prepared = None

    def zero_multipliers(self) -> None:
        self._lam[:] = 0.0

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        t0 = time.perf_counter()
        if self.ocp.n_lag and y0 is None:
            y0 = u_prev                    # actuators settled at the applied command
        try:
            it = 0
            P = self._prepared
            if P is not None and np.abs(np.asarray(x0, float).reshape(12)
                                        - P.w[self._x0_pos]).max() > 2.0:
                self._prepared = None      # stale: the state is far from the linearisation
            for it in range(1, self.max_iterations + 1):
                if self._prepared is None or it > 1:
                    guess = plan_of(guess)
                    self.prepare(x_ref, d, u_prev, guess, y0)
                w, status = self._feedback(x0, x_ref, d, u_prev, y0)
                if w is None:
                    return self._failed(plan_of(guess), t0, it, status)
                guess = self._guess.unpack(w) if self._guess is not None else self.ocp.unpack(w)
        except RuntimeError as exc:      # casadi evaluation errors
            self._prepared = None
            return self._failed(plan_of(guess), t0, 0, f"exception: {exc}")
        u, x = guess
        return u, x, SolveInfo(SolveStatus.OK, it, time.perf_counter() - t0,
                               self._cost(w, x_ref), status)

    def _feedback(self, x0, x_ref, d, u_prev, y0=None):
        P, o = self._prepared, self.ocp
        self._prepared = None
        x0 = np.asarray(x0, float).reshape(12)
        d = np.asarray(d, float).reshape(6)
        tilt = np.asarray(u_prev, float)[0:4] if o.tilting else None
        if self._kernel is not None:
            return self._feedback_compiled(P, x0, x_ref, d, tilt, y0)
        gaps = P.gaps
        dd = d - P.d
        if np.any(dd):
            gaps = gaps + (P.jd @ dd).ravel()
        grad = P.grad
        xr_w = np.zeros(P.w.size)
        xr_w[self._x_pos] = np.asarray(x_ref, float).reshape(self._N + 1, self._nx)
        if not np.array_equal(xr_w, P.xr_w):
            grad = grad - self._q2_w * (xr_w - P.xr_w)
        lbw, ubw = o.bounds(x0, tilt, y0)
        if self.qp_interface == "direct":
            return self._solve_direct(P, gaps, grad, lbw, ubw)
        res = self._qp(h=P.h, g=grad, a=P.a, lba=-gaps, uba=-gaps, lbx=lbw - P.w, ubx=ubw - P.w)
        st = self._qp.stats()
        self.qp_iterations = int(st.get("iter_count", -1))
        dw = np.asarray(res["x"]).ravel()
        lam = np.asarray(res["lam_a"]).ravel()
        if not (np.all(np.isfinite(dw)) and np.all(np.isfinite(lam))):
            return None, "non-finite QP step"
        if self.hessian == "exact":
            self._lam = lam
        w = np.clip(P.w + dw, lbw, ubw)
        msg = "rti" if st.get("success", False) else f"rti (QP: {st.get('return_status')})"
        return w, msg

    def _feedback_compiled(self, P, x0, x_ref, d, tilt, y0):
        """`_feedback` through the compiled kernel (nmpc/feedback.py): the same corrections,
        bounds, QP and step in one call."""
        ns = self._ns
        if P.h is not None:                               # exact Hessian: per-stage blocks
            self._hqp.set_hessian(P.h, self._hcN)
            s0_hess = P.h[0][ns:, :ns]
        else:
            s0_hess = self._s0_hess
        # the preparation's constraint and cost data: in the buffers the kernel reads
        w, status = self._kernel(P.w, P.d, d, P.xr_w,
                                 np.reshape(x_ref, (self._N + 1, self._nx)),
                                 self.ocp.initial_stage(x0, tilt, y0), s0_hess)
        self.qp_iterations = self._hqp.iterations
        if w is None:
            return None, "non-finite QP step"
        if self.hessian == "exact":
            self._lam = self._hqp.pi.ravel().copy()
        return w, ("rti" if status == 0 else f"rti (QP: HPIPM status {status})")

    def _solve_direct(self, P, gaps, grad, lbw, ubw):
        """The QP through nmpc/hpipm.py: s_0 eliminated (ds_0 is known), only finite bounds."""
        o, N, ns, hq = self.ocp, self._N, self._ns, self._hqp
        w = P.w
        s_idx, v_idx = o.s_index, o.v_index
        ds0 = lbw[s_idx[0]] - w[s_idx[0]]
        at, bt = P.a[:, :ns, :], P.a[:, ns:, :]           # A_k', B_k' (column-major A_k, B_k)
        b = gaps.reshape(N, ns).copy()
        b[0] += ds0 @ at[0]
        q, r = grad[s_idx], grad[v_idx]
        if P.h is not None:                               # exact Hessian: per-stage blocks
            hq.set_hessian(P.h, self._hcN)
            s0 = P.h[0][ns:, :ns]
        else:
            s0 = self._hc[ns:, :ns]
        r[0] += s0 @ ds0
        lo, hi = lbw - w, ubw - w
        x, u, pi = hq.solve(at, bt, b, q, r, lo[self._sbx], hi[self._sbx], lo[v_idx],
                            hi[v_idx])
        self.qp_iterations = hq.iterations
        dw = np.empty(w.size)
        dw[s_idx[1:]] = x[1:]
        dw[s_idx[0]] = ds0
        dw[v_idx] = u
        if not (np.all(np.isfinite(dw)) and np.all(np.isfinite(pi))):
            return None, "non-finite QP step"
        if self.hessian == "exact":
            self._lam = pi.ravel().copy()
        w = np.clip(w + dw, lbw, ubw)
        return w, ("rti" if hq.status == 0 else f"rti (QP: HPIPM status {hq.status})")

    def _cost(self, w, x_ref) -> float:
        """The NLP's cost at w (the Ocp's cost function, compiled; p's u_trim part set once,
        its d part unused by the cost)."""
        fn = self._cost_fn
        w_in, p_in = fn.args
        w_in[:] = w
        p_in[:x_ref.size] = np.ravel(x_ref)          # (N+1, nx) rows: vec of (nx, N+1)
        fn.evaluate()
        return float(fn.results[0][0])
