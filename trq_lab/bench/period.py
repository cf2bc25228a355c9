"""The controller's whole control period measured from outside its process, over both daemons.

    figures = daemons_period(short_s=5, long_s=35)     # trq-bench-nmpc --daemons

Flies the vehicle daemon and the controller daemon (trq_nmpc_eso, or another controller file) in
lockstep over UDP on free ports, twice: for `short_s` and for `long_s` seconds of vehicle time
(the vehicle's --duration; the default sim, the controller's helix). Each process's CPU time
(user + system, all its threads, from the kernel's rusage of the exited child, os.wait4) is read
when it has exited. The difference of the two flights over the control periods between them
cancels start-up, build and shut-down:

    controller CPU per period = (cpu_long - cpu_short) / periods,   periods = (long - short) rate

and the same for the vehicle; the real-time factor of the closed loop is
(long_s - short_s) / (wall_long - wall_short) (simulated seconds per wall second, both daemons
in lockstep, the vehicle's whole run). The long flight's controller.csv gives the parts of the
same periods (the controller's own measurement, records.StepTimes and PeriodTimes), their mean
over the rows stamped in (short_s, long_s]; their whole period (every thread, from one step's
start to the next) is the inside view of the outside figure. Both flights write their logs, as a
scenario's do (the log's cost is one of the parts).

A controller flown for the first time in the process (with a sensing profile) first flies a
warm-up flight of `warm_s` (its figures dropped): the compiled parts of both daemons are built
and cached on disk by the first flight on a machine, and a build in the short flight alone would
be subtracted from the long one's CPU (a negative period on a fresh machine). A replay of that
controller's flight (`controller_cmd`, the floor bench's) builds nothing the controller's own
flights have not, and flies no warm-up of its own.

`bracket`: a callable run right before the short flight, between the two and right after the
long one, while neither daemon runs (trq-bench-nmpc's anchor: acados stepped through a
recorded flight at the same moments of the machine); what it returns is kept, in that order,
as the figures' "brackets".
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from trq_lab import procs

__all__ = ["daemons_period", "PARTS", "parts_table"]

# what has flown in this process (controller, sensing): warm, caches built
_WARM: set = set()
# the vehicle's clock modes a bench flies (sil_vehicle --mode): lockstep, or the wall clock
VEHICLE_MODES = ("lockstep", "realtime")

PARTS = ("observer", "effectiveness", "predictor", "feedback", "prepare", "wire", "log",
         "period")


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _reap(proc: subprocess.Popen, block: bool = True) -> float | None:
    """`proc`'s CPU seconds (user + system, all threads) once it has exited (waiting for it
    with `block`, else None while it runs). Popen.poll or wait must not be called on it: they
    would reap it without its rusage."""
    pid, status, ru = os.wait4(proc.pid, 0 if block else os.WNOHANG)
    if pid == 0:
        return None
    proc.returncode = os.waitstatus_to_exitcode(status)
    return ru.ru_utime + ru.ru_stime


def _listening(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    """Until UDP 127.0.0.1:`port` is taken (trq_lab.procs.wait_bound without Popen.poll)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return
        time.sleep(0.05)
    raise RuntimeError(f"the controller did not listen on {port} within {timeout_s:g} s")


def fly_daemons(seconds: float, controller: str, log_dir: Path,
                python: str = sys.executable,
                controller_cmd: list[str] | None = None, sensing: str | None = None,
                listen_timeout_s: float = 60.0, controller_env: dict | None = None,
                vehicle_mode: str = "lockstep") -> dict:
    """One flight of both daemons for `seconds` of vehicle time: CPU s of each
    process, the vehicle's wall time (start to exit) and both exit codes. `controller_cmd`: the
    command that starts the controller daemon, before its options (default
    `python -m trq_offboard`; another program taking trq-offboard's options, e.g.
    trq_lab/bench/period_floor.py's replay, or either under a profiler). `sensing`: the
    vehicle's sensing profile (its --sensing; None: the sim file's). `listen_timeout_s`: how
    long the controller may take to start listening. `controller_env`: variables set for the
    controller's process only. `vehicle_mode`: lockstep (default) or realtime (the vehicle on
    the wall clock: the control loop at its rate, waiting between two steps as on a vehicle)."""
    pv, pc, pg, pt = _free_ports(4)
    if vehicle_mode not in VEHICLE_MODES:
        raise ValueError(f"vehicle mode {vehicle_mode!r}: expected lockstep or realtime")
    vcmd = [python, "-m", "sil_vehicle", "--duration", f"{seconds:g}", "--mode", vehicle_mode,
            "--offboard-bind", f"127.0.0.1:{pv}", "--offboard-target", f"127.0.0.1:{pc}",
            "--gcs-bind", f"127.0.0.1:{pg}", "--gcs-target", f"127.0.0.1:{pt}",
            "--log-dir", str(log_dir)] + (["--sensing", sensing] if sensing else [])
    ccmd = list(controller_cmd or [python, "-m", "trq_offboard"])
    ccmd += ["--controller", controller, "--connect", f"udpin:127.0.0.1:{pc}",
             "--log-dir", str(log_dir)]
    out = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctl = subprocess.Popen(ccmd, **out, env={**os.environ, **(controller_env or {})})
    _listening(pc, ctl, listen_timeout_s)  # built and listening: the vehicle's clock starts now
    t0 = time.monotonic()
    veh = subprocess.Popen(vcmd, **out)
    veh_cpu = _reap(veh)
    wall = time.monotonic() - t0
    ctl_cpu = _reap(ctl, block=False)
    if ctl_cpu is None:
        ctl.send_signal(signal.SIGINT)     # the daemon hands over and closes its logs
        deadline = time.monotonic() + 15.0
        while ctl_cpu is None and time.monotonic() < deadline:
            time.sleep(0.05)
            ctl_cpu = _reap(ctl, block=False)
        if ctl_cpu is None:
            ctl.kill()
            ctl_cpu = _reap(ctl)
    procs.controller_csv(log_dir)          # on the ground: after the controller's CPU is read
    return {"seconds": seconds, "controller_cpu_s": ctl_cpu, "vehicle_cpu_s": veh_cpu,
            "wall_s": wall, "vehicle_rc": veh.returncode, "controller_rc": ctl.returncode}


def add_flight_lengths(ap, short_s: float, long_s: float) -> None:
    """The two flights' --short-s and --long-s (s of vehicle time) on a bench's parser."""
    ap.add_argument("--short-s", type=float, default=short_s,
                    help=f"the short flight, s of vehicle time (default {short_s:g})")
    ap.add_argument("--long-s", type=float, default=long_s,
                    help=f"the long flight, s of vehicle time (default {long_s:g})")


def cpu_parts(csv_path: Path, lo_s: float, hi_s: float) -> dict:
    """{part: {mean_ms, p50_ms, p99_ms}} of a controller.csv's cpu_*_ms columns and its solve
    time, over the steps stamped in (lo_s, hi_s] (nan for a column the log lacks)."""
    from trq_lab import metrics
    _, cols = metrics.read_csv(csv_path)
    t = np.asarray(cols["stamp_us"], float) * 1e-6
    keep = (t > lo_s) & (t <= hi_s)
    out = {}
    nan = float("nan")
    for part in PARTS:
        name = f"cpu_{part}_ms"        # a controller older than these columns: nan
        v = np.asarray(cols[name], float)[keep] if name in cols else np.empty(0)
        v = v[~np.isnan(v)]            # no value at all: nan, without numpy's empty-slice warning
        out[part] = ({"mean_ms": float(np.mean(v)), "p50_ms": float(np.median(v)),
                      "p99_ms": float(np.percentile(v, 99))} if v.size else
                     {"mean_ms": nan, "p50_ms": nan, "p99_ms": nan})
    s = np.asarray(cols["solve_ms"], float)[keep]
    out["solve (wall)"] = {"mean_ms": float(np.nanmean(s)), "p50_ms": float(np.nanmedian(s)),
                           "p99_ms": float(np.nanpercentile(s, 99))}
    return out


def daemons_period(short_s: float = 5.0, long_s: float = 35.0,
                   controller: str = "trq_nmpc_eso", control_rate_hz: int = 100,
                   controller_cmd: list[str] | None = None,
                   log_root: Path | None = None, sensing: str | None = None,
                   bracket: Callable[[str], object] | None = None,
                   warm_s: float = 1.0, vehicle_mode: str = "lockstep") -> dict:
    """The two flights and what follows from them (see the module docstring).
    `controller_cmd`: fly_daemons'. `log_root`: the flights' logs go to its `short/` and
    `long/` and stay (default: a temporary directory, removed). `sensing`: the vehicle's
    sensing profile (fly_daemons'). `bracket`: called with "before", "between" and "after"
    around the flights (the module docstring). `warm_s`: the warm-up flight's seconds (the
    module docstring; 0: none). `vehicle_mode`: fly_daemons'."""
    brackets = []

    def at(point: str) -> None:
        if bracket is not None:
            brackets.append(bracket(point))

    with contextlib.ExitStack() as stack:
        root = Path(log_root) if log_root is not None else Path(
            stack.enter_context(tempfile.TemporaryDirectory(prefix="trq-bench-period-")))
        key = (controller, sensing)
        if warm_s > 0 and key not in _WARM:
            fly_daemons(warm_s, controller, root / "warm", controller_cmd=controller_cmd,
                        sensing=sensing, vehicle_mode=vehicle_mode)
            _WARM.add(key)
        at("before")
        short = fly_daemons(short_s, controller, root / "short", controller_cmd=controller_cmd,
                            sensing=sensing, vehicle_mode=vehicle_mode)
        at("between")
        long_ = fly_daemons(long_s, controller, root / "long", controller_cmd=controller_cmd,
                            sensing=sensing, vehicle_mode=vehicle_mode)
        at("after")
        parts = cpu_parts(root / "long" / "controller.csv", short_s, long_s)
    periods = (long_s - short_s) * control_rate_hz
    dwall = long_["wall_s"] - short["wall_s"]
    return {
        "short": short, "long": long_, "periods": periods,
        "controller_cpu_ms": (long_["controller_cpu_s"] - short["controller_cpu_s"])
        / periods * 1e3,
        "vehicle_cpu_ms": (long_["vehicle_cpu_s"] - short["vehicle_cpu_s"]) / periods * 1e3,
        "realtime_factor": (long_s - short_s) / dwall if dwall > 0 else float("nan"),
        "parts": parts,
        **({"brackets": brackets} if bracket is not None else {}),
    }


def parts_table(fig: dict) -> str:
    """The controller's period by part beside the outside figures (markdown)."""
    lines = ["| part | mean ms | p50 ms | p99 ms |", "|---|---|---|---|"]
    for name, v in fig["parts"].items():
        label = "whole period (every thread, from inside)" if name == "period" else name
        lines.append(f"| {label} | {v['mean_ms']:.3f} | {v['p50_ms']:.3f} | {v['p99_ms']:.3f} |")
    lines.append(f"| the controller process, from outside (CPU per period) "
                 f"| {fig['controller_cpu_ms']:.3f} | - | - |")
    lines.append(f"| the vehicle process, from outside (CPU per period) "
                 f"| {fig['vehicle_cpu_ms']:.3f} | - | - |")
    return "\n".join(lines)
