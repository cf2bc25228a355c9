"""The vehicle daemon over real UDP: `python -m sil_vehicle` as a subprocess on free ports, with
pymavlink clients playing the ground station and the offboard controller.

(1) real time: telemetry streams, the parameter list, fault injection seen in SERVO_OUTPUT_RAW,
    unsupported commands, garbage that does not kill it;
(2) lockstep: a scripted flight flown twice gives byte-identical flight logs; another seed with
    gusts on gives another flight.
The vehicle is started by the `daemons` fixture (stopped at teardown); every wait has a
wall-clock deadline.
"""

from __future__ import annotations

import math
import os
import socket
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT

from sil_vehicle.config import load_vehicle

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

STARTUP_S = 15.0            # first datagram (a cold interpreter imports numpy and pymavlink)


class Client:
    """A UDP socket speaking MAVLink 2 as system 255, and its parser."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.rx = mavlink.MAVLink(None)
        self.last: dict[str, mavlink.MAVLink_message] = {}

    def pack(self, *msgs) -> bytes:
        return b"".join(bytes(m.pack(self.mav)) for m in msgs)

    def send(self, port: int, *msgs) -> None:
        self.sock.sendto(self.pack(*msgs), ("127.0.0.1", port))

    def poll(self, timeout_s: float) -> list[mavlink.MAVLink_message]:
        self.sock.settimeout(max(timeout_s, 1e-3))
        try:
            data, _ = self.sock.recvfrom(65535)
        except socket.timeout:
            return []
        msgs = []
        for m in self.rx.parse_buffer(data) or []:
            if m.get_srcSystem() == 1:
                msgs.append(m)
                self.last[m.get_type()] = m
        return msgs

    def wait_for(self, predicate, timeout_s: float, what: str, on_idle=None):
        """Read until predicate(msg) holds; on_idle() is called between reads (e.g. to send)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if on_idle:
                on_idle()
            for m in self.poll(min(0.05, deadline - time.monotonic())):
                if predicate(m):
                    return m
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")

    def close(self) -> None:
        self.sock.close()


def command(cmd, p1=0.0, p2=0.0, p3=0.0, p4=0.0):
    return mavlink.MAVLink_command_long_message(1, 1, cmd, 0, p1, p2, p3, p4, 0, 0, 0)


def target(stamp_us, throttle, tilt=(0.0,) * 4):
    return mavlink.MAVLink_set_actuator_control_target_message(stamp_us, 0, 1, 1,
                                                               list(throttle) + list(tilt))


def param_set(name, value):
    return mavlink.MAVLink_param_set_message(1, 1, name.encode(), value,
                                             mavlink.MAV_PARAM_TYPE_REAL32)


def is_ack(cmd):
    return lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd


# --- (1) real time ------------------------------------------------------------------------------

def test_realtime_daemon(tmp_path, daemons):
    gcs, off = Client(), Client()
    log_dir = tmp_path / "rt"
    proc = daemons.vehicle("--mode", "realtime", log_dir=log_dir, gcs_target=gcs.port,
                           offboard_target=off.port)
    gcs_port, off_port = proc.gcs_port, proc.offboard_port
    try:
        # telemetry: the first datagram once the process is up, then every gcs stream in 3 s
        gcs.wait_for(lambda m: True, STARTUP_S, "any telemetry")
        wanted = {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT",
                  "SERVO_OUTPUT_RAW"}
        seen: set[str] = set()
        gcs.wait_for(lambda m: seen.add(m.get_type()) or wanted <= seen, 3.0, f"{wanted}")
        hb = gcs.last["HEARTBEAT"]
        assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.get_srcComponent() == 1
        assert hb.system_status == mavlink.MAV_STATE_STANDBY
        assert abs(gcs.last["GLOBAL_POSITION_INT"].lat - 515246000) < 100     # home, degE7

        # parameters: every one, each index once, the count matching
        gcs.send(gcs_port, mavlink.MAVLink_param_request_list_message(1, 1))
        values: dict[int, mavlink.MAVLink_message] = {}

        def collect(m):
            if m.get_type() == "PARAM_VALUE":
                values[m.param_index] = m
                return len(values) == m.param_count
            return False
        last = gcs.wait_for(collect, 3.0, "the whole parameter list")
        assert last.param_count == 34 and sorted(values) == list(range(34))
        assert {v.param_id for v in values.values()} >= {"SIM_WIND_SPD", "SIM_MOT1_OFF"}

        # motor 1 off, armed, fed 60 % on the offboard link (on the ground: 4 x 3.27 N < m g)
        gcs.send(gcs_port, command(mavlink.MAV_CMD_INJECT_FAILURE,
                                   mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, 1))
        ack = gcs.wait_for(is_ack(mavlink.MAV_CMD_INJECT_FAILURE), 3.0, "INJECT_FAILURE ack")
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        gcs.send(gcs_port, command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
        ack = gcs.wait_for(is_ack(mavlink.MAV_CMD_COMPONENT_ARM_DISARM), 3.0, "arm ack")
        assert ack.result == mavlink.MAV_RESULT_ACCEPTED
        next_send = [0.0]

        def feed():
            if time.monotonic() >= next_send[0]:
                off.send(off_port, target(0, [0.6] * 4))
                next_send[0] = time.monotonic() + 0.02

        raw = gcs.wait_for(lambda m: m.get_type() == "SERVO_OUTPUT_RAW" and m.servo2_raw == 1600
                           and m.servo3_raw == 1600 and m.servo4_raw == 1600, 5.0,
                           "motors 2-4 at 60 %", on_idle=feed)
        assert raw.servo1_raw == 1000
        hb = gcs.wait_for(lambda m: m.get_type() == "HEARTBEAT", 2.5, "a heartbeat once armed")
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert hb.system_status == mavlink.MAV_STATE_ACTIVE

        # an unknown command
        gcs.send(gcs_port, command(mavlink.MAV_CMD_NAV_TAKEOFF))
        ack = gcs.wait_for(is_ack(mavlink.MAV_CMD_NAV_TAKEOFF), 3.0, "takeoff ack")
        assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED

        # garbage on both links: it keeps talking, and counts it
        junk = [b"", b"\x00" * 10, b"\xfd" * 300, b"\xfe\x05", os.urandom(1000),
                gcs.pack(command(mavlink.MAV_CMD_NAV_TAKEOFF))[:-3]]
        for data in junk:
            gcs.sock.sendto(data, ("127.0.0.1", gcs_port))
            off.sock.sendto(data, ("127.0.0.1", off_port))
        t_before = gcs.last["ATTITUDE"].time_boot_ms
        status = gcs.wait_for(lambda m: m.get_type() == "SYS_STATUS" and m.errors_count1 > 0,
                              3.0, "SYS_STATUS counting bad frames")
        assert status.errors_comm > 0
        gcs.wait_for(lambda m: m.get_type() == "ATTITUDE" and m.time_boot_ms > t_before + 500,
                     3.0, "telemetry after the garbage")
        assert proc.alive(), proc.why()
    finally:
        proc.stop()
        gcs.close()
        off.close()
    assert (log_dir / "flight.csv").stat().st_size > 0


# --- (2) lockstep replay ------------------------------------------------------------------------

DURATION_S = 3.0
FAULT_AT_US = 2_800_000


def profile(t_us: int, trim_pct: float) -> tuple[list[float], list[float]]:
    """Deterministic open-loop throttle and tilt, normalised (0..1, -1..1)."""
    t = t_us * 1e-6
    if t < 0.3:
        zeta = 0.0
    elif t < 1.3:
        zeta = trim_pct + 5.0
    else:
        zeta = trim_pct + 0.5 * math.sin(3.0 * t)
    tilt = 0.05 * math.sin(2.0 * t)    # all four alike: a yaw moment, no roll or pitch
    return [zeta / 100.0] * 4, [tilt] * 4


def fly_lockstep(daemons, tmp_path: Path, name: str, seed: int) -> Path:
    trim = load_vehicle(ROOT / "params" / "vehicle" / "trq.yaml").hover_throttle_pct
    off, gcs = Client(), Client()
    log_dir = tmp_path / name
    proc = daemons.vehicle("--mode", "lockstep", "--seed", str(seed),
                           "--duration", str(DURATION_S), log_dir=log_dir, name=name,
                           gcs_target=gcs.port, offboard_target=off.port)
    off_port = proc.offboard_port
    answered: set[int] = set()
    try:
        deadline = time.monotonic() + STARTUP_S + 15.0
        while proc.alive():
            assert time.monotonic() < deadline, "lockstep flight did not finish in time\n" \
                + proc.why()
            for m in off.poll(0.1):
                if m.get_type() != "ODOMETRY" or m.time_usec in answered:
                    continue        # a resend of a stamp already answered: answer it once only
                t = m.time_usec
                answered.add(t)
                msgs = []
                if t == 0:          # before the first answer: arm, gusts and a mean wind
                    msgs += [command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0),
                             param_set("SIM_WIND_SPD", 4.0), param_set("SIM_GUST_EN", 1.0),
                             param_set("SIM_GUST_SIG", 2.0)]
                if t == FAULT_AT_US:
                    msgs += [param_set("SIM_MOT2_EFF", 0.95)]
                throttle, tilt = profile(t, trim)
                msgs.append(target(t, throttle, tilt))
                off.send(off_port, *msgs)            # one datagram: applied in this order
        assert proc.wait(5) == 0, proc.why()
    finally:
        proc.stop()
        off.close()
        gcs.close()
    assert len(answered) >= DURATION_S * 50
    return log_dir / "flight.csv"


def rows(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if not line.startswith("#")]


def test_lockstep_replay_is_bit_identical(tmp_path, daemons):
    a = fly_lockstep(daemons, tmp_path, "a", seed=11)
    b = fly_lockstep(daemons, tmp_path, "b", seed=11)
    c = fly_lockstep(daemons, tmp_path, "c", seed=12)
    assert a.read_bytes() == b.read_bytes()

    ra = rows(a)
    header, data = ra[0].split(","), [list(map(float, r.split(","))) for r in ra[1:]]
    col = {name: i for i, name in enumerate(header)}
    assert len(data) == DURATION_S * 100                         # 100 Hz log
    t = [r[col["t_us"]] for r in data]
    assert t[0] == 10_000 and t[-1] == DURATION_S * 1e6
    last = data[-1]
    assert last[col["armed"]] == 1.0 and last[col["crashed"]] == 0.0
    assert min(r[col["pos_d_m"]] for r in data) < -0.3          # it flew
    # the mid-flight fault took effect on the tick after the stamp it came with
    factor = {int(r[col["t_us"]]): r[col["motor2_factor"]] for r in data}
    assert factor[FAULT_AT_US] == 1.0
    assert factor[FAULT_AT_US + 10_000] == pytest.approx(0.95, abs=1e-7)
    assert factor[FAULT_AT_US - 10_000] == 1.0 and last[col["motor1_factor"]] == 1.0
    assert any(r[col["wind_e_m_s"]] != 0.0 for r in data)        # gusts were on

    # another seed: other gusts, so another flight (not just another header)
    rc = rows(c)
    assert rc[0] == ra[0] and len(rc) == len(ra)
    assert rc[1:] != ra[1:]
    wind_a = [r.split(",")[col["wind_n_m_s"]] for r in ra[1:]]
    wind_c = [r.split(",")[col["wind_n_m_s"]] for r in rc[1:]]
    assert wind_a != wind_c
