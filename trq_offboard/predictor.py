"""The delay predictor: the commands sent, the actuators through their lags, the state when the
next command acts (a Smith predictor's role), and the observer's b0 under the commands that were
really in effect. The Controller owns one (`Controller.predictor`).

    p = DelayPredictor(model, vehicle, applied_delay_s, control_dt_s, lagged, u0)
    built = compile(p.functions()); p.bind(built)        # its compiled functions, built once
    p.reset(t_s, u); p.sent_command(t_s, u)             # the commands sent, stamped
    path, y_t1, y_cut = p.actuator_walk(t0, t1, cut, x)   # the actuators over [t0, t1]
    b0 = p.b0_delayed(x, t0, t1, path)                  # the observer's b0 over [t0, t1]
    x1 = p.predict(x, t0, t1, d, path)                  # the state at t1 from the one at t0

Each command acts `applied_delay_s` after the stamp of the state it answered, until the next one
does. With `lagged` the actuators follow the commands through their first-order lags and rate
limits (vehicle file: motor and servo time constants and rate limits), rebuilt from the
remembered commands (SENT_KEPT periods: many time constants); without, each command acts at
once. Pure: no clock, no I/O.

The actuator walk of the observer and the predictor as one compiled function (issue 18,
`walk_function`):

`DelayPredictor.actuator_walk` lays the commands in effect out as lag steps (one per piece of a
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
same IEEE operations in the same order as the NumPy layout and `DelayPredictor.lag` (np.minimum as
fmin, np.clip as fmin of fmax, libm's expm1), so that the two agree to the bit; the tests hold
the compiled walk to the step-by-step specification.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from trq_offboard.config import VehicleModel
from trq_offboard.model import PredictionModel

__all__ = ["DelayPredictor", "CommandHistory", "WalkPath", "walk_function", "run_walk",
           "walk_sizes", "PREDICT_STEP_S", "CHAIN_STEPS", "SENT_KEPT"]

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

    def lag(y, u, h):                     # DelayPredictor.lag: y + clip(gain (u - y), -lim, lim)
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
    """The steps of a compiled walk from t0 on, as `DelayPredictor.actuator_path`'s list of
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


class DelayPredictor:
    """The commands sent and what they do once in effect (see the module docstring): `lagged`,
    through the actuators' lags; `u0`, the command taken as sent before any is."""

    def __init__(self, model: PredictionModel, vm: VehicleModel, applied_delay_s: float,
                 control_dt_s: float, lagged: bool, u0: np.ndarray) -> None:
        self.model = model
        self.applied_delay_s = applied_delay_s
        self.lagged = lagged
        tilts = 4 if model.tilting else 0
        self.tau = np.array([vm.servo_time_constant_s] * tilts + [vm.motor_time_constant_s] * 4)
        self.rate_limit = np.array([vm.servo_rate_limit_rad_s] * tilts
                                   + [vm.motor_rate_limit_pct_s] * 4)
        self._gains: dict[float, np.ndarray] = {}
        self._step_dt = model.discrete_dt()
        # the walk's layout, lag chain and the observer's b0 sum in one function, in two sizes:
        # a regular period's (the pieces of the round trip delay and one more), then a larger
        # one for late or lost samples (the NumPy layout serves what fits neither)
        self._walk_sizes = walk_sizes(applied_delay_s, control_dt_s) if lagged else []
        self.sent = CommandHistory(SENT_KEPT, model.nu)
        self.last_u = u0                    # the last command sent

    def functions(self) -> dict[str, ca.Function]:
        """The functions to compile (nmpc/cache.py), by name, for `bind`: the lag chain, the
        observer's b0 and the compiled walks."""
        fns = {"chain": self._chain_function(), "b0": self.model.b0.fn}
        for i, (pieces, substeps) in enumerate(self._walk_sizes):
            fns[f"walk{i}"] = walk_function(self.tau, self.rate_limit, self.model.b0.fn,
                                            SENT_KEPT, PREDICT_STEP_S, pieces, substeps)
        return fns

    def bind(self, built: dict) -> None:
        """The compiled `functions` (NumpyFunction by name)."""
        self._chain_fn, self._b0_fn = built["chain"], built["b0"]
        self._walk_fns = [built[name] for name in built if name.startswith("walk")]

    def reset(self, t_s: float, u: np.ndarray) -> None:
        """Forget the commands sent: `u`, sent for the state at t_s, is the only one."""
        self.sent = CommandHistory(SENT_KEPT, self.model.nu, [(float(t_s), u)])
        self.last_u = u

    def sent_command(self, t_s: float, u: np.ndarray) -> None:
        """`u` was sent, answering the state stamped t_s."""
        self.sent.append(t_s, u)
        self.last_u = u

    def b0(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The observer's b0(u): the nominal model's accelerations under u (9: NED, Euler,
        body angular; the observer picks its channels' with b0_of)."""
        return self._b0_fn(x, u)

    def b0_delayed(self, x: np.ndarray, t0: float, t1: float, path=None) -> np.ndarray:
        """b0 averaged over [t0, t1] with each command acting applied_delay_s after it was sent
        (the time of the state it answered): the commands that were really in effect."""
        if isinstance(path, WalkPath):             # the compiled walk's sum, if for these
            got = path.b0_over(x, t0, t1)
            if got is not None:
                return got / (t1 - t0)
        total = np.zeros(9)
        if self.lagged:
            for a, b, y in (path if path is not None else self.actuator_path(t0, t1)):
                if t0 < 0.5 * (a + b) < t1:        # steps never straddle t0 or t1
                    total += (b - a) * self.b0(x, y)
            return total / (t1 - t0)
        if self.applied_delay_s <= 0.0 or not len(self.sent):
            return self.b0(x, self.last_u)
        for lo, hi, u in self.in_effect(t0, t1):
            total += (hi - lo) * self.b0(x, u)
        return total / (t1 - t0)

    def in_effect(self, t0: float, t1: float) -> list[tuple[float, float, np.ndarray]]:
        """The commands acting over [t0, t1] as (start, end, u) segments: each command acts
        from the stamp of the state it answered plus applied_delay_s until the next one does;
        before the oldest remembered command, the oldest one."""
        sent = self.sent
        if not len(sent):
            return [(t0, t1, self.last_u)] if t1 > t0 else []
        if t1 <= t0:                    # an empty interval (the walk after t1 with no delay):
            # the oldest command's piece before it acts, of no length, if it acts after t0
            s0 = float(sent.times[0]) + self.applied_delay_s
            return [(t0, min(s0, t1), sent.commands[0])] if s0 > t0 else []
        starts, cmds = sent.times + self.applied_delay_s, sent.commands
        segs = []
        if starts[0] > t0:
            segs.append((t0, min(float(starts[0]), t1), cmds[0]))
        if float(starts.max()) <= t0:   # every command acts from t0 or before: the newest,
            return [(t0, t1, cmds[-1])]  # from max(start, t0) = t0 to min(inf, t1) = t1
        # each command from its start to the next one's (the last one on), within [t0, t1]
        lo = np.maximum(starts, t0).tolist()
        hi = np.minimum(np.append(starts[1:], math.inf), t1).tolist()
        for i in np.flatnonzero(np.greater(hi, lo)).tolist():
            segs.append((lo[i], hi[i], cmds[i]))
        return segs

    def actuator_path(self, t0: float, t1: float, cut: float | None = None):
        """The actuators over [t0, t1] as (a, b, y_mid) steps of at most PREDICT_STEP_S: the
        commands in effect (each from its state's stamp + applied_delay_s) through the
        actuators' first-order lags and rate limits (vehicle file: motor and servo time
        constants), y_mid at each step's midpoint. Their state at t0 is rebuilt from the
        remembered commands (32 periods: many time constants). `cut`: a time in (t0, t1) that
        no step straddles (one path serves the observer before it and the predictor after
        it)."""
        return self.actuator_walk(t0, t1, cut)[0]

    def actuator_walk(self, t0: float, t1: float, cut: float | None = None,
                      x: np.ndarray | None = None):
        """(actuator_path(t0, t1, cut), the actuators' outputs at t1, at `cut` (in [t0, t1];
        None without one)). The commands in effect (each from its state's stamp +
        applied_delay_s until the next one's, the oldest remembered one's output held before
        it) are laid out as lag steps: one for each piece of a command before t0 (nothing
        recorded there), steps of at most PREDICT_STEP_S from t0 on, none straddling t0 or
        `cut`; the lag chain through them is one call of a compiled function (`_chain`). The
        history before t0 is laid out with NumPy (the same differences of the same floats as
        step by step). The compiled walk (walk_function) does all of it in one call when the
        layout fits it (its path then also carries the observer's b0 sum for the state `x`)."""
        sent = self.sent
        if len(sent):
            for fn in self._walk_fns:
                got = run_walk(fn, sent.times, sent.commands, self.applied_delay_s,
                               t0, t1, cut, x)
                if got is not None:
                    return got
        if len(sent):
            starts = sent.times + self.applied_delay_s
            cmds = sent.commands
            # the oldest command's output held before it acts, then each command's piece
            lo = np.concatenate(([-math.inf], starts))
            hi = np.minimum(np.append(starts, math.inf), t1)
            which = np.concatenate(([0], np.arange(len(sent))))
        else:
            cmds = self.last_u[None, :]
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
        (outputs after each step, the lag's midpoint of each, `lag(y, u, h / 2)`), as `lag`
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
        (m x K each); a step with h < 0 leaves y as it is. Each step is `lag`'s
        arithmetic in the same order, its gain `_lag_gain`'s: 1 - exp(-h / T) as -expm1(-h / T)
        (libm's expm1), 1 where T = 0."""
        m, K = self.model.nu, CHAIN_STEPS
        y0 = ca.SX.sym("y0", m)
        U = ca.SX.sym("u", m, K)
        H = ca.SX.sym("h", 2, K)
        rate = ca.DM(self.rate_limit)
        lagged = [tau > 0.0 for tau in self.tau]
        tau = ca.DM(np.maximum(self.tau, 1e-12))

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

    def walk_from(self, y0: np.ndarray, t0: float, t1: float, scale: np.ndarray):
        """(path, outputs at t1) of the actuators from y0 at t0 under the commands in effect
        over [t0, t1], each scaled by `scale` (the motors' effectiveness: the effective
        throttle), as actuator_path's steps."""
        y, path = np.asarray(y0, float).copy(), []
        for lo, hi, u in self.in_effect(t0, t1):
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
                path.append((a + i * h, end, self.lag(y, u, 0.5 * h)))
            y = self.lag(y, u, h)
        return y

    def predict(self, x: np.ndarray, t0: float, t1: float, d: np.ndarray,
                 path=None) -> np.ndarray:
        """The state at t1 predicted from the one measured at t0: the delay compensation of a
        link whose round trip is applied_delay_s (a Smith predictor's role). The model (RK4)
        is driven by the commands in flight, sent but not yet acting when x was measured
        (through the actuators' lags with lagged_actuators), with the disturbance estimate d
        held."""
        xk = x
        if self.lagged:
            for a, b, y in (path if path is not None else self.actuator_path(t0, t1)):
                if t0 < 0.5 * (a + b) < t1:        # steps never straddle t0 or t1
                    xk = self._step_dt(xk, y, d, b - a)
        else:
            for lo, hi, u in self.in_effect(t0, t1):
                n = max(1, math.ceil((hi - lo) / PREDICT_STEP_S - 1e-9))
                for _ in range(n):
                    xk = self._step_dt(xk, u, d, (hi - lo) / n)
        xk = np.asarray(xk).ravel()
        return xk if np.all(np.isfinite(xk)) else x

    def lag(self, y: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """The actuators (first-order lag, rate limit) after dt towards the command u."""
        step = self._lag_gain(dt) * (u - y)
        lim = self.rate_limit * dt
        return y + np.clip(step, -lim, lim)

    def _lag_gain(self, dt: float) -> np.ndarray:
        gain = self._gains.get(dt)           # the same few step lengths come back every period
        if gain is None:
            # libm's expm1 (math's, as the compiled chain's): NumPy's own may differ in the
            # last bit (its SIMD loops); cached, so once per step length
            gain = np.array([-math.expm1(-dt / t) if t > 0.0 else 1.0 for t in self.tau])
            if len(self._gains) < 256:
                self._gains[dt] = gain
        return gain
