"""The controller's diagnosis on a ground station (issue 20), both daemons over UDP in lockstep
and a ground station listening where QGroundControl would: the controller's HEARTBEAT (system 1,
component 191) arrives through the vehicle; after motor 1 is set to half effectiveness (the
vehicle's SIM_MOT1_EFF, from a fault script at t = 3 s) a STATUSTEXT names motor 1 within a
second of flight time, MOT1_EFF reads about 0.5 and the other motors about 1."""

from __future__ import annotations

import socket
import threading

import pytest
from pymavlink.dialects.v20 import common as mavlink

from trq_lab.overlays import write_controller_overlay

pytestmark = pytest.mark.slow      # starts daemons and flies: the full run only

FAULT_AT_MS = 3000
HOVER = {"kind": "hover", "altitude_m": 1.0, "hold_s": 6.0, "duration_s": 8.0, "ramp_s": 0.5}


class GroundStation:
    """A UDP listener decoding everything the vehicle sends it, on a thread of its own."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.heard: list[tuple[int, object]] = []     # (vehicle time ms when heard, message)
        self._now_ms = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            for msg in mav.parse_buffer(data) or []:
                if msg.get_srcComponent() == 1 and hasattr(msg, "time_boot_ms"):
                    self._now_ms = msg.time_boot_ms          # the vehicle's clock
                self.heard.append((self._now_ms, msg))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def test_the_controllers_diagnosis_reaches_the_ground_station(tmp_path, daemons):
    script = tmp_path / "motor1_half.yaml"
    script.write_text(f"events:\n  - {{at_s: {FAULT_AT_MS / 1000}, motor: 1, "
                      "effectiveness: 0.5}\n")
    overlay = write_controller_overlay("trq_nmpc_eso", HOVER, tmp_path / "ctl")
    gcs = GroundStation()
    try:
        ctl = daemons.controller("--controller", str(overlay), "--no-log")
        ctl.wait_bound(timeout_s=60)
        daemons.vehicle("--mode", "lockstep", "--faults", str(script), "--no-log",
                        offboard_target=ctl.port, gcs_target=gcs.port)
        assert ctl.wait(180) == 0, ctl.why()
    finally:
        gcs.close()
    from_controller = [(t, m) for t, m in gcs.heard
                       if (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)]
    beats = [m for _, m in from_controller if m.get_type() == "HEARTBEAT"]
    assert beats and beats[0].type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    warnings = [(t, m.text) for t, m in from_controller if m.get_type() == "STATUSTEXT"
                and m.severity == mavlink.MAV_SEVERITY_WARNING]
    assert warnings and warnings[0][1].startswith("motor 1 at "), warnings
    assert FAULT_AT_MS <= warnings[0][0] <= FAULT_AT_MS + 1000, warnings
    assert all(text.startswith("motor 1 ") for _, text in warnings), warnings  # once, motor 1
    assert len(warnings) == 1, warnings
    late = {}        # from 1 s after the fault for 5 s, in the hover
    for _, m in from_controller:
        if m.get_type() == "NAMED_VALUE_FLOAT" and \
                FAULT_AT_MS + 1000 < m.time_boot_ms < FAULT_AT_MS + 6000:
            late.setdefault(m.name, []).append(round(m.value, 3))
    assert set(late) == {"MOT1_EFF", "MOT2_EFF", "MOT3_EFF", "MOT4_EFF"}, late
    assert len(late["MOT1_EFF"]) >= 18, late                  # 4 Hz over 5 s
    assert all(abs(v - 0.5) < 0.05 for v in late["MOT1_EFF"]), late["MOT1_EFF"]
    for name in ("MOT2_EFF", "MOT3_EFF", "MOT4_EFF"):
        assert all(v > 0.9 for v in late[name]), (name, late[name])
    # and at 4 Hz of vehicle time: at least 2 Hz over the flight's last seconds
    stamps = sorted({m.time_boot_ms for _, m in from_controller
                     if m.get_type() == "NAMED_VALUE_FLOAT"})
    assert max(b - a for a, b in zip(stamps, stamps[1:])) <= 500
