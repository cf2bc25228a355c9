"""The floor of the controller daemon's control period: its machinery alone, the math at no cost.

    trq-bench-floor                        # the real controller's flights, then their replay
    trq-bench-floor --repeat 3 --json out/bench_floor.json
    trq-bench-floor --anchor acados        # acados' exact-Hessian RTI step measured in the run
    trq-bench-floor --replay CSV [trq-offboard options]   # the daemon with the replay

`ReplayController` is a measurement device, not a controller: it reads a recorded flight's
controller.csv (trq_offboard/log.py's) and, in a flight that repeats the recorded one, hands the
flight loop at each step the recorded command and a StepInfo rebuilt from the recorded row (the
solver's status, iterations and time, the observer's d, output error, cost, the motors'
effectiveness, the step's CPU parts and, through `last_prepare_cpu_ns`, the preparation's). Its
step is an index into lists built at load, with one check that the step's time is the recorded
one (a replay that left the recording stops with ReplayDiverged); its `prepare` does nothing but
hand over the recorded preparation time. So the daemon around it (asyncio, the telemetry's
receive and decode, the target's encode and send, the step's calls, the reference's sample, the
accounting, the ground-station diagnosis, controller.csv and the .tlog) does the same work as
in the recorded flight: the log writes the same bytes but for the loop's own measurements
(cpu_wire_ms, cpu_log_ms, cpu_period_ms) and its header's solver line, and the vehicle flies
the same flight, identically in lockstep (controller.csv carries the commands
at full precision: trq_wire.logfile writes floats with repr). What the replay's process costs
per control period is the floor: what the daemon costs when the controller's math costs nothing.
It is a lower bound of that machinery's share in the real daemon, where the math's allocations
and its use of the caches also slow the machinery down.

The bench (`main`) flies, per --repeat, interleaved: (a) the real controller's two lockstep
flights over both daemons (trq_lab/bench/period.py's `daemons_period`, `short_s` and `long_s` of
vehicle time, their difference cancelling start-up and shut-down), (b) the replay of (a)'s long
flight's controller.csv, short and long, the same way. It checks that the replay's vehicle flew
(a)'s flight (flight.csv's rows) and prints, medians over the runs: each process's CPU per
control period measured from outside (rusage of the exited child), the replay's share of the real
controller's, the loop's parts from both logs, and against acados' exact-Hessian RTI step (issue
18's anchor; --anchor acados measures it in the same run, trq_lab/bench/acados_anchor.py:
built once on a recorded rti-exact flight and stepped through it right before, between and
after each pair of daemon flights, each run's step the median of its six passes;
--acados-ms takes it from a dated record) the floor's ratio and the best case it implies, the
floor plus a solver as fast as acados (and plus ours), against the target of 1.5x. Without an
anchor it prints the floor in ms beside the machine's calibration (trq_lab/bench/nmpc.py's
`calibration_ms`) and the acados step the target would need.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from trq_offboard.log import COLUMNS as LOG_COLUMNS
from trq_offboard.loop import FlightError
from trq_offboard.records import (
    ActuatorCommand,
    CommandSource,
    SolveInfo,
    SolveStatus,
    StepInfo,
    StepTimes,
)

__all__ = ["ReplayController", "RecordingError", "ReplayDiverged", "replay_command", "main",
           "TARGET_RATIO", "bracket_step"]

TARGET_RATIO = 1.5         # issue 18: the controller's whole CPU per period / acados' RTI step
COMMAND_COLUMNS = ([f"cmd_throttle{i}_pct" for i in range(1, 5)]
                   + [f"cmd_tilt{i}_rad" for i in range(1, 5)])
REQUIRED_COLUMNS = ["t_s"] + COMMAND_COLUMNS
# the StepInfo's columns, replayed when the log has them (an older log: the defaults)
D_COLUMNS = ([f"d_acc_{a}_m_s2" for a in "ned"] + [f"d_ang_{a}_rad_s2" for a in "pqr"])
EFF_COLUMNS = [f"eff_motor{i}" for i in range(1, 5)]
STEP_CPU_COLUMNS = [f"cpu_{p}_ms" for p in ("observer", "effectiveness", "predictor",
                                            "feedback")]
# what the loop itself measures: the replay's log differs from the recording only there
LOOP_COLUMNS = ("cpu_wire_ms", "cpu_log_ms", "cpu_period_ms")
# what a controller with its own filter (the fused filter) logs of it: the state's position and
# velocity (the filter's, where the replay, without a filter, logs the autopilot's) and the
# filter's health (est_*), as the controller's log names them
FILTER_COLUMNS = tuple(c for c in LOG_COLUMNS if c.startswith(("pos_", "vel_", "est_")))
_LOOP_PARTS = ("wire", "log", "period")


class RecordingError(ValueError):
    """A controller.csv that cannot be replayed (missing, lacking a column, a bad value)."""


class ReplayDiverged(FlightError):
    """The flight left the recording: a step beyond its last row, or at another time."""


def _seconds_of(ms: float) -> float:
    """s with s * 1e3 == ms (the log writes solve_time_s * 1e3): ms / 1e3, or a neighbour."""
    s = ms / 1e3
    for cand in (s, math.nextafter(s, math.inf), math.nextafter(s, -math.inf)):
        if cand * 1e3 == ms:
            return cand
    return s


def _ns_of(ms: float) -> int:
    """The ns a CPU column's ms was written from (ns * 1e-6), 0 where not measured."""
    return int(round(ms * 1e6)) if math.isfinite(ms) else 0


class ReplayController:
    """The recorded flight's commands, step by step (a measurement device: see the module
    docstring). `steps`: (command, StepInfo) per recorded row; `t_s`: each row's time;
    `prepare_ns`: each row's preparation CPU (-1 not measured); `source`: the file."""

    def __init__(self, steps: list[tuple[ActuatorCommand, StepInfo]], t_s: list[float],
                 prepare_ns: list[int], source: str = "the recording",
                 controller: str | None = None) -> None:
        if not (len(steps) == len(t_s) == len(prepare_ns)):
            raise ValueError(f"{source}: {len(steps)} steps, {len(t_s)} times and "
                             f"{len(prepare_ns)} preparation times: expected as many of each")
        self._steps = steps
        self._t = t_s
        self._prep = prepare_ns
        self._n = len(steps)
        self._i = 0
        self.source = source
        self.controller = controller          # the recording's controller name, if it says
        self.last_prepare_cpu_ns = 0
        # the raw sensor streams the loop asks the vehicle for: the recording's controller's
        # (replay_daemon sets them from its file), so that the vehicle flies the recorded
        # flight and the loop receives and decodes what it received; none by default
        self.sensor_streams: dict[str, int] = {}

    def __len__(self) -> int:
        return self._n

    @classmethod
    def from_csv(cls, path: Path | str) -> "ReplayController":
        """The replay of a controller.csv. RecordingError naming the file (and the column or
        row) if it is missing, lacks t_s or a command column, or holds a value that is not
        one of a StepInfo's."""
        from trq_lab import metrics

        path = Path(path)
        if not path.is_file():
            raise RecordingError(f"{path}: no such file (a controller.csv of trq-offboard)")
        try:
            meta, cols = metrics.read_csv(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise RecordingError(f"{path}: cannot be read: {exc}") from None
        missing = [c for c in REQUIRED_COLUMNS if c not in cols]
        if missing:
            raise RecordingError(f"{path}: no column {', '.join(missing)} (a controller.csv of "
                                 "trq-offboard carries the time t_s and the commands "
                                 "cmd_throttle1..4_pct, cmd_tilt1..4_rad)")
        n = len(cols["t_s"])
        if n == 0:
            raise RecordingError(f"{path}: no rows")

        def numeric(name: str, default: float) -> list[float]:
            if name not in cols:
                return [default] * n
            v = cols[name]
            if v.dtype == object:
                bad = next(i for i, x in enumerate(v) if not _is_float(x))
                raise RecordingError(f"{path}: column {name}, row {bad + 1}: {v[bad]!r} is "
                                     "not a number")
            return [float(x) for x in v]

        def texts(name: str, kind, default):
            if name not in cols:
                return [default] * n
            out = []
            for i, x in enumerate(cols[name]):
                try:
                    out.append(kind(str(x)))
                except ValueError:
                    known = ", ".join(m.value for m in kind)
                    raise RecordingError(f"{path}: column {name}, row {i + 1}: {x!r} is not "
                                         f"one of {known}") from None
            return out

        t_s = numeric("t_s", 0.0)
        cmd = [numeric(c, 0.0) for c in COMMAND_COLUMNS]
        for c, v in zip(COMMAND_COLUMNS, cmd):
            bad = [i for i, x in enumerate(v) if not math.isfinite(x)]
            if bad:
                raise RecordingError(f"{path}: column {c}, row {bad[0] + 1}: {v[bad[0]]!r} is "
                                     "not a finite command")
        d = [numeric(c, 0.0) for c in D_COLUMNS]
        eff = [numeric(c, 1.0) for c in EFF_COLUMNS]
        cpu = [numeric(c, math.nan) for c in STEP_CPU_COLUMNS]
        solve_ms = numeric("solve_ms", 0.0)
        iterations = numeric("iterations", 0.0)
        output_error = numeric("output_error", 0.0)
        cost = numeric("cost", math.nan)
        prepare_ms = numeric("cpu_prepare_ms", math.nan)
        status = texts("status", SolveStatus, SolveStatus.OK)
        source = texts("source", CommandSource, CommandSource.NMPC)
        steps = []
        for i in range(n):
            command = ActuatorCommand(tuple(c[i] for c in cmd[:4]),
                                      tuple(c[i] for c in cmd[4:]))
            solve = SolveInfo(status[i], int(iterations[i]), _seconds_of(solve_ms[i]), cost[i],
                              "replayed")
            info = StepInfo(source[i], solve, tuple(c[i] for c in d), output_error[i], 0, 0, 0,
                            tuple(c[i] for c in eff),
                            StepTimes(*(_ns_of(c[i]) for c in cpu)))
            steps.append((command, info))
        prepare_ns = [int(round(v * 1e6)) if math.isfinite(v) else -1 for v in prepare_ms]
        return cls(steps, t_s, prepare_ns, source=str(path), controller=meta.get("controller"))

    # --- the flight loop's contract (trq_offboard/loop.py) ----------------------------------
    def reset(self, t_s: float, state, applied=None) -> None:
        """The flight starts: back to the recording's first row."""
        self._i = 0
        self.last_prepare_cpu_ns = 0

    def step(self, t_s: float, state, applied, reference,
             sensors=None) -> tuple[ActuatorCommand, StepInfo]:
        """The recorded row of this step (ReplayDiverged past the last or at another time);
        `sensors` (the raw sensors of a recording that asked for them) received and dropped."""
        i = self._i
        if i >= self._n or t_s != self._t[i]:
            raise self._diverged(i, t_s)
        self._i = i + 1
        return self._steps[i]

    def solver_line(self) -> str:
        """What 'solves' this controller, for the log's header: the recording."""
        return f"replay of {self.source}"

    def prepare(self, reference) -> None:
        """Nothing to prepare: hands over the recorded preparation time of the last step."""
        self.last_prepare_cpu_ns = self._prep[self._i - 1] if self._i else 0

    def _diverged(self, i: int, t_s: float) -> ReplayDiverged:
        if i >= self._n:
            return ReplayDiverged(
                f"replay of {self.source}: step {i + 1} at t = {t_s!r} s is beyond the "
                f"recording's {self._n} steps (last at t = {self._t[-1]!r} s): fly at most as "
                "long as the recorded flight")
        return ReplayDiverged(
            f"replay of {self.source}: step {i + 1} at t = {t_s!r} s, the recording's step "
            f"{i + 1} is at t = {self._t[i]!r} s: the flight is not the recorded one (another "
            "vehicle, simulation settings or link than the recording's, or not in lockstep)")


def _is_float(x) -> bool:
    try:
        float(x)
    except (TypeError, ValueError):
        return False
    return True


# --- the daemon with the replay --------------------------------------------------------------
def replay_command(csv: Path | str, python: str = sys.executable) -> list[str]:
    """The command that starts the controller daemon with the replay of `csv`, before
    trq-offboard's options (trq_lab/bench/period.py's `controller_cmd`)."""
    return [python, "-m", "trq_lab.bench.period_floor", "--replay", str(csv)]


def replay_daemon(csv: str, argv: list[str]) -> int:
    """trq-offboard (`argv`: its options) flying the replay of `csv` instead of its
    controller. 2 and a message naming the file on a recording that cannot be replayed, or on
    a controller file other than the recording's."""
    from trq_offboard import daemon
    from trq_offboard.controller import sensor_streams_of

    try:
        replay = ReplayController.from_csv(csv)
    except RecordingError as exc:
        print(f"trq-bench-floor --replay: {exc}", file=sys.stderr)
        return 2

    def make_controller(cfg):
        if replay.controller is not None and replay.controller != cfg.name:
            raise RecordingError(f"{csv}: recorded with controller {replay.controller}, "
                                 f"replayed with {cfg.name} ({cfg.file}): the reference and "
                                 "the flight would differ")
        replay.sensor_streams = sensor_streams_of(cfg)
        return replay

    try:
        return daemon.main(argv, make_controller=make_controller)
    except RecordingError as exc:
        print(f"trq-bench-floor --replay: {exc}", file=sys.stderr)
        return 2


# --- the bench ---------------------------------------------------------------------------------
def same_flight(recorded: Path, replayed: Path) -> tuple[bool, str]:
    """Whether the vehicle's flight.csv rows of a replay are the recorded flight's, over the
    rows both have (the header's metadata aside): (identical, what was found)."""
    def rows(path: Path) -> list[str]:
        with open(path, encoding="ascii") as f:
            return [ln for ln in f if not ln.startswith("#")]
    a, b = rows(recorded), rows(replayed)
    if not a or not b or a[0] != b[0]:
        return False, f"{recorded} and {replayed}: not the same columns"
    n = min(len(a), len(b))
    for i in range(1, n):
        if a[i] != b[i]:
            return False, f"row {i} differs: {a[i][:80]!r} / {b[i][:80]!r}"
    return True, f"{n - 1} rows identical (recorded {len(a) - 1}, replayed {len(b) - 1})"


def replayed_steps(recorded: Path, replayed: Path) -> tuple[bool, str]:
    """Whether a replay's controller.csv is the recording's first rows in every column but
    the loop's own measurements (LOOP_COLUMNS), the last row's preparation time (an
    interrupted flight may not have closed it) and, when the recording's controller ran its
    own filter (its est_test_ratio filled), what it logs of it (FILTER_COLUMNS)."""
    from trq_lab import metrics

    _, a = metrics.read_csv(recorded)
    _, b = metrics.read_csv(replayed)
    n = len(b["t_s"])
    if n > len(a["t_s"]):
        return False, f"{n} steps replayed, {len(a['t_s'])} recorded"
    ratio = a.get("est_test_ratio")
    own_filter = ratio is not None and ratio.dtype != object and not np.all(_nan(ratio))
    for name in a:
        if name in LOOP_COLUMNS or (own_filter and name in FILTER_COLUMNS):
            continue
        x, y = a[name][:n], b[name]
        if name == "cpu_prepare_ms":
            x, y = x[:-1], y[:-1]
        same = (x == y) | (_nan(x) & _nan(y))
        if not np.all(same):
            i = int(np.flatnonzero(~same)[0])
            return False, f"{name} differs at row {i + 1}: {x[i]!r} / {y[i]!r}"
    return True, f"{n} steps, the recording's"


def _nan(v: np.ndarray) -> np.ndarray:
    return np.array([isinstance(x, float) and math.isnan(x) for x in v.tolist()], dtype=bool)


def floor_run(short_s: float, long_s: float, controller: str, work: Path,
              bracket=None) -> dict:
    """One run: the real controller's flights, then the replay of its long flight's log.
    `bracket`: period.daemons_period's, around both pairs of flights."""
    from trq_lab.bench.period import daemons_period

    real = daemons_period(short_s, long_s, controller, log_root=work / "real", bracket=bracket)
    csv = work / "real" / "long" / "controller.csv"
    floor = daemons_period(short_s, long_s, controller,
                           controller_cmd=replay_command(csv), log_root=work / "floor",
                           bracket=bracket)
    checks = {}
    for flight in ("short", "long"):
        rc = floor[flight]["controller_rc"]
        ok_f, why_f = same_flight(work / "real" / "long" / "flight.csv",
                                  work / "floor" / flight / "flight.csv")
        ok_s, why_s = replayed_steps(csv, work / "floor" / flight / "controller.csv")
        checks[flight] = {"controller_rc": rc, "same_flight": ok_f, "flight": why_f,
                          "same_steps": ok_s, "steps": why_s}
    return {"real": real, "floor": floor, "checks": checks}


def _median(vals) -> float:
    vals = [v for v in vals if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def summary(runs: list[dict], acados_ms: float | None,
            acados_runs: list[float] | None = None) -> dict:
    """Medians over the runs, the floor's ratios, and the best cases against the target
    (`acados_ms`: acados' step, the median of `acados_runs` when measured in each run; then
    also the ratios within each run, their median and range)."""
    med = {}
    for who in ("real", "floor"):
        med[who] = {k: _median([r[who][k] for r in runs])
                    for k in ("controller_cpu_ms", "vehicle_cpu_ms", "realtime_factor")}
        # the replay's log holds the recording's step parts (and preparation): only the
        # loop's own measurements are the floor's
        names = [p for p in runs[0][who]["parts"] if who == "real" or p in _LOOP_PARTS]
        med[who]["parts"] = {p: _median([r[who]["parts"][p]["mean_ms"] for r in runs])
                             for p in names}
    real, floor = med["real"], med["floor"]
    solver_ms = real["parts"]["solve (wall)"] + real["parts"]["prepare"]
    out = {"runs": len(runs), "real": real, "floor": floor,
           "floor_share": _median([r["floor"]["controller_cpu_ms"]
                                   / r["real"]["controller_cpu_ms"] for r in runs]),
           "our_solver_ms": solver_ms, "acados_ms": acados_ms}
    if acados_ms:
        out.update(
            floor_over_acados=floor["controller_cpu_ms"] / acados_ms,
            best_with_acados=(floor["controller_cpu_ms"] + acados_ms) / acados_ms,
            best_with_ours=(floor["controller_cpu_ms"] + solver_ms) / acados_ms,
            real_over_acados=real["controller_cpu_ms"] / acados_ms)
    if acados_runs:
        per_run = [r["floor"]["controller_cpu_ms"] / a for r, a in zip(runs, acados_runs)]
        out["floor_over_acados_runs"] = per_run
        out["floor_over_acados_paired"] = _median(per_run)
    return out


def table(s: dict, acados_label: str) -> str:
    real, floor = s["real"], s["floor"]
    lines = ["| figure (median of %d run(s)) | the real controller | the replay (the floor) |"
             % s["runs"], "|---|---|---|"]
    lines.append(f"| controller process CPU per control period, from outside, ms "
                 f"| {real['controller_cpu_ms']:.3f} | {floor['controller_cpu_ms']:.3f} |")
    for p in ("wire", "log", "period"):
        label = ("whole period from inside (every thread, the loop's clock)" if p == "period"
                 else f"the loop's {p} part")
        lines.append(f"| {label}, mean ms | {real['parts'][p]:.3f} | {floor['parts'][p]:.3f} |")
    lines.append(f"| the solver's own step (feedback wall + preparation CPU), mean ms "
                 f"| {s['our_solver_ms']:.3f} | - |")
    lines.append(f"| vehicle process CPU per control period, ms | {real['vehicle_cpu_ms']:.3f} "
                 f"| {floor['vehicle_cpu_ms']:.3f} |")
    lines.append(f"| closed loop, lockstep, x real time | {real['realtime_factor']:.2f} "
                 f"| {floor['realtime_factor']:.2f} |")
    lines.append(f"\nthe floor's share of the real controller's CPU per period: "
                 f"{s['floor_share']:.2f}")
    a = s["acados_ms"]
    if a:
        def verdict(ratio):
            return "reachable" if ratio <= TARGET_RATIO else "out of reach"
        lines += [
            f"acados' exact-Hessian RTI step ({acados_label}): {a:.3f} ms",
            f"the floor / acados' step: {s['floor_over_acados']:.2f}" + (
                f" (within each run: {' '.join(f'{v:.2f}' for v in s['floor_over_acados_runs'])}"
                f", median {s['floor_over_acados_paired']:.2f})"
                if "floor_over_acados_runs" in s else ""),
            f"best case, the floor + a solver as fast as acados: {s['best_with_acados']:.2f}x "
            f"acados' step (target <= {TARGET_RATIO:g}x: {verdict(s['best_with_acados'])})",
            f"the floor + our solver's own step: {s['best_with_ours']:.2f}x (target <= "
            f"{TARGET_RATIO:g}x: {verdict(s['best_with_ours'])})",
            f"the real controller today: {s['real_over_acados']:.2f}x"]
    else:
        lines.append(f"no acados step here (--anchor acados or --acados-ms): the target "
                     f"({TARGET_RATIO:g}x with a solver as fast as acados) needs acados' step to "
                     f"be at least {floor['controller_cpu_ms'] / (TARGET_RATIO - 1):.3f} ms on "
                     "this machine at this moment")
        cal = s.get("calibration_ms")
        if cal:
            lines.append(f"the floor / the calibration at the end ({cal:.2f} ms): "
                         f"{floor['controller_cpu_ms'] / cal:.3f} (to compare with a record's "
                         "acados step over its calibration)")
    return "\n".join(lines)


def acados_server(stack, controller: str, seconds: float = 16.0):
    """acados' exact-Hessian RTI built on our rti-exact flight of `seconds` (the flight
    `trq-bench-nmpc --modes rti-exact --anchor acados --quick` replays), in a server process
    (trq_lab/bench/nmpc.py's AnchorServer) kept until `stack` closes."""
    from trq_lab.bench import nmpc

    rec_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="trq-bench-floor-rec-")))
    rec = rec_dir / "flight.npz"
    nmpc.run_mode("rti-exact", seconds, controller, record=rec)
    return stack.enter_context(nmpc.AnchorServer(rec, "exact", controller))


def bracket_step(run: dict) -> dict:
    """acados' step in one run: the median of its passes' step p50 around the run's four
    flights (the real controller's two, the replay's two), and the passes."""
    passes = [b["total_median_ms"] for who in ("real", "floor") for b in run[who]["brackets"]]
    return {"total_median_ms": float(np.median(passes)), "passes_ms": passes}


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="trq-bench-floor", description=__doc__.splitlines()[0],
                                 allow_abbrev=False)
    ap.add_argument("--replay", metavar="CSV", default=None,
                    help="be the controller daemon flying the replay of this controller.csv "
                         "(first on the line; every option after CSV is trq-offboard's)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs, each the real controller's flights then their replay "
                         "(interleaved); the figures are medians (default 3)")
    from trq_lab.bench.period import add_flight_lengths
    add_flight_lengths(ap, 5.0, 35.0)
    ap.add_argument("--controller", default="trq_nmpc_eso",
                    help="the controller file of the real flights (default trq_nmpc_eso)")
    ap.add_argument("--anchor", choices=("acados",), default=None,
                    help="measure acados' exact-Hessian RTI step in each run, on our rti-exact "
                         "flight of 16 s, built once and stepped through that flight right "
                         "before, between and after each pair of daemon flights (needs acados: "
                         "trq_lab/bench/acados_anchor.py)")
    ap.add_argument("--acados-ms", type=float, default=None,
                    help="acados' exact-Hessian RTI step (ms) from a dated record, where the "
                         "anchor cannot run here: the ratios are then across runs")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["--replay"]:
        if len(argv) < 2:
            print("trq-bench-floor --replay: expected the controller.csv to replay",
                  file=sys.stderr)
            return 2
        return replay_daemon(argv[1], argv[2:])
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.replay is not None:
        ap.error("--replay CSV comes first: trq-bench-floor --replay CSV [trq-offboard options]")
    if args.repeat < 1:
        ap.error(f"--repeat {args.repeat}: expected at least 1")
    if not 0 < args.short_s < args.long_s:
        ap.error(f"--short-s {args.short_s:g}, --long-s {args.long_s:g}: expected "
                 "0 < short < long")
    if args.acados_ms is not None and not args.acados_ms > 0:
        ap.error(f"--acados-ms {args.acados_ms}: expected a positive number of ms")
    if args.anchor and args.acados_ms is not None:
        ap.error("--anchor acados measures acados' step: leave out --acados-ms")
    if args.anchor:
        from trq_lab.bench import acados_anchor
        ok, why = acados_anchor.available()
        if not ok:
            ap.error(f"--anchor acados: {why}")
    from trq_lab.bench.nmpc import machine_line

    print(machine_line(), flush=True)
    print(f"controller: {args.controller}; flights {args.short_s:g} s and {args.long_s:g} s of "
          f"vehicle time in lockstep; "
          f"{args.repeat} run(s)", flush=True)
    with contextlib.ExitStack() as stack:
        server = acados_server(stack, args.controller) if args.anchor else None
        return _runs(args, server)


def _runs(args, server) -> int:
    """The runs, the table and the JSON (main's, after its checks); `server`: acados' bracket
    (acados_server) or None."""
    from trq_lab.bench.nmpc import bracket_passes, calibration_ms, machine_line

    def one_pass(point: str) -> dict:
        return bracket_passes({"rti-exact": server})["rti-exact"]

    bracket = one_pass if server is not None else None
    runs, anchors = [], []
    for k in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="trq-bench-floor-") as work:
            r = floor_run(args.short_s, args.long_s, args.controller, Path(work), bracket)
        runs.append(r)
        c = r["checks"]
        print(f"  run {k + 1}: controller {r['real']['controller_cpu_ms']:.3f} ms CPU a period "
              f"from outside, replay {r['floor']['controller_cpu_ms']:.3f} ms; replay exit "
              f"{c['short']['controller_rc']}/{c['long']['controller_rc']}, the vehicle's "
              f"flight: {c['short']['flight']}; {c['long']['flight']}; the steps: "
              f"{c['long']['steps']}", flush=True)
        if not all(c[f]["same_flight"] and c[f]["same_steps"] for f in c):
            print(f"trq-bench-floor: the replay did not fly the recorded flight: {c}",
                  file=sys.stderr)
            return 1
        if server is not None:
            a = bracket_step(r)
            anchors.append(a)
            print(f"  run {k + 1}: acados exact prep+feedback p50 {a['total_median_ms']:.3f} ms "
                  f"(the median of its passes around the run's flights: "
                  f"{' '.join(f'{v:.3f}' for v in a['passes_ms'])})", flush=True)
    acados_ms, label = args.acados_ms, "given with --acados-ms, not measured in this run"
    if anchors:
        acados_ms = _median([a["total_median_ms"] for a in anchors])
        label = (f"measured in this run around each run's flights, median of "
                 f"{len(anchors)} runs")
    s = summary(runs, acados_ms, [a["total_median_ms"] for a in anchors] or None)
    s["calibration_ms"] = cal = calibration_ms()
    print("per run, CPU per period from outside, ms: the real controller "
          + " ".join(f"{r['real']['controller_cpu_ms']:.3f}" for r in runs) + "; the floor "
          + " ".join(f"{r['floor']['controller_cpu_ms']:.3f}" for r in runs)
          + ("; acados' step " + " ".join(f"{a['total_median_ms']:.3f}" for a in anchors)
             if anchors else ""))
    print(table(s, label))
    if any(r[w]["controller_cpu_ms"] <= 0 for r in runs for w in ("real", "floor")):
        print("note: a CPU per period at or below zero: the long flight did not cost more than "
              "the short one (flights too short for the machine's noise: lengthen --long-s)")
    print(f"calibration at the end {cal:.2f} ms")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine_line(), "time": time.strftime(
            "%Y-%m-%d %H:%M:%S"), "summary": s, "runs": runs, "anchors": anchors,
            "calibration_end_ms": cal}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
