"""Closed loop in one process, on the one harness (trq_lab.harness.fly_inprocess): the
controller's `OffboardFlight` driving a trq_offboard.controller.Controller against the vehicle's
`Sitl`, joined by the in-memory link that carries the daemons' MAVLink bytes, in lockstep.

Each flight arms, takes off and flies a reference; wind and faults are scripted events the
vehicle plays in its own time. The figures come from the harness's trace: the vehicle's truth
position at each step's stamp against the reference sampled there, and each step's StepInfo.
Telemetry noise is off unless a test turns the sim's noise on. Measures position RMSE on the
manoeuvre and solve times. Run as a script for a report:
`.venv/bin/python tests/integration/test_closed_loop_inprocess.py`.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest
import trq_params

from trq_lab import harness
from trq_offboard.config import load_controller
from trq_offboard.controller import Controller
from trq_offboard.nmpc.base import Solver
from trq_offboard.records import CommandSource, SolveInfo, SolveStatus

pytestmark = pytest.mark.slow


def config(name: str, **ref_changes):
    """A controller file of params/controller/ with its reference changed."""
    cfg = load_controller(trq_params.resolve("controller", name))
    return dataclasses.replace(cfg, reference=dataclasses.replace(cfg.reference, **ref_changes))


def sim_for(cfg, *, seed: int = 1, noise: bool = False):
    """The default sim for the controller's airframe and rate under `truth` (these flights test
    the control, not the sensing); its telemetry noise only with `noise`."""
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=seed, sensing="truth")
    if not noise:
        sim = sim.with_changes(noise_position_m=0.0, noise_velocity_m_s=0.0,
                               noise_attitude_rad=0.0, noise_rates_rad_s=0.0)
    return sim


@dataclasses.dataclass
class Flight:
    t: np.ndarray            # the controller's time of each step (0: first state after arming)
    tv: np.ndarray           # the vehicle's time of each step (the stamp it answered)
    pos: np.ndarray          # truth position at the stamp
    ref: np.ndarray          # reference position at t
    phase: list
    solve_s: np.ndarray
    sources: list
    cmds: np.ndarray         # throttles then tilts
    crashed: bool
    d: np.ndarray
    clips: int
    status: str

    def rmse(self, phases) -> float:
        m = np.array([p in phases for p in self.phase])
        e = self.pos[m] - self.ref[m]
        return float(np.sqrt(np.mean(np.sum(e * e, axis=1))))

    def max_err(self, phases) -> float:
        m = np.array([p in phases for p in self.phase])
        return float(np.max(np.linalg.norm(self.pos[m] - self.ref[m], axis=1)))


def fly(controller, seconds: float | None = None, *, events=(), noise: bool = False,
        seed: int = 1) -> Flight:
    """Fly on the harness until the reference is done (a plan without landing ends in the
    air) or `seconds` of vehicle time. controller: a ControllerConfig (built once per process)
    or a built Controller."""
    cfg = controller.cfg if isinstance(controller, Controller) else controller
    res = harness.fly_inprocess(controller, sim_for(cfg, seed=seed, noise=noise), events,
                                timeout_s=seconds if seconds is not None else 600.0, trace=True)
    assert not res.status.startswith("failed"), res.summary
    steps, tr = res.trace.steps, res.trace
    truth = [tr.truth_at(s.stamp_us) for s in steps]
    return Flight(np.array([s.t_s for s in steps]), np.array([s.stamp_us * 1e-6 for s in steps]),
                  np.array([t.pos_ned_m for t in truth]),
                  np.array([s.ref.pos_ned_m for s in steps]), [s.ref.phase for s in steps],
                  np.array([s.info.solve.solve_time_s for s in steps]),
                  [s.info.source for s in steps],
                  np.array([s.cmd.throttle_pct + s.cmd.tilt_rad for s in steps]),
                  res.status == "crashed" or any(t.crashed for t in tr.truth),
                  np.array([s.info.disturbance for s in steps]),
                  steps[-1].info.clip_count_total if steps else 0, res.status)


SHORT_HELIX = dict(kind="helix", altitude_m=1.5, climb_speed_m_s=0.6, hold_s=1.0,
                   duration_s=12.0, ramp_s=2.0, period_s=8.0, radius_m=1.0,
                   helix_climb_m=-0.4, land=False)


@pytest.mark.parametrize("name,limit", [("trq_nmpc_eso", 0.05), ("trq_nmpc", 0.05),
                                        ("quad_nmpc", 0.05)])
def test_takeoff_hover_helix(name, limit):
    f = fly(config(name, **SHORT_HELIX))
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    rmse = f.rmse(("helix",))
    assert rmse < limit, f"{name}: helix RMSE {rmse:.3f} m"
    assert f.rmse(("hold",)) < limit
    # hover point reached and held: final error small
    assert np.linalg.norm(f.pos[-1] - f.ref[-1]) < 0.1
    assert sum(s is CommandSource.NMPC for s in f.sources) >= 0.98 * len(f.sources)


class _FailingSolver(Solver):
    """Wraps a real solver and fails on chosen calls (to exercise the fallback); no
    preparation (every solve prepares itself)."""

    def __init__(self, inner, fail_from: int, fail_to: int, nan: bool = False):
        self.inner, self.ocp = inner, inner.ocp
        self.calls, self.fail_from, self.fail_to, self.nan = 0, fail_from, fail_to, nan

    def discard(self) -> None:
        """At take-over the inner solver forgets its warm start, as it does unwrapped."""
        self.inner.discard()

    def zero_multipliers(self) -> None:
        self.inner.zero_multipliers()

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        self.calls += 1
        u, x, info = self.inner.solve(x0, x_ref, d, u_prev, guess, y0)
        if self.fail_from <= self.calls < self.fail_to:
            if self.nan:     # a broken solver that returns NaN with an OK status
                return u * np.nan, x, info
            return u, x, SolveInfo(SolveStatus.FAILED, 0, 0.0, float("nan"), "injected")
        return u, x, info


def test_solver_failure_falls_back_and_stays_finite():
    cfg = config("trq_nmpc", **SHORT_HELIX)
    base = harness.build_controller(cfg)
    # The harness's steps are the controller's steps: record i is the solver's call i + 1
    # (arming is answered without stepping). The last good plan (call first - 1) covers N h
    # seconds: steps of elapsed < N h fly it shifted, then the hover command. The steps at the
    # boundaries (elapsed a whole multiple of h, in float) are left out of both checks.
    plan = round(cfg.horizon_steps * cfg.step_s * cfg.control_rate_hz)
    first, last = 2 * cfg.control_rate_hz, 2 * cfg.control_rate_hz + plan + 10
    ctl = Controller(cfg, solver=_FailingSolver(base.solver, first, last))
    f = fly(ctl, seconds=8.0)
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    assert all(s is CommandSource.SHIFTED_PLAN for s in f.sources[first - 1:first + plan - 3])
    assert all(s is CommandSource.HOVER for s in f.sources[first + plan - 1:last - 1])
    assert f.sources[last - 1] is CommandSource.NMPC
    assert np.max(np.abs(f.pos[last:] - f.ref[last:])) < 0.3
    ctl2 = Controller(cfg, solver=_FailingSolver(base.solver, 150, 153, nan=True))
    f2 = fly(ctl2, seconds=4.0)
    assert np.all(np.isfinite(f2.cmds)) and not f2.crashed
    assert f2.sources[149] is CommandSource.SHIFTED_PLAN


GENTLE_HOVER = dict(kind="hover", altitude_m=1.5, climb_speed_m_s=0.6, hold_s=2.0,
                    duration_s=14.0, ramp_s=3.0, land=False)


def wind_and_fault(wind_at_s=2.0, fault_at_s=6.0):
    """8 m/s wind from the north, then motor 1 at 50 %: a script the vehicle plays."""
    return harness.script(
        {"at_s": wind_at_s, "wind": {"speed_m_s": 8.0, "direction_deg": 0.0, "gusts": False}},
        {"at_s": fault_at_s, "motor": 1, "effectiveness": 0.5})


def test_trq_nmpc_eso_survives_wind_and_motor_fault():
    """8 m/s wind (2 N) from 2 s, motor 1 at 50 % from 6 s (vehicle time), telemetry noise on:
    the tilt-rotor with the observer stays up and returns to the hover point (motor 1
    saturated at 100 %)."""
    f = fly(config("trq_nmpc_eso", **GENTLE_HOVER), seconds=11.0, events=wind_and_fault(),
            noise=True)
    assert not f.crashed
    assert np.all(np.isfinite(f.cmds))
    after = f.tv > 6.0
    assert np.max(np.linalg.norm(f.pos[after] - f.ref[after], axis=1)) < 0.5
    late = f.tv > 9.0
    e = f.pos[late] - f.ref[late]
    assert np.sqrt(np.mean(np.sum(e * e, axis=1))) < 0.05
    assert np.mean(f.cmds[late, 0]) > 95.0          # motor 1 (50 % effective) near saturation


class _TickTimer:
    """Every reading one microsecond later than the one before (wall and CPU each)."""

    def __init__(self) -> None:
        self.wall, self.cpu = 0.0, 0.0

    def wall_s(self) -> float:
        self.wall += 1e-6
        return self.wall

    def cpu_s(self) -> float:
        self.cpu += 1e-6
        return self.cpu


def test_tracing_flies_the_same_flight_and_reads_the_injected_timer(tmp_path):
    """A traced flight's logs are the untraced flight's, bit for bit; the trace's times are
    the injected timer's (no clock of its own in the loop)."""
    cfg = config("trq_nmpc_eso", kind="hover", altitude_m=1.0, climb_speed_m_s=0.8,
                 hold_s=0.5, duration_s=0.5, ramp_s=0.5, land=False)
    sim = sim_for(cfg, noise=True)
    events = harness.script({"at_s": 1.0, "motor": 1, "effectiveness": 0.8})
    seen = []
    plain = harness.fly_inprocess(cfg, sim, events, out_dir=tmp_path / "plain")
    traced = harness.fly_inprocess(cfg, sim, events, out_dir=tmp_path / "traced", trace=True,
                                   timer=_TickTimer(), on_step=seen.append)

    def rows(path):
        return hashlib.sha256(b"".join(line for line in path.read_bytes().splitlines(True)
                                       if not line.startswith(b"#"))).hexdigest()

    assert rows(plain.flight_csv) == rows(traced.flight_csv)
    tr = traced.trace
    assert seen == tr.steps and len(tr.steps) == traced.steps > 0
    assert tr.events_played == [(1_000_000, "motor 1 effectiveness 0.8")]
    for s in tr.steps:       # two readings of each clock around the call, nothing between
        assert s.step_wall_s == pytest.approx(1e-6) and s.prepare_cpu_s == pytest.approx(1e-6)
        assert s.period_wall_s > s.step_wall_s + s.prepare_wall_s
        assert tr.truth_at(s.stamp_us).t_us == s.stamp_us


def report() -> None:
    for name in ("trq_nmpc_eso", "trq_nmpc", "quad_nmpc"):
        f = fly(config(name, **SHORT_HELIX))
        st = f.solve_s[1:] * 1e3
        print(f"{name:14s} helix RMSE {f.rmse(('helix',)):.4f} m  max {f.max_err(('helix',)):.3f}"
              f"  hold RMSE {f.rmse(('hold',)):.4f}  takeoff RMSE {f.rmse(('takeoff',)):.3f}"
              f"  solve median {np.median(st):.2f} p99 {np.percentile(st, 99):.2f} "
              f"max {st.max():.2f} ms  crashed {f.crashed} clips {f.clips}"
              f" fallbacks {sum(s is not CommandSource.NMPC for s in f.sources)}")
    for name in ("trq_nmpc_eso", "trq_nmpc", "quad_nmpc"):
        f = fly(config(name, **GENTLE_HOVER), seconds=14.0, events=wind_and_fault(), noise=True)
        late = f.tv > 9.0
        e = f.pos[late] - f.ref[late]
        rm = float(np.sqrt(np.mean(np.sum(e * e, axis=1)))) if late.any() else float("nan")
        st = f.solve_s[1:] * 1e3
        print(f"{name:14s} wind+fault (noise): crashed {f.crashed} at {f.tv[-1]:.2f} s  "
              f"RMSE t>9 s {rm:.4f} m  max err after fault "
              f"{np.max(np.linalg.norm(f.pos[f.tv > 6] - f.ref[f.tv > 6], axis=1)):.3f} m  "
              f"solve median {np.median(st):.2f} p99 {np.percentile(st, 99):.2f} ms")


if __name__ == "__main__":
    report()
