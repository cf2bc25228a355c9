"""The observers hold on the ground (Controller.landed, set by the flight loop): at a spool-up
on the gear and after a touchdown the ground's reaction and friction are not learnt as a
disturbance (docs/decisions/2026-12-06-observer-on-the-gear.md)."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ROOT
from trq_offboard.config import load_controller
from trq_offboard.controller import Controller
from trq_offboard.nmpc.base import Solver
from trq_offboard.records import ReferenceSample, SolveInfo, SolveStatus, StateEstimate
from trq_offboard.reference import ConstantReference


class Hold(Solver):
    """A solver that flies one fixed command, whatever the state."""

    def __init__(self, n: int, u: np.ndarray) -> None:
        self.n, self.u = n, u
        self.ocp = type("NoOcp", (), {"n_lag": 0, "set_throttle_scale": lambda s, e: None})()

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        return (np.tile(self.u, (self.n, 1)), np.tile(x0, (self.n + 1, 1)),
                SolveInfo(SolveStatus.OK, 1, 1e-4, 0.0))


def spool_up(landed: bool) -> np.ndarray:
    """Half a second of a spool-up to 70 % of the hover's throttle on a vehicle the ground
    holds still: the model says it sinks, it does not. The observer's last d."""
    cfg = load_controller(ROOT / "params" / "controller" / "trq_nmpc_eso.yaml")
    ctl = Controller(cfg, solver=Hold(cfg.horizon_steps, None))
    ctl.solver.u = ctl.u_trim.copy()
    ctl.solver.u[ctl._nt:] *= 0.7
    ref = ConstantReference(ReferenceSample((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0))
    state = StateEstimate((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    ctl.landed = landed
    for k in range(1, 51):
        ctl.step(0.01 * k, state, None, ref)
    return np.asarray(ctl._eso_d)


def test_the_observer_does_not_learn_the_ground_while_landed():
    free = spool_up(landed=False)
    held = spool_up(landed=True)
    assert abs(free[2]) > 1.0            # the ground's reaction read as an upward push
    np.testing.assert_array_equal(held, np.zeros(6))


@pytest.mark.slow
def test_a_flight_holds_the_observers_on_the_gear_and_flies_them_in_the_air(tmp_path):
    """A short hover in one process: the steps before the lift-off (the vehicle's land detector
    says ON_GROUND, then TAKEOFF while the vehicle does not yet climb) and after the touchdown
    hold the observer (its d logged zero); in between the controller flies it."""
    from trq_lab import harness
    from trq_lab.metrics import read_csv
    reference = {"kind": "hover", "altitude_m": 1.0, "climb_speed_m_s": 0.8, "hold_s": 0.5,
                 "duration_s": 4.0, "ramp_s": 0.5}
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso", reference, tmp_path))
    ctl = Controller(cfg)
    seen: list[bool] = []
    real = ctl.step

    def step(t_s, state, *args, **kw):
        seen.append(ctl.landed)
        return real(t_s, state, *args, **kw)
    ctl.step = step
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing="mocap")
    res = harness.fly_inprocess(ctl, sim, out_dir=tmp_path / "f", timeout_s=20.0)
    assert res.status == "done", res.summary
    _, steps = read_csv(res.controller_csv)
    landed = np.array(seen[:len(steps["t_s"])])
    assert landed[0] and landed[-1] and not landed.all()
    air = np.flatnonzero(~landed)
    assert np.all(~landed[air[0]:air[-1] + 1])          # one stretch in the air
    d = np.column_stack([steps[f"d_acc_{a}_m_s2"] for a in "ned"])
    assert np.all(d[landed] == 0.0) and np.abs(d[~landed]).max() > 0.0
    # through the vehicle's TAKEOFF state the hold lasts until the vehicle climbs: the first
    # step in the air finds the gear off the ground (the plant's truth)
    _, truth = read_csv(res.flight_csv)
    k = np.searchsorted(truth["t_us"], steps["stamp_us"][air[0]])
    assert truth["on_ground"][k] == 0 and truth["on_ground"][0] == 1
