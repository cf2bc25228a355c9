"""The controller core: observer + NMPC + allocation, one object per controller config.

    ctl = Controller.from_yaml("params/controller/trq_nmpc_eso.yaml")   # build once (~2 s)
    ctl.reset(t_s, state)                       # take over (ground or flying) without a jump
    cmd, info = ctl.step(t_s, state, applied, reference)   # once per control period
    ctl.prepare(reference)                      # after sending cmd: the RTI's preparation phase

`reference` is a reference.FlightReference (Reference, or ConstantReference for a fixed
target); the NMPC takes its grid at t_s + k h, k = 0..N.
`applied` is the ActuatorCommand the vehicle has been flying since the previous step (None:
the one this controller returned last).

Per step: (1) the observer (if any) is advanced one control period with the measurement and
the applied command and gives d; with motor_effectiveness, the motor effectiveness observer
(effectiveness.py) reads d as one motor's output deficit and estimates each motor's
effectiveness e: the NMPC then plans the effective throttles (e x command, bounded by
[e idle, e 100]; the command sent is the plan / e), from the motors' estimated outputs, with d
less the motors' share; (2) the NMPC is solved from the measured state with d held
over the horizon, warm-started from the previous plan shifted by the elapsed time (first step:
the allocation's hover trim, rolled out through the model); (3) on a solver failure the previous
plan shifted in time is flown while it lasts, then the allocation's hover command; (4) the
command is clipped to the actuator limits as a last line of defence (counted) and is always
finite. `step` never prints or sleeps, and reads no clock but the injected CPU clock `cpu_ns`
(default time.thread_time_ns) that times its parts for StepInfo.cpu (observer, effectiveness,
predictor, feedback) and `prepare` for `last_prepare_cpu_ns`: measurements only, never an input
of what is computed (the solver measures its own wall time).

`prepare` (optional, for solvers with a preparation phase such as the real-time iteration): called
after the command of `step` has been sent, it linearises the NMPC at the plan expected one control
period later, so that the next `step` only embeds the measured state and solves a QP. Without it
the solver prepares inside `step` (same result, longer latency).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

from trq_offboard.allocation import Allocator
from trq_offboard.config import ControllerConfig, load_controller
from trq_offboard.effectiveness import MotorEffectivenessObserver
from trq_offboard.eso import ExtendedStateObserver
from trq_offboard.model import PredictionModel
from trq_offboard.model.dynamics import NumpyFunction
from trq_offboard.nmpc.cache import compiled_many
from trq_offboard.nmpc.base import Solver
from trq_offboard.nmpc.factory import make_solver
from trq_offboard.reference import FlightReference
from trq_offboard.records import (
    ActuatorCommand,
    CommandSource,
    SolveInfo,
    SolveStatus,
    StateEstimate,
    StepInfo,
    StepTimes,
)
from trq_offboard.walk import WalkPath, run_walk, walk_function, walk_sizes

__all__ = ["Controller"]

PREDICT_STEP_S = 0.005        # RK4 step of the delay predictor
CHAIN_STEPS = 48              # steps of the compiled actuator lag chain per call
SENT_KEPT = 32                # commands remembered (many actuator time constants)


class CommandHistory:
    """The last `size` commands sent, oldest first: the stamp (s) of the state each answered and
    the command u (nu), in two NumPy arrays that the actuator walk reads whole every period.
    `times` and `commands` are views, valid until the next append."""

    def __init__(self, size: int, nu: int, items=()) -> None:
        self._t, self._u, self._n = np.empty(size), np.empty((size, nu)), 0
        for t, u in items:
            self.append(t, u)

    def append(self, t_s: float, u: np.ndarray) -> None:
        n, size = self._n, self._t.size
        if n == size:                               # full: drop the oldest
            self._t[:-1], self._u[:-1] = self._t[1:], self._u[1:]
            n -= 1
        self._t[n], self._u[n] = t_s, u
        self._n = n + 1

    @property
    def times(self) -> np.ndarray:
        return self._t[:self._n]

    @property
    def commands(self) -> np.ndarray:
        return self._u[:self._n]

    def __len__(self) -> int:
        return self._n


def _wrap(a):
    """Angle(s) (float or array) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _on_microseconds(t_s: float) -> float:
    """t_s on the microsecond grid, as a time formed from MAVLink's integer microseconds:
    (stamp_us - t0_us) * 1e-6 (trq_offboard/loop.py)."""
    return round(t_s * 1e6) * 1e-6


def _interp_rows(x: np.ndarray, h: float, times: np.ndarray) -> np.ndarray:
    """Rows of x (n+1, m), sampled every h seconds from 0, linearly interpolated at `times`
    (clamped to [0, n h], as np.interp does), all columns at once: (len(times), m)."""
    return _interp_with(x, _interp_weights(x.shape[0] - 1, h, times))


def _interp_weights(n: int, h: float, times: np.ndarray):
    """`_interp_rows`' rows and weights for n + 1 rows: (i, i + 1, 1 - f, f)."""
    s = np.clip(times / h, 0.0, n)
    i = np.minimum(s.astype(int), n - 1)
    f = (s - i)[:, None]
    return i, i + 1, 1.0 - f, f


def _interp_with(x: np.ndarray, w) -> np.ndarray:
    i, i1, g, f = w
    return x[i] * g + x[i1] * f


class Controller:
    def __init__(self, cfg: ControllerConfig, solver: Solver | None = None,
                 cpu_ns: Callable[[], int] = time.thread_time_ns) -> None:
        self.cfg = cfg
        self.cpu_ns = cpu_ns                 # the parts' CPU clock (a measurement only)
        self.last_prepare_cpu_ns = 0
        vm = cfg.vehicle
        self.model = PredictionModel(vm)
        self.allocator = Allocator(vm)
        self.hover_command = self.allocator.hover()
        self.u_trim = self.allocator.command_vector(self.hover_command)
        self.solver = solver if solver is not None else make_solver(cfg, self.model, self.u_trim)
        self.eso = (ExtendedStateObserver(cfg.eso, cfg.control_dt_s,
                                          codegen=cfg.solver.codegen == "auto")
                    if cfg.eso is not None else None)
        self.N, self.h = cfg.horizon_steps, cfg.step_s
        self._rollout = self.model.discrete(self.h, 1)
        self._step_dt = self.model.discrete_dt()
        # auto: predict, and through the actuator lags, once the delay reaches one control
        # period; below it the observer's delayed b0 alone does better (nmpc.yaml: measured)
        predict = cfg.predicts_delay
        self.delay_s = cfg.applied_delay_s if predict else 0.0
        # the motor effectiveness observer (motor_effectiveness): reads the observer's d as motor
        # outputs; it needs the actuators' lags (its motor model is the lag)
        self.effectiveness = (MotorEffectivenessObserver(cfg.effectiveness,
                                                         vm.motor_time_constant_s,
                                                         cfg.control_dt_s,
                                                         codegen=cfg.solver.codegen == "auto")
                              if cfg.effectiveness is not None and self.eso is not None else None)
        self._nt = 4 if self.model.tilting else 0         # where the throttles start in u
        self._scale = np.ones(self.model.nu)              # plan (effective) = scale x command
        # auto: also whenever the NMPC carries the lag states, which must not meet an observer
        # whose b0 ignores the lags (measured: docs/decisions/2026-12-02-figures-from-comments.md);
        # always with the effectiveness observer
        self._lagged = self.effectiveness is not None or cfg.lagged_actuators == "on" or (
            cfg.lagged_actuators == "auto"
            and ((predict and self.delay_s > 0.0) or cfg.nmpc_actuator_states))
        tilts = 4 if self.model.tilting else 0
        self._tau = np.array([vm.servo_time_constant_s] * tilts + [vm.motor_time_constant_s] * 4)
        self._rate_limit = np.array([vm.servo_rate_limit_rad_s] * tilts
                                    + [vm.motor_rate_limit_pct_s] * 4)
        self._gains: dict[float, np.ndarray] = {}
        self._shifts: dict[float, tuple] = {}     # _shift's, by elapsed time
        # the controller's own functions, compiled (nmpc/cache.py; in parallel, one per core):
        # the lag chain; the observer's b0; the walk's layout, lag chain and the observer's b0
        # sum in one function (walk.py), in two sizes: a regular period's (the pieces of the
        # round trip delay and one more), then a larger one for late or lost samples (the
        # NumPy layout serves what fits neither); the motors' deficit and the regular period
        # of _effective (one command in effect) in one
        fns = {"chain": self._chain_function(), "b0": self.model.b0.fn}
        if self._lagged:
            for i, (pieces, substeps) in enumerate(walk_sizes(cfg.applied_delay_s,
                                                              cfg.control_dt_s)):
                fns[f"walk{i}"] = walk_function(self._tau, self._rate_limit, self.model.b0.fn,
                                                SENT_KEPT, PREDICT_STEP_S, pieces, substeps)
        if self.effectiveness is not None:
            fns["deficit"] = self._deficit_function()
            fns["effective"] = self._effective_function()
        built = {name: NumpyFunction(fn) for name, (fn, _) in
                 zip(fns, compiled_many(list(fns.values()), cfg.solver.codegen == "auto"))}
        self._chain_fn, self._b0_fn = built["chain"], built["b0"]
        self._walk_fns = [built[name] for name in built if name.startswith("walk")]
        self._deficit_fn = built.get("deficit")
        self._effective_fn = built.get("effective")
        # the NMPC's stage carries the actuators' lag states (actuator_states): its plan starts
        # from the actuators' outputs predicted for t + delay (self._y_act)
        self._act_states = bool(self.solver.ocp.n_lag)
        self._y_act: np.ndarray | None = None
        self._u_lo = np.array(([vm.tilt_min_rad] * 4 if self.model.tilting else [])
                              + [vm.idle_pct] * 4)
        self._u_hi = np.array(([vm.tilt_max_rad] * 4 if self.model.tilting else []) + [100.0] * 4)
        self._plan: tuple[np.ndarray, np.ndarray] | None = None
        self._plan_t = 0.0
        self._last_t: float | None = None
        self._last_d = np.zeros(6)
        self._last_u = self.u_trim.copy()
        self._prev_u = self.u_trim.copy()
        self._sent = CommandHistory(SENT_KEPT, self.model.nu)
        self._grid_key: tuple | None = None     # (reference, t) of the last reference grid
        self._grid_val: tuple | None = None
        self.clip_count = 0
        self.failures = 0

    @classmethod
    def from_yaml(cls, path: Path | str) -> "Controller":
        return cls(load_controller(path))

    def solver_line(self) -> str:
        """What solves this controller's NMPC, for the log's header: the solver's own account
        (its describe(): the QP path and the libhpipm)."""
        return self.solver.describe()

    # --- lifecycle ------------------------------------------------------------------------------
    def reset(self, t_s: float, state: StateEstimate,
              applied: ActuatorCommand | None = None) -> None:
        """Initialise observer and plan from the measured state (and the command being flown,
        default the hover trim), so the controller takes over without a jump."""
        x = state.as_vector()
        self._last_u = (self.allocator.command_vector(applied) if applied is not None
                        else self.u_trim.copy())
        self._last_u = np.clip(self._last_u, self._u_lo, self._u_hi)
        self._prev_u = self._last_u.copy()
        self._sent = CommandHistory(SENT_KEPT, self.model.nu, [(float(t_s), self._last_u)])
        if self.eso is not None:
            eta_dot = np.asarray(self._euler_rate(x)).ravel()
            self.eso.reset(self.eso.measurement(x), np.concatenate([x[3:6], eta_dot]))
        self._scale = np.ones(self.model.nu)
        if self.effectiveness is not None:
            self.effectiveness.reset(self._last_u[self._nt:])
            self.solver.ocp.set_throttle_scale(np.ones(4))
        self._plan = None
        self._y_act = None
        self._last_t = float(t_s)
        self._last_d = np.zeros(6)
        self.solver.discard()
        self.clip_count = 0
        self.failures = 0

    def _b0(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The observer's b0(u): the nominal model's accelerations under u (9: NED, Euler,
        body angular; the observer picks its channels' with b0_of)."""
        return self._b0_fn(x, u)

    def _b0_delayed(self, x: np.ndarray, t0: float, t1: float, path=None) -> np.ndarray:
        """b0 averaged over [t0, t1] with each command acting applied_delay_s after it was sent
        (the time of the state it answered): the commands that were really in effect."""
        if isinstance(path, WalkPath):             # the compiled walk's sum, if for these
            got = path.b0_over(x, t0, t1)
            if got is not None:
                return got / (t1 - t0)
        total = np.zeros(9)
        if self._lagged:
            for a, b, y in (path if path is not None else self._actuator_path(t0, t1)):
                if t0 < 0.5 * (a + b) < t1:        # steps never straddle t0 or t1
                    total += (b - a) * self._b0(x, y)
            return total / (t1 - t0)
        if self.cfg.applied_delay_s <= 0.0 or not len(self._sent):
            return self._b0(x, self._last_u)
        for lo, hi, u in self._in_effect(t0, t1):
            total += (hi - lo) * self._b0(x, u)
        return total / (t1 - t0)

    def _in_effect(self, t0: float, t1: float) -> list[tuple[float, float, np.ndarray]]:
        """The commands acting over [t0, t1] as (start, end, u) segments: each command acts
        from the stamp of the state it answered plus applied_delay_s until the next one does;
        before the oldest remembered command, the oldest one."""
        sent = self._sent
        if not len(sent):
            return [(t0, t1, self._last_u)] if t1 > t0 else []
        starts, cmds = sent.times + self.cfg.applied_delay_s, sent.commands
        segs = []
        if starts[0] > t0:
            segs.append((t0, min(float(starts[0]), t1), cmds[0]))
        if t1 <= t0:                    # an empty interval: no command's piece is in it
            return segs
        if float(starts.max()) <= t0:   # every command acts from t0 or before: the newest,
            return [(t0, t1, cmds[-1])]  # from max(start, t0) = t0 to min(inf, t1) = t1
        # each command from its start to the next one's (the last one on), within [t0, t1]
        lo = np.maximum(starts, t0).tolist()
        hi = np.minimum(np.append(starts[1:], math.inf), t1).tolist()
        for i in np.flatnonzero(np.greater(hi, lo)).tolist():
            segs.append((lo[i], hi[i], cmds[i]))
        return segs

    def _actuator_path(self, t0: float, t1: float, cut: float | None = None):
        """The actuators over [t0, t1] as (a, b, y_mid) steps of at most PREDICT_STEP_S: the
        commands in effect (each from its state's stamp + applied_delay_s) through the
        actuators' first-order lags and rate limits (vehicle file: motor and servo time
        constants), y_mid at each step's midpoint. Their state at t0 is rebuilt from the
        remembered commands (32 periods: many time constants). `cut`: a time in (t0, t1) that
        no step straddles (one path serves the observer before it and the predictor after
        it)."""
        return self._actuator_walk(t0, t1, cut)[0]

    def _actuator_walk(self, t0: float, t1: float, cut: float | None = None,
                       x: np.ndarray | None = None):
        """(_actuator_path(t0, t1, cut), the actuators' outputs at t1, at `cut` (in [t0, t1];
        None without one)). The commands in effect (each from its state's stamp +
        applied_delay_s until the next one's, the oldest remembered one's output held before
        it) are laid out as lag steps: one for each piece of a command before t0 (nothing
        recorded there), steps of at most PREDICT_STEP_S from t0 on, none straddling t0 or
        `cut`; the lag chain through them is one call of a compiled function (`_chain`). The
        history before t0 is laid out with NumPy (the same differences of the same floats as
        step by step). The compiled walk (walk.py) does all of it in one call when the layout
        fits it (its path then also carries the observer's b0 sum for the state `x`)."""
        sent = self._sent
        if len(sent):
            for fn in self._walk_fns:
                got = run_walk(fn, sent.times, sent.commands, self.cfg.applied_delay_s,
                               t0, t1, cut, x)
                if got is not None:
                    return got
        if len(sent):
            starts = sent.times + self.cfg.applied_delay_s
            cmds = sent.commands
            # the oldest command's output held before it acts, then each command's piece
            lo = np.concatenate(([-math.inf], starts))
            hi = np.minimum(np.append(starts, math.inf), t1)
            which = np.concatenate(([0], np.arange(len(sent))))
        else:
            cmds = self._last_u[None, :]
            lo, hi, which = np.array([-math.inf]), np.array([t1]), np.array([0])
        keep = hi > lo
        y0 = cmds[0]
        # before t0: one step per piece, [lo, min(hi, t0)] (none before the oldest command)
        hist = keep & np.isfinite(lo) & (lo < t0)
        hist_b = np.minimum(hi[hist], t0)
        hist_h = hist_b - lo[hist]
        n_hist = int(hist_h.size)
        cut_at = n_hist - 1 if cut is not None and n_hist and hist_b[-1] == cut else None
        # from t0 on: steps of at most PREDICT_STEP_S, cut at `cut`
        rec_h, rec_idx, rec_ab = [], [], []
        for i in np.flatnonzero(keep & (hi > t0)):
            a0, b0 = max(float(lo[i]), t0), float(hi[i])
            cuts = [a0] + ([cut] if cut is not None and a0 < cut < b0 else []) + [b0]
            for a, b in zip(cuts[:-1], cuts[1:]):
                if b <= a:
                    continue
                n = max(1, math.ceil((b - a) / PREDICT_STEP_S - 1e-9))
                h = (b - a) / n
                for k in range(n):
                    rec_h.append(h)
                    rec_idx.append(which[i])
                    rec_ab.append((a + k * h, b if k == n - 1 else a + (k + 1) * h))
                if cut is not None and b == cut:
                    cut_at = n_hist + len(rec_h) - 1
        hs = np.concatenate((hist_h, rec_h))
        idx = np.concatenate((which[hist], np.array(rec_idx, int)))
        ys, mids = self._chain(y0, cmds[idx], hs)
        path = [(a, b, mids[n_hist + k]) for k, (a, b) in enumerate(rec_ab)]
        y = ys[-1].copy() if hs.size else y0.copy()
        y_cut = None if cut is None else (y.copy() if cut_at is None else ys[cut_at].copy())
        return path, y, y_cut

    def _chain(self, y0: np.ndarray, us: np.ndarray, hs: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """The actuators from y0 through the steps (commands us (n, m), lengths hs (n)):
        (outputs after each step, the lag's midpoint of each, `_lag(y, u, h / 2)`), as `_lag`
        step by step would give them, in chunks of CHAIN_STEPS steps through the compiled
        chain (its inputs written in place)."""
        m, K, n = self.model.nu, CHAIN_STEPS, len(hs)
        ys, mids = np.empty((n, m)), np.empty((n, m))
        fn = self._chain_fn
        y_in, u_in, h_in = fn.args
        u_in, h_in = u_in.reshape(K, m), h_in.reshape(K, 2)   # (m, K) column-major
        out_y, out_mid = (r.reshape(K, m) for r in fn.results)
        y_in[:] = y0
        for s0 in range(0, n, K):
            k = min(K, n - s0)
            u_in[:k] = us[s0:s0 + k]
            h_in[:k, 0] = hs[s0:s0 + k]
            h_in[:k, 1] = 0.5 * h_in[:k, 0]
            h_in[k:, 0] = -1.0      # inactive steps
            fn.evaluate()
            ys[s0:s0 + k] = out_y[:k]
            mids[s0:s0 + k] = out_mid[:k]
            y_in[:] = ys[s0 + k - 1]
        return ys, mids

    def _chain_function(self) -> ca.Function:
        """The lag chain of `_chain` as one CasADi function (generated as C and compiled
        once): (y0 (m), u (m x K), [h; h/2] (2 x K)) -> (outputs after each step, midpoints)
        (m x K each); a step with h < 0 leaves y as it is. Each step is `_lag`'s
        arithmetic in the same order, its gain `_lag_gain`'s: 1 - exp(-h / T) as -expm1(-h / T)
        (libm's expm1), 1 where T = 0."""
        m, K = self.model.nu, CHAIN_STEPS
        y0 = ca.SX.sym("y0", m)
        U = ca.SX.sym("u", m, K)
        H = ca.SX.sym("h", 2, K)
        rate = ca.DM(self._rate_limit)
        lagged = [tau > 0.0 for tau in self._tau]
        tau = ca.DM(np.maximum(self._tau, 1e-12))

        def gain(h):
            g = -ca.expm1(-h / tau)
            return ca.vertcat(*[g[i] if lagged[i] else ca.SX(1.0) for i in range(m)])

        y, outs, mids = y0, [], []
        for k in range(K):
            u = U[:, k]
            lim_m = rate * H[1, k]
            mids.append(y + ca.fmin(ca.fmax(gain(H[1, k]) * (u - y), -lim_m), lim_m))
            lim = rate * H[0, k]
            y1 = y + ca.fmin(ca.fmax(gain(H[0, k]) * (u - y), -lim), lim)
            y = ca.if_else(H[0, k] >= 0, y1, y)
            outs.append(y)
        return ca.Function(f"actuator_chain_expm1_{m}_{K}", [y0, U, H],
                           [ca.horzcat(*outs), ca.horzcat(*mids)])

    def _walk_from(self, y0: np.ndarray, t0: float, t1: float, scale: np.ndarray):
        """(path, outputs at t1) of the actuators from y0 at t0 under the commands in effect
        over [t0, t1], each scaled by `scale` (the motors' effectiveness: the effective
        throttle), as _actuator_path's steps."""
        y, path = np.asarray(y0, float).copy(), []
        for lo, hi, u in self._in_effect(t0, t1):
            y = self._walk_segment(y, u * scale, lo, hi, path)
        return path, y

    def _walk_segment(self, y: np.ndarray, u: np.ndarray, a: float, b: float,
                      path: list | None) -> np.ndarray:
        """The actuators y after [a, b] under the command u: steps of at most PREDICT_STEP_S,
        each appended to `path` as (start, end, y_mid); None: one step, nothing recorded (the
        history before the path starts)."""
        n = max(1, math.ceil((b - a) / PREDICT_STEP_S - 1e-9)) if path is not None else 1
        h = (b - a) / n
        for i in range(n):
            if path is not None:
                end = b if i == n - 1 else a + (i + 1) * h
                path.append((a + i * h, end, self._lag(y, u, 0.5 * h)))
            y = self._lag(y, u, h)
        return y

    def _predict(self, x: np.ndarray, t0: float, t1: float, d: np.ndarray,
                 path=None) -> np.ndarray:
        """The state at t1 predicted from the one measured at t0: the delay compensation of a
        link whose round trip is applied_delay_s (a Smith predictor's role). The model (RK4)
        is driven by the commands in flight, sent but not yet acting when x was measured
        (through the actuators' lags with lagged_actuators), with the disturbance estimate d
        held."""
        xk = x
        if self._lagged:
            for a, b, y in (path if path is not None else self._actuator_path(t0, t1)):
                if t0 < 0.5 * (a + b) < t1:        # steps never straddle t0 or t1
                    xk = self._step_dt(xk, y, d, b - a)
        else:
            for lo, hi, u in self._in_effect(t0, t1):
                n = max(1, math.ceil((hi - lo) / PREDICT_STEP_S - 1e-9))
                for _ in range(n):
                    xk = self._step_dt(xk, u, d, (hi - lo) / n)
        xk = np.asarray(xk).ravel()
        return xk if np.all(np.isfinite(xk)) else x

    def _lag(self, y: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """The actuators (first-order lag, rate limit) after dt towards the command u."""
        step = self._lag_gain(dt) * (u - y)
        lim = self._rate_limit * dt
        return y + np.clip(step, -lim, lim)

    def _lag_gain(self, dt: float) -> np.ndarray:
        gain = self._gains.get(dt)           # the same few step lengths come back every period
        if gain is None:
            # libm's expm1 (math's, as the compiled chain's): NumPy's own may differ in the
            # last bit (its SIMD loops); cached, so once per step length
            gain = np.array([-math.expm1(-dt / t) if t > 0.0 else 1.0 for t in self._tau])
            if len(self._gains) < 256:
                self._gains[dt] = gain
        return gain

    def _euler_rate(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.model.f(x, self._last_u, np.zeros(6))).ravel()[6:9]

    # --- one control step -----------------------------------------------------------------------
    def step(self, t_s: float, state: StateEstimate, applied: ActuatorCommand | None,
             reference: FlightReference) -> tuple[ActuatorCommand, StepInfo]:
        clock = self.cpu_ns
        c0 = clock()
        if self._last_t is None:
            self.reset(t_s, state, applied)
        x = state.as_vector()
        if not np.all(np.isfinite(x)):
            return self._emergency(t_s, "non-finite state", c0)
        # the input that acted since the last step: the previous command, or what the vehicle
        # reports it produced (applied_input in the controller file)
        u_applied = (np.clip(self.allocator.command_vector(applied), self._u_lo, self._u_hi)
                     if applied is not None and self.cfg.applied_input == "outputs"
                     else self._last_u)
        d = np.zeros(6)
        d_obs = d                               # the observer's own estimate (logged)
        out_err = 0.0
        # the actuators through their lags from the last step to when this command acts: one
        # path for the observer (before t_s) and the predictor (after it)
        t_act = t_s + self.delay_s
        path, y_act, y_now = None, None, None
        t_prev = self._last_t
        if self._lagged:
            # with the effectiveness observer the predictor's part (after t_s) is walked in
            # effective throttles by _effective: the healthy walk stops at t_s
            t_end = t_s if self.effectiveness is not None else t_act
            path, y_act, y_now = self._actuator_walk(min(self._last_t, t_s), t_end, t_s, x)
        elif self._act_states:
            y_act = self._actuator_walk(t_act, t_act)[1]
        if self.eso is not None:
            y = self.eso.measurement(x)
            if t_s > self._last_t:
                dt = t_s - self._last_t         # the true gap: samples can be lost or skipped
                if self.cfg.applied_input == "outputs" and applied is not None:
                    b0 = self._b0(x, u_applied)
                else:
                    b0 = self._b0_delayed(x, self._last_t, t_s, path)
                self.eso.update(y, self.eso.b0_of(b0), dt)
            d = d_obs = self.eso.disturbance(x[6:9])
            out_err = self.eso.output_error(y)
        c1 = clock()
        if self.eso is not None and self.effectiveness is not None:
            d, path, y_act = self._effective(x, d, y_now, t_prev, t_s, t_act)
        c2 = clock()
        self._last_t = float(t_s)
        self._last_d = d

        # the command computed now acts from t_act: plan from the state predicted for then
        x0 = self._predict(x, t_s, t_act, d, path) if self.delay_s > 0.0 else x
        c3 = clock()
        x_ref = self._reference_states(t_act, x0, reference)

        def guess():           # a prepared real-time iteration needs it only to fail with
            return self._guess(t_act, x0, d)
        if self._act_states:
            self._y_act = y_act
            u_plan, x_plan, info = self.solver.solve(x0, x_ref, d, u_applied, guess, y0=y_act)
        else:
            u_plan, x_plan, info = self.solver.solve(x0, x_ref, d, u_applied, guess)
        if info.status is SolveStatus.OK and np.all(np.isfinite(u_plan)) \
                and np.all(np.isfinite(x_plan)):
            self._plan, self._plan_t = (u_plan, x_plan), t_act
            u, source = u_plan[0] / self._scale, CommandSource.NMPC
        else:
            self.failures += 1
            if info.status is SolveStatus.OK:      # finite-status but non-finite plan
                info = SolveInfo(SolveStatus.FAILED, info.iterations, info.solve_time_s,
                                 float("nan"), "non-finite plan")
            u, source = self._fallback(t_act)
        return self._finish(u, source, info, d_obs, out_err, (c0, c1, c2, c3))

    def _motor_deficit(self, x: np.ndarray, d: np.ndarray, y_nom: np.ndarray) -> np.ndarray:
        """The motors' outputs less their healthy ones y_nom (4, throttle %) that explain the
        disturbance d: one motor at a time, the one whose pattern (the model's sensitivity of
        the vertical, roll and pitch accelerations to its throttle) explains most of d[2:5]
        with a deficit; the others 0. One call of the compiled `_deficit_function`."""
        return self._deficit_fn(x, d, y_nom)

    def _deficit_function(self) -> ca.Function:
        """`_motor_deficit` as one CasADi function (x, d, y_nom) -> dz (generated as C and
        compiled once): each motor's least-squares deficit alone and its share of |r|^2
        (r = d[2:5]), the first motor with the largest share (np.argmax's), and for it, if it
        explains some of r with a deficit, Gauss-Newton on |A(y + delta) - A(y) - r| (the
        thrust and torque curves are quadratic in the throttle: the change A is the mean of the
        two end slopes times delta, exactly) from the tangent's estimate, 3 steps (quadratic
        convergence), clamped to a deficit. Every motor's candidate is computed and the chosen
        one selected: the same operations in the same order as the plain-float specification
        that a test (test_ctrl_effectiveness.py) holds it to."""
        nt, nu = self._nt, self.model.nu
        jac_fn = self.model.motor_jacobian.fn
        x, d, y = ca.SX.sym("x", 12), ca.SX.sym("d", 6), ca.SX.sym("y_nom", nu)
        r = d[2:5]
        jac = jac_fn(x, y)[0:3, :]

        def dot3(a, b):
            return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]

        num = [dot3(jac[:, j], r) for j in range(4)]
        den = [ca.fmax(dot3(jac[:, j], jac[:, j]), 1e-12) for j in range(4)]
        fit = [ca.if_else(num[j] < 0.0, num[j] * num[j] / den[j], -1.0) for j in range(4)]
        deficit = []
        for j in range(4):
            delta, col0 = num[j] / den[j], jac[:, j]
            for _ in range(3):
                u_end = ca.vertcat(y[:nt + j], y[nt + j] + delta, y[nt + j + 1:])
                col1 = jac_fn(x, u_end)[0:3, j]
                rho = 0.5 * (col0 + col1) * delta - r
                delta = delta - dot3(col1, rho) / ca.fmax(dot3(col1, col1), 1e-12)
            deficit.append(ca.fmin(0.0, delta))
        best, pick = fit[0], ca.SX(0)
        for j in range(1, 4):                          # the first of the largest (np.argmax)
            better = fit[j] > best
            best, pick = ca.if_else(better, fit[j], best), ca.if_else(better, j, pick)
        dz = ca.vertcat(*[ca.if_else(ca.logic_and(pick == j, best > 0.0), deficit[j], 0.0)
                          for j in range(4)])
        return ca.Function(f"motor_deficit_{nu}", [x, d, y], [dz], ["x", "d", "y_nom"], ["dz"])

    def _effective_function(self) -> ca.Function:
        """`_effective` over a period with one command in effect, as one CasADi function of
        (x, d, y_nom, the effectiveness observer's y, e and last measured outputs, the
        command's throttles c, [dur, 0, dt, n]) -> (y, e, y_meas, d less the motors' share):
        the deficit, the observer's piece and b0(y_true) - b0(y_nom) composed symbolically,
        each the same operations as its own compiled function in `_effective`'s order."""
        nt, nu = self._nt, self.model.nu
        x, d, y_nom = ca.SX.sym("x", 12), ca.SX.sym("d", 6), ca.SX.sym("y_nom", nu)
        y, e, y0, c = (ca.SX.sym(name, 4) for name in ("y", "e", "y0", "c"))
        p = ca.SX.sym("p", 4)
        dz = self._deficit_function()(x, d, y_nom)
        y_meas = y_nom[nt:] + dz
        y1, e1, _ = self.effectiveness.piece_function()(y, e, y0, y_meas, c, p)
        y_true = ca.vertcat(y_nom[:nt], y1)
        b0 = self.model.b0.fn
        share = b0(x, y_true) - b0(x, y_nom)
        d1 = d - share[[0, 1, 2, 6, 7, 8]]
        return ca.Function(f"effective_step_{nu}_{self.effectiveness.cfg.substeps}",
                           [x, d, y_nom, y, e, y0, c, p], [y1, e1, y_meas, d1],
                           ["x", "d", "y_nom", "y", "e", "y_meas_prev", "c", "p"],
                           ["y_next", "e_next", "y_meas", "d_less_share"])

    def _effective(self, x, d, y_nom, t0, t1, t_act):
        """With the motor effectiveness observer: advance it over [t0, t1] and return (d less
        the motors' share, the predictor's actuator path over [t1, t_act] and the actuators'
        outputs at t_act, both in effective throttles). y_nom: the actuators' outputs at t1 if
        the motors were healthy (the observer's b0 flies those)."""
        nt, eff = self._nt, self.effectiveness
        segs = self._in_effect(t0, t1) if t1 > t0 else []
        n = eff.piece_steps(segs[0][1] - segs[0][0]) if len(segs) == 1 else 0
        if n and self._effective_fn is not None:         # one command in effect: one call
            lo, hi, u = segs[0]
            y, e, y_meas, d = self._effective_fn.outputs(
                x, d, y_nom, eff.y, eff.e, eff._y_meas_prev, u[nt:], (hi - lo, 0.0, t1 - t0, n))
            eff.advance(y, e, y_meas)
            return self._effective_end(e, y_nom, d, t1, t_act)
        dz = self._motor_deficit(x, d, y_nom)
        if t1 > t0:
            e = eff.update(y_nom[nt:] + dz, [(hi - lo, u[nt:]) for lo, hi, u in segs], t1 - t0)
        else:
            e = eff.e.copy()
        y_true = y_nom.copy()
        y_true[nt:] = eff.y
        share = self._b0(x, y_true) - self._b0(x, y_nom)
        return self._effective_end(e, y_nom, d - share[[0, 1, 2, 6, 7, 8]], t1, t_act)

    def _effective_end(self, e, y_nom, d, t1, t_act):
        """`_effective`'s result once the observer has its e and outputs: the plan's throttle
        scale and bounds, and the predictor's walk from the estimated outputs."""
        nt = self._nt
        self._scale = np.ones(self.model.nu)
        self._scale[nt:] = e
        self.solver.ocp.set_throttle_scale(e)
        y_true = y_nom.copy()
        y_true[nt:] = self.effectiveness.y
        path, y_act = self._walk_from(y_true, t1, t_act, self._scale)
        return d, path, y_act

    def prepare(self, reference: FlightReference) -> None:
        """Preparation phase for the next step (t + one control period): the solver linearises
        at the current plan shifted by one period, with the current disturbance estimate. A
        no-op for solvers without one and before the first plan."""
        c0 = self.cpu_ns()
        try:
            self._prepare(reference)
        finally:
            self.last_prepare_cpu_ns = self.cpu_ns() - c0

    def _prepare(self, reference: FlightReference) -> None:
        if not self.solver.prepares or self._plan is None or self._last_t is None:
            return
        # when the next step's command acts: the next state's time formed as the flight loop
        # forms a state's (whole microseconds times 1e-6), so that the next step, one period
        # on, finds this reference grid and this preparation's reference as its own
        t_next = _on_microseconds(self._last_t + self.cfg.control_dt_s) + self.delay_s
        elapsed = t_next - self._plan_t
        if elapsed >= self.N * self.h:
            return
        # the plan's states from t_next on: the guess's, its first row the predicted state
        xs = _interp_with(self._plan[1], self._shift(elapsed)[1])
        x_pred = xs[0].copy()
        x_ref = self._reference_states(t_next, x_pred, reference)
        guess = self._guess(t_next, x_pred, self._last_d, xs)
        if self._act_states and self._y_act is not None:
            # the actuators one period on, under the command just sent (it acts from t_act)
            y_next = self._lag(self._y_act, self._last_u * self._scale, self.cfg.control_dt_s)
            self.solver.prepare(x_ref, self._last_d, self._last_u, guess, y0=y_next)
        else:
            self.solver.prepare(x_ref, self._last_d, self._last_u, guess)

    # --- helpers --------------------------------------------------------------------------------
    def _reference_states(self, t_s: float, x: np.ndarray,
                          reference: FlightReference) -> np.ndarray:
        """The reference states of the horizon from t_s (N+1, 12), the yaw unwrapped next to
        x's. A reference's grid is a pure function of time: the same object asked for the same
        t gives the same grid."""
        xr = np.zeros((self.N + 1, 12))
        yaw = x[8]
        # the preparation samples the time the next step then asks for (when the two floats
        # agree): the last grid kept
        key = self._grid_key
        if key is not None and key[0] is reference and key[1] == t_s:
            pv, yaw_ref = self._grid_val
        else:
            pv, yaw_ref = reference.grid(t_s, self.h, self.N + 1)
            self._grid_key, self._grid_val = (reference, t_s), (pv, yaw_ref)
        xr[:, 0:6] = pv
        xr[:, 8] = yaw + _wrap(yaw_ref - yaw)
        return xr

    def _guess(self, t_s: float, x: np.ndarray, d: np.ndarray, xs: np.ndarray | None = None):
        """The plan (u, x) shifted to t_s, x its first state (the yaw kept next to x's), or
        the hover trim rolled out from x without a plan (or past its end). `xs`: the plan's
        states interpolated at t_s + k h, when the caller has them."""
        N, h = self.N, self.h
        if self._plan is not None:
            u_old, x_old = self._plan
            elapsed = t_s - self._plan_t
            if elapsed < N * h:
                idx, weights = self._shift(elapsed)
                u = u_old[idx]
                xg = _interp_with(x_old, weights) if xs is None else xs
                xg[:, 8] += x[8] - xg[0, 8]          # keep yaw next to the measured one
                xg[0] = x
                return u, xg
        u = np.tile(self.u_trim, (N, 1))
        xs = [x]
        for k in range(N):
            nxt = np.asarray(self._rollout(xs[-1], u[k], d)).ravel()
            xs.append(nxt if np.all(np.isfinite(nxt)) else xs[-1])
        return u, np.array(xs)

    def _shift(self, elapsed: float):
        """The plan shifted by `elapsed` s: its input rows at elapsed + k h (k < N, held) and
        `_interp_rows`' weights of its states at elapsed + k h (k <= N). Cached: the same
        elapsed time (one control period, and the delay) comes back every period."""
        got = self._shifts.get(elapsed)
        if got is None:
            N, h = self.N, self.h
            times = elapsed + h * np.arange(N + 1)
            idx = np.minimum((times[:N] / h + 1e-9).astype(int), N - 1)
            got = (idx, _interp_weights(N, h, times))
            if len(self._shifts) < 256:
                self._shifts[elapsed] = got
        return got

    def _fallback(self, t_s: float) -> tuple[np.ndarray, CommandSource]:
        if self._plan is not None:
            elapsed = t_s - self._plan_t
            k = int(elapsed / self.h + 1e-9)
            if k < self.N:
                return self._plan[0][k] / self._scale, CommandSource.SHIFTED_PLAN
        return self.u_trim.copy(), CommandSource.HOVER

    def _finish(self, u, source, info, d, out_err, marks) -> tuple[ActuatorCommand, StepInfo]:
        """The command of the step (clipped, finite) and its StepInfo; `marks`: the CPU clock
        at the step's start and after its observer, effectiveness and predictor parts (any of
        them the same when a part did not run)."""
        u = np.array(u, float)
        bad = ~np.isfinite(u)
        n_bad = int(np.count_nonzero(bad))
        if n_bad:
            u[bad] = self.u_trim[bad]
        clipped_u = np.minimum(np.maximum(u, self._u_lo), self._u_hi)    # np.clip's values
        n_clip = n_bad + int(np.count_nonzero(np.abs(clipped_u - u) > 1e-9))
        self.clip_count += n_clip
        self._prev_u = self._last_u
        self._last_u = clipped_u
        self._sent.append(self._last_t, clipped_u)       # sent for the state at _last_t
        cmd = self.allocator.command_of(clipped_u)
        c0, c1, c2, c3 = marks
        cpu = StepTimes(c1 - c0, c2 - c1, c3 - c2, self.cpu_ns() - c3)
        info = StepInfo(source, info, tuple(d.tolist()), out_err, n_clip,
                        self.clip_count, self.failures, tuple(self._scale[self._nt:].tolist()),
                        cpu)
        return cmd, info

    def _emergency(self, t_s, why, c0) -> tuple[ActuatorCommand, StepInfo]:
        self.failures += 1
        u, source = self._fallback(t_s + self.delay_s)
        info = SolveInfo(SolveStatus.FAILED, 0, 0.0, float("nan"), why)
        return self._finish(u, source, info, np.zeros(6), 0.0, (c0, c0, c0, c0))
