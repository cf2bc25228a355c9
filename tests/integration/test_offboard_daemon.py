"""Both daemons over real UDP: `python -m sil_vehicle` and `python -m trq_offboard` as separate
processes on free ports, exactly as trq-scenario starts them.

(1) lockstep, no wind, no fault, a short helix: trq_nmpc_eso and trq_nmpc fly in parallel (two
    process pairs); each exits 0 with a landed-and-disarmed summary, tracks the reference within
    5 cm RMS (truth from the vehicle's flight.csv against the reference in controller.csv), and
    its log is sane (finite commands inside the actuator ranges, strictly increasing stamps, the
    vehicle applying exactly the command of each stamp);
(2) the command line: no vehicle, a bad controller file, --help;
(3) real time: the same controller flies a short hover against the wall-clock vehicle.
The daemons come from the `daemons` fixtures (stopped at teardown); every wait has a wall-clock
deadline. Nothing depends on
the working directory: paths come from this file and the processes run in tmp directories.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import Daemons, Process

from trq_lab import metrics
from trq_lab.overlays import write_controller_overlay

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

ENV = dict(os.environ)
STARTUP_S = 60.0               # the controller builds its NMPC before it listens
FLIGHT_TIMEOUT_S = 120.0        # a ~32 s simulated flight takes ~25 s of wall time here
HELIX = {"kind": "helix", "hold_s": 1.0, "duration_s": 12.0, "ramp_s": 2.0}
HOVER = {"kind": "hover", "altitude_m": 1.0, "hold_s": 1.0, "duration_s": 2.0, "ramp_s": 0.5}
LOCKSTEP_CONTROLLERS = ("trq_nmpc_eso", "trq_nmpc")
RMSE_LIMIT_M = 0.05
TILT_LIMIT_RAD = math.radians(30.0)


def write_overlay(out: Path, controller: str, reference: dict) -> Path:
    """A controller file extending params/controller/<controller>.yaml with absolute paths and a
    short reference (the tools' own writer)."""
    from trq_offboard.config import load_controller

    path = write_controller_overlay(controller, reference, out)
    assert load_controller(path).reference.kind == reference["kind"]
    return path


@dataclass
class Flight:
    name: str
    out: Path
    vehicle: Process
    controller: Process
    returncode: int | None = None
    stdout: str = ""

    def wait(self, deadline: float) -> None:
        try:
            self.returncode = self.controller.popen.wait(
                timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            self.returncode = None
        finally:
            self.stop()
        self.stdout = self.controller.text()

    def stop(self) -> None:
        self.controller.stop()
        self.vehicle.stop()

    def why(self) -> str:
        return (f"{self.name}: controller rc {self.returncode}\n"
                f"{self.controller.why()}\n{self.vehicle.why()}")


def start_flight(daemons: Daemons, out: Path, controller: str, reference: dict,
                 *vehicle_args: str, controller_args: tuple[str, ...] = ()) -> Flight:
    overlay = write_overlay(out, controller, reference)
    # The controller first, the vehicle once the controller listens: a lockstep vehicle left
    # unanswered for clock.free_run_after_s (2 s) runs on in real time, and the controller's
    # NMPC build (2-3 s, more on a loaded machine) would then race its first answers.
    ctl = daemons.controller("--controller", str(overlay), *controller_args,
                             log_dir=out / "controller", out_dir=out)
    ctl.wait_bound(timeout_s=STARTUP_S)
    vehicle = daemons.vehicle(*vehicle_args, log_dir=out / "vehicle", offboard_target=ctl.port,
                              out_dir=out)
    return Flight(controller, out, vehicle, ctl)


def fly_all(flights: list[Flight], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    try:
        for f in flights:
            f.wait(deadline)
    finally:
        for f in flights:
            f.stop()


def logs(flight: Flight) -> tuple[dict, dict]:
    _, truth = metrics.read_csv(flight.out / "vehicle" / "flight.csv")
    _, steps = metrics.read_csv(flight.out / "controller" / "controller.csv")
    return truth, steps


def assert_landed_summary(flight: Flight) -> None:
    assert flight.returncode == 0, flight.why()
    lines = [ln for ln in flight.stdout.splitlines() if ln.startswith("trq-offboard: ")
             and "RMSE" in ln]
    assert len(lines) == 1, flight.why()
    assert ", landed, disarmed" in lines[0] and "NOT landed" not in lines[0], lines[0]


# --- (1) lockstep flights ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def lockstep_flights(module_daemons) -> dict[str, Flight]:
    base = module_daemons.tmp / "offboard_lockstep"
    flights = []
    try:
        for name in LOCKSTEP_CONTROLLERS:
            flights.append(start_flight(module_daemons, base / name, name, HELIX,
                                        "--mode", "lockstep"))
    finally:
        fly_all(flights, FLIGHT_TIMEOUT_S)
    return {f.name: f for f in flights}


@pytest.mark.parametrize("controller", LOCKSTEP_CONTROLLERS)
def test_lockstep_helix_flight(lockstep_flights, controller):
    flight = lockstep_flights[controller]
    assert_landed_summary(flight)
    truth, steps = logs(flight)

    # tracking: vehicle truth against the reference the controller flew
    m = metrics.compute(controller, "trq", truth, steps, None)
    print(f"{controller}: truth position RMSE {m.rmse_pos_m:.4f} m "
          f"(max {m.max_pos_err_m:.4f} m), yaw RMSE {m.rmse_yaw_deg:.3f} deg")
    assert not m.crashed
    assert m.rmse_pos_m <= RMSE_LIMIT_M, m
    phases = set(steps["phase"])
    assert {"takeoff", "hold", "helix", "land"} <= phases, phases
    assert m.flight_s > 25.0, m             # the whole plan was flown (~31.6 s)

    # the log: strictly increasing stamps one control period apart, finite commands in range
    stamps = steps["stamp_us"].astype(np.int64)
    # (stamp 0 is answered with idle while the ARM waits for its ACK: the first step follows)
    assert len(stamps) > 2500 and np.all(np.diff(stamps) > 0) and stamps[0] <= 10_000
    assert np.all(np.diff(stamps) == 10_000), "lockstep must answer every stamp, in order"
    thr = np.column_stack([steps[f"cmd_throttle{i}_pct"] for i in range(1, 5)])
    tilt = np.column_stack([steps[f"cmd_tilt{i}_rad"] for i in range(1, 5)])
    assert np.all(np.isfinite(thr)) and np.all(np.isfinite(tilt)), "nan in the commands"
    assert thr.min() >= 0.0 and thr.max() <= 100.0, (thr.min(), thr.max())
    assert np.abs(tilt).max() <= TILT_LIMIT_RAD + 1e-9, np.abs(tilt).max()
    assert np.all(steps["source"] == "nmpc"), "a solver fallback in a nominal flight"
    if controller == "trq_nmpc_eso":
        assert np.ptp(tilt) > 1e-3, "the tilt-rotor never tilted"

    # end to end: the vehicle applied exactly the command answering each stamp (held for one
    # period, so the vehicle's row at stamp + 10 ms carries it; float32 on the wire)
    row = {int(t): i for i, t in enumerate(truth["t_us"])}
    k = np.array([i for i, s in enumerate(stamps) if int(s) + 10_000 in row])
    r = np.array([row[int(stamps[i]) + 10_000] for i in k])
    assert len(k) > 0.95 * len(stamps)
    applied_thr = np.column_stack([truth[f"cmd_throttle{i}_pct"][r] for i in range(1, 5)])
    applied_tilt = np.column_stack([truth[f"cmd_tilt{i}_rad"][r] for i in range(1, 5)])
    assert np.abs(applied_thr - thr[k]).max() < 1e-3
    assert np.abs(applied_tilt - tilt[k]).max() < 1e-5


def test_the_log_header_says_what_solved_the_nmpc(lockstep_flights):
    flight = lockstep_flights["trq_nmpc_eso"]
    assert_landed_summary(flight)
    meta, _ = metrics.read_csv(flight.out / "controller" / "controller.csv")
    assert meta["solver"].startswith("rti gauss_newton, hpipm direct "), meta
    assert "libhpipm " in meta["solver"]


# --- (2) the command line ----------------------------------------------------------------------

def run_cli(tmp_path: Path, *args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "trq_offboard", *args], cwd=tmp_path, env=ENV,
                          capture_output=True, text=True, timeout=timeout_s)


def test_no_vehicle_exits_1_naming_the_connection(tmp_path, daemons):
    t0 = time.monotonic()
    ctl = daemons.controller("--connect-timeout", "1", log_dir=tmp_path / "logs",
                             split_stderr=True)
    assert ctl.wait(60.0) == 1, ctl.why()
    stderr = ctl.err()
    assert f"udpin:127.0.0.1:{ctl.port}" in stderr and "heartbeat" in stderr, stderr
    assert "Traceback" not in stderr
    assert time.monotonic() - t0 < 30.0


def test_bad_controller_file_exits_2_naming_file_and_key(tmp_path):
    good = write_overlay(tmp_path, "trq_nmpc", HOVER)        # valid (checked), then spoilt
    bad = tmp_path / "bad.yaml"
    bad.write_text(good.read_text() + "horizon_stepz: 20\n")
    r = run_cli(tmp_path, "--controller", str(bad), "--no-log")
    assert r.returncode == 2, r.stderr
    assert str(bad) in r.stderr and "horizon_stepz" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_bad_connection_string_exits_2(tmp_path):
    r = run_cli(tmp_path, "--connect", "tcp:127.0.0.1:99999", "--no-log")
    assert r.returncode == 2 and "tcp:127.0.0.1:99999" in r.stderr, r.stderr
    assert "serial://DEVICE[:BAUD]" in r.stderr and "udpin:HOST:PORT" in r.stderr, r.stderr


def test_a_serial_device_that_is_not_there_exits_1_naming_it(tmp_path):
    r = run_cli(tmp_path, "--connect", "/dev/nonexistent-uart,921600", "--no-log")
    assert r.returncode == 1 and "cannot open" in r.stderr, r.stderr
    assert "/dev/nonexistent-uart" in r.stderr, r.stderr


def test_help_lists_every_option(tmp_path):
    from trq_offboard.daemon import build_parser

    r = run_cli(tmp_path, "--help", timeout_s=30.0)
    assert r.returncode == 0
    options = [s for a in build_parser()._actions for s in a.option_strings if s.startswith("--")]
    assert {"--controller", "--connect", "--reference", "--log-dir", "--no-log",
            "--connect-timeout", "--verbose"} <= set(options)
    missing = [o for o in options if o not in r.stdout]
    assert not missing, missing


# --- (3) real time -----------------------------------------------------------------------------

@pytest.mark.parametrize("controller", ["trq_nmpc", "trq_nmpc_eso"])
def test_realtime_hover_flight(tmp_path, daemons, controller):
    """The same controller program against the wall-clock vehicle (no lockstep): it connects,
    arms, hovers, lands and disarms without crashing. This takes the flight's wall time (~12 s)."""
    # in real time a command acts about one solve after its state was measured: the observer
    # is told so (in lockstep the vehicle waits and the delay is zero)
    flight = start_flight(daemons, tmp_path / "realtime", controller, HOVER, "--mode", "realtime",
                          controller_args=("--applied-delay-s", "0.005"))
    fly_all([flight], 60.0)
    assert_landed_summary(flight)
    truth, steps = logs(flight)
    assert not np.any(truth["crashed"] > 0.5)
    stamps = steps["stamp_us"].astype(np.int64)
    assert np.all(np.diff(stamps) > 0)
    # in real time the vehicle does not wait: most periods are answered, a few may be skipped
    assert len(stamps) > 0.6 * (stamps[-1] - stamps[0]) / 10_000
    assert np.all(np.isfinite(np.column_stack(
        [steps[f"cmd_throttle{i}_pct"] for i in range(1, 5)])))
    # it did take off and hover: at least 0.8 m up at some point (truth, NED down negative),
    # never further than 0.3 m from the reference
    assert truth["pos_d_m"].min() < -0.8
    m = metrics.compute(controller, "trq", truth, steps, None)
    print(f"{controller} real time: truth position RMSE {m.rmse_pos_m:.4f} m "
          f"(max {m.max_pos_err_m:.4f} m), yaw RMSE {m.rmse_yaw_deg:.3f} deg")
    assert m.max_pos_err_m < 0.3, m
