"""Benchmark of the NMPC solver modes on the paper's fault flight, side by side in one run.

    trq-bench-nmpc                 # all modes, the whole flight
    trq-bench-nmpc --quick         # 16 s (4 s after the fault)
    trq-bench-nmpc --modes rti-gn,ipopt --json out/bench_nmpc.json
    trq-bench-nmpc --quick --repeat 3   # median of 3 interleaved runs
    trq-bench-nmpc --modes rti-gn --daemons    # and the whole period over both daemons
    trq-bench-nmpc --quick --modes rti-gn,rti-exact --anchor acados   # acados' RTI beside ours
    trq-bench-nmpc --quick --modes rti-gn,rti-exact --anchor acados --daemons --repeat 3 \
        --controller trq_nmpc_eso_fused --against trq_nmpc_eso   # the fused filter's period

The flight is trq_lab.harness's (`fly_inprocess`, the loop the campaigns and tests fly): the
vehicle's `Sitl` and the controller's `OffboardFlight` in one process, joined by an in-memory link
carrying the daemons' MAVLink bytes, in lockstep, the step called
from the flight loop. trq_nmpc_eso (--controller:
another file of params/controller/) arms, takes off and flies the helix of its reference on the
SITL plant of params/sim/default.yaml (its seed and telemetry noise), 8 m/s wind from the north
from the start, motor 1 at 50 % from t = 12 s of vehicle time (a fault script the vehicle plays).
Each step: the controller steps on the ODOMETRY it receives, its target goes back over the link
and the vehicle flies it for one control period, while `Controller.prepare` runs (the RTI's
preparation phase; a no-op for the other solvers).

A controller that asks the vehicle for raw sensor streams (the fused filter of
trq_nmpc_eso_fused: HIGHRES_IMU and ATT_POS_MOCAP) flies these flights under --sensing (default
mocap); the others under the sim file's profile (truth), as before.

Each mode runs in its own subprocess (so that peak memory, ru_maxrss, is its own) with its own
empty cache directory: the first controller construction is the cold build (code generation and
compilation), the second the cached build; the flight is flown with the second. Step times:
`solve` is the solver call inside Controller.step (SolveInfo.solve_time_s: for RTI the feedback
phase, the latency from state to command), `prep` the preparation after the command, `total` their
sum (the solver work per control period); `ctl period` everything the controller does per control
period in this loop (the telemetry's MAVLink parse, the flight loop's turn, Controller.step with
its observer, the target's MAVLink encode, prepare; not the vehicle's work, no log written: the
harness's StepSample.period_wall_s). Wall times from time.perf_counter, CPU times from
time.thread_time (the harness's PerfTimer). Tracking errors: the vehicle's truth position at each
step's stamp against the reference there. The machine is shared: compare medians and the ratios
to the fastest mode.

--anchor acados (trq_lab/bench/acados_anchor.py): the flights of rti-gn and rti-exact are
recorded (what the solver was handed per step) and acados' real-time iteration on the same OCP,
Gauss-Newton and exact Hessian, replays each right after it in its own process; its preparation
and feedback times are printed beside ours with the ratios ours / acados'. --anchor-regularize
METHOD regularises acados' exact Hessian by one of its regularize_method values before each QP
(the default, NO_REGULARIZE, leaves it as our solver does; what the methods do to the failures
and to the step: docs/decisions/2026-12-06-acados-exact-regularisation.md). With --daemons the
controller daemon's CPU per period from outside (trq_lab/bench/period.py) is set against acados'
step too, and --against CONTROLLER flies a second controller file over the daemons in the same
run, interleaved, for the ratio of the two (paired run by run).

The bracket (--anchor acados with --daemons): a replay a few minutes away from the daemons'
flights can meet the shared machine in another state. So each anchored mode is flown once more,
recorded, and acados is built on that recording once, in a server process (AnchorServer; the
child `python -m trq_lab.bench.acados_anchor --serve`). It steps acados through the whole
recording right before each run's short daemon flight, between the short and the long one, and
right after the long one, while neither daemon runs (period.daemons_period's `bracket`). The
target is printed a third way: each run's CPU per period over the median of its three passes'
step p50, with the range of every pass (a machine that moved during the run shows there).

--pacing realtime (with --daemons): the vehicle runs on the wall clock, so that the control loop
runs at its rate and waits a whole control period less its own work between two steps, and
acados' bracket passes are paced at the same period (each feedback one control period after the
previous one started; a pass then takes the recording's steps times the period, 16 s with
--quick). Both sides then find the machine as long after their last step. The
default, lockstep, sets the lockstep daemons against acados' tight loop: on a shared VM a step's
cost grows with the time since the last one, and the two pacings differ by a factor
(docs/decisions/2026-12-07-period-paced.md).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trq_params

from trq_lab.bench.acados_anchor import REGULARIZE_METHODS, check_regularize
from trq_lab.bench.period import VEHICLE_MODES

# acados' exact Hessian as our solver has it (the anchor's default: --anchor-regularize unset)
UNREGULARISED = ("NO_REGULARIZE", None)

MODES = {     # name: solver overrides of params/controller/trq_nmpc_eso.yaml (and in "controller"
              # overrides of the controller's own keys)
    "rti-gn": dict(kind="rti", hessian="gauss_newton", max_iterations=1),
    "rti-gn-lag": dict(kind="rti", hessian="gauss_newton", max_iterations=1,
                       controller=dict(actuator_states="on")),   # the actuators' lag states
    "rti-gn-conic": dict(kind="rti", hessian="gauss_newton", max_iterations=1,
                         hpipm_interface="conic"),     # HPIPM through casadi.conic
    "rti-gn-cap8": dict(kind="rti", hessian="gauss_newton", max_iterations=1,
                        qp_max_iterations=8),          # the QP stopped after 8 iterations
    "rti-exact": dict(kind="rti", hessian="exact", max_iterations=1),
    "rti-gn-py": dict(kind="rti", hessian="gauss_newton", max_iterations=1, codegen="off"),
    "sqp-gn": dict(kind="sqp", hessian="gauss_newton", max_iterations=1),
    "ipopt": dict(kind="ipopt"),
}
DEFAULT_MODES = "rti-gn,rti-gn-conic,rti-exact,rti-gn-py,sqp-gn,ipopt"
FAULT_T_S, EFFECTIVENESS, WIND_M_S = 12.0, 0.5, 8.0


def inprocess_sensing(sensor_streams: dict[str, int], sensing: str) -> str | None:
    """The sensing profile of the in-process flights: `truth` for a controller on the
    autopilot's estimate, so that those flights stay what they were (the bench times the
    controller, not the vehicle's estimator); `sensing` (the bench's --sensing) for one that
    asks the vehicle for raw sensor streams (the fused filter's HIGHRES_IMU and ATT_POS_MOCAP),
    which truth does not send."""
    return sensing if sensor_streams else "truth"


def fly(mode: str, seconds: float | None, controller: str = "trq_nmpc_eso",
        record: Path | None = None, sensing: str = "mocap") -> dict:
    """Child process: build twice (cold, cached), fly on the harness, return the figures.
    `record`: also save what the solver was handed per step (acados_anchor.Recorder) there.
    `sensing`: the vehicle's profile if the controller asks for sensor streams
    (`inprocess_sensing`)."""
    from sil_vehicle.config import load_sim
    from trq_lab import harness
    from trq_offboard.config import load_controller
    from trq_offboard.controller import Controller
    from trq_offboard.nmpc import cache
    from trq_offboard.records import SolveStatus
    from trq_wire.cache import forget_built

    timer = harness.PerfTimer()
    cfg = load_controller(trq_params.resolve("controller", controller))
    overrides = dict(MODES[mode])
    cfg = dataclasses.replace(cfg, **overrides.pop("controller", {}))
    cfg = dataclasses.replace(cfg, solver=dataclasses.replace(cfg.solver, **overrides))
    t0 = timer.wall_s()
    Controller(cfg)
    build_cold = timer.wall_s() - t0
    compiled_cold = cache.COUNTS["compiled"]
    forget_built()                    # the second build as a new process's: from the disk cache
    t0 = timer.wall_s()
    ctl = Controller(cfg)
    build_cached = timer.wall_s() - t0
    compiled_cached = cache.COUNTS["compiled"] - compiled_cold
    recorder = None
    if record is not None:
        from trq_lab.bench.acados_anchor import Recorder
        recorder = Recorder(ctl)

    seed = load_sim(harness.SIM_DEFAULT, cfg.vehicle.file).seed
    flown_sensing = inprocess_sensing(ctl.sensor_streams, sensing)
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=seed,
                             wind_speed_m_s=WIND_M_S, wind_from_deg=0.0, sensing=flown_sensing)
    events = harness.script({"at_s": FAULT_T_S, "motor": 1, "effectiveness": EFFECTIVENESS}) \
        if EFFECTIVENESS < 1 else ()
    qp_iterations = []          # the QP's iterations of each step (read after its prepare)
    res = harness.fly_inprocess(
        ctl, sim, events, timeout_s=seconds if seconds is not None else 600.0, trace=True,
        timer=timer, name=mode,
        on_step=lambda sample: qp_iterations.append(ctl.solver.qp_iterations))
    if res.status.startswith("failed"):
        raise RuntimeError(f"{mode}: {res.summary}")
    if recorder is not None:
        recorder.save(record, mode=mode, controller=controller, seconds=seconds)
    steps = res.trace.steps
    rows = np.array([(s.info.solve.solve_time_s, s.step_cpu_s, s.prepare_wall_s, s.prepare_cpu_s,
                      s.info.solve.iterations, q, s.period_wall_s, s.period_cpu_s)
                     for s, q in zip(steps, qp_iterations)])
    failures = sum(s.info.solve.status is not SolveStatus.OK for s in steps)
    errs, yerr, times = [], [], []
    for s in steps:
        truth = res.trace.truth_at(s.stamp_us)
        rp = np.array(s.ref.pos_ned_m)
        rp[2] = min(rp[2], 0.0)
        errs.append(float(np.linalg.norm(np.array(truth.pos_ned_m) - rp)))
        times.append(s.stamp_us * 1e-6)
        yerr.append(math.degrees((truth.euler_rad[2] - s.ref.yaw_rad + math.pi) % (2 * math.pi)
                                 - math.pi))
    a = rows
    errs, times, yerr = map(np.array, (errs, times, yerr))
    after = times >= FAULT_T_S
    ms = 1e3
    total = a[:, 0] + a[:, 2]
    crashed = res.status == "crashed" or any(t.crashed for t in res.trace.truth)
    return dict(
        name=mode, steps=len(steps), flight_s=float(res.sim_s), crashed=bool(crashed),
        sensing=flown_sensing or "the sim file's",
        median_ms=float(np.median(a[:, 0]) * ms), p99_ms=float(np.percentile(a[:, 0], 99) * ms),
        max_ms=float(a[:, 0].max() * ms),
        step_cpu_median_ms=float(np.median(a[:, 1]) * ms),
        step_cpu_p99_ms=float(np.percentile(a[:, 1], 99) * ms),
        prep_median_ms=float(np.median(a[:, 2]) * ms),
        prep_cpu_median_ms=float(np.median(a[:, 3]) * ms),
        total_median_ms=float(np.median(total) * ms),
        total_p99_ms=float(np.percentile(total, 99) * ms),
        period_median_ms=float(np.median(a[:, 6]) * ms),
        period_p99_ms=float(np.percentile(a[:, 6], 99) * ms),
        period_cpu_median_ms=float(np.median(a[:, 7]) * ms),
        iterations_median=float(np.median(a[:, 4])), iterations_max=int(a[:, 4].max()),
        qp_iterations_median=float(np.median(a[:, 5])), qp_iterations_max=int(a[:, 5].max()),
        failures=int(failures),
        rmse_pos_m=float(np.sqrt(np.mean(errs ** 2))),
        rmse_after_fault_m=(float(np.sqrt(np.mean(errs[after] ** 2))) if after.any()
                            else float("nan")),
        max_yaw_err_deg=float(np.abs(yerr).max()),
        build_cold_s=build_cold, build_cached_s=build_cached,
        compilations_cold=compiled_cold, compilations_cached=compiled_cached,
        build_mode=ctl.solver.build_mode,
        qp=ctl.solver_line(),
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)


def run_mode(mode: str, seconds: float | None, controller: str = "trq_nmpc_eso",
             record: Path | None = None, sensing: str = "mocap") -> dict:
    with tempfile.TemporaryDirectory(prefix="trq-bench-cache-") as cache_dir:
        env = dict(os.environ, TRQ_CACHE_DIR=cache_dir)
        cmd = [sys.executable, "-m", "trq_lab.bench.nmpc", "--child", mode,
               "--controller", controller, "--sensing", sensing]
        if seconds is not None:
            cmd += ["--seconds", str(seconds)]
        if record is not None:
            cmd += ["--record", str(record)]
        out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"mode {mode} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_anchor(recording: Path, hessian: str, controller: str, init: str = "shift",
               regularize: str = "NO_REGULARIZE", reg_epsilon: float | None = None) -> dict:
    """acados' RTI replaying a recorded flight, in its own subprocess (acados' libhpipm and
    CasADi's share a soname: they cannot be loaded in one process). `regularize`,
    `reg_epsilon`: acados' Hessian regularisation (acados_anchor.build_ocp)."""
    from trq_lab.bench import acados_anchor

    regularize, reg_epsilon = check_regularize(regularize, reg_epsilon)
    with tempfile.TemporaryDirectory(prefix="trq-bench-acados-") as work:
        cmd = _anchor_cmd(recording, hessian, controller, init, regularize, reg_epsilon)
        out = subprocess.run(cmd, env=acados_anchor.library_env(), cwd=work,
                             capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"acados anchor ({hessian}) failed:\n{out.stderr[-2000:]}")
    return json.loads(_last_json_line(out.stdout))


def _anchor_cmd(recording: Path, hessian: str, controller: str, init: str,
                regularize: str, reg_epsilon: float | None) -> list[str]:
    cmd = [sys.executable, "-m", "trq_lab.bench.acados_anchor", "--replay", str(recording),
           "--hessian", hessian, "--controller", controller, "--init", init,
           "--split-s", str(FAULT_T_S), "--regularize", regularize]
    return cmd + (["--reg-epsilon", repr(reg_epsilon)] if reg_epsilon is not None else [])


# what a bracketing pass keeps of acados' figures (the rest is the per-run replay's to print)
BRACKET_KEYS = ("total_median_ms", "total_cpu_median_ms", "failures", "steps", "pass")


class AnchorServer:
    """acados' RTI built once for a recorded flight, in its own process
    (`python -m trq_lab.bench.acados_anchor --serve`), stepped through the whole flight on each
    `one_pass()`: the bench's bracket of the daemons' flights, so that acados' step is taken
    seconds before, between and after them, at the same moment of the machine. A context
    manager: the process is ended (and its work directory removed) on exit."""

    def __init__(self, recording: Path, hessian: str, controller: str, init: str = "shift",
                 regularize: str = "NO_REGULARIZE", reg_epsilon: float | None = None):
        from trq_lab.bench import acados_anchor

        regularize, reg_epsilon = check_regularize(regularize, reg_epsilon)
        self._work = tempfile.TemporaryDirectory(prefix="trq-bench-acados-")
        self._stderr_path = Path(self._work.name) / "stderr.txt"
        self._stderr = open(self._stderr_path, "w")
        self._proc = subprocess.Popen(
            _anchor_cmd(recording, hessian, controller, init, regularize, reg_epsilon)
            + ["--serve"], env=acados_anchor.library_env(), cwd=self._work.name,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True)
        try:
            ready = self._answer()
        except Exception:
            self.close()
            raise
        self.name, self.build_s = ready["name"], ready["build_s"]

    def _answer(self) -> dict:
        line = self._proc.stdout.readline()
        if not line:
            rc = self._proc.wait()
            self._stderr.flush()
            tail = self._stderr_path.read_text(errors="replace")[-2000:]
            raise RuntimeError(f"acados' replay server ended (exit {rc}):\n{tail}")
        obj = json.loads(line)
        if "error" in obj:
            raise RuntimeError(f"acados' replay server: {obj['error']}")
        return obj

    def one_pass(self, pace_ms: float = 0.0) -> dict:
        """One pass through the recording: its figures (acados_anchor.Replayer.summary);
        `pace_ms` > 0: paced as a control loop at that period (acados_anchor's docstring)."""
        self._proc.stdin.write(f"pass {pace_ms:g}\n" if pace_ms > 0.0 else "pass\n")
        self._proc.stdin.flush()
        return self._answer()

    def close(self) -> None:
        if self._proc.poll() is None:
            try:
                self._proc.stdin.write("quit\n")
                self._proc.stdin.close()
                self._proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self._proc.kill()
                self._proc.wait()
        self._stderr.close()
        self._work.cleanup()

    def __enter__(self) -> "AnchorServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bracket_passes(servers: dict[str, "AnchorServer"], pace_ms: float = 0.0
                   ) -> dict[str, dict]:
    """One pass of every server (mode -> BRACKET_KEYS of its figures), paced at `pace_ms`
    (0: a tight loop): one bracket point."""
    out = {}
    for mode, server in servers.items():
        fig = server.one_pass(pace_ms)
        out[mode] = {k: fig[k] for k in BRACKET_KEYS}
    return out


def _controller_file(name_or_path: str) -> str:
    """How the header names a controller: params/controller/NAME.yaml for a built-in, the
    path as given for a user's file."""
    return (f"params/controller/{name_or_path}.yaml" if trq_params.is_name(name_or_path)
            else name_or_path)


def _last_json_line(stdout: str) -> str:
    """The child's JSON line: the last line that opens an object (acados' C library prints its
    QP failures to the same stdout, and flushes what it holds at the process's exit, after the
    JSON)."""
    lines = [line for line in stdout.splitlines() if line.startswith("{")]
    if not lines:
        raise RuntimeError(f"no JSON line in the child's output:\n{stdout[-2000:]}")
    return lines[-1]


def anchor_table(results: list[dict], anchors: dict[str, dict],
                 daemons: dict | None = None, against: dict | None = None,
                 controller: str = "the controller") -> str:
    """acados' figures beside ours, and the ratios ours / acados' (issue 18's targets: the
    solver's preparation + feedback at most 1.0x acados' RTI step on the median and 1.2x on the
    p99; the controller's whole CPU per period at most 1.5x). prep, prep+feedback: the bench's
    (Controller.prepare, with the controller's guess and reference); "solver's own": the
    solver's feedback plus its own preparation, per step, from the recorded flight."""
    ours = {r["name"]: r for r in results}
    head = ("| acados (replaying) | prep p50 ms | feedback p50 ms | feedback p99 ms "
            "| prep+feedback p50 ms | prep+feedback p99 ms | CPU p50 ms | acados' own p50 ms "
            "| QP it p50/max | failures (first at s) | first command vs ours before the fault: "
            "tilt deg p50/max | throttle % p50/max | after the fault: tilt deg p50/max "
            "| throttle % p50/max | build s |")
    lines = _table_head(head)

    def close(a, tag):
        if f"du_tilt_deg_median{tag}" not in a:
            return "- | -"
        return (f"{a[f'du_tilt_deg_median{tag}']:.2g}/{a[f'du_tilt_deg_max{tag}']:.2g} "
                f"| {a[f'du_throttle_pct_median{tag}']:.2g}/{a[f'du_throttle_pct_max{tag}']:.2g}")

    for mode, a in anchors.items():
        first = a.get("first_failure_s", math.nan)
        lines.append(
            f"| {a['name']} ({mode}'s flight) | {a['prep_median_ms']:.3f} "
            f"| {a['feedback_median_ms']:.3f} | {a['feedback_p99_ms']:.3f} "
            f"| {a['total_median_ms']:.3f} | {a['total_p99_ms']:.3f} "
            f"| {a['total_cpu_median_ms']:.3f} | {a['internal_total_median_ms']:.3f} "
            f"| {a['qp_iterations_median']:.0f}/{a['qp_iterations_max']} "
            f"| {a['failures']}{'' if math.isnan(first) else f' ({first:.2f})'} "
            f"| {close(a, '_before')} | {close(a, '_after')} | {a['build_s']:.1f} |")
    lines.append("")
    head = ("| ours / acados | prep p50 | feedback p50 | prep+feedback p50 (target <= 1.0) "
            "| prep+feedback p99 (target <= 1.2) | solver's own p50 | solver's own p99 "
            "| ctl period CPU p50 / acados' step p50 (target <= 1.5) |")
    lines += _table_head(head)
    for mode, a in anchors.items():     # the exact one (issue 18's anchor) against every mode
        names = [mode] + ([n for n in ours if n != mode] if a["hessian"] == "exact" else [])
        for name in names:
            r = ours[name]
            own = anchors.get(name, {})          # our solver's own step, from its recording
            label = f"{name} / {a['name']}" + ("" if name == mode else " (another flight)")
            solver = (f"{own['ours_solver_total_median_ms'] / a['total_median_ms']:.2f} "
                      f"| {own['ours_solver_total_p99_ms'] / a['total_p99_ms']:.2f}"
                      if "ours_solver_total_median_ms" in own else "- | -")
            lines.append(
                f"| {label} | {r['prep_median_ms'] / a['prep_median_ms']:.2f} "
                f"| {r['median_ms'] / a['feedback_median_ms']:.2f} "
                f"| {r['total_median_ms'] / a['total_median_ms']:.2f} "
                f"| {r['total_p99_ms'] / a['total_p99_ms']:.2f} | {solver} "
                f"| {r['period_cpu_median_ms'] / a['total_median_ms']:.2f} |")
    flown = ([(controller, daemons)] if daemons is not None else []) + \
        ([(against["controller"], against)] if against is not None else [])
    for name, fig in flown:
        # the flights paced in real time against the replays' tight loop: not alike
        unlike = (" (the daemons paced in real time, acados' replay a tight loop: only the "
                  "bracket paces both alike)" if fig.get("pacing") == "realtime" else "")
        for mode, a in anchors.items():
            lines.append(f"\nthe controller daemon's CPU per period from outside ({name}) / "
                         f"{a['name']}'s step p50 (target <= 1.5): "
                         f"{fig['controller_cpu_ms'] / a['total_median_ms']:.2f}{unlike}")
            ratios = paired_to_anchor(fig, a)
            if len(ratios) > 1:
                lines.append(f"  paired run by run (the flight and the replay of one run): "
                             f"median {float(np.median(ratios)):.2f}; runs "
                             f"{', '.join(f'{r:.2f}' for r in ratios)}")
            ratios = bracketed_to_anchor(fig, mode)
            if ratios:
                passes = [ms for run in fig["bracket_passes_ms"][mode] for ms in run]
                lines.append(f"  bracketed (acados stepped through {mode}'s flight right before, "
                             f"between and right after each run's two flights; its step p50 "
                             f"{min(passes):.3f}-{max(passes):.3f} ms over "
                             f"{len(passes)} passes): median {float(np.median(ratios)):.2f}; "
                             f"runs {', '.join(f'{r:.2f}' for r in ratios)}")
    return "\n".join(lines)


def paired_to_anchor(daemons: dict, anchor: dict) -> list[float]:
    """The controller's CPU per period over acados' step p50, run k's flight against run k's
    replay (the two a few minutes apart, where the medians of all runs can be a machine's
    slow spell apart); [] when either lacks its runs' figures or their counts differ."""
    ours = daemons.get("controller_cpu_runs_ms", [])
    theirs = anchor.get("total_median_runs_ms", [])
    if not ours or len(ours) != len(theirs):
        return []
    return [c / t for c, t in zip(ours, theirs)]


def bracketed_to_anchor(daemons: dict, mode: str) -> list[float]:
    """The controller's CPU per period over acados' step p50 taken around the same run's
    flights (the median of the bracket's passes through `mode`'s flight: before, between and
    after the two flights, seconds apart); [] without brackets."""
    ours = daemons.get("controller_cpu_runs_ms", [])
    passes = daemons.get("bracket_passes_ms", {}).get(mode, [])
    if not ours or len(ours) != len(passes):
        return []
    return [c / float(np.median(p)) for c, p in zip(ours, passes)]


def combine(runs: list[dict]) -> dict:
    """One row from K runs of a mode: the median of each number, the worst of crashes and
    failures (each run flies the same bit-identical flight: only the times differ)."""
    out = dict(runs[0])
    for key, val in runs[0].items():
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            continue
        vals = [r[key] for r in runs]
        out[key] = max(vals) if key in ("failures", "qp_iterations_max", "iterations_max") \
            else float(np.median(vals))
    out["crashed"] = any(r.get("crashed", False) for r in runs)
    out["runs"] = len(runs)
    return out


def _table_head(head: str) -> list[str]:
    """A markdown table's header row and its separator."""
    return [head, "|" + "---|" * head.count(" | ") + "---|"]


def table(results: list[dict]) -> str:
    fastest = min(r["total_median_ms"] for r in results)
    head = ("| mode | solve p50 ms | solve p99 ms | solve max ms | step CPU p50 ms | prep p50 ms "
            "| solve+prep p50 ms | solve+prep p99 ms | ctl period p50 ms | ctl period p99 ms "
            "| x fastest | SQP it | QP it p50/max "
            "| failures | pos RMSE m | RMSE after fault m | max yaw err deg | build cold s "
            "| build cached s | peak RSS MB |")
    lines = _table_head(head)
    for r in results:
        lines.append(
            f"| {r['name']} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} | {r['max_ms']:.1f} "
            f"| {r['step_cpu_median_ms']:.2f} | {r['prep_median_ms']:.2f} "
            f"| {r['total_median_ms']:.2f} | {r['total_p99_ms']:.2f} "
            f"| {r['period_median_ms']:.2f} | {r['period_p99_ms']:.2f} "
            f"| {r['total_median_ms'] / fastest:.1f} | {r['iterations_median']:.0f} "
            f"| {r['qp_iterations_median']:.0f}/{r['qp_iterations_max']} | {r['failures']} "
            f"| {r['rmse_pos_m']:.4f} | {r['rmse_after_fault_m']:.4f} "
            f"| {r['max_yaw_err_deg']:.2f} | {r['build_cold_s']:.1f} | {r['build_cached_s']:.2f} "
            f"| {r['peak_rss_mb']:.0f} |")
    return "\n".join(lines)


def daemon_order(controller: str, against: str | None, k: int) -> list[str]:
    """The controllers flown over the daemons in repeat `k`: `controller` alone, or both in
    alternating order (A B, B A, A B, ...) so that a drift of the shared machine across a repeat
    weighs on both alike."""
    if against is None:
        return [controller]
    return [controller, against] if k % 2 == 0 else [against, controller]


def paired_ratios(runs: list[dict], against_runs: list[dict]) -> list[float]:
    """The controller's CPU per period over the other's, run k against run k (flown next to
    each other, so that the machine's moment cancels in each ratio)."""
    if len(runs) != len(against_runs):
        raise ValueError(f"paired_ratios: {len(runs)} runs against {len(against_runs)}")
    return [r["controller_cpu_ms"] / a["controller_cpu_ms"] for r, a in zip(runs, against_runs)]


def _daemons_summary(runs: list[dict]) -> dict:
    """The median over the daemon runs of each figure and part."""
    med = lambda vals: float(np.median(vals))           # noqa: E731
    parts = {name: {k: med([r["parts"][name][k] for r in runs]) for k in runs[0]["parts"][name]}
             for name in runs[0]["parts"]}
    ratio = [r["controller_cpu_ms"] / (r["parts"]["solve (wall)"]["mean_ms"]
                                        + r["parts"]["prepare"]["mean_ms"]) for r in runs]
    bracketed = all(r.get("brackets") for r in runs)
    passes = ({mode: [[b[mode]["total_median_ms"] for b in r["brackets"]] for r in runs]
               for mode in runs[0]["brackets"][0]} if bracketed else {})
    return {"runs": len(runs), "parts": parts, "ratio_to_solver": med(ratio),
            "controller_cpu_runs_ms": [r["controller_cpu_ms"] for r in runs],
            **({"bracket_passes_ms": passes} if bracketed else {}),
            **{k: med([r[k] for r in runs])
               for k in ("controller_cpu_ms", "vehicle_cpu_ms", "realtime_factor")}}


def calibration_ms(repeats: int = 5) -> float:
    """Median time of a fixed piece of dense linear algebra (100 products of two 64 x 64 matrices
    and a Cholesky factorisation of the result): how fast this shared machine is right now, to
    compare runs made at different times."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(64, 64))
    spd = a @ a.T + 64 * np.eye(64)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        m = spd
        for _ in range(100):
            m = (m @ spd) / 100.0
            np.linalg.cholesky(spd)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def machine_line() -> str:
    try:
        load = "load %.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        load = ""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import casadi
    return (f"machine: {cpu}, {os.cpu_count()} cores, {load}; Python {platform.python_version()}, "
            f"casadi {casadi.__version__}; calibration {calibration_ms():.2f} ms "
            "(lower is a faster moment of the machine)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-nmpc", description=__doc__.splitlines()[0])
    ap.add_argument("--modes", default=DEFAULT_MODES,
                    help=f"comma-separated, of {', '.join(MODES)} (default: {DEFAULT_MODES})")
    ap.add_argument("--quick", action="store_true", help="fly 16 s (4 s after the fault)")
    ap.add_argument("--seconds", type=float, default=None, help="flight length (default: all)")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    ap.add_argument("--repeat", type=int, default=1,
                    help="fly every mode K times, interleaved (A B C A B C ...), and report the "
                         "median of each figure over the K runs (a shared machine drifts)")
    ap.add_argument("--controller", default="trq_nmpc_eso",
                    help="a controller file of params/controller/ without .yaml (default: "
                         "trq_nmpc_eso; the README's tables before the observer measured rates: "
                         "trq_nmpc_eso_paper)")
    ap.add_argument("--daemons", action="store_true",
                    help="also fly both daemons in lockstep over UDP (5 s and 35 s of vehicle "
                         "time, once per --repeat) and report the controller process's CPU per "
                         "control period measured from outside, its parts from its log, the "
                         "vehicle's CPU per period and the closed loop's real-time factor "
                         "(trq_lab/bench/period.py)")
    ap.add_argument("--pacing", choices=VEHICLE_MODES, default="lockstep",
                    help="with --daemons: lockstep (default: the vehicle waits for each answer, "
                         "acados' bracket passes a tight loop) or realtime (the vehicle on the "
                         "wall clock, the control loop at its rate, and acados' bracket passes "
                         "paced at the same control period: both sides given the same time "
                         "between two steps, docs/decisions/2026-12-07-period-paced.md)")
    ap.add_argument("--sensing", default="mocap", metavar="NAME|PATH",
                    help="the vehicle's sensing profile in --daemons (default: mocap, as the "
                         "scenarios fly; truth: the near-truth stream, no estimator), and in the "
                         "in-process flights of a controller that asks for raw sensors (the "
                         "fused filter; the others fly the sim file's profile there)")
    ap.add_argument("--against", default=None, metavar="CONTROLLER",
                    help="with --daemons: also fly this controller file over both daemons, "
                         "interleaved with --controller's flights (in alternating order), and "
                         "print the ratio of the two controllers' CPU per period from outside, "
                         "paired run by run (e.g. --controller trq_nmpc_eso_fused --against "
                         "trq_nmpc_eso: the fused filter's cost)")
    ap.add_argument("--anchor", choices=("acados",), default=None,
                    help="also step acados' real-time iteration (the same OCP, built from our "
                         "model, weights and bounds) through the flights of rti-gn (Gauss-Newton) "
                         "and rti-exact (exact Hessian) that this run flies, each replay right "
                         "after its flight, and print its preparation and feedback times beside "
                         "ours with the ratios (needs acados: trq_lab/bench/acados_anchor.py); "
                         "with --daemons, also stepped through a flight of its own right "
                         "before, between and after each run's two daemon flights, and the "
                         "target printed against those passes (the bracket)")
    ap.add_argument("--anchor-init", choices=("shift", "ours"), default="shift",
                    help="acados' warm start: its own previous solution shifted by one control "
                         "period (shift, default) or the guess our solver was handed (ours)")
    ap.add_argument("--anchor-regularize", default="NO_REGULARIZE", metavar="METHOD",
                    help="acados' regularize_method for the exact-Hessian replay (rti-exact's "
                         "flight; the Gauss-Newton replay's Hessian is left as it is), one of "
                         f"{', '.join(REGULARIZE_METHODS)} (default NO_REGULARIZE, acados' own: "
                         "docs/decisions/2026-12-06-acados-exact-regularisation.md)")
    ap.add_argument("--anchor-reg-epsilon", type=float, default=None, metavar="EPS",
                    help="acados' reg_epsilon for --anchor-regularize's MIRROR, PROJECT, "
                         "CONVEXIFY or GERSHGORIN_LEVENBERG_MARQUARDT (default: acados')")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--record", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    for flag, name in (("--controller", args.controller), ("--against", args.against)):
        if name is not None and not trq_params.exists("controller", name):
            ap.error(f"{flag} {name}: no params/controller/{name}.yaml")
    if args.pacing != "lockstep" and not args.daemons:
        ap.error(f"--pacing {args.pacing} paces the daemons' flights: add --daemons")
    if args.against is not None and not args.daemons:
        ap.error("--against compares the controllers over both daemons: add --daemons")
    if args.against == args.controller:
        ap.error(f"--against {args.against}: the same file as --controller")
    regularize = (args.anchor_regularize, args.anchor_reg_epsilon)
    if regularize != UNREGULARISED:
        try:
            regularize = check_regularize(*regularize)
        except ValueError as exc:
            ap.error(f"--anchor-regularize {args.anchor_regularize}: {exc}")
        if args.anchor != "acados":
            ap.error("--anchor-regularize regularises acados' replay: add --anchor acados")
    seconds = args.seconds if args.seconds is not None else (16.0 if args.quick else None)
    if args.child:
        print(json.dumps(fly(args.child, seconds, args.controller, args.record, args.sensing)),
              flush=True)
        return 0
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    unknown = [m for m in modes if m not in MODES]
    if unknown:
        ap.error(f"unknown mode(s) {unknown}; known: {', '.join(MODES)}")
    anchored: dict[str, str] = {}
    if args.anchor == "acados":
        from trq_lab.bench import acados_anchor
        ok, why = acados_anchor.available()
        if not ok:
            ap.error(f"--anchor acados: {why}")
        anchored = {m: acados_anchor.ANCHORED_MODES[m] for m in modes
                    if m in acados_anchor.ANCHORED_MODES}
        if not anchored:
            ap.error("--anchor acados replays the flights of "
                     f"{' and '.join(acados_anchor.ANCHORED_MODES)}: add one to --modes")
        if regularize != UNREGULARISED and "exact" not in anchored.values():
            ap.error("--anchor-regularize regularises the exact Hessian's replay: add "
                     "rti-exact to --modes")
    print(machine_line(), flush=True)
    print(f"controller: {_controller_file(args.controller)}"
          + (f", against {_controller_file(args.against)} over the daemons"
             if args.against else ""), flush=True)
    if anchored:
        reg = "" if regularize == UNREGULARISED else (
            f"; exact Hessian regularised by {regularize[0]}"
            + (f", reg_epsilon {regularize[1]:g}" if regularize[1] is not None else ""))
        print(f"anchor: {why}; warm start {args.anchor_init}{reg}", flush=True)
    if args.repeat < 1:
        ap.error(f"--repeat {args.repeat}: expected at least 1")
    with contextlib.ExitStack() as stack:
        servers = {}
        if args.daemons and anchored:
            servers = _bracket_servers(stack, anchored, seconds, args, regularize)
        return _runs(args, modes, anchored, seconds, regularize, servers)


def _bracket_servers(stack: contextlib.ExitStack, anchored: dict[str, str], seconds, args,
                     regularize) -> dict[str, AnchorServer]:
    """For the daemons' bracket: each anchored mode flown once more, recorded, and acados built
    on its recording in a server process (AnchorServer), kept until `stack` closes."""
    rec_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="trq-bench-bracket-")))
    servers = {}
    for m, hessian in anchored.items():
        rec = rec_dir / f"{m}.npz"
        run_mode(m, seconds, args.controller, record=rec, sensing=args.sensing)
        servers[m] = stack.enter_context(AnchorServer(
            rec, hessian, args.controller, args.anchor_init,
            *(regularize if hessian == "exact" else UNREGULARISED)))
        print(f"  bracket of the daemons' flights: {servers[m].name} built on a flight of {m} "
              f"({servers[m].build_s:.1f} s)", flush=True)
    return servers


def _runs(args, modes: list[str], anchored: dict[str, str], seconds, regularize,
          servers: dict[str, AnchorServer]) -> int:
    """The repeats, the tables and the JSON (main's, after its checks)."""
    from trq_offboard.config import load_controller

    realtime = args.pacing == "realtime"
    pace_ms = load_controller(trq_params.resolve("controller", args.controller)
                              ).control_dt_s * 1e3 if realtime else 0.0
    bracket = (lambda point: bracket_passes(servers, pace_ms)) if servers else None
    runs: dict[str, list[dict]] = {m: [] for m in modes}
    anchor_runs: dict[str, list[dict]] = {m: [] for m in anchored}
    daemon_runs: list[dict] = []
    against_runs: list[dict] = []
    for k in range(args.repeat):
        if args.daemons:      # interleaved with the modes, as they are with each other
            from trq_lab.bench.period import daemons_period
            for name in daemon_order(args.controller, args.against, k):
                d = daemons_period(controller=name, sensing=args.sensing, bracket=bracket,
                                   vehicle_mode=args.pacing)
                (daemon_runs if name == args.controller else against_runs).append(d)
                print(f"  daemons, {name}{f' (run {k + 1})' if args.repeat > 1 else ''}: "
                      f"controller {d['controller_cpu_ms']:.2f} ms CPU a period from outside, "
                      f"vehicle {d['vehicle_cpu_ms']:.2f} ms, {args.pacing} "
                      f"{d['realtime_factor']:.2f}x real time"
                      + "".join(f"; {servers[m].name} p50 "
                                + "/".join(f"{b[m]['total_median_ms']:.3f}"
                                           for b in d["brackets"]) + " ms around it"
                                for m in servers), flush=True)
        for m in modes:       # one after the other: the modes do not share the cores
            if m in anchored:     # the flight recorded, acados replays it right after
                with tempfile.TemporaryDirectory(prefix="trq-bench-rec-") as rec_dir:
                    rec = Path(rec_dir) / "flight.npz"
                    r = run_mode(m, seconds, args.controller, record=rec,
                                 sensing=args.sensing)
                    a = run_anchor(rec, anchored[m], args.controller, args.anchor_init,
                                   *(regularize if anchored[m] == "exact"
                                     else UNREGULARISED))
                anchor_runs[m].append(a)
                print(f"  {a['name']} on {m}'s flight{f' (run {k + 1})' if args.repeat > 1 else ''}"
                      f": {a['steps']} steps, failures {a['failures']}, prep/feedback p50 "
                      f"{a['prep_median_ms']:.3f}/{a['feedback_median_ms']:.3f} ms, "
                      f"prep+feedback p50/p99 {a['total_median_ms']:.3f}/"
                      f"{a['total_p99_ms']:.3f} ms"
                      + (f" (p50 over the solved steps {a['total_median_solved_ms']:.3f} ms)"
                         if a['failures'] and 'total_median_solved_ms' in a else ""),
                      flush=True)
            else:
                r = run_mode(m, seconds, args.controller, sensing=args.sensing)
            runs[m].append(r)
            print(f"  {m}{f' (run {k + 1})' if args.repeat > 1 else ''}: {r['steps']} steps, "
                  f"crashed {r['crashed']}, build {r['build_mode']}, compilations cold/cached "
                  f"{r['compilations_cold']}/{r['compilations_cached']}, sensing "
                  f"{r['sensing']}, solver {r['qp']}, solve "
                  f"p50/p99 {r['median_ms']:.2f}/{r['p99_ms']:.2f} ms, controller period "
                  f"p50 {r['period_median_ms']:.2f} ms", flush=True)
    results = [combine(runs[m]) for m in modes]
    if args.repeat > 1:
        print(f"median of {args.repeat} interleaved runs per mode; solve p50 and p99 ranges:")
        for m in modes:
            p50 = [r["median_ms"] for r in runs[m]]
            p99 = [r["p99_ms"] for r in runs[m]]
            print(f"  {m}: p50 {min(p50):.2f}-{max(p50):.2f} ms, p99 {min(p99):.2f}-"
                  f"{max(p99):.2f} ms")
    print(table(results))
    daemons = _daemons_summary(daemon_runs) if daemon_runs else None
    if daemons is not None:
        from trq_lab.bench.period import parts_table
        daemons["pacing"] = args.pacing
        print(f"\nthe whole period over both daemons in {args.pacing}, sensing {args.sensing} "
              f"(median of {len(daemon_runs)} run(s)):")
        print(parts_table(daemons))
        print(f"controller CPU per period / the solver's own step (feedback wall + preparation "
              f"CPU, same flights): {daemons['ratio_to_solver']:.2f}; closed loop "
              f"{daemons['realtime_factor']:.2f}x real time")
    against = None
    if against_runs:
        against = _daemons_summary(against_runs)
        against["controller"] = args.against
        against["pacing"] = args.pacing
        ratios = paired_ratios(daemon_runs, against_runs)
        against["ratio"] = float(np.median(ratios))
        against["ratios"] = ratios
        print(f"\n{args.against} over both daemons in the same run (median of "
              f"{len(against_runs)} run(s)):")
        print(parts_table(against))
        print(f"controller CPU per period from outside, {args.controller} / {args.against}, "
              f"paired run by run: {against['ratio']:.2f} (median; runs "
              f"{', '.join(f'{r:.2f}' for r in ratios)}); {args.controller} "
              f"{daemons['controller_cpu_ms']:.3f} ms, {args.against} "
              f"{against['controller_cpu_ms']:.3f} ms")
    anchors = {m: {**combine(anchor_runs[m]),
                   "total_median_runs_ms": [a["total_median_ms"] for a in anchor_runs[m]]}
               for m in anchored}
    if anchors:
        print(f"\nacados' real-time iteration on the same OCP, replaying our flights (median of "
              f"{args.repeat} run(s); times around acados' calls, wall unless said):")
        print(anchor_table(results, anchors, daemons, against,
                           controller=args.controller))
    print(f"calibration at the end {calibration_ms():.2f} ms")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        out = {"machine": machine_line(), "controller": args.controller, "modes": results,
               "daemons": daemons, "daemon_runs": daemon_runs}
        if against is not None:
            out["against"] = against
            out["against_runs"] = against_runs
        if anchors:
            out["anchor"] = {"modes": anchors, "runs": anchor_runs}
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
