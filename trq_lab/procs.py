"""Child processes of the experiment layer (the two daemons, started by the scenario runner, the
stress tool and the tests): waiting until one listens, and stopping one for certain.

    wait_bound(port, proc, timeout_s) -> bool    True once someone holds UDP 127.0.0.1:port
    stop(proc, grace_s)                           SIGINT (a daemon's clean shutdown: it closes
                                                  its logs), then SIGKILL after grace_s
    controller_csv(log_dir)                       the controller daemon's controller.ulg as
                                                  controller.csv, once it has exited (the
                                                  ground's conversion: trq_wire.ulog)
"""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from pathlib import Path

__all__ = ["wait_bound", "stop", "controller_csv"]


def wait_bound(port: int, proc: subprocess.Popen, timeout_s: float) -> bool:
    """Poll until UDP 127.0.0.1:`port` is taken (by `proc`, presumably); False if `proc` exits
    or `timeout_s` passes first."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return True
        time.sleep(0.05)
    return False


def stop(proc: subprocess.Popen | None, grace_s: float = 10.0) -> None:
    """Stop `proc` if it still runs: SIGINT, then SIGKILL if it has not exited after grace_s."""
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def controller_csv(log_dir: Path) -> Path | None:
    """controller.csv of a controller daemon's log folder: written from its controller.ulg
    (trq_wire.ulog.to_csv) unless a CSV at least as new is there; None when the folder has
    neither (a daemon run with --no-log, or one that never started its flight log)."""
    from trq_wire.ulog import to_csv

    log_dir = Path(log_dir)
    ulg, csv = log_dir / "controller.ulg", log_dir / "controller.csv"
    if ulg.exists() and not (csv.exists() and csv.stat().st_mtime_ns >= ulg.stat().st_mtime_ns):
        return to_csv(ulg, csv)
    return csv if csv.exists() else None
