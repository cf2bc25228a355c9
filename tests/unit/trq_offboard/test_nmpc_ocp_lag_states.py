"""The NMPC's actuator lag states (controller key actuator_states, trq_offboard/nmpc/ocp.py):
the stage state carries the servo angles and throttles through their first-order lags, the plan's
inputs are the commands. Off (the default on a clean link) is the old stage exactly."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest
import yaml

from trq_offboard.allocation import Allocator
from trq_offboard.config import ConfigError, load_controller
from trq_params.loader import read_yaml     # the loader's YAML 1.2 dialect: `off` stays a string
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc.ocp import Ocp, Stage
from trq_offboard.nmpc.base import Solver

from conftest import ROOT

PARAMS = ROOT / "params"
CTRL = PARAMS / "controller"
RNG = np.random.default_rng(3)


def _cfg(name="trq_nmpc_eso", states="on", **changes):
    cfg = load_controller(CTRL / f"{name}.yaml")
    return dataclasses.replace(cfg, actuator_states=states, **changes)


def _hover(cfg):
    alloc = Allocator(cfg.vehicle)
    return alloc.command_vector(alloc.hover())


def _state():
    x = np.zeros(12)
    x[0:3] = (0.1, -0.2, -2.0)
    x[3:6] = (0.3, -0.1, 0.05)
    x[6:9] = (0.05, -0.04, 0.3)
    x[9:12] = (0.2, -0.1, 0.05)
    return x


def test_auto_follows_the_delay_predictor():
    paper = load_controller(CTRL / "trq_nmpc_eso_paper.yaml")
    assert paper.actuator_states == "off"                    # nmpc.yaml's default (measured)
    assert not dataclasses.replace(paper, applied_delay_s=0.04).nmpc_actuator_states
    cfg = load_controller(CTRL / "trq_nmpc_eso.yaml")
    assert cfg.actuator_states == "auto"                     # with the observer on rates
    assert not cfg.nmpc_actuator_states                      # lockstep: no delay, no states
    assert dataclasses.replace(cfg, applied_delay_s=0.04).nmpc_actuator_states
    assert not dataclasses.replace(cfg, applied_delay_s=0.005).nmpc_actuator_states  # < period
    assert not dataclasses.replace(cfg, applied_delay_s=0.04,
                                   delay_compensation="none").nmpc_actuator_states
    assert not dataclasses.replace(cfg, applied_delay_s=0.04,
                                   actuator_states="off").nmpc_actuator_states
    assert dataclasses.replace(cfg, actuator_states="on").nmpc_actuator_states


def test_config_key_is_validated(tmp_path):
    src = read_yaml(CTRL / "nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    src["observer"]["file"] = str(CTRL / "eso.yaml")
    src["actuator_states"] = "sometimes"
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(src))
    with pytest.raises(ConfigError, match=r"actuator_states.*sometimes.*on\|off\|auto"):
        load_controller(path)
    del src["actuator_states"]                                # default: auto
    path.write_text(yaml.safe_dump(src))
    assert load_controller(path).actuator_states == "auto"


@pytest.mark.parametrize("name", ["trq_nmpc_eso", "quad_nmpc"])
def test_off_is_the_old_stage(name):
    """Off: s = [x, a] (TRQ) or x (quad) and the dynamics are the model's RK4 over h with the
    input held (up to the rounding of a + h w computed here in NumPy; the lockstep flight log
    of paper_fault50 is bit-identical to the code before the option)."""
    cfg = _cfg(name, "off")
    model = PredictionModel(cfg.vehicle)
    stage = Stage.build(cfg, model)
    assert stage.n_lag == 0
    assert (stage.ns, stage.nv) == ((16, 8) if model.tilting else (12, 4))
    F = model.discrete(cfg.step_s, 1)
    h = cfg.step_s
    u0 = _hover(cfg)
    for _ in range(5):
        x, d = _state() + 0.01 * RNG.standard_normal(12), 0.3 * RNG.standard_normal(6)
        if model.tilting:
            a = 0.1 * RNG.standard_normal(4)
            w = RNG.standard_normal(4)
            c = (u0[4:8] + RNG.uniform(-5, 5, 4)) / 100.0
            s, v = np.concatenate([x, a]), np.concatenate([w, c])
            u = np.concatenate([a + h * w, 100.0 * c])
            ref = np.concatenate([np.asarray(F(x, u, d)).ravel(), a + h * w])
        else:
            c = (u0 + RNG.uniform(-5, 5, 4)) / 100.0
            s, v = x, c
            ref = np.asarray(F(x, 100.0 * c, d)).ravel()
        out = np.asarray(stage.dynamics(s, v, d)).ravel()
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-14)
    ocp = Ocp.build(cfg, model)
    assert ocp.n_lag == 0 and ocp.ns == stage.ns


@pytest.mark.parametrize("name", ["trq_nmpc_eso", "quad_nmpc"])
def test_lag_states_follow_the_analytic_first_order_step(name):
    """A command held from y0: after k steps the lag states are u + (y0 - u) exp(-k h / T)."""
    cfg = _cfg(name)
    model = PredictionModel(cfg.vehicle)
    stage = Stage.build(cfg, model)
    vm = cfg.vehicle
    nx, h = model.nx, cfg.step_s
    assert stage.n_lag == model.nu
    assert stage.ns == nx + (4 if model.tilting else 0) + model.nu
    u_hover = _hover(cfg)
    tau = np.array(([vm.servo_time_constant_s] * 4 if model.tilting else [])
                   + [vm.motor_time_constant_s] * 4)
    scale = np.array(([1.0] * 4 if model.tilting else []) + [100.0] * 4)
    y0 = u_hover / scale
    u_cmd = y0.copy()
    u_cmd[-4:] += 0.08                                       # +8 % throttle
    if model.tilting:
        u_cmd[0:4] = (0.1, -0.05, 0.2, 0.0)                  # rad
        a0 = u_cmd[0:4].copy()                               # commanded tilt already there
        v = np.concatenate([np.zeros(4), u_cmd[4:8]])         # no tilt rate: command held
        s = np.concatenate([_state(), a0, y0])
    else:
        v = u_cmd
        s = np.concatenate([_state(), y0])
    d = np.zeros(6)
    for k in range(1, 6):
        s = np.asarray(stage.dynamics(s, v, d)).ravel()
        y = s[stage.ns - stage.n_lag:]
        expect = u_cmd + (y0 - u_cmd) * np.exp(-k * h / tau)
        np.testing.assert_allclose(y, expect, rtol=0, atol=1e-12)


def test_model_inside_the_step_sees_the_lagged_input():
    """x_{k+1} of the lag stage against a fine integration (RK4, 1 ms) of the model driven by
    the analytic lag y(t) = u + (y0 - u) exp(-t / T): the RK4 inside the stage samples the
    exact lag at 0, h/2, h. Settled actuators (y0 = u) give the old stage's x_{k+1}."""
    cfg = _cfg()
    model = PredictionModel(cfg.vehicle)
    on = Stage.build(cfg, model)
    off = Stage.build(_cfg(states="off"), model)
    vm = cfg.vehicle
    h = cfg.step_s
    tau = np.array([vm.servo_time_constant_s] * 4 + [vm.motor_time_constant_s] * 4)
    scale = np.array([1.0] * 4 + [100.0] * 4)
    x = _state()
    d = np.array([0.2, -0.1, 0.5, 3.0, -2.0, 0.5])
    a_prev = np.array([0.05, -0.05, 0.1, 0.0])
    w = np.array([1.0, -0.5, 0.0, 2.0])
    c = (_hover(cfg)[4:8] + np.array([6.0, -4.0, 2.0, 0.0])) / 100.0
    u = np.concatenate([a_prev + h * w, c])                    # the commands of this step
    y0 = np.concatenate([a_prev - 0.05, c - 0.1])              # actuators behind the commands
    s_on = np.concatenate([x, a_prev, y0])
    x_on = np.asarray(on.dynamics(s_on, np.concatenate([w, c]), d)).ravel()[0:12]
    # fine reference
    f_dt = model.discrete_dt()
    n = 50
    xr = x.copy()
    for i in range(n):
        t_mid = (i + 0.5) * h / n
        y = u + (y0 - u) * np.exp(-t_mid / tau)
        xr = np.asarray(f_dt(xr, scale * y, d, h / n)).ravel()
    x_hold = np.asarray(off.dynamics(np.concatenate([x, a_prev]), np.concatenate([w, c]), d)
                        ).ravel()[0:12]
    err_on = np.max(np.abs(x_on - xr))
    err_hold = np.max(np.abs(x_hold - xr))
    assert err_on < 0.05 * err_hold                # the lag matters, and the stage has it
    assert np.max(np.abs(x_on[9:12] - xr[9:12])) < 2e-3      # rad/s
    # settled actuators: nothing to lag, the old stage
    s_set = np.concatenate([x, a_prev, u])
    np.testing.assert_allclose(np.asarray(on.dynamics(s_set, np.concatenate([w, c]), d)
                                          ).ravel()[0:12], x_hold, rtol=0, atol=1e-12)


def test_ocp_packs_and_fixes_the_actuators():
    """s_0's lag rows are fixed to y0 (scaled); the guess is rolled out through the lags, so
    the packed guess has no gap in the lag rows; the unpacked plan is the commands."""
    cfg = _cfg()
    model = PredictionModel(cfg.vehicle)
    ocp = Ocp.build(cfg, model)
    stage = Stage.build(cfg, model)
    N, nx, ns = ocp.n_steps, ocp.nx, ocp.ns
    assert ocp.n_lag == 8 and ns == 24
    u_hover = _hover(cfg)
    u_plan = np.tile(u_hover, (N, 1))
    u_plan[:, 4] += 5.0
    u_plan[:, 0] = np.linspace(0.0, 0.2, N)
    x_plan = np.tile(_state(), (N + 1, 1))
    y0 = u_hover.copy()
    y0[5] -= 3.0
    y0[1] += 0.02
    alpha_prev = u_hover[0:4]
    with pytest.raises(ValueError, match="y0"):
        ocp.bounds(_state(), alpha_prev)
    lbw, ubw = ocp.bounds(_state(), alpha_prev, y0)
    s0 = ocp.s_index[0]
    np.testing.assert_array_equal(lbw[s0], ubw[s0])
    np.testing.assert_allclose(lbw[s0][ns - 8:], y0 / ocp.u_scale)
    w = ocp.pack(x_plan, u_plan, alpha_prev, y0)
    d = np.zeros(6)
    for k in range(N):
        nxt = np.asarray(stage.dynamics(w[ocp.s_index[k]], w[ocp.v_index[k]], d)).ravel()
        np.testing.assert_allclose(nxt[nx:], w[ocp.s_index[k + 1]][nx:], atol=1e-12)
    u_back, x_back = ocp.unpack(w)
    np.testing.assert_allclose(u_back, u_plan, atol=1e-9)
    np.testing.assert_allclose(x_back, x_plan)
    # every constraint stays local to a stage: the gap of stage k depends on s_k, v_k, s_{k+1}
    jsp = ca.jacobian(ocp.nlp["g"], ocp.nlp["x"]).sparsity()
    rows, cols = jsp.get_triplet()
    nz = ns + ocp.nv
    for r, c in zip(rows, cols):
        k = r // ns
        assert k * nz <= c < (k + 1) * nz + ns
    assert jsp.size1() == N * ns


class _LagOcp:
    """The part of the NMPC's OCP the controller asks about when it is built: it carries the
    actuators' lag states, and takes the motors' effectiveness estimates."""
    n_lag = 8

    def set_throttle_scale(self, e):
        pass


class _LagSolver(Solver):
    ocp = _LagOcp()

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        raise NotImplementedError              # only built, never flown


def test_controller_starts_the_plan_from_the_lagged_actuators():
    """With a 40 ms round trip the controller builds the lag-state NMPC (auto) and starts its
    plan from the actuators' outputs predicted for t + delay: the lag of the commands in
    flight, as its delay predictor computes them."""
    from trq_offboard.controller import Controller
    from trq_offboard.predictor import CommandHistory

    cfg = dataclasses.replace(load_controller(CTRL / "trq_nmpc_eso.yaml"), applied_delay_s=0.04)
    ctl = Controller(cfg, solver=_LagSolver())
    assert ctl._act_states and ctl.predictor.lagged and ctl.delay_s == 0.04
    hover = ctl.u_trim
    up = hover.copy()
    up[4:8] += 10.0
    ctl.predictor.sent = CommandHistory(32, ctl.model.nu,
                                        [(-0.01 * k, hover) for k in range(32, 0, -1)]
                                        + [(0.0, up)])
    # the step command (sent for the state at 0) acts from 0.04; at 0.07 it has lagged 30 ms
    path, y, y_cut = ctl.predictor.actuator_walk(0.0, 0.07, 0.05)
    tau = cfg.vehicle.motor_time_constant_s
    expect = up[4:8] + (hover[4:8] - up[4:8]) * math.exp(-0.03 / tau)
    np.testing.assert_allclose(y[4:8], expect, rtol=0, atol=1e-9)
    # and at the cut (the observer's side of the path ends there): 10 ms of lag
    expect = up[4:8] + (hover[4:8] - up[4:8]) * math.exp(-0.01 / tau)
    np.testing.assert_allclose(y_cut[4:8], expect, rtol=0, atol=1e-9)
    np.testing.assert_allclose(y[0:4], hover[0:4], atol=1e-12)
    again = ctl.predictor.actuator_path(0.0, 0.07, 0.05)
    assert len(path) == len(again)
    for (a, b, ym), (a2, b2, ym2) in zip(path, again):
        assert (a, b) == (a2, b2)
        np.testing.assert_array_equal(ym, ym2)


def test_lag_states_bring_the_lagged_observer_along():
    """lagged_actuators auto is on whenever the NMPC carries the lag states, even without a
    delay (the observer's b0 must see the same lags); auto in lockstep has neither. The shipped
    trq_nmpc_eso sets it on (its observer on body rates needs it), trq_nmpc_eso_paper auto."""
    from trq_offboard.controller import Controller

    shipped = load_controller(CTRL / "trq_nmpc_eso.yaml")
    assert Controller(shipped, solver=_LagSolver()).predictor.lagged
    base = load_controller(CTRL / "trq_nmpc_eso_paper.yaml")
    assert base.lagged_actuators == "auto"
    assert not Controller(base, solver=_LagSolver()).predictor.lagged           # auto, lockstep
    forced = dataclasses.replace(base, actuator_states="on")
    ctl = Controller(forced, solver=_LagSolver())
    assert ctl.predictor.lagged and ctl._act_states and ctl.delay_s == 0.0
    off = dataclasses.replace(forced, lagged_actuators="off")
    assert not Controller(off, solver=_LagSolver()).predictor.lagged


def test_bare_yaml_on_off_read_as_words(tmp_path):
    """YAML 1.1 reads a bare `off` as false: an on|off|auto key takes it as the word."""
    src = read_yaml(CTRL / "nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    src["observer"]["file"] = str(CTRL / "eso.yaml")
    del src["actuator_states"], src["lagged_actuators"]
    base = yaml.safe_dump(src)
    path = tmp_path / "c.yaml"
    for word in ("off", "on", "auto"):
        path.write_text(base + f"actuator_states: {word}\nlagged_actuators: {word}\n")
        cfg = load_controller(path)
        assert (cfg.actuator_states, cfg.lagged_actuators) == (word, word)
    path.write_text(base + "actuator_states: 1\n")
    with pytest.raises(ConfigError, match="actuator_states.*one of on"):
        load_controller(path)
