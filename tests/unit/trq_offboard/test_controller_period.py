"""The controller's period, measured by part and made cheap (issue 18): the parts' CPU times come
from an injected clock and add up; the compiled observers and the actuators' lag chain compute
what their NumPy loops compute; the log writes every row, in order, after its period."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import ROOT, Ticks

from trq_offboard.config import load_controller
from trq_offboard.controller import Controller
from trq_offboard.effectiveness import MotorEffectivenessObserver
from trq_offboard.eso import ExtendedStateObserver
from trq_offboard.nmpc.base import Solver
from trq_offboard.predictor import PREDICT_STEP_S, CommandHistory, run_walk
from trq_offboard.records import (
    CommandSource,
    ReferenceSample,
    SolveInfo,
    SolveStatus,
    StateEstimate,
)
from trq_offboard.reference import ConstantReference

PARAMS = ROOT / "params" / "controller"
CTRL = PARAMS / "trq_nmpc_eso.yaml"


class _NoOcp:
    """The part of an Ocp the controller uses: no lag states, throttle bounds ignored."""
    n_lag = 0

    def set_throttle_scale(self, e) -> None:
        pass


class _HoverSolver(Solver):
    """No NMPC (building one costs seconds): the plan holds the given command."""

    def __init__(self, u, n, nx=12):
        self.u, self.n, self.nx = np.asarray(u, float), n, nx
        self.ocp = _NoOcp()

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        return (np.tile(self.u, (self.n, 1)), np.tile(x0, (self.n + 1, 1)),
                SolveInfo(SolveStatus.OK, 1, 1e-4, 0.0))


def _hover_state(z=-2.0):
    return StateEstimate((0.0, 0.0, z), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def test_step_parts_come_from_the_injected_clock_and_add_up():
    cfg = dataclasses.replace(load_controller(CTRL), effectiveness=None)
    clock = Ticks()
    probe = Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))
    ctl = Controller(cfg, solver=_HoverSolver(probe.u_trim, cfg.horizon_steps), cpu_ns=clock)
    ctl.reset(0.0, _hover_state())
    for k in range(1, 4):
        before = clock.t
        cmd, info = ctl.step(0.01 * k, _hover_state(), None, _const_reference())
        cpu = info.cpu
        parts = (cpu.observer_ns, cpu.effectiveness_ns, cpu.predictor_ns, cpu.feedback_ns)
        assert info.source is CommandSource.NMPC
        assert all(p >= 1000 for p in parts)      # each part between two readings
        # the parts are contiguous: the step's first reading to its last
        assert sum(parts) == clock.t - before - 1000
        ctl.prepare(_const_reference())           # no preparation on this solver: timed anyway
        assert ctl.last_prepare_cpu_ns == 1000


def _const_reference() -> ConstantReference:
    return ConstantReference(ReferenceSample((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), 0.0))


@pytest.mark.parametrize("name", ["trq_nmpc_eso", "trq_nmpc_eso_paper"])
@pytest.mark.parametrize("kind", ["nonlinear", "linear"])
def test_compiled_eso_period_is_the_numpy_loop(name, kind):
    cfg = load_controller(PARAMS / f"{name}.yaml")
    ec = dataclasses.replace(cfg.eso, kind=kind)
    fast, ref = ExtendedStateObserver(ec, 0.01), ExtendedStateObserver(ec, 0.01)
    ref._period_fn = None                          # the NumPy loop
    rng = np.random.default_rng(3)
    fast.reset(rng.normal(size=6), rng.normal(size=6))
    ref.z, ref._y_prev = fast.z.copy(), fast._y_prev.copy()
    worst = 0.0
    for k in range(300):
        y = fast._y_prev + rng.normal(size=6) * (0.05 if k % 7 else 3.0)  # in and out of fal's band
        b0 = rng.normal(size=6) * 5.0
        fast.update(y, b0)
        ref.update(y, b0)
        worst = max(worst, float(np.max(np.abs(fast.z - ref.z))))
        ref.z = fast.z.copy()
    # the same arithmetic; NumPy's SIMD pow may differ from libm's in the last bit
    assert worst == 0.0 if kind == "linear" else worst < 1e-12


def test_compiled_effectiveness_pieces_are_the_numpy_loop():
    cfg = load_controller(CTRL)
    args = (cfg.effectiveness, cfg.vehicle.motor_time_constant_s, 0.01)
    fast, ref = MotorEffectivenessObserver(*args), MotorEffectivenessObserver(*args)
    ref._piece_fn = None
    fast.reset(np.full(4, 50.0))
    ref.reset(np.full(4, 50.0))
    rng = np.random.default_rng(4)
    for k in range(300):
        segs = ([(0.004, rng.uniform(10, 100, 4)), (0.006, rng.uniform(10, 100, 4))]
                if k % 5 == 0 else [(0.01, rng.uniform(10, 100, 4))])
        y_meas = fast._y_meas_prev - np.abs(rng.normal(size=4))
        e_fast = fast.update(y_meas, segs, 0.01)
        e_ref = ref.update(y_meas, segs, 0.01)
        assert np.array_equal(e_fast, e_ref) and np.array_equal(fast.y, ref.y)


def test_lag_chain_is_the_step_by_step_lag():
    cfg = dataclasses.replace(load_controller(CTRL), effectiveness=None)
    ctl = Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))
    rng = np.random.default_rng(5)
    lo, hi = ctl._u_lo, ctl._u_hi
    for n in (1, 5, 48, 49, 100):                  # within one chunk, at and past its end
        y0 = rng.uniform(lo, hi)
        us = rng.uniform(lo, hi, (n, len(lo)))
        hs = rng.choice([0.0025, 0.005, 0.01, 0.03, 0.0123456789], n)
        ys, mids = ctl.predictor._chain(y0, us, hs)
        y = y0
        for k, (u, h) in enumerate(zip(us, hs)):
            assert np.array_equal(mids[k], ctl.predictor.lag(y, u, 0.5 * h))
            y = ctl.predictor.lag(y, u, h)
            assert np.array_equal(ys[k], y)


@pytest.mark.parametrize("form", ["csv", "ulg"])
def test_controller_log_writes_every_row_in_order_after_its_period(tmp_path, form):
    """In either form (controller.csv formatted in flight, controller.ulg packed and written
    as the same CSV on the ground: its bytes equal the CSV form's)."""
    from trq_lab import metrics
    from trq_offboard.log import ControllerLog
    from trq_offboard.loop import StepRecord
    from trq_offboard.records import ActuatorCommand, ReferenceSample
    from trq_wire.ulog import to_csv

    logs = [ControllerLog(tmp_path / f"controller.{f}", {"controller": "x", "frames": "a b"},
                          batch=3) for f in ("csv", "ulg")]
    cmd = ActuatorCommand((50.0,) * 4, (0.0,) * 4)
    records = []
    for k in range(8):
        if records:        # as the loop does: the last period closes at the next step's start
            records[-1].cpu.period_ns = 2_000_000 + k
        ref = ReferenceSample((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), 0.0,
                              "hold" if k < 5 else "land")
        r = StepRecord(0.01 * k, 10_000 * k, _hover_state(), ref, cmd, None, None)
        for log in logs:
            log(r)
        r.cpu.prepare_ns, r.cpu.wire_ns, r.cpu.log_ns = 300_000, 100_000, 1_000
        records.append(r)
    for log in logs:
        log.close()
    path = tmp_path / "controller.csv"
    if form == "ulg":
        csv_bytes = path.read_bytes()
        path = to_csv(tmp_path / "controller.ulg", tmp_path / "ground.csv")
        assert path.read_bytes() == csv_bytes
    _, cols = metrics.read_csv(path)
    assert cols["stamp_us"].tolist() == [10_000 * k for k in range(8)]
    assert cols["cpu_period_ms"][:7].tolist() == [(2_000_000 + k) * 1e-6 for k in range(1, 8)]
    assert math.isnan(cols["cpu_period_ms"][7])        # the last period never closed
    assert cols["cpu_prepare_ms"].tolist() == [0.3] * 8
    assert np.isnan(cols["cpu_observer_ms"]).all()      # no StepInfo: not measured


def _walk_step_by_step(ctl, t0, t1, cut=None):
    """The actuator walk laid out command piece by command piece, each step through `_lag`:
    the specification `DelayPredictor.actuator_walk` (NumPy layout, compiled chain) must meet to
    the bit."""
    segs = ctl.predictor.in_effect(-math.inf, t1)
    y = segs[0][2].copy()
    path, y_cut = [], None
    for lo, hi, u in segs:
        cuts = [lo] + [c for c in (t0, cut) if c is not None and lo < c < hi] + [hi]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b <= a or not math.isfinite(a):
                continue
            if a >= t0:
                n = max(1, math.ceil((b - a) / PREDICT_STEP_S - 1e-9))
                h = (b - a) / n
                for i in range(n):
                    path.append((a + i * h, b if i == n - 1 else a + (i + 1) * h,
                                 ctl.predictor.lag(y, u, 0.5 * h)))
                    y = ctl.predictor.lag(y, u, h)
            else:
                y = ctl.predictor.lag(y, u, b - a)
            if cut is not None and b == cut:
                y_cut = y.copy()
    if cut is not None and y_cut is None:
        y_cut = y.copy()
    return path, y, y_cut


def _history_controller(delay: float, lagged: str = "auto") -> Controller:
    """A controller without the effectiveness observer, on a hover solver, `delay` applied."""
    cfg = dataclasses.replace(load_controller(CTRL), effectiveness=None, applied_delay_s=delay,
                              lagged_actuators=lagged)
    return Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))


def _same_walk(got, want, why):
    assert len(got[0]) == len(want[0]), why
    for (a, b, ym), (a2, b2, ym2) in zip(got[0], want[0]):
        assert (a, b) == (a2, b2) and np.array_equal(ym, ym2), why
    assert np.array_equal(got[1], want[1]), why
    assert (got[2] is None) == (want[2] is None), why
    if got[2] is not None:
        assert np.array_equal(got[2], want[2]), why


@pytest.mark.parametrize("delay", [0.0, 0.004, 0.04])
def test_actuator_walk_is_the_step_by_step_walk(delay):
    """Random histories of commands (stamps regular, jittered, repeated, some out of order),
    walks over (t0, t1] with and without a cut in [t0, t1], t0 = t1, the cut at t0 or t1, t0
    before the oldest command, gaps of lost samples, and no commands at all: the NumPy layout
    and each compiled walk that fits (predictor.walk_function) give the same path, outputs and
    cut outputs as the step-by-step walk, bit for bit, and the compiled b0 sum is the observer's
    loop's."""

    ctl = _history_controller(delay, lagged="on")
    fns = list(ctl.predictor._walk_fns)
    assert len(fns) == 2
    fitted = [0] * len(fns)
    rng = np.random.default_rng(11)
    lo, hi = ctl._u_lo, ctl._u_hi
    x = np.zeros(12)
    for trial in range(400):
        n = int(rng.integers(0, 40))
        step = rng.choice([0.01, 0.0097])
        stamps = np.cumsum(rng.choice([step, step, 0.0, 2 * step], n)) if n else np.zeros(0)
        stamps = np.maximum.accumulate(stamps + rng.uniform(0, 1e-3, n) * (trial % 3 == 0))
        if trial % 7 == 0 and n > 3:                      # a late sample: an older stamp last
            stamps[-1] = stamps[-3] - 0.001
        ctl.predictor.sent = CommandHistory(32, ctl.model.nu,
                                   [(float(t), rng.uniform(lo, hi)) for t in stamps])
        ctl.predictor.last_u = rng.uniform(lo, hi)
        last = float(stamps[-1]) if n else 0.0
        t0 = last - float(rng.choice([0.0, 0.0, 0.01, 0.02, 0.5]))
        t1 = t0 + float(rng.choice([0.0, 0.01, 0.01, 0.0102, 0.013, 0.03, delay + 0.01]))
        cut = [None, t0, t1, 0.5 * (t0 + t1), last, t0 + 0.004][trial % 6]
        if cut is not None and not t0 <= cut <= t1:      # the controller's cut: in [t0, t1]
            cut = None
        x = rng.normal(size=12) * 0.3
        want = _walk_step_by_step(ctl, t0, t1, cut)
        ctl.predictor._walk_fns = []
        _same_walk(ctl.predictor.actuator_walk(t0, t1, cut), want, ("numpy", trial))
        ctl.predictor._walk_fns = fns
        for i, fn in enumerate(fns):
            sent = ctl.predictor.sent
            got = (run_walk(fn, sent.times, sent.commands, delay, t0, t1, cut, x)
                   if len(sent) else None)
            if got is None:
                continue
            fitted[i] += 1
            _same_walk(got, want, ("compiled", i, trial))
            if cut is not None and cut > t0:              # the observer's b0 over (t0, cut)
                b0 = ctl.predictor.b0_delayed(x, t0, cut, got[0])
                loop = ctl.predictor.b0_delayed(x, t0, cut, list(got[0]))
                assert np.array_equal(b0, loop), ("b0", i, trial)
    assert min(fitted) >= 40, fitted                     # each size serves many of them


def _counting_reference():
    """A Reference class that counts its grid calls (in `calls`, on the class)."""
    from trq_offboard.reference import Reference

    class Counting(Reference):
        calls = 0

        def grid(self, t_s, step_s, n):
            Counting.calls += 1
            return super().grid(t_s, step_s, n)

    return Counting


def test_reference_grid_is_sampled_once_for_the_same_time():
    """The preparation and the next step ask for the same time: one grid for both, the same
    states as a fresh one; another time or another reference object samples again."""
    from trq_offboard.reference import Reference

    cfg = dataclasses.replace(load_controller(CTRL), effectiveness=None)
    ctl = Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))

    Counting = _counting_reference()

    ref = Counting(cfg.reference, [0.0, 0.0, 0.0], 0.0)
    fresh = Reference(cfg.reference, [0.0, 0.0, 0.0], 0.0)
    x = np.zeros(12)
    x[8] = 3.0                                   # the yaw is unwrapped next to this one
    for t in (12.3, 12.3, 12.31, 12.31, 12.3):
        got = ctl._reference_states(t, x, ref)
        want = Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps)
                          )._reference_states(t, x, fresh)
        assert np.array_equal(got, want)
    assert Counting.calls == 3
    other = Counting(cfg.reference, [0.0, 0.0, 0.0], 0.0)
    ctl._reference_states(12.3, x, other)
    assert Counting.calls == 4


class _PreparingSolver(_HoverSolver):
    """_HoverSolver with a preparation phase: records the reference each phase is handed."""

    prepares = True

    def __init__(self, u, n, nx=12):
        super().__init__(u, n, nx)
        self.solved, self.prepared = [], []

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        self.solved.append(np.array(x_ref))
        return super().solve(x0, x_ref, d, u_prev, guess, y0)

    def prepare(self, x_ref, d, u_prev, guess, y0=None):
        self.prepared.append(np.array(x_ref))


@pytest.mark.parametrize("delay", [0.0, 0.004, 0.023])
def test_the_preparation_samples_the_reference_the_next_step_flies(delay):
    """Times as the flight loop forms them (whole microseconds times 1e-6), one period apart:
    the preparation asks for the very time the next step asks for (adding the period to the
    last float would miss it by a rounding, most periods), so one grid a period serves both,
    and the prepared reference is the next step's."""
    cfg = dataclasses.replace(load_controller(CTRL), effectiveness=None, applied_delay_s=delay,
                              delay_compensation="predict")
    probe = Controller(cfg, solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))
    solver = _PreparingSolver(probe.u_trim, cfg.horizon_steps)
    ctl = Controller(cfg, solver=solver)
    assert ctl.delay_s == pytest.approx(delay)

    Counting = _counting_reference()

    ref = Counting(cfg.reference, [0.0, 0.0, 0.0], 0.0)
    period_us = round(cfg.control_dt_s * 1e6)
    start_us = 7_654_321
    ctl.reset(start_us * 1e-6, _hover_state())
    steps = 60
    for k in range(1, steps + 1):
        ctl.step((start_us + k * period_us) * 1e-6, _hover_state(), None, ref)
        ctl.prepare(ref)
    assert Counting.calls == steps + 1          # the first step's own, then one a period
    assert len(solver.prepared) == steps and len(solver.solved) == steps
    for prepared, flown in zip(solver.prepared, solver.solved[1:]):
        # the yaw is unwrapped next to each phase's own state (predicted, then measured): the
        # same angle to a rounding
        assert np.array_equal(np.delete(prepared, 8, axis=1), np.delete(flown, 8, axis=1))
        assert np.max(np.abs(prepared[:, 8] - flown[:, 8])) < 1e-12


def _in_effect_spec(sent, last_u, delay, t0, t1):
    """The segments in effect, written out command by command (the specification)."""
    acts = [(ts + delay, u) for ts, u in sent] or [(t0, last_u)]
    segs = []
    if acts[0][0] > t0:
        segs.append((t0, min(acts[0][0], t1), acts[0][1]))
    for i, (start, u) in enumerate(acts):
        end = acts[i + 1][0] if i + 1 < len(acts) else math.inf
        lo, hi = max(start, t0), min(end, t1)
        if hi > lo:
            segs.append((lo, hi, u))
    return segs


@pytest.mark.parametrize("delay", [0.0, 0.004, 0.04])
def test_commands_in_effect_are_the_command_by_command_segments(delay):
    """Random histories (in order, with repeats, out of order, empty), intervals inside,
    before, after and across them, empty ones: the same segments, bit for bit."""
    ctl = _history_controller(delay)
    rng = np.random.default_rng(17)
    lo, hi = ctl._u_lo, ctl._u_hi
    for trial in range(400):
        n = int(rng.integers(0, 40))
        stamps = np.cumsum(rng.choice([0.01, 0.01, 0.0, 0.02], n))
        if trial % 4 == 0:
            stamps = rng.permutation(stamps)               # out of order: still the spec's
        sent = [(float(t), rng.uniform(lo, hi)) for t in stamps]
        ctl.predictor.sent = CommandHistory(32, ctl.model.nu, sent)
        ctl.predictor.last_u = rng.uniform(lo, hi)
        last = float(stamps[-1]) if n else 0.0
        t0 = last - float(rng.choice([-0.01, 0.0, 0.01, 0.03, 0.5]))
        t1 = t0 + float(rng.choice([-0.01, 0.0, 0.01, 0.013, delay + 0.01]))
        got = ctl.predictor.in_effect(t0, t1)
        want = _in_effect_spec(sent[-32:], ctl.predictor.last_u, delay, t0, t1)
        assert len(got) == len(want), (trial, got, want)
        for (a, b, u), (a2, b2, u2) in zip(got, want):
            assert a == a2 and b == b2 and np.array_equal(u, u2), trial


class _ScaledHoverSolver(_HoverSolver):
    """The hover solver with the throttle bounds the effectiveness observer sets (recorded)."""

    class _Ocp(_NoOcp):
        def __init__(self):
            self.scales = []

        def set_throttle_scale(self, e):
            self.scales.append(np.array(e, float))

    def __init__(self, u, n):
        super().__init__(u, n)
        self.ocp = self._Ocp()


@pytest.mark.parametrize("path", ["composed", "effective", "composed without motors"])
def test_compiled_observer_periods_are_the_call_by_call_ones(path):
    """The observers' period in one compiled call against the same period call by call: the
    ESO, the rate observer and the motors' effectiveness observer (deficit, observer piece, the
    motors' share of d) composed (observer_period.py), or the effectiveness observer's period
    alone as one call (`effective`); the same estimates, outputs, d, output error and throttle
    bounds after every step of a flight with disturbances, regular periods, late and lost
    samples (those take the call-by-call path in both)."""
    cfg = load_controller(CTRL)
    probe = Controller(dataclasses.replace(cfg, effectiveness=None),
                       solver=_HoverSolver(np.zeros(8), cfg.horizon_steps))
    if path == "composed without motors":
        cfg = dataclasses.replace(cfg, effectiveness=None)
    ctls = [Controller(cfg, solver=_ScaledHoverSolver(probe.u_trim, cfg.horizon_steps))
            for _ in range(2)]
    a, b = ctls
    assert a.rate_observer is not None and a._period is not None
    b._period = None                                    # call by call
    if b.motors is not None:
        b.motors._effective_fn = None
    if path == "effective":
        a._period = None
    calls = [0]
    fn = a._period._fn if a._period is not None else a.motors._effective_fn
    name = "evaluate" if a._period is not None else "outputs"
    real = getattr(fn, name)

    def counted(*args):
        calls[0] += 1
        return real(*args)
    setattr(fn, name, counted)
    rng = np.random.default_rng(23)
    x = np.zeros(12)
    x[2] = -2.0
    t = 0.0
    for c in ctls:
        c.reset(t, StateEstimate.from_vector(x))
    for k in range(300):
        t += float(rng.choice([0.01, 0.01, 0.01, 0.02, 0.0, 0.0103]))
        x[3:6] += rng.normal(size=3) * 0.02 + (0.0, 0.0, 0.004 if k > 100 else 0.0)   # sinking
        x[6:9] += rng.normal(size=3) * 0.002
        x[9:12] = rng.normal(size=3) * 0.05
        s = StateEstimate.from_vector(x)
        out = [c.step(t, s, None, _const_reference()) for c in ctls]
        assert out[0][0] == out[1][0], k
        ia, ib = (dataclasses.replace(o[1], cpu=None) for o in out)
        assert ia == ib, k                   # d, the output error, the effectiveness
        assert np.array_equal(a._last_d, b._last_d), k
        assert np.array_equal(a._eso_d, b._eso_d), k
        assert np.array_equal(a.eso.z, b.eso.z) and np.array_equal(a.eso._y_prev, b.eso._y_prev)
        assert np.array_equal(a.rate_observer.s, b.rate_observer.s), k
        assert np.array_equal(a.rate_observer._y_prev, b.rate_observer._y_prev), k
        if a.motors is None:
            continue
        for name in ("e", "y", "_y_meas_prev"):
            assert np.array_equal(getattr(a.motors.observer, name),
                                  getattr(b.motors.observer, name)), (k, name)
        assert np.array_equal(a._scale, b._scale)
        assert np.array_equal(a.solver.ocp.scales[-1], b.solver.ocp.scales[-1])
    assert calls[0] > 150                        # the compiled call served most periods
    if a.motors is not None:
        assert np.min(a.motors.observer.e) < 1.0  # and the deficit was read
