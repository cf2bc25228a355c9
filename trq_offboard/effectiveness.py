"""Motor effectiveness observer: what fraction e_i of its command each motor produces.

The vehicle's motor i answers a throttle command c_i with an output y_i that follows
    y_i' = (e_i c_i - y_i) / T          (T: the motor time constant of the vehicle file)
where e_i = 1 for a healthy motor and e_i < 1 for a loss of effectiveness (the paper's fault:
the throttle actually produced is e_i times the command). The extended state observer (eso.py)
already sees what a fault does, as a disturbance d on the accelerations; an additive d cannot tell
the NMPC that the motor's loss will keep growing as its output falls behind, nor that raising its
command buys only e_i of the thrust. This observer reads the same d as motor outputs and estimates
e_i, so that the NMPC can plan with it (controller.py: the effective throttle e_i c_i).

Per control step (controller.py):
  1. the outputs the motors would produce if healthy, y_nom (the commands in effect through the
     motors' lags: what the observer's b0 flies), and the model's sensitivity of the vertical
     (NED z) and the body roll and pitch accelerations to each motor's throttle at y_nom;
  2. isolation (Controller._motor_deficit): the deficit of each motor alone that best explains
     the disturbance's vertical, roll and pitch parts in least squares; the motor whose deficit
     (< 0) explains the largest share takes it, refined by Gauss-Newton on the quadratic thrust
     and torque curves (exact to 1e-3 % of throttle); the other motors get none. So
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

__all__ = ["MotorEffectivenessObserver"]


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
        self._piece_fn = self._build_piece(codegen)

    def _build_piece(self, codegen: bool):
        """`piece_function`, compiled."""
        from trq_offboard.model.dynamics import NumpyFunction
        from trq_offboard.nmpc.cache import compiled

        return NumpyFunction(compiled(self.piece_function(), codegen)[0])

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
