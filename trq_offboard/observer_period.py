"""The observers' regular control period as one compiled call: the ESO, the rate observer and
the motors' effectiveness (steps 3 and 4 of `Controller.step`) composed into one CasADi
function, generated as C and compiled once with the controller's other functions.

    period = ObserverPeriod.of(eso, rate_observer, motors)   # None where it cannot serve
    fn = period.function()                                    # compiled with the controller's
    period.bind(NumpyFunction(compiled))
    got = period.run(x, b0, dt, y_nom, segments)  # None: not a regular period (Python's path)
    d_obs, d, out_err = got                       # the observers' state advanced in place

Why: each observer's period is already one compiled call, a microsecond or so of arithmetic,
but the Python around them (the measured outputs picked, the arguments copied into each
kernel's buffers, the results copied back and reshaped, the disturbance clipped, the motors'
piece laid out) cost tens of times the kernels, a share of the controller's whole period
(issue 39, item 5; docs/decisions/2026-12-06-period-on-the-ground.md). Here the state of all
three observers goes in as one vector and comes out as one, with d and the output error.

The same figures to the bit: the function calls the observers' own CasADi functions
(ExtendedStateObserver._period_function, RateObserver._period_function,
MotorEffectiveness._effective_function) on symbols, so that their operations are inlined in
the same order, and adds only what `Controller._observe` does around them with the same IEEE
operations: the channels' outputs and b0 picked by index, the disturbance clipped as
np.minimum of np.maximum (fmin of fmax: the same for the finite values the step lets in), the
rate observer's d in place of the ESO's body channels, and y_hat - y for the output error
(whose dot product stays NumPy's). tests/unit/trq_offboard/test_controller_period.py holds a
flight's every step equal to the call-by-call path.

It serves the regular period only: both observers advancing by their compiled period (the gap
gives `substeps` substeps), and the motors' observer with one command in effect over it, fitting
its compiled piece. Everything else (a lost or late sample, the first period, the ground, an
ESO on Euler angles, whose d needs W(eta)^-1, a controller without codegen) stays on the
observers' own methods, which remain the reference. Pure: no clock, no I/O.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from trq_offboard.effectiveness import MotorEffectiveness
from trq_offboard.eso import ExtendedStateObserver
from trq_offboard.rate_observer import RateObserver

__all__ = ["ObserverPeriod"]


class ObserverPeriod:
    """The composed period over the observers' state (see the module docstring). The state
    vector's layout: the ESO's z (3 x 6, row-major) and last output (6); the rate observer's s
    (4 x 3, row-major) and last rates (3); the motors' observer's y, e and last measured
    outputs (4 each); absent parts take no room."""

    def __init__(self, eso: ExtendedStateObserver, ro: RateObserver | None,
                 motors: MotorEffectiveness | None) -> None:
        self.eso, self.ro, self.motors = eso, ro, motors
        self._n_eso = 24
        self._n_ro = 15 if ro is not None else 0
        self.n_mem = self._n_eso + self._n_ro + (12 if motors is not None else 0)
        self._nt = motors._nt if motors is not None else 0
        self._nu = motors.model.nu if motors is not None else 0
        self._fn = None

    @classmethod
    def of(cls, eso: ExtendedStateObserver | None, ro: RateObserver | None,
           motors: MotorEffectiveness | None) -> "ObserverPeriod | None":
        """The composed period for these observers, or None where it cannot serve: no ESO, an
        ESO on Euler angles (its d needs W(eta)^-1 in NumPy)."""
        if eso is None or not eso._rates:
            return None
        return cls(eso, ro, motors)

    def function(self) -> ca.Function:
        """(mem, x (12), b0 (9), p) -> (mem', d_obs (6), d (6), y_hat - y (6)); p = (dt, and
        for the motors: the piece's duration, its start 0, its Euler steps n), y_nom (nu) and
        c (4: the throttles in effect)."""
        eso, ro, motors = self.eso, self.ro, self.motors
        mem = ca.SX.sym("mem", self.n_mem)
        x, b0, p = ca.SX.sym("x", 12), ca.SX.sym("b0", 9), ca.SX.sym("p", 4)
        y = ca.vertcat(*[x[int(i)] for i in eso._y_index])
        b = ca.vertcat(*[b0[int(i)] for i in eso._b0_index])
        z = eso._period_function()(mem[0:18], mem[18:24], y, b, p[0])
        lim = eso._lim
        d = [ca.fmin(ca.fmax(z[12 + j], float(-lim[j])), float(lim[j])) for j in range(6)]
        out_mem = [z, y]
        k = self._n_eso
        if ro is not None:
            rates = x[9:12]
            s = ro._period_function()(mem[k:k + 12], mem[k + 12:k + 15], rates, b[3:6], p[0])
            d[3:6] = [s[9 + j] for j in range(3)]
            out_mem += [s, rates]
            k += self._n_ro
        d_obs = ca.vertcat(*d)
        d_out = d_obs
        ins = [mem, x, b0, p]
        names = ["mem", "x", "b0", "p"]
        if motors is not None:
            y_nom, c = ca.SX.sym("y_nom", self._nu), ca.SX.sym("c", 4)
            piece = ca.vertcat(p[1], p[2], p[0], p[3])    # (dur, t, dt, n) of the piece
            y1, e1, y_meas, d_out = motors._effective_function()(
                x, d_obs, y_nom, mem[k:k + 4], mem[k + 4:k + 8], mem[k + 8:k + 12], c, piece)
            out_mem += [y1, e1, y_meas]
            ins += [y_nom, c]
            names += ["y_nom", "c"]
        err = z[0:6] - y
        return ca.Function(f"observer_period_{self.n_mem}", ins,
                           [ca.vertcat(*out_mem), d_obs, d_out, err],
                           names, ["mem_next", "d_obs", "d", "output_error"])

    def bind(self, fn) -> None:
        """The compiled `function` (a NumpyFunction)."""
        self._fn = fn
        args = fn.args
        self._mem, self._x, self._b0, self._p = args[0:4]
        if self.motors is not None:
            self._y_nom, self._c = args[4], args[5]

    def run(self, x: np.ndarray, b0: np.ndarray, dt: float, y_nom: np.ndarray | None,
            segments) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The observers advanced over a regular period of dt to the state x with the model's
        accelerations b0 (9), and (with the motors' observer) their healthy outputs y_nom and
        the commands in effect `segments` (DelayPredictor.in_effect's): (d_obs, d less the
        motors' share (d_obs without them), the output error). None where the period is not
        regular (see the module docstring): nothing is changed then."""
        eso, ro, motors = self.eso, self.ro, self.motors
        # each observer as its own `update` would take the gap (its compiled period: a test
        # may take one's away to fly the NumPy path)
        if self._fn is None or not eso.takes_period(dt) \
                or (ro is not None and not ro.takes_period(dt)):
            return None
        p = self._p
        p[0] = dt
        if motors is not None:
            eff = motors.observer
            if len(segments) != 1 or motors._effective_fn is None:
                return None
            lo, hi, u = segments[0]
            n = eff.piece_steps(hi - lo)
            if not n:
                return None
            p[1], p[2], p[3] = hi - lo, 0.0, n
            self._y_nom[:] = y_nom
            self._c[:] = u[self._nt:]
        mem = self._mem
        mem[0:18] = eso.z.ravel()
        mem[18:24] = eso._y_prev
        k = self._n_eso
        if ro is not None:
            mem[k:k + 12] = ro.s.ravel()
            mem[k + 12:k + 15] = ro._y_prev
            k += self._n_ro
        if motors is not None:
            mem[k:k + 4] = eff.y
            mem[k + 4:k + 8] = eff.e
            mem[k + 8:k + 12] = eff._y_meas_prev
        self._x[:] = x
        self._b0[:] = b0
        self._fn.evaluate()
        out, d_obs, d, err = self._fn.results
        new = out.copy()
        eso.z = new[0:18].reshape(3, 6)
        eso._y_prev = new[18:24]
        k = self._n_eso
        if ro is not None:
            ro.s = new[k:k + 12].reshape(4, 3)
            ro._y_prev = new[k + 12:k + 15]
            k += self._n_ro
        if motors is not None:
            motors.observer.advance(new[k:k + 4], new[k + 4:k + 8], new[k + 8:k + 12])
        return d_obs.copy(), d.copy(), float(err @ err)
