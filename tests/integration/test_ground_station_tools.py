"""The tools against a real vehicle over UDP: `python -m sil_vehicle --mode realtime` as a
subprocess on free ports (one for the module), driven by trq-inject-fault and watched by
trq-monitor, both run as subprocesses the way a user runs them, and checked with
trq_lab.gcs.client.MavClient. Plus trq-envelope's analysis, called directly.

Every subprocess has a wall-clock timeout; the vehicle is module_daemons', stopped at teardown.
"""

from __future__ import annotations

import os
import re
import subprocess
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import PARAMS, cli, free_udp_port

from trq_lab.gcs.client import MavClient, NoAnswer

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

STARTUP_S = 15.0            # a cold interpreter imports numpy and pymavlink
TOOL_TIMEOUT_S = 30.0
ENV = dict(os.environ)


class Vehicle:
    def __init__(self, proc: subprocess.Popen, gcs_port: int, log_dir: Path) -> None:
        self.proc, self.gcs_port, self.log_dir = proc, gcs_port, log_dir
        self.connect = f"udpout:127.0.0.1:{gcs_port}"

    def client(self) -> MavClient:
        return MavClient(self.connect)


@pytest.fixture(scope="module")
def vehicle(module_daemons):
    log_dir = module_daemons.tmp / "log"
    proc = module_daemons.vehicle("--mode", "realtime", log_dir=log_dir)
    deadline = time.monotonic() + STARTUP_S
    with MavClient(f"udpout:127.0.0.1:{proc.gcs_port}") as client:
        while True:          # the first hello may go out before the vehicle listens
            assert proc.alive(), proc.why()
            try:
                client.hello(1.0)
                break
            except NoAnswer:
                assert time.monotonic() < deadline, "the vehicle did not start in time\n" \
                    + proc.why()
    return Vehicle(proc.popen, proc.gcs_port, log_dir)


def run_tool(tool: str, *args: str, cwd: Path, timeout: float = TOOL_TIMEOUT_S):
    return subprocess.run([*cli(tool), *args], cwd=cwd, env=ENV,
                          capture_output=True, text=True, timeout=timeout)


def inject(vehicle: Vehicle, *args: str, cwd: Path):
    return run_tool("trq-inject-fault", "--connect", vehicle.connect, *args, cwd=cwd)


def params(vehicle: Vehicle) -> dict[str, float]:
    with vehicle.client() as client:
        client.hello(5.0)
        return client.params(timeout_s=5.0)


# --- inject_fault.py ----------------------------------------------------------------------------

def test_motor_off_is_acknowledged(vehicle, tmp_path):
    r = inject(vehicle, "motor", "1", "off", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "motor 1 off" in r.stdout and "acknowledged" in r.stdout
    assert params(vehicle)["SIM_MOT1_OFF"] == 1.0
    r = inject(vehicle, "motor", "1", "on", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert params(vehicle)["SIM_MOT1_OFF"] == 0.0


def test_servo_stuck_outside_the_range_is_denied(vehicle, tmp_path):
    r = inject(vehicle, "servo", "2", "stuck", "45", cwd=tmp_path)    # the servos reach +-30
    assert r.returncode == 1
    assert "FAILED" in r.stderr and "DENIED" in r.stderr
    assert params(vehicle)["SIM_SRV2_STK"] == 0.0                  # nothing changed


def test_bad_instance_is_a_usage_error(vehicle, tmp_path):
    r = inject(vehicle, "motor", "5", "off", cwd=tmp_path)
    assert r.returncode == 2
    assert "instance '5'" in r.stderr and "1..4" in r.stderr


def test_a_sensor_fault_under_truth_is_denied(vehicle, tmp_path):
    # the daemon flies the default sim file's `truth` profile: no sensor to fail
    r = inject(vehicle, "sensor", "mocap", "off", cwd=tmp_path)
    assert r.returncode == 1
    assert "FAILED" in r.stderr and "DENIED" in r.stderr
    r = inject(vehicle, "sensor", "mocap", "ok", cwd=tmp_path)     # healthy: nothing to clear
    assert r.returncode == 0, r.stderr


def test_wind_with_gusts(vehicle, tmp_path):
    r = inject(vehicle, "wind", "8", "90", "--gusts", "on", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "acknowledged" in r.stdout
    p = params(vehicle)
    assert (p["SIM_WIND_SPD"], p["SIM_WIND_DIR"], p["SIM_GUST_EN"]) == (8.0, 90.0, 1.0)
    # read one back on its own as well
    with vehicle.client() as client:
        client.hello(5.0)
        client.send(mavlink.MAVLink_param_request_read_message(1, 1, b"SIM_WIND_SPD", -1))
        reply = client.wait(lambda m: m.get_type() == "PARAM_VALUE"
                            and m.param_id == "SIM_WIND_SPD", 3.0, "PARAM_VALUE SIM_WIND_SPD")
        assert reply.param_value == 8.0


def test_script_tour(vehicle, tmp_path):
    r = inject(vehicle, "script", str(PARAMS / "faults" / "tour.yaml"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    played = [ln for ln in r.stdout.splitlines() if re.match(r"inject_fault: t=\d+\.\d+ s: ", ln)]
    assert len(played) == 7, r.stdout
    assert "all faults cleared" in played[-1]
    p = params(vehicle)
    assert p["SIM_WIND_SPD"] == 4.0 and p["SIM_WIND_DIR"] == 90.0     # the tour's wind stays
    for n in range(1, 5):                                             # cleared at the end
        assert p[f"SIM_MOT{n}_EFF"] == 1.0 and p[f"SIM_MOT{n}_OFF"] == 0.0
        assert p[f"SIM_SRV{n}_STK"] == 0.0


def test_bad_script_is_a_usage_error(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("events: [{at_s: 1, motor: 5, stopped: true}]\n")
    r = run_tool("trq-inject-fault", "--connect", "udpout:127.0.0.1:9", "script", str(bad),
                 cwd=tmp_path)
    assert r.returncode == 2
    assert "bad.yaml" in r.stderr and "events[0].motor" in r.stderr


def test_nobody_listening(tmp_path):
    port = free_udp_port()
    t0 = time.monotonic()
    r = run_tool("trq-inject-fault", "--connect", f"udpout:127.0.0.1:{port}", "--timeout", "1",
                 "motor", "1", "off", cwd=tmp_path)
    elapsed = time.monotonic() - t0
    assert r.returncode == 1
    assert "FAILED" in r.stderr and "HEARTBEAT" in r.stderr and "1 s" in r.stderr
    assert elapsed < 1.0 + 5.0           # the timeout, plus the interpreter's start-up


# --- monitor.py ---------------------------------------------------------------------------------

def test_monitor_once(vehicle, tmp_path):
    with vehicle.client() as client:
        client.hello(5.0)
        client.param_set("SIM_MOT3_EFF", 0.7)
        assert client.command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SYSTEM_SERVO,
                              mavlink.FAILURE_TYPE_STUCK, 4, 12.0) == mavlink.MAV_RESULT_ACCEPTED
    try:
        time.sleep(0.3)                   # the stuck servo slews there (300 deg/s)
        r = run_tool("trq-monitor", "--once", "--connect", vehicle.connect, cwd=tmp_path)
    finally:
        with vehicle.client() as client:
            client.hello(5.0)
            client.param_set("SIM_MOT3_EFF", 1.0)
            client.command(mavlink.MAV_CMD_INJECT_FAILURE, mavlink.FAILURE_UNIT_SYSTEM_SERVO,
                           mavlink.FAILURE_TYPE_OK, 4)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "\x1b[" not in out                               # --once: no escape codes
    assert "position" in out and "attitude" in out and "velocity" in out
    assert re.search(r"vehicle time\s+\d+\.\d\d s", out)
    assert "disarmed, on the ground" in out
    # the 8 outputs: disarmed, motors stopped; servo 4 held at 12 deg, the others centred
    head = next(ln for ln in out.splitlines() if ln.startswith("outputs"))
    assert head.split()[1:] == ["M1", "M2", "M3", "M4", "S1", "S2", "S3", "S4"]
    values = out.splitlines()[out.splitlines().index(head) + 1]
    numbers = [float(x) for x in re.findall(r"[-+]?\d+\.\d", values)]
    assert len(numbers) == 8, values
    assert numbers[:4] == [0.0] * 4
    assert numbers[4:7] == [0.0] * 3 and numbers[7] == pytest.approx(12.0, abs=0.1)
    assert "motor 3: effectiveness 0.7" in out and "servo 4: stuck at 12.0 deg" in out
    assert re.search(r"wind\s+\S+ m/s from", out)
    assert re.search(r"ATTITUDE \d+\.\d", out) and "datagrams/s" in out
    assert "drop rate" in out and "errors_comm" in out


def test_monitor_without_vehicle(tmp_path):
    t0 = time.monotonic()
    r = run_tool("trq-monitor", "--once", "--timeout", "1", "--connect",
                 f"udpout:127.0.0.1:{free_udp_port()}", cwd=tmp_path)
    assert r.returncode == 1
    assert "no heartbeat" in r.stderr
    assert time.monotonic() - t0 < 1.0 + 5.0


def test_monitor_conversions():
    from trq_lab.gcs import monitor
    assert monitor.throttle_pct(1000) == 0.0 and monitor.throttle_pct(1773) == 77.3
    assert monitor.tilt_deg(1500, 30.0) == 0.0 and monitor.tilt_deg(2000, 30.0) == 30.0
    assert monitor.tilt_deg(1250, 30.0) == -15.0


# --- envelope.py --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def envelope():
    from trq_lab.analysis import envelope
    return envelope


def test_envelope_healthy_trq_in_wind(envelope, trq):
    out = envelope.analyse(trq, [1.0] * 4, 8.0, 0.0)
    assert out["feasible"]
    assert max(abs(v) for v in out["residual"].values()) < 1e-3
    assert out["trim"]["throttle_pct"] == pytest.approx([77.0] * 4, abs=1.0)
    assert all(v is not None and v > 0 for v in out["margin"].values()), out["margin"]


def test_envelope_trq_with_half_a_motor(envelope, trq):
    out = envelope.analyse(trq, [0.5, 1.0, 1.0, 1.0], 0.0, 0.0)
    assert out["feasible"]
    thr = out["trim"]["throttle_pct"]
    assert thr[0] > thr[1]             # the weak motor works harder than its diagonal partner
    assert all(v <= 100.0 for v in thr)


def test_envelope_quad_with_half_a_motor_cannot_hold_yaw(envelope, quad):
    out = envelope.analyse(quad, [0.5, 1.0, 1.0, 1.0], 0.0, 0.0)
    assert not out["feasible"]
    assert abs(out["residual"]["Mz"]) > 1e-2     # the yaw torque is what it cannot balance
    assert out["trim"]["tilt_deg"] == [] and out["margin"] == {}
