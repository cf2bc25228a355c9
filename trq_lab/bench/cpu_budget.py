"""Real time on a slower computer: a scenario flown in real time with the controller process held
to a fraction of one core, from the whole core (the anchor, in the same run) down.

    trq-bench-cpu-budget                                  paper_fault50, trq_nmpc_eso, 1 .. 1/4
    trq-bench-cpu-budget --shares 1,0.5,0.33 --out out/cpu_budget --json out/cpu_budget.json

Each flight is `trq-scenario SCENARIO --realtime --only CONTROLLER`, the vehicle pinned to one core
and the controller to the other, the controller in a CPU cgroup whose quota is `share` of every
`--period-us` (Linux CFS bandwidth control; cgroup v1's cpu controller or cgroup v2's cpu.max,
which needs root). A quota of a third is the closest this machine comes to a companion computer
three times slower per core: the controller runs at full speed for a third of each period and
waits for the rest, so the granularity of the period (4 ms by default, the kernel's minimum quota
being 1 ms) adds to the latency of a step that overruns its share. It prints, per share: the
scenario's outcome (its targets met or not), the tracking after the fault, the solve times, the
controller's own CPU per control period (every thread of its process, from its controller.csv),
and how often and how long the kernel held the controller back; and the tracking as a ratio of
the anchor's, so that what degrades first is read off one table.

The controller loads the HPIPM that `$TRQ_HPIPM_LIBRARY` names (trq-hpipm-fetch), else CasADi's
bundled one; the header says which.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import subprocess
import sys
from dataclasses import asdict, dataclass
from fractions import Fraction
from pathlib import Path

import trq_params

from trq_lab.bench.period import cpu_parts

CGROUP_V1 = Path("/sys/fs/cgroup/cpu")
CGROUP_V2 = Path("/sys/fs/cgroup")


class NoQuota(RuntimeError):
    """This machine gives the tool no way to set a CPU quota (not Linux, not root, no cgroup)."""


MIN_QUOTA_US = 1000          # CFS bandwidth control refuses a smaller quota


class CpuQuota:
    """A CPU cgroup with `share` of one CPU in every `period_us`, entered by a command prefix."""

    def __init__(self, name: str, share: float, period_us: int) -> None:
        quota_us = round(share * period_us)
        if quota_us < MIN_QUOTA_US:
            raise ValueError(f"share {share:g} of {period_us} us is {quota_us} us: the kernel's "
                             f"minimum quota is {MIN_QUOTA_US} us (raise --period-us)")
        if (CGROUP_V1 / "cpu.cfs_quota_us").exists():
            self.dir = CGROUP_V1 / name
            self._make()
            (self.dir / "cpu.cfs_period_us").write_text(f"{period_us}\n")
            (self.dir / "cpu.cfs_quota_us").write_text(f"{quota_us}\n")
        elif "cpu" in _read(CGROUP_V2 / "cgroup.controllers").split():
            self.dir = CGROUP_V2 / name
            self._make()
            (self.dir / "cpu.max").write_text(f"{quota_us} {period_us}\n")
        else:
            raise NoQuota("no CPU cgroup controller found (cgroup v1 /sys/fs/cgroup/cpu or v2 "
                          "cpu in /sys/fs/cgroup/cgroup.controllers)")

    def _make(self) -> None:
        try:
            self.dir.mkdir()
        except OSError as exc:
            raise NoQuota(f"cannot create the cgroup {self.dir}: {exc.strerror} (run as root)") \
                from exc

    def prefix(self, core: int) -> str:
        """A command prefix that moves the process into the cgroup, pinned to `core`."""
        procs = shlex.quote(str(self.dir / "cgroup.procs"))
        return (f"sh -c 'echo $$ > {procs} && exec \"$@\"' trq-cpu-budget "
                f"taskset -c {core}")

    def throttling(self) -> dict[str, float]:
        """The kernel's count of periods, of periods in which the quota ran out, and the time
        held back (cpu.stat)."""
        stat = dict(line.split() for line in _read(self.dir / "cpu.stat").splitlines()
                    if len(line.split()) == 2)
        held_us = (int(stat["throttled_time"]) / 1000 if "throttled_time" in stat
                   else int(stat.get("throttled_usec", 0)))
        return {"periods": int(stat.get("nr_periods", 0)),
                "throttled_periods": int(stat.get("nr_throttled", 0)),
                "throttled_s": held_us * 1e-6}

    def remove(self) -> None:
        try:
            self.dir.rmdir()
        except OSError:
            pass


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""


@dataclass
class Row:
    share: float
    exit_code: int
    targets_met: bool
    crashed: bool | None
    rmse_pos_after_fault_m: float | None
    max_yaw_err_deg: float | None
    solve_ms_p50: float | None
    solve_ms_p99: float | None
    cpu_period_ms_p50: float | None = None
    cpu_period_ms_p99: float | None = None
    periods: int = 0
    throttled_periods: int = 0
    throttled_s: float = 0.0


def fly(scenario: str, controller: str, share: float, period_us: int, out: Path,
        name: str) -> Row:
    """One real-time flight of `controller` in `scenario` at `share` of a core."""
    quota = None if share >= 1.0 else CpuQuota(name, share, period_us)
    try:
        prefix = quota.prefix(1) if quota else "taskset -c 1"
        cmd = [sys.executable, "-m", "trq_lab.scenario", scenario, "--realtime", "--only",
               controller, "--out", str(out), "--no-figures", "--jobs", "1",
               "--controller-prefix", prefix, "--vehicle-prefix", "taskset -c 0"]
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "run.log", "w") as log:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
        held = quota.throttling() if quota else {}
    finally:
        if quota:
            quota.remove()
    try:
        (m,) = [r for r in json.loads((out / "metrics.json").read_text())["runs"]
                if r.get("controller") == controller]
    except (OSError, ValueError, KeyError):
        m = {}
    period = period_cpu_ms(out / controller / "controller.csv")
    return Row(share, rc, rc == 0, m.get("crashed"), m.get("rmse_pos_after_fault_m"),
               m.get("max_yaw_err_deg"), m.get("solve_ms_p50"), m.get("solve_ms_p99"),
               *period, **held)


def period_cpu_ms(path: Path) -> tuple[float | None, float | None]:
    """(p50, p99) of the controller's CPU per control period (cpu_period_ms: every thread of its
    process) over the steps of its log; (None, None) without one."""
    try:
        got = cpu_parts(path, -math.inf, math.inf)["period"]
    except (OSError, KeyError, ValueError):
        return None, None
    return (got["p50_ms"], got["p99_ms"]) if math.isfinite(got["p50_ms"]) else (None, None)


def table(rows: list[Row]) -> str:
    anchor = next((r for r in rows if r.share >= 1.0 and r.rmse_pos_after_fault_m), None)

    def num(v, fmt):
        return "-" if v is None else format(v, fmt)

    lines = ["| CPU share | targets met | crashed | pos RMSE after fault m | x the whole core "
             "| max yaw err deg | solve p50 / p99 ms | CPU a period p50 / p99 ms "
             "| throttled periods | held back s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = (r.rmse_pos_after_fault_m / anchor.rmse_pos_after_fault_m
                 if anchor and r.rmse_pos_after_fault_m is not None else None)
        lines.append(
            f"| {r.share:.2f} | {'yes' if r.targets_met else 'no'} | {r.crashed} "
            f"| {num(r.rmse_pos_after_fault_m, '.4f')} | {num(ratio, '.1f')} "
            f"| {num(r.max_yaw_err_deg, '.2f')} "
            f"| {num(r.solve_ms_p50, '.2f')} / {num(r.solve_ms_p99, '.2f')} "
            f"| {num(r.cpu_period_ms_p50, '.2f')} / {num(r.cpu_period_ms_p99, '.2f')} "
            f"| {r.throttled_periods} of {r.periods} | {r.throttled_s:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-cpu-budget",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper_fault50",
                    help="a built-in scenario name or a scenario YAML path (default "
                         "paper_fault50)")
    ap.add_argument("--controller", default="trq_nmpc_eso",
                    help="the controller of the scenario to fly (default trq_nmpc_eso)")
    ap.add_argument("--shares", default="1,1/2,1/3,1/4",
                    help="fractions of one core (0.5 or 1/2), comma-separated; 1 is the anchor "
                         "(pinned, no quota); default 1,1/2,1/3,1/4")
    ap.add_argument("--period-us", type=int, default=4000,
                    help="the quota's period in microseconds (default 4000)")
    ap.add_argument("--out", type=Path, default=Path("out/cpu_budget"), help="output folder")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = ap.parse_args(argv)
    try:
        shares = [float(Fraction(s)) for s in args.shares.split(",")]
    except (ValueError, ZeroDivisionError):
        ap.error(f"--shares: expected numbers in (0, 1], got {args.shares!r}")
    if not shares or not all(0.0 < s <= 1.0 for s in shares):
        ap.error(f"--shares: expected numbers in (0, 1], got {args.shares!r}")
    if not 1000 <= args.period_us <= 1_000_000:
        ap.error(f"--period-us: expected 1000 .. 1000000, got {args.period_us}")
    short = [s for s in shares if s < 1.0 and round(s * args.period_us) < MIN_QUOTA_US]
    if short:                # refused before any flight, not after the shares before it
        need = math.ceil(MIN_QUOTA_US / min(short))
        ap.error(f"--shares: {min(short):g} of --period-us {args.period_us} is "
                 f"{round(min(short) * args.period_us)} us, under the kernel's minimum quota "
                 f"of {MIN_QUOTA_US} us: "
                 + (f"raise --period-us to at least {need}" if need <= 1_000_000 else
                    "too small a share for any quota period this tool takes"))
    if (os.cpu_count() or 1) < 2:
        print("trq-bench-cpu-budget: needs two cores (vehicle and controller on their own)",
              file=sys.stderr)
        return 2
    try:
        trq_params.resolve("scenarios", args.scenario)
    except trq_params.UnknownName as exc:
        print(f"trq-bench-cpu-budget: {exc}", file=sys.stderr)
        return 2
    from trq_lab.bench.nmpc import machine_line
    from trq_offboard.nmpc.hpipm import LIBRARY_ENV

    print(machine_line())
    print(f"{args.scenario} in real time, {args.controller}, quota period "
          f"{args.period_us} us; HPIPM: "
          + (f"${LIBRARY_ENV}={os.environ[LIBRARY_ENV]}" if os.environ.get(LIBRARY_ENV)
             else "CasADi's bundled library"))
    rows = []
    try:
        for k, share in enumerate(shares):
            row = fly(args.scenario, args.controller, share, args.period_us,
                      args.out / f"share_{share:.3f}", f"trq-cpu-budget-{os.getpid()}-{k}")
            print(f"  share {share:.3f}: exit {row.exit_code}, RMSE after fault "
                  f"{row.rmse_pos_after_fault_m}, crashed {row.crashed}", flush=True)
            rows.append(row)
    except (NoQuota, ValueError) as exc:
        print(f"trq-bench-cpu-budget: {exc}", file=sys.stderr)
        return 2
    print()
    print(table(rows))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps([asdict(r) for r in rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
