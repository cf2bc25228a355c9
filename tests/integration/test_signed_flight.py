"""A signed flight over real UDP: both daemons hold the key; an attacker on the same ports sends
unsigned, wrongly signed and replayed commands and targets all flight long. The legitimate
signed stream flies on: the controller lands and disarms, nothing crashes, and the vehicle
counts what it refused."""

from __future__ import annotations

import signal
import socket
import threading
import time
from pathlib import Path

import pytest

import yaml
from pymavlink.dialects.v20 import common as mavlink

from conftest import ROOT

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

KEY_HEX = "5a" * 32
WRONG = bytes.fromhex("a5" * 32)


def _overlay(out: Path) -> Path:
    base = ROOT / "params/controller/trq_nmpc_eso.yaml"
    path = out / "controller.yaml"
    path.write_text(yaml.safe_dump({
        "extends": str(base), "vehicle": str(ROOT / "params/vehicle/trq.yaml"),
        "observer": {"file": str(ROOT / "params/controller/eso.yaml")},
        "reference": {"kind": "hover", "altitude_m": 1.0, "hold_s": 1.0, "duration_s": 3.0,
                      "ramp_s": 0.5}}))
    return path


def _tlog_frames(path: Path, msg_id: int) -> list[bytes]:
    """Signed frames of one message id from a .tlog (8-byte stamp + frame)."""
    frames, data = [], path.read_bytes() if path.exists() else b""
    i = 0
    while i + 18 <= len(data):
        frame_start = i + 8
        if data[frame_start] != 0xFD:
            break
        length = 10 + data[frame_start + 1] + 2 + (13 if data[frame_start + 2] & 1 else 0)
        frame = data[frame_start:frame_start + length]
        if (frame[7] | frame[8] << 8 | frame[9] << 16) == msg_id:
            frames.append(frame)
        i = frame_start + length
    return frames


def _attack(ports: list[int], tlog: Path, stop: threading.Event, sent: list[int]) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plain = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    forger = mavlink.MAVLink(None, srcSystem=255, srcComponent=191)
    forger.signing.secret_key, forger.signing.sign_outgoing = WRONG, True
    forger.signing.timestamp = 2 ** 47                       # far in the future
    disarm = mavlink.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)
    full = mavlink.MAVLink_set_actuator_control_target_message(0, 0, 1, 1, [1.0] * 4 + [1.0] * 4)
    while not stop.wait(0.02):
        frames = [disarm.pack(plain), full.pack(plain), disarm.pack(forger), full.pack(forger)]
        frames += _tlog_frames(tlog, mavlink.MAVLINK_MSG_ID_SET_ACTUATOR_CONTROL_TARGET)[-3:]
        for port in ports:
            for frame in frames:
                sock.sendto(bytes(frame), ("127.0.0.1", port))
                sent[0] += 1
    sock.close()


def test_signed_flight_survives_forged_and_replayed_traffic(tmp_path, daemons):
    key_file = tmp_path / "key.hex"
    key_file.write_text(KEY_HEX + "\n")
    ctl = daemons.controller("--controller", str(_overlay(tmp_path)),
                             "--signing-key-file", str(key_file), log_dir=tmp_path / "ctl")
    time.sleep(1.0)
    veh = daemons.vehicle("--signing-key-file", str(key_file), log_dir=tmp_path / "veh",
                          offboard_target=ctl.port)
    stop, sent = threading.Event(), [0]
    attacker = threading.Thread(target=_attack, args=(
        [veh.offboard_port, veh.gcs_port], tmp_path / "ctl" / "offboard.tlog", stop, sent))
    attacker.start()
    try:
        ctl.wait(180)
    finally:
        stop.set()
        attacker.join()
        veh.send_signal(signal.SIGINT)
        veh.wait(30)
    text, vtext = ctl.text(), veh.text()
    assert ctl.returncode == 0, text[-2000:]
    assert "landed" in text and "disarmed" in text
    assert "no crash" in vtext, vtext[-2000:]
    assert sent[0] > 100
    summary = vtext.strip().splitlines()[-1]
    refused = int(summary.split("(")[1].split(" unauthenticated")[0])
    assert refused > 100, summary
    assert KEY_HEX not in text + vtext                      # the key is never printed
