"""The actuator walk of the observer and the predictor as one compiled function (issue 18).

`Controller._actuator_walk` lays the commands in effect out as lag steps (one per piece of a
command before t0, steps of at most PREDICT_STEP_S from t0 on, none straddling t0 or the cut) and
runs the actuators' first-order lags and rate limits through them; the observer then averages the
model's b0 over the steps between t0 and the cut. Laid out with NumPy, that is some forty small
array operations a period around one compiled chain. Here the layout, the chain and the b0 sum
are one CasADi function of fixed size, generated as C and compiled once (nmpc/cache.py):

    inputs   starts (K): the remembered commands' stamps + applied_delay_s, oldest first,
                        front-padded with the oldest (padding pieces have no length: inactive)
             u (m x K): their commands, padded alike
             t (3):     t0, t1, cut (NaN: none)
             x (12):    the measured state (for b0)
    outputs  y (m):     the actuators at t1
             y_cut (m): at the cut (y without one, or when no step ends there)
             b0 (9):    sum over the steps from t0 on, with their midpoint in (t0, cut), of
                        (b - a) b0(x, y_mid)
             a, b, on (R), y_mid (m x R): the steps from t0 on (R slots, `on` the active ones)
             overflow (1): the layout did not fit (a piece older than the newest `pieces`
                        reaches past t0, or a piece part needs more than `substeps` steps);
                        the outputs are then meaningless and the caller walks with NumPy

Every step is masked, never branched on: pieces 0..K (piece 0 the oldest command's output held
before it acts), each with its history step (lo < t0) and, for the newest `pieces`, up to two
parts (before and after the cut) of up to `substeps` steps. Each quantity is computed by the
same IEEE operations in the same order as the NumPy layout and `Controller._lag` (np.minimum as
fmin, np.clip as fmin of fmax, libm's expm1), so that the two agree to the bit; the tests hold
the compiled walk to the step-by-step specification.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

__all__ = ["WalkPath", "walk_function", "run_walk", "walk_sizes"]


def walk_sizes(delay_s: float, period_s: float) -> list[tuple[int, int]]:
    """(pieces, substeps) of the compiled walks to try in turn: the pieces laid out from t0 on
    are the commands in effect over the round trip delay and a period (and one more for a
    late sample); each part of a piece takes up to `substeps` steps of PREDICT_STEP_S. The
    first size fits a regular period with some jitter (the slots are evaluated whether active
    or not: the smallest that fits costs least); the second a few lost samples."""
    pieces = 2 + max(0, math.ceil(delay_s / period_s - 1e-9))
    return [(pieces, 3), (pieces + 2, 4)]


def walk_function(tau: np.ndarray, rate: np.ndarray, b0_fn: ca.Function, kept: int,
                  step_s: float, pieces: int, substeps: int) -> ca.Function:
    """The walk above for actuators with time constants `tau` (m; 0: no lag) and rate limits
    `rate`, `kept` remembered commands, steps of at most `step_s`; `b0_fn` the model's (x, u)
    -> accelerations (9), an SXFunction (inlined)."""
    m, K = len(tau), kept
    starts = ca.SX.sym("starts", K)
    U = ca.SX.sym("u", m, K)
    tt = ca.SX.sym("t", 3)
    x = ca.SX.sym("x", 12)
    t0, t1, cut = tt[0], tt[1], tt[2]
    lagged = [float(t) > 0.0 for t in tau]
    tau_dm = ca.DM(np.maximum(tau, 1e-12))
    rate_dm = ca.DM(rate)

    def lag(y, u, h):                     # Controller._lag: y + clip(gain (u - y), -lim, lim)
        g = -ca.expm1(-h / tau_dm)
        gain = ca.vertcat(*[g[i] if lagged[i] else ca.SX(1.0) for i in range(m)])
        lim = rate_dm * h
        return y + ca.fmin(ca.fmax(gain * (u - y), -lim), lim)

    # pieces 0..K: lo = [-inf, starts], hi = min([starts, inf], t1), command [0, 0..K-1]
    lo = [-ca.inf] + [starts[i] for i in range(K)]
    hi = [ca.fmin(starts[i], t1) for i in range(K)] + [t1]
    cmd = [U[:, 0]] + [U[:, i] for i in range(K)]
    keep = [hi[p] > lo[p] for p in range(K + 1)]
    recent = [ca.logic_and(keep[p], hi[p] > t0) for p in range(K + 1)]
    first = K + 1 - pieces                 # the pieces laid out from t0 on
    overflow = ca.SX(0)
    for p in range(first):
        overflow = ca.logic_or(overflow, recent[p])

    # before t0: one step per piece, [lo, min(hi, t0)] (none for piece 0: lo = -inf)
    y = U[:, 0]
    cut_hist, y_hist = ca.SX(0), y          # the last history step: ends at the cut? its y
    for p in range(1, K + 1):
        on = ca.logic_and(keep[p], lo[p] < t0)
        end = ca.fmin(hi[p], t0)
        y = ca.if_else(on, lag(y, cmd[p], end - lo[p]), y)
        cut_hist = ca.if_else(on, end == cut, cut_hist)
        y_hist = ca.if_else(on, y, y_hist)
    has_cut, y_cut = cut_hist, y_hist

    # from t0 on: each piece's parts before and after the cut, steps of at most step_s
    b0 = ca.SX.zeros(9)
    out_a, out_b, out_on, out_mid = [], [], [], []
    for p in range(first, K + 1):
        a0, b_end = ca.fmax(lo[p], t0), hi[p]
        split = ca.logic_and(a0 < cut, cut < b_end)
        parts = ((a0, ca.if_else(split, cut, b_end), recent[p]),
                 (cut, b_end, ca.logic_and(recent[p], split)))
        for part, (a, b, part_on) in enumerate(parts):
            n = ca.fmax(1.0, ca.ceil((b - a) / step_s - 1e-9))
            overflow = ca.logic_or(overflow, ca.logic_and(part_on, n > substeps))
            h = (b - a) / n
            for k in range(substeps):
                on = ca.logic_and(part_on, k < n)
                s = a + k * h
                e = ca.if_else(k == n - 1, b, a + (k + 1) * h)
                mid = lag(y, cmd[p], 0.5 * h)
                y = ca.if_else(on, lag(y, cmd[p], h), y)
                last = ca.logic_and(on, k == n - 1)
                at_cut = ca.logic_and(last, b == cut)
                has_cut = ca.if_else(at_cut, 1, has_cut)
                y_cut = ca.if_else(at_cut, y, y_cut)
                if part == 0:     # after the cut s >= cut, so the midpoint is never below it
                    centre = 0.5 * (s + e)
                    use = ca.logic_and(on, ca.logic_and(t0 < centre, centre < cut))
                    b0 = ca.if_else(use, b0 + (e - s) * b0_fn(x, mid), b0)
                out_a.append(s)
                out_b.append(e)
                out_on.append(on)
                out_mid.append(mid)
    y_cut = ca.if_else(has_cut, y_cut, y)
    outs = [y, y_cut, b0, ca.vertcat(*out_a), ca.vertcat(*out_b), ca.vertcat(*out_on),
            ca.horzcat(*out_mid), overflow]
    name = f"actuator_walk_{m}_{K}_{pieces}_{substeps}"
    return ca.Function(name, [starts, U, tt, x], ca.cse(outs), ["starts", "u", "t", "x"],
                       ["y", "y_cut", "b0", "a", "b", "on", "y_mid", "overflow"])


class WalkPath:
    """The steps of a compiled walk from t0 on, as `Controller._actuator_path`'s list of
    (a, b, y_mid), built when first read (the observer alone needs only `b0_sum`); and the b0
    sum over those with their midpoint in (t0, cut) for the state x."""

    __slots__ = ("_rows", "_steps", "x", "t0", "cut", "b0_sum")

    def __init__(self, a, b, on, mids, x, t0, cut, b0_sum) -> None:
        self._rows = (a, b, on, mids)
        self._steps = None
        self.x, self.t0, self.cut, self.b0_sum = x, t0, cut, b0_sum

    def _list(self) -> list:
        if self._steps is None:
            a, b, on, mids = self._rows
            idx = np.flatnonzero(on).tolist()
            al, bl = a.tolist(), b.tolist()
            self._steps = [(al[i], bl[i], mids[i].copy()) for i in idx]
        return self._steps

    def __iter__(self):
        return iter(self._list())

    def __len__(self) -> int:
        return len(self._list())

    def __getitem__(self, i):
        return self._list()[i]

    def b0_over(self, x: np.ndarray, t0: float, t1: float) -> np.ndarray | None:
        """The sum for (x, t0, t1) if it is the one computed (the same state object, t0 and
        cut), else None."""
        if x is self.x and t0 == self.t0 and t1 == self.cut:
            return self.b0_sum
        return None


def run_walk(fn, times: np.ndarray, commands: np.ndarray, delay_s: float,
             t0: float, t1: float, cut: float | None, x: np.ndarray | None):
    """(WalkPath, y at t1, y at the cut or None) of `walk_function`, compiled, over the remembered
    commands (times (n >= 1), commands (n, m), n <= kept), or None when the layout overflows."""
    st, u, tt, xin = fn.args
    K = st.size
    n = times.size
    m = commands.shape[1]
    pad = K - n
    st[pad:] = times
    st[pad:] += delay_s                    # the NumPy layout's times + delay, element by element
    st[:pad] = st[pad]
    uv = u.reshape(K, m)                   # column j of the (m x K) input: command j
    uv[pad:] = commands
    uv[:pad] = commands[0]
    tt[0], tt[1], tt[2] = t0, t1, (math.nan if cut is None else cut)
    if x is not None:
        xin[:] = x
    fn.evaluate()
    y, y_cut, b0, a, b, on, mids, overflow = fn.results
    if overflow[0]:
        return None
    path = WalkPath(a.copy(), b.copy(), on.copy(), mids.reshape(-1, m).copy(),
                    x, t0, cut, b0.copy() if x is not None else None)
    return path, y.copy(), (None if cut is None else y_cut.copy())
