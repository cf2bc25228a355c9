"""The NMPC optimal control problem (paper eq. 5-8) as one CasADi NLP, built once.

Formulation (multiple shooting, N steps of h seconds, RK4 per step, d held over the horizon).
For the tilt-rotor the tilt angles are carried as four extra states and the servo *rates* are
inputs, so that every constraint is local to one stage (the banded structure that structured QP
solvers such as HPIPM exploit):

    stage state   s_k = [x_k (12), a_k (4)]     a_k: tilt commanded over the previous step (rad)
    stage input   v_k = [w_k (4), c_k (4)]      w_k: tilt rate (rad/s), c_k = zeta_k / 100
    a_{k+1} = a_k + h w_k
    x_{k+1} = F(x_k, [a_{k+1}, 100 c_k], d)     the tilt applied over step k is a_{k+1}
    s_0 = [x_meas, alpha_prev]                  fixed by equal bounds (no constraint row)

so the plan's input k is u_k = [a_{k+1}, zeta_k] in the paper's order [alpha, zeta]. The fixed-rotor
quadcopter has s_k = x_k and v_k = c_k (4 scaled throttles).

Actuator lag states (controller key actuator_states, `ControllerConfig.nmpc_actuator_states`):
the plan's inputs become the *commands* and the stage state carries what the actuators produce,
through their first-order lags (vehicle file: servo and motor time constants T; rate limits are
left out):

    s_k = [x_k, a_k, y_k]       y_k = [servo angles (4), throttles / 100 (4)] (quad: throttles)
    y_{k+1} = y_k + (1 - exp(-h/T)) (u_k - y_k)        exact for u_k held over the step
    x_{k+1} = RK4 over h with the input y(t) = u_k + (y_k - u_k) exp(-t/T) evaluated exactly at
              the RK4 times 0, h/2, h
    s_0 = [x_meas, alpha_prev, y_meas]     y_meas: the actuators when the plan starts (the
                                           controller's predictor: at t + applied_delay_s)

Every constraint stays local to a stage. The cost is still on the commands u_k.

Cost (scaled inputs: tilt in rad, throttle as a fraction about the hover trim)
    sum_{k<N} (x_k - xr_k)' Q (x_k - xr_k) + (u_k - u_trim)' R (u_k - u_trim) + w_rate |w_k|^2
    + (x_N - xr_N)' c_N Q (x_N - xr_N)
Bounds  idle <= zeta <= 100 %; tilt limits on a_k (k >= 1); |w_k| <= servo rate, and
        |w_0| <= servo rate * control period / h (the first command against the applied one);
        |roll|, |pitch| <= bound and |p|, |q|, |r| <= bound on x_k (k >= 1).
The paper's output-error term (y_hat - y)' (y_hat - y): d is held constant over the horizon and
the prediction model already contains it, so over the horizon the observer's output prediction
and the model's coincide; what remains is the observer's current output error, a constant that
does not move the minimiser. The controller evaluates and reports it (StepInfo.output_error).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from trq_offboard.config import ControllerConfig
from trq_offboard.model import PredictionModel

__all__ = ["Ocp", "Stage"]

_BIG = 1e20


@dataclass(frozen=True)
class Stage:
    """One shooting interval of the OCP as CasADi SX Functions, shared by the whole-horizon NLP
    (`Ocp`, inlined) and the real-time iteration (`rti`, compiled once and reused per stage):

        dynamics(s, v, d) -> s_next            RK4 over h (tilt states: a + h w; lag states:
                                               y + g (u - y), g = 1 - exp(-h/T))
        cost(s, v, x_ref_k, u_trim) -> l_k     quadratic (constant Hessian)
        terminal_cost(s, x_ref_N) -> l_N
    """
    dynamics: ca.Function
    cost: ca.Function
    terminal_cost: ca.Function
    ns: int
    nv: int
    n_lag: int = 0                     # actuator lag states (0, 4 quad, 8 TRQ) at the end of s

    @staticmethod
    def lag_gain(cfg: ControllerConfig, model: PredictionModel, dt_s: float) -> np.ndarray:
        """1 - exp(-dt/T) per input ([servo (4),] motor (4)); 1 for T = 0 (no lag)."""
        vm = cfg.vehicle
        tau = np.array(([vm.servo_time_constant_s] * 4 if model.tilting else [])
                       + [vm.motor_time_constant_s] * 4)
        return np.where(tau > 0.0, -np.expm1(-dt_s / np.maximum(tau, 1e-12)), 1.0)

    @staticmethod
    def build(cfg: ControllerConfig, model: PredictionModel) -> "Stage":
        h = cfg.step_s
        nx, nu, tilting = model.nx, model.nu, model.tilting
        n_lag = nu if cfg.nmpc_actuator_states else 0
        ns, nv = (nx + 4 + n_lag, 8) if tilting else (nx + n_lag, 4)
        F = model.discrete(h, 1)
        wts = cfg.weights
        Q = np.array([*wts.position, *wts.velocity, *wts.euler, *wts.rates])
        R = np.array(([wts.tilt] * 4 if tilting else []) + [wts.throttle] * 4)
        s, v = ca.SX.sym("s", ns), ca.SX.sym("v", nv)
        xr, u_trim, d = ca.SX.sym("x_ref", nx), ca.SX.sym("u_trim", nu), ca.SX.sym("d", 6)
        x = s[0:nx]
        ex = x - xr
        if tilting:
            a_next = s[nx:nx + 4] + h * v[0:4]
            u_scaled = ca.vertcat(a_next, v[4:8])
            u_phys = ca.vertcat(a_next, 100.0 * v[4:8])
            l_rate = wts.tilt_rate * ca.sumsqr(v[0:4])
        else:
            u_scaled, u_phys, l_rate = v, 100.0 * v, 0
        eu = u_scaled - u_trim
        l_k = ca.dot(Q * ex, ex) + ca.dot(R * eu, eu) + l_rate
        if n_lag:
            scale = ca.DM(([1.0] * 4 if tilting else []) + [100.0] * 4)
            y = s[ns - n_lag:ns]
            g_mid = ca.DM(Stage.lag_gain(cfg, model, 0.5 * h))
            g_end = ca.DM(Stage.lag_gain(cfg, model, h))
            y_mid = y + g_mid * (u_scaled - y)
            y_end = y + g_end * (u_scaled - y)
            x_next = model.discrete_varying(h)(x, scale * y, scale * y_mid, scale * y_end, d)
            s_next = (ca.vertcat(x_next, a_next, y_end) if tilting
                      else ca.vertcat(x_next, y_end))
        else:
            x_next = F(x, u_phys, d)
            s_next = ca.vertcat(x_next, a_next) if tilting else x_next
        return Stage(
            ca.Function("stage_dynamics", [s, v, d], [s_next], ["s", "v", "d"], ["s_next"]),
            ca.Function("stage_cost", [s, v, xr, u_trim], [l_k],
                        ["s", "v", "x_ref", "u_trim"], ["l"]),
            ca.Function("terminal_cost", [s, xr], [wts.terminal_factor * ca.dot(Q * ex, ex)],
                        ["s", "x_ref"], ["l"]),
            ns, nv, n_lag)

@dataclass
class Ocp:
    """Symbolic NLP {x: w, p: p, f: cost, g: gaps} with bounds and index maps."""
    nlp: dict
    lbg: np.ndarray
    ubg: np.ndarray
    lbw: np.ndarray                    # s_0 rows are filled per solve
    ubw: np.ndarray
    n_steps: int
    step_s: float
    nx: int                            # model state (12)
    nu: int                            # model input (8 TRQ, 4 quad)
    ns: int                            # stage state (16 TRQ, 12 quad; + n_lag)
    nv: int                            # stage input (8 TRQ, 4 quad)
    tilting: bool                      # TRQ: s carries the 4 tilt states a_k, v the servo rates
    s_index: np.ndarray                # (N+1, ns) positions of s_k in w
    v_index: np.ndarray                # (N, nv) positions of v_k in w
    cost_fn: ca.Function               # cost(w, p)
    n_params: int
    n_lag: int = 0                     # actuator lag states, the last n_lag rows of s_k
    lag_gain: np.ndarray | None = None  # (n_lag,) 1 - exp(-h/T) (scaled units, as v)
    _c_bounds: tuple | None = None     # set_throttle_scale: (indices, healthy lbw, healthy ubw)
    _c_views: tuple | None = None      # and the (lbw, ubw) views of those indices

    @staticmethod
    def build(cfg: ControllerConfig, model: PredictionModel) -> "Ocp":
        vm = cfg.vehicle
        N, h = cfg.horizon_steps, cfg.step_s
        nx, nu = model.nx, model.nu
        tilting = model.tilting
        stage = Stage.build(cfg, model)
        ns, nv, n_lag = stage.ns, stage.nv, stage.n_lag
        ss = [ca.SX.sym(f"s{k}", ns) for k in range(N + 1)]
        vs = [ca.SX.sym(f"v{k}", nv) for k in range(N)]
        x_ref = ca.SX.sym("x_ref", nx, N + 1)
        u_trim = ca.SX.sym("u_trim", nu)         # scaled: [alpha, zeta / 100]
        d = ca.SX.sym("d", 6)
        p = ca.vertcat(ca.vec(x_ref), u_trim, d)

        slo, shi = np.full(ns, -_BIG), np.full(ns, _BIG)
        tb = math.radians(cfg.max_tilt_deg)
        slo[6:8], shi[6:8] = -tb, tb
        slo[9:12], shi[9:12] = -cfg.max_rate_rad_s, cfg.max_rate_rad_s
        rate = vm.servo_rate_limit_rad_s
        c_lo, c_hi = [vm.idle_pct / 100.0] * 4, [1.0] * 4
        if tilting:
            slo[12:16], shi[12:16] = vm.tilt_min_rad, vm.tilt_max_rad
            vlo, vhi = np.array([-rate] * 4 + c_lo), np.array([rate] * 4 + c_hi)
            rate0 = min(rate, rate * cfg.control_dt_s / h)
            v0lo, v0hi = np.array([-rate0] * 4 + c_lo), np.array([rate0] * 4 + c_hi)
        else:      # the quadcopter: throttles only
            vlo, vhi = np.array(c_lo), np.array(c_hi)
            v0lo, v0hi = vlo, vhi

        w, lbw, ubw, s_index, v_index = [], [], [], [], []
        pos = 0
        cost = 0
        gaps = []
        for k in range(N + 1):
            w.append(ss[k])
            s_index.append(np.arange(pos, pos + ns))
            pos += ns
            lbw.append(slo)
            ubw.append(shi)
            if k == N:
                cost += stage.terminal_cost(ss[k], x_ref[:, k])
                break
            w.append(vs[k])
            v_index.append(np.arange(pos, pos + nv))
            pos += nv
            lbw.append(v0lo if k == 0 else vlo)
            ubw.append(v0hi if k == 0 else vhi)
            cost += stage.cost(ss[k], vs[k], x_ref[:, k], u_trim)
            gaps.append(stage.dynamics(ss[k], vs[k], d) - ss[k + 1])
        wv = ca.vertcat(*w)
        g = ca.vertcat(*gaps)
        nlp = {"x": wv, "p": p, "f": cost, "g": g}
        zeros = np.zeros(g.shape[0])
        return Ocp(nlp, zeros, zeros.copy(), np.concatenate(lbw), np.concatenate(ubw), N, h,
                   nx, nu, ns, nv, tilting, np.array(s_index), np.array(v_index),
                   ca.Function("cost", [wv, p], [cost]), int(p.shape[0]), n_lag,
                   Stage.lag_gain(cfg, model, h) if n_lag else None)

    def set_throttle_scale(self, e) -> None:
        """Bound the throttles of every stage to [e idle, e 100 %] (e (4): the motors'
        effectiveness, 1 healthy): the plan's throttles are then the effective ones, e times the
        command (controller.py divides them back). Changes lbw / ubw in place."""
        e = np.asarray(e, float).reshape(4)
        if self._c_bounds is None:
            cols = slice(4, 8) if self.tilting else slice(0, 4)
            idx = self.v_index[:, cols]
            self._c_bounds = (idx, self.lbw[idx].copy(), self.ubw[idx].copy())
            if self.stage_major():
                # the same bounds as (N, 4) views of lbw and ubw (w stage by stage): a
                # strided copy each period instead of a fancy-indexed assignment
                c = slice(self.ns + cols.start, self.ns + cols.stop)
                self._c_views = (self.stages(self.lbw)[0][:, c], self.stages(self.ubw)[0][:, c])
        idx, lo, hi = self._c_bounds
        if self._c_views is not None:
            np.multiply(lo, e, out=self._c_views[0])
            np.multiply(hi, e, out=self._c_views[1])
        else:
            self.lbw[idx] = lo * e
            self.ubw[idx] = hi * e

    # --- packing (all NumPy) ------------------------------------------------------------------
    def params(self, x_ref, u_trim, d) -> np.ndarray:
        """p from the reference states (N+1, 12), the trim input (physical) and d (6)."""
        scale = self.u_scale
        return np.concatenate([np.asarray(x_ref, float).reshape(self.n_steps + 1, self.nx)
                               .reshape(-1), np.asarray(u_trim, float) / scale,
                               np.asarray(d, float).reshape(6)])

    @property
    def u_scale(self) -> np.ndarray:
        return np.array(([1.0] * 4 if self.tilting else []) + [100.0] * 4)

    def _lag_rows(self, y0) -> np.ndarray:
        """The actuator part of s_0 (scaled) from y0, physical [alpha, zeta] (nu)."""
        if y0 is None:
            raise ValueError("the OCP has actuator lag states: y0 (the actuators' outputs when "
                             "the plan starts) is required")
        return np.asarray(y0, float).reshape(self.nu) / self.u_scale

    def initial_stage(self, x0, alpha_prev, y0=None) -> np.ndarray:
        """s_0 (ns): x0, the applied tilt (tilts as states) and the actuators' outputs (lag
        states, scaled)."""
        s0 = np.concatenate([x0, alpha_prev]) if self.tilting else np.asarray(x0, float)
        if self.n_lag:
            s0 = np.concatenate([s0, self._lag_rows(y0)])
        return s0

    def bounds(self, x0, alpha_prev, y0=None) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of w with s_0 fixed to [x0, alpha_prev (TRQ), y0 (with lag states)]."""
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        s0 = self.initial_stage(x0, alpha_prev, y0)
        lbw[self.s_index[0]] = s0
        ubw[self.s_index[0]] = s0
        return lbw, ubw

    def stage_major(self) -> bool:
        """w is laid out stage by stage, [s_0, v_0, s_1, ..., s_N], as `build` lays it out and
        s_index and v_index say: the premise of `stages` (and of the compiled feedback)."""
        N, ns, nv = self.n_steps, self.ns, self.nv
        base = np.arange(N + 1)[:, None] * (ns + nv)
        return (self.lbw.size == N * (ns + nv) + ns
                and np.array_equal(self.s_index, base + np.arange(ns))
                and np.array_equal(self.v_index, base[:N] + ns + np.arange(nv)))

    def stages(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Views of w's stages: (N, ns + nv) rows [s_k, v_k] and s_N. `build` lays w out stage
        by stage, [s_0, v_0, s_1, ..., s_N] (s_index and v_index say the same), so plain
        slices of these views replace fancy indexing in pack and unpack."""
        nz, N = self.ns + self.nv, self.n_steps
        return w[:N * nz].reshape(N, nz), w[N * nz:]

    def pack(self, x_plan, u_plan, alpha_prev, y0=None) -> np.ndarray:
        """w from physical plans x (N+1, 12), u (N, nu), the previously applied tilt and (with
        lag states) the actuators' outputs y0 when the plan starts, rolled out through the
        lags under the plan's commands."""
        N, nx, ns = self.n_steps, self.nx, self.ns
        w = np.zeros(self.lbw.size)
        W, sN = self.stages(w)
        x_plan = np.asarray(x_plan, float)
        u_plan = np.asarray(u_plan, float)
        W[:, :nx] = x_plan[:N]
        sN[:nx] = x_plan[N]
        if self.tilting:              # s_k's tilts: the applied one, then the plan's
            W[0, nx:nx + 4] = np.asarray(alpha_prev, float).reshape(4)
            W[1:, nx:nx + 4] = u_plan[:N - 1, 0:4]
            sN[nx:nx + 4] = u_plan[N - 1, 0:4]
            # the servos' rates: the differences of [applied tilt; the plan's tilts]
            W[:, ns:ns + 4] = (u_plan[:, 0:4] - W[:, nx:nx + 4]) / self.step_s
            W[:, ns + 4:] = u_plan[:, 4:8] / 100.0
        else:
            W[:, ns:] = u_plan / self.u_scale
        if self.n_lag:
            ys = [self._lag_rows(y0)]
            for u in u_plan / self.u_scale:
                ys.append(ys[-1] + self.lag_gain * (u - ys[-1]))
            W[:, ns - self.n_lag:ns] = ys[:N]
            sN[ns - self.n_lag:] = ys[N]
        return w

    def unpack(self, w) -> tuple[np.ndarray, np.ndarray]:
        """(u_plan (N, nu) physical [alpha, zeta], x_plan (N+1, 12)) of w."""
        N, nx, ns = self.n_steps, self.nx, self.ns
        W, sN = self.stages(np.asarray(w, float).reshape(-1))
        x = np.empty((N + 1, nx))
        x[:N] = W[:, :nx]
        x[N] = sN[:nx]
        if self.tilting:              # the plan's tilts are s_1..s_N's
            u = np.empty((N, self.nu))
            u[:N - 1, 0:4] = W[1:, nx:nx + 4]
            u[N - 1, 0:4] = sN[nx:nx + 4]
            u[:, 4:8] = 100.0 * W[:, ns + 4:ns + 8]
        else:
            u = W[:, ns:] * self.u_scale
        return u, x
