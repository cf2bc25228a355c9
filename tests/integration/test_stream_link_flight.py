"""The offboard link on a byte stream, end to end: the same lockstep flight (a hover with a
motor fault) between `trq-sil-vehicle` and `trq-offboard` over UDP, over a pty pair at 921600
baud (`--offboard-serial A`, `--connect serial://B:921600`) and over the vehicle's TCP server
gives the vehicle the same flight log, bit for bit, over every controller step, signed or not;
garbage sprayed onto the serial line while the controller flies costs time (resends), not the
flight; over TCP a controller killed mid-flight leaves the vehicle to its failsafe, and a
restarted one connects again and takes over."""

from __future__ import annotations

import dataclasses
import signal
import socket
import threading
from pathlib import Path

import pytest
import yaml
from conftest import ROOT
from trq_params import builtin

from sil_vehicle.config import SerialPort, load_sim
from sil_vehicle.daemon import serial_budget
from trq_lab import metrics
from trq_lab.ptypair import PtyPair

pytestmark = pytest.mark.slow      # starts daemons and flies: the full run only

FLIGHT_S = 180


def _overlay(out: Path) -> Path:
    path = out / "controller.yaml"
    path.write_text(yaml.safe_dump({
        "extends": str(ROOT / "params/controller/trq_nmpc_eso.yaml"),
        "vehicle": str(ROOT / "params/vehicle/trq.yaml"),
        "observer": {"file": str(ROOT / "params/controller/eso.yaml")},
        "reference": {"kind": "hover", "altitude_m": 1.0, "hold_s": 1.0, "duration_s": 2.5,
                      "ramp_s": 0.5}}))
    return path


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fly(daemons, out: Path, link: str, pair: PtyPair | None = None,
        key_file: Path | None = None) -> tuple[list[str], str]:
    """One flight; (the vehicle's flight.csv data rows up to the controller's last step, the
    vehicle's output)."""
    out.mkdir(parents=True)
    vehicle_args = ["--seed", "3", "--faults", "motor1_smoke", "--wind-speed", "4"]
    controller_args = ["--controller", str(_overlay(out))]
    if key_file is not None:
        vehicle_args += ["--signing-key-file", str(key_file)]
        controller_args += ["--signing-key-file", str(key_file)]
    if link == "udp":
        ctl = daemons.controller(*controller_args, log_dir=out / "ctl", name=f"ctl-{link}")
        veh = daemons.vehicle(*vehicle_args, log_dir=out / "veh", offboard_target=ctl.port,
                              name=f"veh-{link}")
    else:
        if link == "serial":
            vlink, connect = ["--offboard-serial", pair.a], f"serial://{pair.b}:921600"
        else:
            port = _free_tcp_port()
            vlink, connect = ["--offboard-tcp", f"127.0.0.1:{port}"], f"tcp:127.0.0.1:{port}"
        veh = daemons.vehicle(*vehicle_args, *vlink, log_dir=out / "veh", name=f"veh-{link}")
        ctl = daemons.controller(*controller_args, "--connect", connect, log_dir=out / "ctl",
                                 name=f"ctl-{link}")
    try:
        assert ctl.wait(FLIGHT_S) == 0, ctl.why()
    finally:
        veh.send_signal(signal.SIGINT)
        veh.wait(30)
    assert "landed" in ctl.text() and "disarmed" in ctl.text(), ctl.why()
    _, steps = metrics.read_csv(out / "ctl" / "controller.csv")
    last = int(steps["stamp_us"][-1])
    rows = [ln for ln in open(out / "veh" / "flight.csv") if not ln.startswith("#")][1:]
    return [ln for ln in rows if int(ln.split(",", 1)[0]) <= last], veh.text()


@pytest.fixture(scope="module")
def udp_flight(tmp_path_factory, module_daemons):
    return fly(module_daemons, tmp_path_factory.mktemp("udp") / "run", "udp")


def test_a_flight_over_a_pty_pair_is_the_udp_flight_bit_for_bit(udp_flight, daemons, tmp_path):
    with PtyPair() as pair:
        rows, vtext = fly(daemons, tmp_path / "serial", "serial", pair)
        assert pair.copied[pair.a] > 100_000 and pair.copied[pair.b] > 10_000
    assert len(rows) > 300 and rows == udp_flight[0]
    assert "offboard link serial" in vtext and "baud:" in vtext and "of 92160" in vtext, vtext
    assert "0 malformed" in vtext, vtext


def test_a_signed_flight_over_a_pty_pair_is_the_udp_flight_bit_for_bit(udp_flight, daemons,
                                                                       tmp_path):
    key_file = tmp_path / "key.hex"
    key_file.write_text("3c" * 32 + "\n")
    with PtyPair() as pair:
        rows, vtext = fly(daemons, tmp_path / "signed", "serial", pair, key_file)
    assert rows == udp_flight[0]
    assert "0 unauthenticated" in vtext, vtext
    # the budget printed counts the signature of every frame
    link = load_sim(builtin("sim", "default")).link("offboard")
    signed, _ = serial_budget(dataclasses.replace(link, serial=SerialPort(pair.a, 921600)), True)
    unsigned, _ = serial_budget(dataclasses.replace(link, serial=SerialPort(pair.a, 921600)),
                                False)
    assert f"baud: {signed} B/s needed of 92160" in vtext and signed > unsigned, vtext


def test_a_flight_over_tcp_is_the_udp_flight_bit_for_bit(udp_flight, daemons, tmp_path):
    rows, vtext = fly(daemons, tmp_path / "tcp", "tcp")
    assert len(rows) > 300 and rows == udp_flight[0]
    assert "0 malformed" in vtext, vtext


def test_garbage_on_the_serial_line_costs_time_not_the_flight(udp_flight, daemons, tmp_path):
    """Garbage sprayed into both ends while the controller flies (after its ARM and mode
    commands, before it lands and disarms: a command or ACK lost to the noise would be retried
    a wall second later, and the flight would go on from a later instant). What it cuts of the
    telemetry and the targets is resent (PROTOCOL.md): the same flight, later."""
    from test_failsafe import controller_time

    stop = threading.Event()
    sprayed = [0]
    csv = tmp_path / "noisy" / "ctl" / "controller.ulg"

    def spray(pair: PtyPair) -> None:
        # bursts that look like MAVLink (magics, plausible headers) into both ends
        junk = bytes([0xFD, 0x09, 0x00, 0x00, 0x07, 0x01, 0x01, 0x00, 0x00, 0x00, 0x55]) * 3
        while not stop.wait(0.01):   # the flight outruns a slower spray
            t = controller_time(csv)
            if 1.5 <= t <= 4.0:
                for end in (pair.a, pair.b):
                    pair.inject(end, b"\x00noise" + junk)
                    sprayed[0] += 1

    with PtyPair() as pair:
        t = threading.Thread(target=spray, args=(pair,))
        t.start()
        try:
            rows, vtext = fly(daemons, tmp_path / "noisy", "serial", pair)
        finally:
            stop.set()
            t.join()
    assert sprayed[0] > 20 and rows == udp_flight[0]
    summary = vtext.strip().splitlines()[-1]
    malformed = int(summary.split("unauthenticated, ")[1].split(" malformed")[0])
    assert malformed > 10, summary


def test_over_tcp_a_killed_controller_leaves_the_failsafe_and_a_new_one_takes_over(daemons,
                                                                                   tmp_path):
    from conftest import wait_until
    from test_failsafe import AUTO_LAND, controller_time

    from trq_lab.gcs.client import MavClient

    port = _free_tcp_port()
    overlay = tmp_path / "controller.yaml"
    overlay.write_text(yaml.safe_dump({
        "extends": str(ROOT / "params/controller/trq_nmpc_eso.yaml"),
        "vehicle": str(ROOT / "params/vehicle/trq.yaml"),
        "observer": {"file": str(ROOT / "params/controller/eso.yaml")},
        "reference": {"kind": "hover", "altitude_m": 1.5, "climb_speed_m_s": 0.8,
                      "hold_s": 1.0, "duration_s": 3.0, "ramp_s": 0.5}}))
    veh = daemons.vehicle("--wind-speed", "4", "--offboard-tcp", f"127.0.0.1:{port}",
                          log_dir=tmp_path / "veh")
    controller = ("--controller", str(overlay), "--connect", f"tcpout://127.0.0.1:{port}")
    ctl_a = daemons.controller(*controller, log_dir=tmp_path / "a", name="ctl_a")
    wait_until(lambda: controller_time(tmp_path / "a" / "controller.ulg") >= 3.0, 90,
               "the first controller to fly", lambda: ctl_a.why() + veh.why())
    ctl_a.kill()                                        # SIGKILL: its connection just ends
    with MavClient(f"udpout:127.0.0.1:{veh.gcs_port}") as gcs:
        gcs.hello(10.0)
        gcs.wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1
                 and m.custom_mode == AUTO_LAND, 15.0, "the vehicle's failsafe (AUTO.LAND)")
    ctl_b = daemons.controller(*controller, log_dir=tmp_path / "b", name="ctl_b")
    assert ctl_b.wait(150) == 0, ctl_b.why()
    assert "took over in flight" in ctl_b.text() and "disarmed" in ctl_b.text(), ctl_b.why()
    veh.send_signal(signal.SIGINT)
    veh.wait(30)
    assert "no crash" in veh.text(), veh.why()
    _, truth = metrics.read_csv(tmp_path / "veh" / "flight.csv")
    assert not truth["crashed"].any() and truth["armed"][-1] == 0
