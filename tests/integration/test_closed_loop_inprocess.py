"""Closed loop in one process: trq_offboard.Controller flying sil_vehicle.Vehicle (no MAVLink).

Each control step: read the plant's truth state, step the controller, hold its command for
physics_rate / control_rate plant ticks. Measures position RMSE on the manoeuvre and solve
times. Run as a script for a report: `.venv/bin/python tests/integration/test_closed_loop_inprocess.py`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from sil_vehicle.config import load_sim
from sil_vehicle.vehicle import ActuatorCommand as PlantCommand
from sil_vehicle.vehicle import Vehicle
from trq_offboard.config import load_controller
from trq_offboard.controller import Controller
from trq_offboard.records import (CommandSource, SolveInfo, SolveStatus, StateEstimate)
from trq_offboard.reference import Reference

ROOT = Path(__file__).resolve().parents[2]
SIM = ROOT / "params" / "sim" / "default.yaml"
CTRL = ROOT / "params" / "controller"

_CACHE: dict[str, Controller] = {}


def controller(name: str, **ref_changes) -> tuple[Controller, object]:
    cfg = load_controller(CTRL / f"{name}.yaml")
    ref_cfg = dataclasses.replace(cfg.reference, **ref_changes)
    if name not in _CACHE:
        _CACHE[name] = Controller(cfg)
    return _CACHE[name], ref_cfg


def estimate(vs, sim=None, rng=None) -> StateEstimate:
    """The plant's truth state, plus the telemetry noise of the sim settings if rng is given."""
    x = np.array(vs.x)
    eul = np.array(vs.euler_rad)
    if rng is not None:
        x[0:3] += rng.normal(0, sim.noise_position_m, 3)
        x[3:6] += rng.normal(0, sim.noise_velocity_m_s, 3)
        eul += rng.normal(0, sim.noise_attitude_rad, 3)
        x[10:13] += rng.normal(0, sim.noise_rates_rad_s, 3)
    return StateEstimate(tuple(x[0:3]), tuple(x[3:6]), tuple(eul), tuple(x[10:13]))


@dataclasses.dataclass
class Flight:
    t: np.ndarray
    pos: np.ndarray
    ref: np.ndarray
    phase: list
    solve_s: np.ndarray
    sources: list
    cmds: np.ndarray
    crashed: bool
    d: np.ndarray
    clips: int

    def rmse(self, phases) -> float:
        m = np.array([p in phases for p in self.phase])
        e = self.pos[m] - self.ref[m]
        return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))

    def max_err(self, phases) -> float:
        m = np.array([p in phases for p in self.phase])
        return float(np.max(np.linalg.norm(self.pos[m] - self.ref[m], axis=1)))


def fly(ctl: Controller, ref_cfg, seconds: float | None = None, seed: int = 1,
        events=(), stop_when_done: bool = True, noise: bool = False) -> Flight:
    sim = load_sim(SIM, vehicle=ctl.cfg.vehicle.file)
    veh = Vehicle(sim, np.random.default_rng(seed))
    noise_rng = np.random.default_rng(seed + 1000) if noise else None
    ticks = sim.physics_rate_hz // ctl.cfg.control_rate_hz
    dt = 1.0 / ctl.cfg.control_rate_hz
    veh.set_armed(True)
    st = estimate(veh.state)
    ref = Reference(ref_cfg, st.pos_ned_m, st.euler_rad[2], 0.0)
    ctl.reset(0.0, st)
    n = int(round((seconds if seconds is not None else ref.end_time_s + 1.0) / dt))
    log = {k: [] for k in ("t", "pos", "ref", "phase", "solve", "src", "cmd", "d")}
    applied = None
    for k in range(n):
        t = k * dt
        for at, fn in events:
            if abs(at - t) < 0.5 * dt:
                fn(veh)
        truth_pos = veh.state.x[0:3]
        st = estimate(veh.state, sim, noise_rng)
        cmd, info = ctl.step(t, st, applied, ref)
        s = ref.sample(t)
        veh.command = PlantCommand(throttle_pct=cmd.throttle_pct, tilt_rad=cmd.tilt_rad)
        applied = cmd
        for _ in range(ticks):
            veh.step()
        log["t"].append(t)
        log["pos"].append(truth_pos)
        log["ref"].append(s.pos_ned_m)
        log["phase"].append(s.phase)
        log["solve"].append(info.solve.solve_time_s)
        log["src"].append(info.source)
        log["cmd"].append(cmd.throttle_pct + cmd.tilt_rad)
        log["d"].append(info.disturbance)
        if veh.state.crashed or (stop_when_done and ref.done(t)):
            break
    return Flight(np.array(log["t"]), np.array(log["pos"]), np.array(log["ref"]), log["phase"],
                  np.array(log["solve"]), log["src"], np.array(log["cmd"]), veh.state.crashed,
                  np.array(log["d"]), ctl.clip_count)


SHORT_HELIX = dict(kind="helix", altitude_m=1.5, climb_speed_m_s=0.6, hold_s=1.0,
                   duration_s=12.0, ramp_s=2.0, period_s=8.0, radius_m=1.0,
                   helix_climb_m=-0.4, land=False)


@pytest.mark.parametrize("name,limit", [("trq_nmpc_eso", 0.05), ("trq_nmpc", 0.05),
                                        ("quad_nmpc", 0.05)])
def test_takeoff_hover_helix(name, limit):
    ctl, rc = controller(name, **SHORT_HELIX)
    f = fly(ctl, rc)
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    rmse = f.rmse(("helix",))
    assert rmse < limit, f"{name}: helix RMSE {rmse:.3f} m"
    assert f.rmse(("hold",)) < limit
    # hover point reached and held: final error small
    assert np.linalg.norm(f.pos[-1] - f.ref[-1]) < 0.1
    assert sum(s is CommandSource.NMPC for s in f.sources) >= 0.98 * len(f.sources)


class _FailingSolver:
    """Wraps a real solver and fails on chosen calls (to exercise the fallback)."""

    def __init__(self, inner, fail_from: int, fail_to: int, nan: bool = False):
        self.inner, self.ocp = inner, inner.ocp
        self.calls, self.fail_from, self.fail_to, self.nan = 0, fail_from, fail_to, nan

    def solve(self, x0, x_ref, d, u_prev, guess):
        self.calls += 1
        u, x, info = self.inner.solve(x0, x_ref, d, u_prev, guess)
        if self.fail_from <= self.calls < self.fail_to:
            if self.nan:     # a broken solver that returns NaN with an OK status
                return u * np.nan, x, info
            return u, x, SolveInfo(SolveStatus.FAILED, 0, 0.0, float("nan"), "injected")
        return u, x, info


def test_solver_failure_falls_back_and_stays_finite():
    base, rc = controller("trq_nmpc", **SHORT_HELIX)
    cfg = base.cfg
    # the last good plan covers N h seconds: that many control steps of shifted plan, then hover
    plan = round(cfg.horizon_steps * cfg.step_s * cfg.control_rate_hz)
    first, last = 2 * cfg.control_rate_hz, 2 * cfg.control_rate_hz + plan + 10
    ctl = Controller(cfg, solver=_FailingSolver(base.solver, first, last))
    f = fly(ctl, rc, seconds=8.0)
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    assert all(s is CommandSource.SHIFTED_PLAN for s in f.sources[first - 1:first + plan - 3])
    assert all(s is CommandSource.HOVER for s in f.sources[first + plan - 1:last - 1])
    assert f.sources[last - 1] is CommandSource.NMPC
    assert np.max(np.abs(f.pos[last:] - f.ref[last:])) < 0.3
    ctl2 = Controller(base.cfg, solver=_FailingSolver(base.solver, 150, 153, nan=True))
    f2 = fly(ctl2, rc, seconds=4.0)
    assert np.all(np.isfinite(f2.cmds)) and not f2.crashed
    assert f2.sources[149] is CommandSource.SHIFTED_PLAN


GENTLE_HOVER = dict(kind="hover", altitude_m=1.5, climb_speed_m_s=0.6, hold_s=2.0,
                    duration_s=14.0, ramp_s=3.0, land=False)


def wind_and_fault(wind_at_s=2.0, fault_at_s=6.0):
    return [(wind_at_s, lambda v: v.set_wind(8.0, 0.0, False, 1.0, 50.0)),
            (fault_at_s, lambda v: setattr(v, "faults", v.faults.with_motor(0, effectiveness=0.5)))]


def test_trq_nmpc_eso_survives_wind_and_motor_fault():
    """8 m/s wind (2 N) from 2 s, motor 1 at 50 % from 6 s, telemetry noise on: the tilt-rotor
    with the observer stays up and returns to the hover point (motor 1 saturated at 100 %)."""
    ctl, rc = controller("trq_nmpc_eso", **GENTLE_HOVER)
    f = fly(ctl, rc, seconds=11.0, events=wind_and_fault(), stop_when_done=False, noise=True)
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    after = f.t > 6.0
    assert np.max(np.linalg.norm(f.pos[after] - f.ref[after], axis=1)) < 0.5
    late = f.t > 9.0
    e = f.pos[late] - f.ref[late]
    assert np.sqrt(np.mean(np.sum(e * e, axis=1))) < 0.05
    assert np.mean(f.cmds[late, 0]) > 95.0          # motor 1 (50 % effective) near saturation


def report() -> None:
    for name in ("trq_nmpc_eso", "trq_nmpc", "quad_nmpc"):
        ctl, rc = controller(name, **SHORT_HELIX)
        f = fly(ctl, rc)
        st = f.solve_s[1:] * 1e3
        print(f"{name:14s} helix RMSE {f.rmse(('helix',)):.4f} m  max {f.max_err(('helix',)):.3f}"
              f"  hold RMSE {f.rmse(('hold',)):.4f}  takeoff RMSE {f.rmse(('takeoff',)):.3f}"
              f"  solve median {np.median(st):.2f} p99 {np.percentile(st, 99):.2f} "
              f"max {st.max():.2f} ms  crashed {f.crashed} clips {f.clips}"
              f" fallbacks {sum(s is not CommandSource.NMPC for s in f.sources)}")
    for name in ("trq_nmpc_eso", "trq_nmpc", "quad_nmpc"):
        ctl, rc = controller(name, **GENTLE_HOVER)
        f = fly(ctl, rc, seconds=14.0, events=wind_and_fault(), stop_when_done=False, noise=True)
        late = f.t > 9.0
        e = f.pos[late] - f.ref[late]
        rm = float(np.sqrt(np.mean(np.sum(e * e, axis=1)))) if late.any() else float("nan")
        st = f.solve_s[1:] * 1e3
        print(f"{name:14s} wind+fault (noise): crashed {f.crashed} at {f.t[-1]:.2f} s  "
              f"RMSE t>9 s {rm:.4f} m  max err after fault "
              f"{np.max(np.linalg.norm(f.pos[f.t > 6] - f.ref[f.t > 6], axis=1)):.3f} m  "
              f"solve median {np.median(st):.2f} p99 {np.percentile(st, 99):.2f} ms")


if __name__ == "__main__":
    report()
