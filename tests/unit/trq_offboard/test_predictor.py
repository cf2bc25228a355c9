"""The controller's delay predictor (predictor.DelayPredictor.predict): over a link whose round
trip is applied_delay_s, the NMPC plans from the state predicted for the time its command will
act, driven by the commands in flight, through the actuators' lags when asked to."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from trq_offboard.config import load_controller
from trq_offboard.controller import Controller
from trq_offboard.nmpc.base import Solver
from trq_offboard.predictor import CommandHistory

from conftest import ROOT

CTRL = ROOT / "params" / "controller" / "trq_nmpc_eso.yaml"
DELAY_S = 0.04


class _NoSolver(Solver):
    """The predictor needs no NMPC; building one would cost seconds."""
    ocp = SimpleNamespace(n_lag=0)

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        raise NotImplementedError


def controller(lagged: str, delay_s: float = DELAY_S) -> Controller:
    # the predictor alone: without the motor effectiveness observer (which needs an NMPC)
    cfg = dataclasses.replace(load_controller(CTRL), applied_delay_s=delay_s,
                              lagged_actuators=lagged, effectiveness=None)
    assert cfg.delay_compensation == "auto"
    return Controller(cfg, solver=_NoSolver())


def hover_state() -> np.ndarray:
    x = np.zeros(12)
    x[2] = -2.0                          # 2 m up (NED)
    return x


def fill(ctl: Controller, commands: list[tuple[float, np.ndarray]]) -> None:
    ctl.predictor.sent = CommandHistory(32, ctl.model.nu, commands)


def test_hover_commands_in_flight_predict_no_motion():
    ctl = controller("on")
    u = ctl.u_trim
    fill(ctl, [(-0.01 * k, u) for k in range(32, -1, -1)])
    x = hover_state()
    xp = ctl.predictor.predict(x, 0.0, DELAY_S, np.zeros(6))
    assert np.max(np.abs(xp - x)) < 1e-6


def test_a_climb_command_in_flight_acts_only_from_its_stamp_plus_the_delay():
    """Commands answering states at -0.02 and -0.01 s act from 0.02 and 0.03 s: over [0, 0.04]
    the step acts for 0.02 s. Without the lags the vertical speed changes by a_z * 0.02; with
    them (30 ms motor time constant) by a_z times the integral of the lagged step."""
    u_up = None
    out = {}
    for lagged in ("off", "on"):
        ctl = controller(lagged)
        hover = ctl.u_trim
        u_up = hover.copy()
        u_up[4:8] += 10.0                             # +10 % throttle on every motor
        fill(ctl, [(-0.01 * k, hover) for k in range(32, 2, -1)]
             + [(-0.02, u_up), (-0.01, u_up)])
        x = hover_state()
        out[lagged] = ctl.predictor.predict(x, 0.0, DELAY_S, np.zeros(6))
    ctl = controller("off")
    a_z = float(np.asarray(ctl.model.accel(hover_state(), u_up)).ravel()[2])
    assert a_z < -1.0                                  # upward (NED) and not small
    dv_off, dv_on = out["off"][5], out["on"][5]
    assert dv_off == pytest.approx(a_z * 0.02, rel=1e-3)
    tau = ctl.cfg.vehicle.motor_time_constant_s
    lagged_s = 0.02 - tau * (1.0 - math.exp(-0.02 / tau))    # integral of the lagged step
    assert dv_on == pytest.approx(a_z * lagged_s, rel=0.05)
    assert a_z * 0.02 < dv_on < 0.0
    # nothing but the vertical channel moves
    for xp in out.values():
        assert np.max(np.abs(xp[[0, 1, 3, 4, 6, 7, 8, 9, 10, 11]])) < 1e-9


def test_actuator_path_is_the_first_order_lag():
    """A small throttle step held from t = 0 (no rate limit reached): after one time constant
    the reconstructed throttle has gone 1 - 1/e of the way."""
    ctl = controller("on", delay_s=0.0)
    tau = ctl.cfg.vehicle.motor_time_constant_s
    assert tau > 0.0
    hover = ctl.u_trim
    step = hover.copy()
    step[4:8] += 2.0
    fill(ctl, [(-0.01 * k, hover) for k in range(31, 0, -1)] + [(0.0, step)])
    path = ctl.predictor.actuator_path(tau - 0.0025, tau + 0.0025)     # one step centred on tau
    (a, b, y_mid), = path
    assert (a, b) == pytest.approx((tau - 0.0025, tau + 0.0025))
    assert y_mid[4:8] == pytest.approx(hover[4:8] + 2.0 * (1.0 - math.exp(-1.0)), abs=1e-9)
    # tilts were not commanded to move and have not
    assert y_mid[0:4] == pytest.approx(hover[0:4], abs=1e-12)


def test_no_delay_no_prediction():
    ctl = controller("auto", delay_s=0.0)
    assert ctl.delay_s == 0.0 and not ctl.predictor.lagged
    assert controller("auto").predictor.lagged and controller("off").delay_s == DELAY_S
    assert not controller("off").predictor.lagged
    # auto: nothing is predicted below one control period (10 ms; real time's solve latency)
    short = controller("auto", delay_s=0.005)
    assert short.delay_s == 0.0 and not short.predictor.lagged
    cfg = dataclasses.replace(load_controller(CTRL), applied_delay_s=0.005,
                              delay_compensation="predict", lagged_actuators="auto",
                              effectiveness=None)
    forced = Controller(cfg, solver=_NoSolver())
    assert forced.delay_s == 0.005 and forced.predictor.lagged


def test_one_path_serves_the_observer_and_the_predictor():
    """The step builds the actuators' path once, cut at the measurement time: the observer's
    part and the predictor's part are exactly the two paths built on their own, none of their
    steps lost to rounding at the cut (times that are not multiples of the step length)."""
    ctl = controller("on")
    hover = ctl.u_trim
    up = hover.copy()
    up[4:8] += 5.0
    t_last, t_s = 1.0 / 3.0, 1.0 / 3.0 + 0.0101
    fill(ctl, [(t_s - 0.0101 * k, hover if k % 2 else up) for k in range(31, -1, -1)])
    x, d = hover_state(), np.zeros(6)
    path = ctl.predictor.actuator_path(t_last, t_s + DELAY_S, t_s)
    p = ctl.predictor
    b0_alone = p.b0_delayed(x, t_last, t_s)
    pred_alone = p.predict(x, t_s, t_s + DELAY_S, d)
    assert p.b0_delayed(x, t_last, t_s, path) == pytest.approx(b0_alone, rel=1e-12, abs=1e-12)
    assert p.predict(x, t_s, t_s + DELAY_S, d, path) == pytest.approx(pred_alone, rel=1e-9,
                                                                      abs=1e-12)
    # the steps cover both intervals exactly
    before = sum(b - a for a, b, _ in path if 0.5 * (a + b) < t_s)
    after = sum(b - a for a, b, _ in path if 0.5 * (a + b) > t_s)
    assert before == pytest.approx(t_s - t_last, abs=1e-12)
    assert after == pytest.approx(DELAY_S, abs=1e-12)


def test_interp_rows_matches_np_interp():
    """The plan interpolation the controller shifts its guess with: every column as np.interp,
    clamped outside the plan."""
    from trq_offboard.controller import _interp_rows
    rng = np.random.default_rng(1)
    x = rng.normal(size=(21, 12))
    h = 0.05
    times = np.concatenate([[-0.01, 0.0, 0.013, 0.5, 0.999], h * np.arange(21), [1.0, 1.3]])
    grid = h * np.arange(21)
    want = np.column_stack([np.interp(times, grid, x[:, j]) for j in range(12)])
    np.testing.assert_allclose(_interp_rows(x, h, times), want, rtol=0, atol=1e-12)


def test_a_controller_built_again_shares_its_compiled_functions_not_their_buffers():
    """The second controller of a configuration in a process takes the first's compiled
    functions (trq_wire.cache.built_once) and evaluates them into buffers of its own: what one
    evaluates does not change what the other has read."""
    a, b = controller("auto"), controller("auto")
    assert a.predictor._chain_fn is not b.predictor._chain_fn
    assert a.predictor._chain_fn.fn is b.predictor._chain_fn.fn
    assert a.eso._period_fn.fn is b.eso._period_fn.fn
    fa, fb = a.eso._period_fn, b.eso._period_fn
    z, y = np.zeros(18), np.full(6, 0.1)
    read = fa.outputs_in_place(z, np.zeros(6), y, np.zeros(6), 0.01)[0]
    before = read.copy()
    fb.outputs_in_place(z, np.zeros(6), 3.0 * y, np.zeros(6), 0.01)
    assert np.array_equal(read, before) and np.any(before != 0.0)
