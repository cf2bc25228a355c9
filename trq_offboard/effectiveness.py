"""Motor effectiveness observer: what fraction e_i of its command each motor produces.

The vehicle's motor i answers a throttle command c_i with an output y_i that follows
    y_i' = (e_i c_i - y_i) / T          (T: the motor time constant of the vehicle file)
where e_i = 1 for a healthy motor and e_i < 1 for a loss of effectiveness (the paper's fault:
the throttle actually produced is e_i times the command). The extended state observer (eso.py)
already sees what a fault does, as a disturbance d on the accelerations; an additive d cannot tell
the NMPC that the motor's loss will keep growing as its output falls behind, nor that raising its
command buys only e_i of the thrust. This observer reads the same d as motor outputs and estimates
e_i, so that the NMPC can plan with it (controller.py: the effective throttle e_i c_i).

Per control step (`MotorEffectiveness.step`, which composes the observer with the prediction
model's deficit functions and the delay predictor's walk; the Controller owns one):
  1. the outputs the motors would produce if healthy, y_nom (the commands in effect through the
     motors' lags: what the observer's b0 flies), and the model's sensitivity of the vertical
     (NED z) and the body roll and pitch accelerations to each motor's throttle at y_nom;
  2. isolation (MotorEffectiveness.motor_deficit): the deficit of each motor alone that best
     explains the disturbance's vertical, roll and pitch parts in least squares; the motor whose
     deficit (< 0) explains the largest share takes it, refined by Gauss-Newton on the quadratic
     thrust and torque curves (exact to 1e-3 % of throttle); the other motors get none. So
     y_meas = y_nom + that deficit. Yaw is left out (the rotors' drag torque moves it little: a
     small yaw disturbance would read as a large deficit) and so is the horizontal force (wind).
     One fault at a time: a second motor's loss stays in the additive d; and a torque from
     elsewhere (a gust's moment) reads as a small deficit of the motor that would cause it (how
     small, measured in the paper's wind: docs/observer.md);
  3. per motor, a second-order observer of the first-order motor model with e as an unknown
     constant gain, both poles at -p (p: bandwidth_rad_s):
         yh' = (eh c - yh) / T + l1 (y_meas - yh)          l1 = 2 p - 1 / T
         eh' = l2 (y_meas - yh)                            l2 = p^2 T / c
     integrated over the control period in `substeps` Euler steps with the commands in effect
     (c >= idle > 0) and y_meas interpolated linearly; eh is kept in [e_min, 1] (held at the bound
     while the correction pushes past it).
  4. the controller hands the NMPC the effective throttles: bounds [e idle, e 100] %, the command
     sent is the plan / e, the actuators start from the estimated outputs (y_nom with yh for
     the motors) and d loses the motors' share, b0(yh) - b0(y_nom).
A step in e first shows as a change in the *slope* of y (the motor starts lagging towards e c):
the observer reads the fault's size from the slope before the output has fallen, so the NMPC
plans for the whole loss about one motor time constant sooner than an additive estimate.

Pure: `update` is a function of the observer's state and its arguments. A piece of the commands
in effect that needs at most `substeps` Euler steps (the usual case) is integrated by one CasADi
function, generated as C and compiled once through nmpc/cache.py (`codegen`; without a compiler
CasADi's interpreter runs it), with the same arithmetic in the same order as the NumPy loop that
serves longer pieces (lost samples).
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from trq_offboard.config import EffectivenessConfig
from trq_offboard.model import PredictionModel
from trq_offboard.predictor import DelayPredictor

__all__ = ["MotorEffectivenessObserver", "MotorEffectiveness"]


class MotorEffectivenessObserver:
    def __init__(self, cfg: EffectivenessConfig, motor_time_constant_s: float,
                 control_dt_s: float, n_motors: int = 4, codegen: bool = True) -> None:
        if motor_time_constant_s <= 0.0:
            raise ValueError("the motor effectiveness observer needs a motor time constant > 0 "
                             f"(got {motor_time_constant_s!r} s in the vehicle file)")
        self.cfg = cfg
        self.T = float(motor_time_constant_s)
        self.h_max = control_dt_s / cfg.substeps      # the longest Euler substep
        p = cfg.bandwidth_rad_s
        self.l1 = 2.0 * p - 1.0 / self.T
        self.l2T = p * p * self.T                 # l2 = l2T / c
        self.n = n_motors
        self.e = np.ones(n_motors)                # estimated effectiveness
        self.y = np.zeros(n_motors)               # estimated motor outputs (throttle %)
        self._y_meas_prev: np.ndarray | None = None
        self._piece_fn = self._build_piece(codegen, control_dt_s)

    def _build_piece(self, codegen: bool, control_dt_s: float):
        """`piece_function`, compiled once per process for the observer's figures."""
        from trq_offboard.model.dynamics import NumpyFunction
        from trq_offboard.nmpc.cache import compiled_once

        key = ("effectiveness piece", self.cfg, self.T, control_dt_s, self.n)
        return NumpyFunction(compiled_once(key, self.piece_function, codegen))

    def piece_function(self) -> ca.Function:
        """One piece of `update` (up to `substeps` Euler steps, n of them active) as a CasADi
        function: (y, e, y0, y_meas, c (4 each), [dur, t, dt_s, n]) -> (y, e, [t])."""
        m, n_max = self.n, self.cfg.substeps
        y, e, y0, ym, c_in = (ca.SX.sym(name, m) for name in ("y", "e", "y0", "y_meas", "c"))
        p = ca.SX.sym("p", 4)                          # dur, t, dt_s, n
        dur, t, dt_s, n = p[0], p[1], p[2], p[3]
        lo, T = self.cfg.min_effectiveness, self.T
        c = ca.fmax(c_in, 1e-6)
        h = dur / n
        gain = self.l2T / c
        yk, ek, tk = y, e, t
        for i in range(n_max):
            on = i < n
            t1 = tk + h
            err = y0 + (ca.fmin(t1, dt_s) / dt_s) * (ym - y0) - yk
            dy = (ek * c - yk) / T + self.l1 * err
            de = gain * err
            y1 = yk + h * dy
            e1 = ca.fmin(ca.fmax(ek + h * de, lo), 1.0)
            yk, ek, tk = ca.if_else(on, y1, yk), ca.if_else(on, e1, ek), ca.if_else(on, t1, tk)
        return ca.Function(f"effectiveness_piece_{m}_{n_max}", [y, e, y0, ym, c_in, p],
                           [yk, ek, tk])

    def piece_steps(self, dur: float) -> int:
        """The Euler steps `update` takes for a piece of dur s when `piece_function` serves it
        (dur > 0, at most `substeps` steps, compiled), else 0."""
        if dur <= 0.0 or self._piece_fn is None or self._y_meas_prev is None:
            return 0
        n = max(1, int(math.ceil(dur / self.h_max - 1e-9)))
        return n if n <= self.cfg.substeps else 0

    def advance(self, y: np.ndarray, e: np.ndarray, y_meas: np.ndarray) -> None:
        """Take the state `update` would reach over a period of one piece, computed outside
        (the controller's compiled step, from `piece_function`): outputs y, effectiveness e,
        the measured outputs y_meas it reached."""
        self.y, self.e, self._y_meas_prev = y, e, y_meas

    def reset(self, y_outputs: np.ndarray) -> None:
        """Healthy motors producing y_outputs (throttle %)."""
        self.e = np.ones(self.n)
        self.y = np.array(y_outputs, float).reshape(self.n)
        self._y_meas_prev = self.y.copy()

    def update(self, y_meas: np.ndarray, segments, dt_s: float) -> np.ndarray:
        """Advance over dt_s to the measured outputs y_meas (4, %), with `segments` the commands
        in effect as (duration_s, c (4, %)) pieces covering dt_s. Returns e (4). A gap longer
        than a control period (lost samples) gets proportionally more substeps, each at most
        control period / substeps."""
        y_meas = np.asarray(y_meas, float).reshape(self.n)
        if self._y_meas_prev is None:
            self.reset(y_meas)
        lo, T = self.cfg.min_effectiveness, self.T
        y, e, y0 = self.y.copy(), self.e.copy(), self._y_meas_prev
        t = 0.0
        for dur, c in segments:
            if dur <= 0.0:
                continue
            n = max(1, int(math.ceil(dur / self.h_max - 1e-9)))
            if n <= self.cfg.substeps and self._piece_fn is not None:
                y, e, tt = self._piece_fn.outputs(y, e, y0, y_meas, c, (dur, t, dt_s, n))
                t = float(tt[0])
                continue
            c = np.maximum(np.asarray(c, float).reshape(self.n), 1e-6)
            h = dur / n
            for _ in range(n):
                t += h
                err = y0 + (min(t, dt_s) / dt_s) * (y_meas - y0) - y
                dy = (e * c - y) / T + self.l1 * err
                de = (self.l2T / c) * err
                y = y + h * dy
                e = np.clip(e + h * de, lo, 1.0)
        self.y, self.e = y, e
        self._y_meas_prev = y_meas.copy()
        return e.copy()


class MotorEffectiveness:
    """The motor effectiveness observer composed with the prediction model (the motors' deficit
    that explains the disturbance, their share of it) and the delay predictor (the commands in
    effect, the actuators' walk in effective throttles): steps 1 to 4 above, per control step.
    Its compiled functions are built with the controller's (`functions`, then `bind`)."""

    def __init__(self, observer: MotorEffectivenessObserver, model: PredictionModel,
                 predictor: DelayPredictor) -> None:
        self.observer = observer
        self.model = model
        self.predictor = predictor
        self._nt = 4 if model.tilting else 0           # where the throttles start in u
        self._deficit_fn = self._effective_fn = None

    def functions(self) -> dict[str, ca.Function]:
        """The functions to compile (nmpc/cache.py), by name, for `bind`: the motors' deficit
        and a regular period of `step` (one command in effect) in one."""
        return {"deficit": self._deficit_function(), "effective": self._effective_function()}

    def bind(self, built: dict) -> None:
        """The compiled `functions` (NumpyFunction by name)."""
        self._deficit_fn, self._effective_fn = built["deficit"], built["effective"]

    def motor_deficit(self, x: np.ndarray, d: np.ndarray, y_nom: np.ndarray) -> np.ndarray:
        """The motors' outputs less their healthy ones y_nom (4, throttle %) that explain the
        disturbance d: one motor at a time, the one whose pattern (the model's sensitivity of
        the vertical, roll and pitch accelerations to its throttle) explains most of d[2:5]
        with a deficit; the others 0. One call of the compiled `_deficit_function`."""
        return self._deficit_fn(x, d, y_nom)

    def _deficit_function(self) -> ca.Function:
        """`motor_deficit` as one CasADi function (x, d, y_nom) -> dz (generated as C and
        compiled once): each motor's least-squares deficit alone and its share of |r|^2
        (r = d[2:5]), the first motor with the largest share (np.argmax's), and for it, if it
        explains some of r with a deficit, Gauss-Newton on |A(y + delta) - A(y) - r| (the
        thrust and torque curves are quadratic in the throttle: the change A is the mean of the
        two end slopes times delta, exactly) from the tangent's estimate, 3 steps (quadratic
        convergence), clamped to a deficit. Every motor's candidate is computed and the chosen
        one selected: the same operations in the same order as the plain-float specification
        that tests/unit/trq_offboard/test_effectiveness.py holds it to."""
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
        """`step` over a period with one command in effect, as one CasADi function of
        (x, d, y_nom, the effectiveness observer's y, e and last measured outputs, the
        command's throttles c, [dur, 0, dt, n]) -> (y, e, y_meas, d less the motors' share):
        the deficit, the observer's piece and b0(y_true) - b0(y_nom) composed symbolically,
        each the same operations as its own compiled function in `step`'s order."""
        nt, nu = self._nt, self.model.nu
        x, d, y_nom = ca.SX.sym("x", 12), ca.SX.sym("d", 6), ca.SX.sym("y_nom", nu)
        y, e, y0, c = (ca.SX.sym(name, 4) for name in ("y", "e", "y0", "c"))
        p = ca.SX.sym("p", 4)
        dz = self._deficit_function()(x, d, y_nom)
        y_meas = y_nom[nt:] + dz
        y1, e1, _ = self.observer.piece_function()(y, e, y0, y_meas, c, p)
        y_true = ca.vertcat(y_nom[:nt], y1)
        b0 = self.model.b0.fn
        share = b0(x, y_true) - b0(x, y_nom)
        d1 = d - share[[0, 1, 2, 6, 7, 8]]
        return ca.Function(f"effective_step_{nu}_{self.observer.cfg.substeps}",
                           [x, d, y_nom, y, e, y0, c, p], [y1, e1, y_meas, d1],
                           ["x", "d", "y_nom", "y", "e", "y_meas_prev", "c", "p"],
                           ["y_next", "e_next", "y_meas", "d_less_share"])

    def step(self, x, d, y_nom, t0, t1, t_act, ocp):
        """Advance the observer over [t0, t1] and return (d less the motors' share, the
        predictor's actuator path over [t1, t_act] and the actuators' outputs at t_act, both in
        effective throttles, and the plan's throttle scale: 1 but e for the throttles), the
        scale also set as `ocp`'s throttle bounds. y_nom: the actuators' outputs at t1 if
        the motors were healthy (the observer's b0 flies those)."""
        nt, eff = self._nt, self.observer
        segs = self.predictor.in_effect(t0, t1) if t1 > t0 else []
        n = eff.piece_steps(segs[0][1] - segs[0][0]) if len(segs) == 1 else 0
        if n and self._effective_fn is not None:         # one command in effect: one call
            lo, hi, u = segs[0]
            y, e, y_meas, d = self._effective_fn.outputs(
                x, d, y_nom, eff.y, eff.e, eff._y_meas_prev, u[nt:], (hi - lo, 0.0, t1 - t0, n))
            eff.advance(y, e, y_meas)
            return self._end(e, y_nom, d, t1, t_act, ocp)
        dz = self.motor_deficit(x, d, y_nom)
        if t1 > t0:
            e = eff.update(y_nom[nt:] + dz, [(hi - lo, u[nt:]) for lo, hi, u in segs], t1 - t0)
        else:
            e = eff.e.copy()
        y_true = y_nom.copy()
        y_true[nt:] = eff.y
        share = self.predictor.b0(x, y_true) - self.predictor.b0(x, y_nom)
        return self._end(e, y_nom, d - share[[0, 1, 2, 6, 7, 8]], t1, t_act, ocp)

    def after_period(self, y_nom, d, t1, t_act, ocp):
        """`step`'s result where its observer was advanced outside (the controller's composed
        period, trq_offboard/observer_period.py) and d is already less the motors' share."""
        return self._end(self.observer.e, y_nom, d, t1, t_act, ocp)

    def _end(self, e, y_nom, d, t1, t_act, ocp):
        """`step`'s result once the observer has its e and outputs: the plan's throttle scale
        (set as `ocp`'s bounds), and the predictor's walk from the estimated outputs."""
        nt = self._nt
        scale = np.ones(self.model.nu)
        scale[nt:] = e
        ocp.set_throttle_scale(e)
        y_true = y_nom.copy()
        y_true[nt:] = self.observer.y
        path, y_act = self.predictor.walk_from(y_true, t1, t_act, scale)
        return d, path, y_act, scale
