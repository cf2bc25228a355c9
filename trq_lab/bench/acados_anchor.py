"""acados' real-time iteration on this project's NMPC problem: the same-run anchor of
`trq-bench-nmpc --anchor acados` (issue 18's targets are ratios to acados' RTI step).

Needs acados built from its sources (its own instructions) beside the project: `acados_template`
importable, `$ACADOS_SOURCE_DIR` naming the acados tree (its lib/ with libacados, libhpipm and
libblasfeo; the bench puts it on LD_LIBRARY_PATH of its child processes) and acados' template
renderer `t_renderer` in `$ACADOS_SOURCE_DIR/bin` (or `$TERA_PATH`). `available()` says what is
missing; nothing here is imported by the controller or the tests' default path.

The optimal control problem handed to acados is built from trq_offboard's own code
(`nmpc.ocp.Stage`, `model.PredictionModel`, the controller file's weights and bounds), so that the
model and the cost are the project's, term for term:

    state s (16) = [x (12), a (4)]    input v (8) = [w (4), c (4)]    parameter d (6)
    dynamics   s_next = Stage.dynamics(s, v, d): RK4 over h with the tilt a + h w, handed to acados
               as its CasADi expression (integrator DISCRETE, `disc_dyn_expr`)
    cost       linear least squares on y = [x, a + h w, c, w], W = 2 diag(Q, R, w_rate) and
               yref = [x_ref_k, u_trim (scaled), 0]: acados' 1/2 |y - yref|_W^2 is the stage cost
               of ocp.py; terminal y_e = x, W_e = 2 c_N Q; cost_scaling 1 on every stage
               (acados' default scales the stage costs by h, the terminal by 1)
    bounds     s_0 = [x0, alpha_prev]; roll, pitch, body rates and tilts on s_k (k >= 1, N);
               tilt rates and throttles on v_k, per step as our solver had them (the first tilt
               rate within rate * control period / h; the throttles within the motors'
               effectiveness times [idle, 100 %])
    solver     SQP_RTI, preparation and feedback called as two phases (rti_phase 1, 2); exact
               Hessian of the Lagrangian or Gauss-Newton; Levenberg-Marquardt term = the
               solver's `regularization` (our solver's diagonal term); the exact Hessian's
               blocks left as they are (acados' regularize_method NO_REGULARIZE), or, on
               request (`regularize`, trq-bench-nmpc --anchor-regularize), regularised by one
               of acados' methods (REGULARIZE_METHODS) with its reg_epsilon; HPIPM on the 20
               stages un-condensed (PARTIAL_CONDENSING_HPIPM, qp_solver_cond_N = N: what our
               rti-gn does), HPIPM's mode and options as our solver's (`rti.HPIPM_AUTO`), the QP's
               iteration cap, QP cold-started; code generated with acados' default flags

Replay (`replay`): a flight of ours (trq-bench-nmpc's transient) is recorded per step (x0, the
applied tilt, the reference states, d, the input bounds, our first command and the point our
solver linearised at) and acados is stepped through the same sequence: per step the reference,
d and bounds are set, the preparation phase runs (timed), x0 is embedded and the feedback phase
runs (timed). Warm start: acados' own previous solution shifted by one control period as the
controller shifts its plan (states interpolated, inputs held; s_0's tilt = the command just
sent), or (init="ours") our solver's linearisation point (its preparation's guess; on the first
step the solve's), so that both take their step from the same point. acados is handed the step's
reference and d before its preparation; ours prepared with the previous ones and corrects them
in its feedback (exactly for the reference, to first order for d). acados' multipliers stay its
own (exact Hessian). Times: wall (time.perf_counter) and CPU (time.thread_time) around each
acados call, and acados' own time_preparation / time_feedback.

A `Replayer` builds acados once for a recording and makes as many passes through it as asked,
each from acados' memory reset (the same sequence solved each time). `--serve` keeps one in a
process and makes a pass on each request on stdin, its figures on stdout (`serve`): the bench's
bracket of the daemons' flights (trq_lab/bench/nmpc.py).

Pacing (`pace_s`, "pass PACE_MS", --pace-ms): by default the steps follow each other at once, a
tight loop. Paced, each step's feedback starts `pace_s` after the previous step's feedback
started (the wait, untimed, between the preparation and the feedback, where a control loop waits
for its next state): acados stepped as a control loop at 1/pace_s Hz steps it, whose caches the
machine has had that long to take back between two steps
(docs/decisions/2026-12-07-period-paced.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["available", "build_ocp", "AcadosRti", "replay", "Replayer", "serve", "Recorder",
           "ANCHORED_MODES", "REGULARIZE_METHODS", "check_regularize"]

# our benchmark modes with an acados counterpart: mode -> acados' hessian_approx
ANCHORED_MODES = {"rti-gn": "gauss_newton", "rti-exact": "exact"}
_HESSIAN = {"gauss_newton": "GAUSS_NEWTON", "exact": "EXACT"}
_HPIPM_MODE = {"speed_abs": "SPEED_ABS", "speed": "SPEED", "balance": "BALANCE",
               "robust": "ROBUST"}
# acados' regularize_method values (acados_template 0.5.1's AcadosOcpOptions): what is done to
# each stage's Hessian block before the QP. NO_REGULARIZE is acados' default and the anchor's.
REGULARIZE_METHODS = ("NO_REGULARIZE", "MIRROR", "PROJECT", "PROJECT_REDUC_HESS", "CONVEXIFY",
                      "GERSHGORIN_LEVENBERG_MARQUARDT")
# the methods that read reg_epsilon (acados' documentation of the option)
_WITH_EPSILON = ("MIRROR", "PROJECT", "CONVEXIFY", "GERSHGORIN_LEVENBERG_MARQUARDT")


def check_regularize(method: str, epsilon: float | None = None) -> tuple[str, float | None]:
    """(method, epsilon) checked: a method of REGULARIZE_METHODS (upper case, as acados spells
    it) and, if given, an epsilon > 0 for a method that reads one; ValueError otherwise."""
    if method not in REGULARIZE_METHODS:
        raise ValueError(f"regularize method {method!r}: one of "
                         f"{', '.join(REGULARIZE_METHODS)}")
    if epsilon is not None:
        if method not in _WITH_EPSILON:
            raise ValueError(f"reg_epsilon {epsilon!r}: {method} does not use one (only "
                             f"{', '.join(_WITH_EPSILON)})")
        if not (isinstance(epsilon, (int, float)) and math.isfinite(epsilon) and epsilon > 0):
            raise ValueError(f"reg_epsilon {epsilon!r}: expected a finite number > 0")
        epsilon = float(epsilon)
    return method, epsilon


def available() -> tuple[bool, str]:
    """(True, acados' description) if acados can be used here, else (False, what is missing)."""
    try:
        import acados_template  # noqa: F401
    except ImportError as exc:
        return False, (f"acados not installed: acados_template is not importable ({exc}); "
                       "build acados from its sources and pip install its "
                       "interfaces/acados_template")
    src = os.environ.get("ACADOS_SOURCE_DIR")
    if not src:
        return False, "acados not installed: $ACADOS_SOURCE_DIR is not set"
    lib = Path(src) / "lib"
    missing = [n for n in ("libacados.so", "libhpipm.so", "libblasfeo.so")
               if not (lib / n).exists()]
    if missing:
        return False, f"acados not built: {', '.join(missing)} not in {lib}"
    tera = os.environ.get("TERA_PATH") or str(Path(src) / "bin" / "t_renderer")
    if not os.access(tera, os.X_OK):
        return False, (f"acados' template renderer t_renderer not found at {tera} "
                       "($TERA_PATH or $ACADOS_SOURCE_DIR/bin)")
    return True, f"acados at {src} ({_describe(Path(src))})"


def _describe(src: Path) -> str:
    """acados' commit and template version, as far as the tree tells."""
    parts = []
    commit = src / "lib" / "git_commit_hash"
    try:
        parts.append(f"commit {commit.read_text().strip()[:12]}")
    except OSError:
        pass
    try:
        from importlib.metadata import version
        parts.append(f"acados_template {version('acados_template')}")
    except Exception:      # noqa: BLE001 - a description only
        pass
    return ", ".join(parts) or "version unknown"


def library_env(env: dict | None = None) -> dict:
    """`env` (default os.environ) with $ACADOS_SOURCE_DIR/lib on LD_LIBRARY_PATH (a child
    process reads it at its start)."""
    env = dict(os.environ if env is None else env)
    src = env.get("ACADOS_SOURCE_DIR")
    if src:
        lib = str(Path(src) / "lib")
        old = env.get("LD_LIBRARY_PATH", "")
        if lib not in old.split(os.pathsep):
            env["LD_LIBRARY_PATH"] = lib + (os.pathsep + old if old else "")
    return env


# --- the OCP ---------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Problem:
    """Our problem's pieces, as acados is handed them (all NumPy but `stage`)."""
    stage: object            # nmpc.ocp.Stage
    n_steps: int
    step_s: float
    nx: int                  # 12
    ns: int                  # 16
    nv: int                  # 8
    Vx: np.ndarray           # (ny, ns) y = Vx s + Vu v
    Vu: np.ndarray           # (ny, nv)
    W: np.ndarray            # (ny, ny)
    Vx_e: np.ndarray         # (nx, ns)
    W_e: np.ndarray          # (nx, nx)
    idxbx: np.ndarray        # the bounded rows of s_k (k >= 1)
    lbx: np.ndarray
    ubx: np.ndarray
    lbv: np.ndarray          # stage input bounds (k >= 1), healthy motors
    ubv: np.ndarray
    lbv0: np.ndarray         # the first stage's
    ubv0: np.ndarray
    u_trim_scaled: np.ndarray   # (8) [alpha, zeta / 100]
    regularization: float

    def yref(self, x_ref_k: np.ndarray) -> np.ndarray:
        return np.concatenate([x_ref_k, self.u_trim_scaled, np.zeros(4)])


def problem(cfg, model, u_trim) -> Problem:
    """The pieces of our OCP (nmpc/ocp.py) for the tilt-rotor with tilt states and without
    actuator lag states: the configuration the anchor supports."""
    from trq_offboard.nmpc.ocp import Ocp, Stage

    if not model.tilting:
        raise ValueError("the acados anchor is built for the tilt-rotor (12 + 4 tilt states)")
    if cfg.nmpc_actuator_states:
        raise ValueError("the acados anchor has no actuator lag states (actuator_states on)")
    stage = Stage.build(cfg, model)
    ocp = Ocp.build(cfg, model)
    N, h, nx, ns, nv = cfg.horizon_steps, cfg.step_s, model.nx, stage.ns, stage.nv
    wts = cfg.weights
    Q = np.array([*wts.position, *wts.velocity, *wts.euler, *wts.rates])
    R = np.array([wts.tilt] * 4 + [wts.throttle] * 4)
    ny = nx + 8 + 4
    Vx, Vu = np.zeros((ny, ns)), np.zeros((ny, nv))
    Vx[0:nx, 0:nx] = np.eye(nx)                       # x
    Vx[nx:nx + 4, nx:nx + 4] = np.eye(4)              # a + h w
    Vu[nx:nx + 4, 0:4] = h * np.eye(4)
    Vu[nx + 4:nx + 8, 4:8] = np.eye(4)                # c
    Vu[nx + 8:ny, 0:4] = np.eye(4)                    # w
    W = 2.0 * np.diag(np.concatenate([Q, R, np.full(4, wts.tilt_rate)]))
    Vx_e = np.zeros((nx, ns))
    Vx_e[:, 0:nx] = np.eye(nx)
    W_e = 2.0 * wts.terminal_factor * np.diag(Q)
    s1 = ocp.s_index[1]
    idxbx = np.flatnonzero(np.abs(ocp.lbw[s1]) < 1e19)
    v0, v1 = ocp.v_index[0], ocp.v_index[1]
    return Problem(stage, N, h, nx, ns, nv, Vx, Vu, W, Vx_e, W_e, idxbx,
                   ocp.lbw[s1][idxbx].copy(), ocp.ubw[s1][idxbx].copy(),
                   ocp.lbw[v1].copy(), ocp.ubw[v1].copy(), ocp.lbw[v0].copy(),
                   ocp.ubw[v0].copy(), np.asarray(u_trim, float) / ocp.u_scale,
                   cfg.solver.regularization)


def build_ocp(cfg, model, u_trim, hessian: str = "exact", name: str | None = None,
              regularize: str = "NO_REGULARIZE", reg_epsilon: float | None = None):
    """The acados_template AcadosOcp of our problem (no code generated yet). `regularize`,
    `reg_epsilon`: acados' regularize_method and its epsilon (None: acados' default)."""
    import casadi as ca
    from acados_template import AcadosModel, AcadosOcp

    from trq_offboard.nmpc.rti import HPIPM_AUTO

    if hessian not in _HESSIAN:
        raise ValueError(f"hessian {hessian!r}: one of {', '.join(_HESSIAN)}")
    regularize, reg_epsilon = check_regularize(regularize, reg_epsilon)
    pb = problem(cfg, model, u_trim)
    s, v, d = ca.SX.sym("s", pb.ns), ca.SX.sym("v", pb.nv), ca.SX.sym("d", 6)
    am = AcadosModel()
    am.name = name or f"trq_anchor_{'exact' if hessian == 'exact' else 'gn'}"
    am.x, am.u, am.p = s, v, d
    am.disc_dyn_expr = pb.stage.dynamics(s, v, d)     # our RK4 step, as an expression
    ocp = AcadosOcp()
    ocp.model = am
    ocp.solver_options.N_horizon = pb.n_steps
    ocp.solver_options.tf = pb.n_steps * pb.step_s
    ocp.parameter_values = np.zeros(6)
    c = ocp.cost
    c.cost_type_0 = c.cost_type = "LINEAR_LS"
    c.cost_type_e = "LINEAR_LS"
    c.Vx_0, c.Vu_0, c.W_0 = pb.Vx, pb.Vu, pb.W
    c.Vx, c.Vu, c.W = pb.Vx, pb.Vu, pb.W
    c.yref_0 = c.yref = pb.yref(np.zeros(pb.nx))
    c.Vx_e, c.W_e, c.yref_e = pb.Vx_e, pb.W_e, np.zeros(pb.nx)
    k = ocp.constraints
    k.x0 = np.zeros(pb.ns)
    k.idxbx, k.lbx, k.ubx = pb.idxbx, pb.lbx, pb.ubx
    k.idxbx_e, k.lbx_e, k.ubx_e = pb.idxbx, pb.lbx, pb.ubx
    k.idxbu, k.lbu, k.ubu = np.arange(pb.nv), pb.lbv, pb.ubv
    o = ocp.solver_options
    o.integrator_type = "DISCRETE"
    o.nlp_solver_type = "SQP_RTI"
    o.hessian_approx = _HESSIAN[hessian]
    o.qp_solver = "PARTIAL_CONDENSING_HPIPM"
    o.qp_solver_cond_N = pb.n_steps
    mode, opts = HPIPM_AUTO[hessian] if cfg.solver.hpipm_mode == "auto" \
        else (cfg.solver.hpipm_mode, dict(cfg.solver.hpipm_options))
    opts = {**opts, **dict(cfg.solver.hpipm_options)}
    o.hpipm_mode = _HPIPM_MODE[mode]
    if "mu0" in opts:
        o.qp_solver_mu0 = float(opts["mu0"])
    for key in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp"):
        if key in opts:
            setattr(o, f"qp_solver_{key}", float(opts[key]))
    o.qp_solver_iter_max = int(cfg.solver.qp_max_iterations)
    o.qp_solver_warm_start = 0
    o.levenberg_marquardt = float(pb.regularization)
    o.regularize_method = regularize
    if reg_epsilon is not None:
        o.reg_epsilon = reg_epsilon
    # acados scales the stage costs by the interval length by default ([h, ..., h, 1]): ours
    # are summed unscaled beside the terminal cost
    o.cost_scaling = np.ones(pb.n_steps + 1)
    o.print_level = 0
    return ocp, pb


class AcadosRti:
    """acados' RTI of our problem, built once (code generated and compiled in `workdir`)."""

    def __init__(self, cfg, model, u_trim, hessian: str, workdir: Path,
                 regularize: str = "NO_REGULARIZE", reg_epsilon: float | None = None):
        from acados_template import AcadosOcpSolver

        self.cfg, self.hessian = cfg, hessian
        self.ocp, self.pb = build_ocp(cfg, model, u_trim, hessian, regularize=regularize,
                                      reg_epsilon=reg_epsilon)
        workdir = Path(workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        gen = getattr(self.ocp, "code_gen_options", self.ocp)   # acados >= 0.5.4: there
        gen.code_export_directory = str(workdir / "c_generated_code")
        t0 = time.perf_counter()
        cwd = os.getcwd()
        os.chdir(workdir)              # acados writes its build files next to the json
        try:
            self.solver = AcadosOcpSolver(self.ocp, verbose=False)
        finally:
            os.chdir(cwd)
        self.build_s = time.perf_counter() - t0
        self._bounds = None

    def set_stage_data(self, x_ref, d, v_lo, v_hi) -> None:
        """The step's reference (N+1, 12), d (6) and input bounds (N, 8), before preparing."""
        sv, pb = self.solver, self.pb
        for k in range(pb.n_steps):
            sv.cost_set(k, "yref", pb.yref(x_ref[k]))
        sv.cost_set(pb.n_steps, "yref", np.asarray(x_ref[pb.n_steps], float))
        sv.set_flat("p", np.tile(np.asarray(d, float), pb.n_steps + 1))
        if self._bounds is None or not (np.array_equal(self._bounds[0], v_lo)
                                        and np.array_equal(self._bounds[1], v_hi)):
            for k in range(pb.n_steps):
                sv.constraints_set(k, "lbu", np.asarray(v_lo[k], float))
                sv.constraints_set(k, "ubu", np.asarray(v_hi[k], float))
            self._bounds = (np.array(v_lo, float), np.array(v_hi, float))

    def set_init(self, s_traj, v_traj) -> None:
        self.solver.set_flat("x", np.asarray(s_traj, float).ravel())
        self.solver.set_flat("u", np.asarray(v_traj, float).ravel())

    def prepare(self) -> tuple[int, float, float]:
        """The preparation phase: (status, wall s, CPU s)."""
        sv = self.solver
        sv.options_set("rti_phase", 1)
        c0, t0 = time.thread_time(), time.perf_counter()
        status = sv.solve()
        t1, c1 = time.perf_counter(), time.thread_time()
        return status, t1 - t0, c1 - c0

    def feedback(self, s0) -> tuple[int, float, float]:
        """Embed s_0 and run the feedback phase: (status, wall s, CPU s)."""
        sv = self.solver
        s0 = np.asarray(s0, float)
        sv.constraints_set(0, "lbx", s0)
        sv.constraints_set(0, "ubx", s0)
        sv.options_set("rti_phase", 2)
        c0, t0 = time.thread_time(), time.perf_counter()
        status = sv.solve()
        t1, c1 = time.perf_counter(), time.thread_time()
        return status, t1 - t0, c1 - c0

    def solution(self) -> tuple[np.ndarray, np.ndarray]:
        """(s (N+1, 16), v (N, 8)) of the last solve."""
        pb = self.pb
        return (self.solver.get_flat("x").reshape(pb.n_steps + 1, pb.ns),
                self.solver.get_flat("u").reshape(pb.n_steps, pb.nv))

    def command(self, s, v) -> np.ndarray:
        """The plan's first input, physical [alpha (rad), zeta (%)], as our unpack gives it."""
        nx = self.pb.nx
        return np.concatenate([s[1, nx:nx + 4], 100.0 * v[0, 4:8]])


def _shift(s, v, h: float, dt: float, a_sent) -> tuple[np.ndarray, np.ndarray]:
    """A solution shifted by dt as the controller shifts its plan (controller._guess): states
    linearly interpolated at dt + k h (clamped at the end), inputs held (the one in force);
    s_0's tilt the command just sent."""
    N = v.shape[0]
    times = dt + h * np.arange(N + 1)
    q = np.clip(times / h, 0.0, N)
    i = np.minimum(q.astype(int), N - 1)
    f = (q - i)[:, None]
    s_new = s[i] * (1.0 - f) + s[i + 1] * f
    idx = np.minimum((times[:N] / h + 1e-9).astype(int), N - 1)
    v_new = v[idx].copy()
    s_new[0, 12:16] = a_sent
    return s_new, v_new


# --- recording a flight of ours ------------------------------------------------------------------

class Recorder:
    """Wraps a Controller's RTI solver to record what each solve was handed and returned, and
    each preparation's own time: per step, copies of the solve's arguments and of the bounds
    (the effectiveness observer changes them in place) and the linearisation point the step's
    preparation made (w, clipped to the bounds it had), a few microseconds outside the solver's
    own timing (inside the controller's step and period); `arrays` packs them. Both ways of
    preparing are recorded: `prepare` (at a guess) and `prepare_plan` (the compiled guess)."""

    def __init__(self, ctl):
        self.ctl = ctl
        self.rows: list[tuple] = []
        self.prep_s: list[float] = []
        self._pending = None           # the last preparation's linearisation point (w)
        solver = ctl.solver
        self._solve, self._prepare = solver.solve, solver.prepare
        solver.solve = self._rec_solve
        solver.prepare = self._rec_prepare
        if solver.prepares_plans:
            self._prepare_plan = solver.prepare_plan
            solver.prepare_plan = self._rec_prepare_plan

    def _rec_solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        o, c = self.ctl.solver.ocp, np.array
        w = self._pending
        if w is None:                  # not prepared: the solve linearises at its guess
            from trq_offboard.nmpc.base import plan_of
            guess = plan_of(guess)
            w = np.clip(o.pack(c(guess[1], float), c(guess[0], float),
                               c(u_prev, float)[0:4]), o.lbw, o.ubw)   # as rti.prepare
        self._pending = None
        row = [c(x0, float), c(x_ref, float), c(d, float), c(u_prev, float), w,
               o.lbw.copy(), o.ubw.copy()]
        out = self._solve(x0, x_ref, d, u_prev, guess, y0=y0)
        self.rows.append((*row, c(out[0][0], float), out[2].status, out[2].solve_time_s))
        return out

    def _prepared(self, out):
        solver = self.ctl.solver
        self._pending = solver._prepared.w.copy() if solver._prepared is not None else None
        self.prep_s.append(solver.last_prepare_s)
        return out

    def _rec_prepare(self, x_ref, d, u_prev, guess, y0=None):
        return self._prepared(self._prepare(x_ref, d, u_prev, guess, y0=y0))

    def _rec_prepare_plan(self, *args, **kwargs):
        return self._prepared(self._prepare_plan(*args, **kwargs))

    def arrays(self) -> dict:
        """The recording as arrays, one row a step (see `replay`)."""
        from trq_offboard.records import SolveStatus

        o = self.ctl.solver.ocp
        out = {k: [] for k in ("x0", "alpha_prev", "x_ref", "d", "v_lo", "v_hi", "guess_s",
                               "guess_v", "u0", "ok")}
        for x0, x_ref, d, u_prev, w, lbw, ubw, u_plan, status, _ in self.rows:
            a_prev = np.array(u_prev, float)[0:4]
            for key, val in (("x0", x0), ("alpha_prev", a_prev), ("x_ref", x_ref), ("d", d),
                             ("v_lo", lbw[o.v_index]), ("v_hi", ubw[o.v_index]),
                             ("guess_s", w[o.s_index]), ("guess_v", w[o.v_index]),
                             ("u0", u_plan),
                             ("ok", status is SolveStatus.OK)):
                out[key].append(np.array(val, float) if key != "ok" else val)
        arrays = {k: np.array(v) for k, v in out.items()}
        arrays["solver_prep_s"] = np.array(self.prep_s)
        arrays["solve_s"] = np.array([r[-1] for r in self.rows])
        arrays["u_trim"] = np.asarray(self.ctl.u_trim, float)
        return arrays

    def save(self, path: Path, **meta) -> None:
        np.savez(path, **self.arrays(), meta=json.dumps(meta))


# --- the replay ------------------------------------------------------------------------------------

class Replayer:
    """acados built once for a recorded flight, stepped through it pass after pass (`run`):
    the one-shot replay (`replay`) makes one pass; the bench's bracketing server
    (`serve`) one on each request, between the daemons' flights. Every pass after the
    first starts from acados' memory reset (its iterates and the QP's to zero, as built), so
    that each pass solves the same sequence."""

    def __init__(self, recording: Path, hessian: str, controller: str = "trq_nmpc_eso",
                 init: str = "shift", workdir: Path | None = None,
                 regularize: str = "NO_REGULARIZE", reg_epsilon: float | None = None):
        import trq_params

        from trq_offboard.config import load_controller
        from trq_offboard.model import PredictionModel

        ok, why = available()
        if not ok:
            raise RuntimeError(why)
        with np.load(recording) as f:       # read once (an npz reads an array at each access)
            self.rec = {k: f[k] for k in f.files}
        self.cfg = load_controller(trq_params.resolve("controller", controller))
        self.hessian, self.init, self.regularize = hessian, init, regularize
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="trq-acados-")
            workdir = Path(self._tmp.name)
        self.rti = AcadosRti(self.cfg, PredictionModel(self.cfg.vehicle), self.rec["u_trim"],
                             hessian, Path(workdir), regularize=regularize,
                             reg_epsilon=reg_epsilon)
        self.passes = 0

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def run(self, pace_s: float = 0.0, clock=time.perf_counter, sleep=time.sleep
            ) -> tuple[np.ndarray, np.ndarray]:
        """One pass through the recording: per step (prep wall, prep CPU, feedback wall,
        feedback CPU, acados' prep, acados' feedback, QP iterations, feedback status, 1 when
        the solution is finite) and the first commands (K, 8). `pace_s` > 0: each feedback
        starts pace_s after the previous one started (the module's docstring; `clock` and
        `sleep` the wall clock's)."""
        if not (pace_s >= 0.0 and math.isfinite(pace_s)):
            raise ValueError(f"pace {pace_s:g} s: expected a finite time >= 0")
        rti, rec = self.rti, self.rec
        due = None                            # when the next feedback may start (paced)
        if self.passes:
            rti.solver.reset()
        self.passes += 1
        pb, dt = rti.pb, self.cfg.control_dt_s
        K = rec["x0"].shape[0]
        rows = np.zeros((K, 9))
        u0 = np.zeros((K, 8))
        prev = None
        for k in range(K):
            if self.init == "ours" or prev is None:
                rti.set_init(rec["guess_s"][k], rec["guess_v"][k])
            else:
                rti.set_init(*_shift(prev[0], prev[1], pb.step_s, dt, rec["alpha_prev"][k]))
            rti.set_stage_data(rec["x_ref"][k], rec["d"][k], rec["v_lo"][k], rec["v_hi"][k])
            st_p, wp, cp = rti.prepare()
            tp = rti.solver.get_stats("time_preparation")
            s0 = np.concatenate([rec["x0"][k], rec["alpha_prev"][k]])
            if pace_s > 0.0:
                if due is not None and due > clock():
                    sleep(due - clock())
                due = clock() + pace_s
            st_f, wf, cf = rti.feedback(s0)
            tf = rti.solver.get_stats("time_feedback")
            qp_it = np.atleast_1d(rti.solver.get_stats("qp_iter"))
            s, v = rti.solution()
            finite = bool(np.all(np.isfinite(s)) and np.all(np.isfinite(v)))
            prev = (s, v) if finite else None
            u0[k] = rti.command(s, v)
            # a step fails in its feedback (the QP); the preparation returns the status acados
            # holds, the previous feedback's, so that a failure's next step would count again
            rows[k] = (wp, cp, wf, cf, tp, tf, float(qp_it[-1]) if qp_it.size else -1, st_f,
                       finite)
        return rows, u0

    def summary(self, rows: np.ndarray, u0: np.ndarray, split_s: float | None = None,
                pace_s: float = 0.0) -> dict:
        """A pass's figures (see the module's docstring). `split_s`: the first commands also
        compared apart before and after this time of the flight (step k at k control periods;
        the bench's fault). `pace_s`: the pass's pacing (`run`'s), reported as pace_ms."""
        rec, cfg, rti = self.rec, self.cfg, self.rti
        K = rows.shape[0]
        fb_status, nonfinite = rows[:, 7], rows[:, 8] == 0
        statuses: dict[str, int] = {}
        for st in fb_status[fb_status != 0]:
            key = f"feedback {int(st)}"
            statuses[key] = statuses.get(key, 0) + 1
        # a failed feedback counts once, a non-finite solution once more
        failures = int(np.count_nonzero(fb_status) + np.count_nonzero(nonfinite))
        ms = 1e3
        total = rows[:, 0] + rows[:, 2]
        total_cpu = rows[:, 1] + rows[:, 3]
        du_all = np.abs(u0 - rec["u0"])
        ok_ours = rec["ok"].astype(bool)
        med = lambda a: float(np.median(a) * ms)                   # noqa: E731
        p99 = lambda a: float(np.percentile(a, 99) * ms)           # noqa: E731
        t_s = np.arange(K) * cfg.control_dt_s
        parts = {"": np.ones(K, bool)}
        if split_s is not None:
            parts.update({"_before": t_s < split_s, "_after": t_s >= split_s})
        close = {}
        for tag, sel in parts.items():
            du = du_all[sel & ok_ours]
            if du.size:
                close.update({
                    f"du_tilt_deg_median{tag}": float(np.degrees(np.median(du[:, 0:4]))),
                    f"du_tilt_deg_max{tag}": float(np.degrees(du[:, 0:4].max())),
                    f"du_throttle_pct_median{tag}": float(np.median(du[:, 4:8])),
                    f"du_throttle_pct_max{tag}": float(du[:, 4:8].max())})
        first_fail = next((k for k in range(K) if fb_status[k] != 0), None)
        return dict(
            name=anchor_name(self.hessian, self.regularize), hessian=self.hessian,
            regularize=self.regularize,
            reg_epsilon=float(rti.ocp.solver_options.reg_epsilon),
            init=self.init, pace_ms=pace_s * 1e3, steps=int(K), failures=failures,
            build_s=rti.build_s,
            prep_median_ms=med(rows[:, 0]), prep_p99_ms=p99(rows[:, 0]),
            feedback_median_ms=med(rows[:, 2]), feedback_p99_ms=p99(rows[:, 2]),
            feedback_max_ms=float(rows[:, 2].max() * ms),
            total_median_ms=med(total), total_p99_ms=p99(total),
            # the same over the steps whose QP solved: the anchor's cost without its failures'
            total_median_solved_ms=(med(total[fb_status == 0]) if np.any(fb_status == 0)
                                    else math.nan),
            total_cpu_median_ms=med(total_cpu), total_cpu_p99_ms=p99(total_cpu),
            internal_prep_median_ms=med(rows[:, 4]),
            internal_feedback_median_ms=med(rows[:, 5]),
            internal_total_median_ms=med(rows[:, 4] + rows[:, 5]),
            qp_iterations_median=float(np.median(rows[:, 6])),
            qp_iterations_max=int(rows[:, 6].max()),
            **close, failure_statuses=statuses,
            first_failure_s=(math.nan if first_fail is None else float(t_s[first_fail])),
            **_ours_solver_step(rec, med, p99),
            acados=_describe(Path(os.environ["ACADOS_SOURCE_DIR"])))


def replay(recording: Path, hessian: str, controller: str = "trq_nmpc_eso",
           init: str = "shift", workdir: Path | None = None,
           split_s: float | None = None, regularize: str = "NO_REGULARIZE",
           reg_epsilon: float | None = None, pace_s: float = 0.0) -> dict:
    """acados' RTI through a recorded flight of ours: per-step times and first commands against
    ours (see the module's docstring), one pass of a `Replayer` (paced: `pace_s`)."""
    r = Replayer(recording, hessian, controller, init, workdir, regularize, reg_epsilon)
    try:
        return r.summary(*r.run(pace_s), split_s=split_s, pace_s=pace_s)
    finally:
        r.close()


def serve(replayer: Replayer, requests, answer, split_s: float | None = None) -> int:
    """The bench's bracketing server: one JSON line to `answer` when built ({"ready": true,
    "build_s"}), then for each line of `requests`, "pass" (or "pass PACE_MS": paced, the
    module's docstring): one pass through the recording and its figures (`Replayer.summary`
    with `split_s`, and the pass's number); "quit" or the end of `requests`: return the passes
    made. Another line, or a pace that is not a time >= 0, is answered {"error": ...} and the
    server goes on."""
    def say(obj: dict) -> None:
        answer.write(json.dumps(obj) + "\n")
        answer.flush()

    say({"ready": True, "build_s": replayer.rti.build_s, "name": anchor_name(
        replayer.hessian, replayer.regularize)})
    for line in requests:
        word, *rest = line.split() or [""]
        if word == "quit":
            break
        pace_s = _pace_of(rest[0]) if word == "pass" and len(rest) == 1 else 0.0
        if word != "pass" or len(rest) > 1 or pace_s is None:
            say({"error": f"unknown request {line.strip()[:40]!r}: expected pass, "
                          "pass PACE_MS (a time >= 0) or quit"})
            continue
        say({**replayer.summary(*replayer.run(pace_s), split_s=split_s, pace_s=pace_s),
             "pass": replayer.passes})
    return replayer.passes


def _pace_of(text: str) -> float | None:
    """A request's pace in ms as seconds, None if it is not a finite time >= 0."""
    try:
        ms = float(text)
    except ValueError:
        return None
    return ms * 1e-3 if math.isfinite(ms) and ms >= 0.0 else None


def anchor_name(hessian: str, regularize: str = "NO_REGULARIZE") -> str:
    """The anchor's name in the bench's tables: acados-rti-exact, acados-rti-gn, and the
    regularisation's method after it when there is one (acados-rti-exact-mirror)."""
    name = f"acados-rti-{'exact' if hessian == 'exact' else 'gn'}"
    return name if regularize == "NO_REGULARIZE" else f"{name}-{regularize.lower()}"


def _ours_solver_step(rec, med, p99) -> dict:
    """Our solver's own step from the recording: the feedback (SolveInfo.solve_time_s) of step
    k plus the solver's preparation that preceded it (RtiSolver.last_prepare_s; none before the
    first step, whose solve prepared itself), without the controller's work around them."""
    solve, prep = rec["solve_s"], rec["solver_prep_s"]
    if not solve.size:
        return {}
    before = np.concatenate([[0.0], prep[:solve.size - 1]])
    total = solve + before
    return dict(ours_solver_prep_median_ms=med(prep), ours_solver_total_median_ms=med(total),
                ours_solver_total_p99_ms=p99(total))


def main(argv=None) -> int:
    """Child process of trq-bench-nmpc --anchor acados: replay one recording, print JSON; with
    --serve, build once and answer the bench's requests on stdin (`serve`)."""
    ap = argparse.ArgumentParser(prog="python -m trq_lab.bench.acados_anchor",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--replay", type=Path, required=True, help="a recording (.npz) of a flight")
    ap.add_argument("--hessian", choices=sorted(_HESSIAN), default="exact")
    ap.add_argument("--controller", default="trq_nmpc_eso")
    ap.add_argument("--init", choices=("shift", "ours"), default="shift")
    ap.add_argument("--split-s", type=float, default=None,
                    help="compare the first commands also before and after this time")
    ap.add_argument("--regularize", choices=REGULARIZE_METHODS, default="NO_REGULARIZE",
                    help="acados' regularize_method (default NO_REGULARIZE, acados' own)")
    ap.add_argument("--reg-epsilon", type=float, default=None,
                    help="acados' reg_epsilon for the methods that read one (default: acados')")
    ap.add_argument("--pace-ms", type=float, default=0.0, metavar="MS",
                    help="each feedback MS after the previous one started, as a control loop "
                         "paces it (default 0: a tight loop)")
    ap.add_argument("--serve", action="store_true",
                    help="build once, then one pass through the recording for each line "
                         "'pass' on stdin, its figures a JSON line on stdout ('quit' ends)")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.pace_ms) and args.pace_ms >= 0.0):
        ap.error(f"--pace-ms {args.pace_ms:g}: expected a time >= 0")
    try:
        check_regularize(args.regularize, args.reg_epsilon)
    except ValueError as exc:
        ap.error(str(exc))
    ok, why = available()
    if not ok:
        print(why, file=sys.stderr)
        return 2
    if args.serve:
        # acados' C library prints its QP failures to file descriptor 1, buffered: the answers
        # keep the process's stdout to themselves and the library writes to stderr instead
        answer = os.fdopen(os.dup(1), "w")
        os.dup2(2, 1)
        replayer = Replayer(args.replay, args.hessian, args.controller, args.init,
                            regularize=args.regularize, reg_epsilon=args.reg_epsilon)
        try:
            serve(replayer, sys.stdin, answer, split_s=args.split_s)
        finally:
            replayer.close()
        return 0
    print(json.dumps(replay(args.replay, args.hessian, args.controller, args.init,
                            split_s=args.split_s, regularize=args.regularize,
                            reg_epsilon=args.reg_epsilon, pace_s=args.pace_ms * 1e-3)),
          flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
