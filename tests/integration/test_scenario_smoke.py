"""End to end over UDP: trq-scenario flies params/scenarios/smoke.yaml (the vehicle and
the controller as separate processes, in lockstep) and writes metrics, report, figures and logs
that the rest of the toolchain (and pymavlink) can read. About 15-30 s."""

from __future__ import annotations

import json
import math
import os
import subprocess

import pytest
from conftest import PARAMS, cli

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

ENV = dict(os.environ)
FIGURES = ("trajectories.png", "errors.png", "observer.png", "effectiveness.png")


def run_scenario(*args: str, cwd, timeout: float):
    return subprocess.run([*cli("trq-scenario"), *args],
                          cwd=cwd, env=ENV, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("scenario")
    out = tmp / "smoke"
    r = run_scenario(str(PARAMS / "scenarios" / "smoke.yaml"), "--out", str(out), cwd=tmp,
                     timeout=240)
    return r, out


def test_smoke_run_succeeds(smoke):
    r, out = smoke
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "TARGET MISSED" not in r.stdout


def test_smoke_metrics(smoke):
    _, out = smoke
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["scenario"] == "smoke"
    (run,) = doc["runs"]
    assert run["controller"] == "trq_nmpc_eso" and run["vehicle"] == "trq"
    assert run["status"] == "done" and run["crashed"] is False
    assert math.isfinite(run["rmse_pos_m"]) and 0.0 < run["rmse_pos_m"] < 0.1
    assert run["max_pos_err_m"] >= run["rmse_pos_m"]
    assert run["rmse_pos_after_fault_m"] is not None and run["recovery_s"] is not None
    assert run["flight_s"] > 4.0                         # past the fault at 4 s
    for key in ("solve_ms_p50", "solve_ms_p99"):
        assert isinstance(run[key], float) and run[key] > 0.0
    assert run["solve_ms_p99"] >= run["solve_ms_p50"]


def test_smoke_report_and_figures(smoke):
    _, out = smoke
    report = (out / "report.md").read_text()
    assert "# Scenario `smoke`" in report
    assert "| controller | vehicle | crashed |" in report and "| trq_nmpc_eso | trq |" in report
    # the period's parts and what solved the NMPC, from the controller's log
    assert "## The controller's period" in report
    assert "- `trq_nmpc_eso`: rti gauss_newton, hpipm direct " in report and "libhpipm " in report
    for name in FIGURES:
        assert f"({name})" in report
        path = out / name
        assert path.exists() and path.stat().st_size > 1000
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_smoke_logs(smoke):
    from pymavlink import mavutil

    _, out = smoke
    run_dir = out / "trq_nmpc_eso"
    for name in ("flight.csv", "vehicle.tlog", "controller.csv", "offboard.tlog"):
        assert (run_dir / name).stat().st_size > 0, name
    counts, spans = {}, {}
    for name in ("vehicle.tlog", "offboard.tlog"):
        log = mavutil.mavlink_connection(str(run_dir / name))
        try:
            seen: dict[str, int] = {}
            odometry = []                      # (the log's stamp s, the vehicle's time s)
            while (msg := log.recv_match()) is not None:
                seen[msg.get_type()] = seen.get(msg.get_type(), 0) + 1
                if msg.get_type() == "ODOMETRY":
                    odometry.append((msg._timestamp, msg.time_usec / 1e6))
        finally:
            log.close()
        counts[name] = seen
        spans[name] = (odometry[-1][0] - odometry[0][0], odometry[-1][1] - odometry[0][1])
    # lockstep: both logs on the flight's own timeline (PROTOCOL.md, Logs), not the run's
    for name, (logged_s, flown_s) in spans.items():
        assert abs(logged_s - flown_s) < 0.05, (name, logged_s, flown_s)
    for seen in counts.values():
        assert seen.get("ODOMETRY", 0) > 100, seen
        assert seen.get("SET_ACTUATOR_CONTROL_TARGET", 0) > 100, seen
        assert seen.get("BAD_DATA", 0) == 0, seen


def test_scenario_with_unknown_key_exits_2(tmp_path):
    bad = tmp_path / "typo.yaml"
    text = (PARAMS / "scenarios" / "smoke.yaml").read_text()
    bad.write_text(text.replace("recovery_threshold_m:", "recovery_treshold_m:"))
    # the fault script is named relative to the scenario file: point it at the real one
    bad.write_text(bad.read_text().replace("../faults/motor1_smoke.yaml",
                                           str(PARAMS / "faults" / "motor1_smoke.yaml")))
    r = run_scenario(str(bad), "--out", str(tmp_path / "out"), cwd=tmp_path, timeout=60)
    assert r.returncode == 2
    # the misspelt key leaves the real one missing, which is reported first
    assert "typo.yaml" in r.stderr and "recovery_threshold_m" in r.stderr
    assert not (tmp_path / "out").exists()               # nothing was flown


def test_scenario_with_extra_key_exits_2(tmp_path):
    bad = tmp_path / "extra.yaml"
    bad.write_text((PARAMS / "scenarios" / "smoke.yaml").read_text()
                   .replace("../faults/motor1_smoke.yaml",
                            str(PARAMS / "faults" / "motor1_smoke.yaml"))
                   + "colour: blue\n")
    r = run_scenario(str(bad), "--out", str(tmp_path / "out"), cwd=tmp_path, timeout=60)
    assert r.returncode == 2
    assert "extra.yaml" in r.stderr and "unknown key 'colour'" in r.stderr


def test_a_flight_under_mocap_replays_bit_for_bit_over_udp(smoke, tmp_path):
    """The smoke scenario flies mocap: the vehicle refuses arming until its estimator is ready
    and the controller retries in vehicle time. Flown again beside another flight (so that the
    wall clock runs differently), the vehicle's log is the same row for row through the
    flight: the arming, the first command and everything after, to the disarm."""
    _, first = smoke
    procs = [subprocess.Popen([*cli("trq-scenario"), str(PARAMS / "scenarios" / "smoke.yaml"),
                               "--out", str(tmp_path / f"again{i}"), "--no-figures"],
                              cwd=tmp_path, env=ENV, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL) for i in range(2)]
    for p in procs:
        assert p.wait(timeout=240) == 0

    def rows(folder):        # the log without its header (which names its own folder)
        text = (folder / "trq_nmpc_eso" / "flight.csv").read_text().splitlines()
        return [r for r in text if not r.startswith("#")]
    reference = rows(first)
    armed = reference[0].split(",").index("armed")
    for i in range(2):
        again = rows(tmp_path / f"again{i}")
        # the same up to the shorter log's end: the vehicle runs on after the controller has
        # gone (until the runner stops it, in wall time), and that tail may be longer or not
        n = min(len(again), len(reference))
        assert again[:n] == reference[:n]
        flags = [r.split(",")[armed] for r in reference[1:n]]
        assert "1" in flags and flags[-1] == "0"          # armed, flown, and disarmed within
