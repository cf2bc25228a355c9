#!/usr/bin/env python3
"""Open-loop hover check: start the SIL vehicle in lockstep, act as a minimal offboard client
over UDP (arm, spin up, climb with a little more than the trim throttle, hold the trim, descend),
and check what the vehicle reports. No controller: the vehicle is symmetric and the air is calm,
so with equal throttles it climbs and holds level; this checks the plant, the lockstep and the
MAVLink links end to end.

    trq-hover-check [--vehicle params/vehicle/trq.yaml] [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import trq_params
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import load_vehicle


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def throttle_profile(t_s: float, trim_pct: float) -> float:
    """Idle for 1 s, +6 % for 1 s (climb), -6 % for about as long (brake), trim for 3 s (hold),
    then -2 % (descend)."""
    if t_s < 1.0:
        return 0.0
    if t_s < 2.0:
        return trim_pct + 6.0
    if t_s < 3.0:
        return trim_pct - 6.0
    if t_s < 6.0:
        return trim_pct
    return trim_pct - 2.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-hover-check", description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="trq",
                    help="airframe: a built-in name (trq, quad) or a vehicle YAML path (default trq)")
    ap.add_argument("--out", type=Path, default=Path("out/hover_check"))
    ap.add_argument("--duration", type=float, default=10.0, help="simulated seconds")
    args = ap.parse_args(argv)
    vp = load_vehicle(trq_params.resolve("vehicle", args.vehicle))
    trim = vp.hover_throttle_pct
    off_port, gcs_port = free_port(), free_port()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    my_port = sock.getsockname()[1]
    cmd = [sys.executable, "-m", "sil_vehicle", "--vehicle", str(args.vehicle), "--mode", "lockstep",
           "--offboard-bind", f"127.0.0.1:{off_port}", "--offboard-target", f"127.0.0.1:{my_port}",
           "--gcs-bind", f"127.0.0.1:{gcs_port}", "--gcs-target", "127.0.0.1:9",
           "--log-dir", str(args.out), "--duration", str(args.duration)]
    proc = subprocess.Popen(cmd)
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rx = mavlink.MAVLink(None)
    dest = ("127.0.0.1", off_port)
    max_alt, max_tilt, vz_at_hold, vz_end_hold = 0.0, 0.0, None, None
    armed_ack = False
    wall0 = time.monotonic()
    try:
        t_s = 0.0
        arm_sent = False
        while t_s < args.duration:
            data, _ = sock.recvfrom(65535)
            for msg in rx.parse_buffer(data) or []:
                kind = msg.get_type()
                if kind == "COMMAND_ACK" and msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                    armed_ack = msg.result == mavlink.MAV_RESULT_ACCEPTED
                if kind == "ODOMETRY":
                    t_s = msg.time_usec / 1e6
                    if not arm_sent:   # the vehicle is up: arm before answering the first stamp
                        sock.sendto(mavlink.MAVLink_command_long_message(
                            1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0,
                            0).pack(mav), dest)
                        arm_sent = True
                    alt = -msg.z
                    max_alt = max(max_alt, alt)
                    w, x, y, z = msg.q
                    max_tilt = max(max_tilt, math.degrees(math.acos(min(1.0, 1 - 2 * (x * x + y * y)))))
                    if vz_at_hold is None and t_s >= 3.1:
                        vz_at_hold = msg.vz
                    if vz_end_hold is None and t_s >= 5.9:
                        vz_end_hold = msg.vz
                    if t_s >= args.duration:
                        break
                    zeta = throttle_profile(t_s, trim) / 100.0
                    sock.sendto(mavlink.MAVLink_set_actuator_control_target_message(
                        msg.time_usec, 0, 1, 1, [zeta] * 4 + [0.0] * 4).pack(mav), dest)
    except socket.timeout:
        print("hover check: FAILED, no telemetry from the vehicle for 5 s", file=sys.stderr)
        proc.terminate()
        return 1
    finally:
        wall = time.monotonic() - wall0
        sock.close()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.terminate()
    # at the trim throttle the vertical acceleration must vanish: the climb rate stays put
    hold_dv = abs((vz_end_hold or 0.0) - (vz_at_hold or 0.0)) if vz_at_hold is not None else math.inf
    ok = armed_ack and max_alt > 0.5 and hold_dv < 0.05 and max_tilt < 2.0 and proc.returncode == 0
    print(f"hover check ({vp.name}, trim {trim:.1f} %): armed={armed_ack}, max altitude "
          f"{max_alt:.2f} m, vertical speed change over the 2.8 s trim hold {hold_dv:.3f} m/s, "
          f"max tilt {max_tilt:.2f} deg, {args.duration:.0f} s simulated in {wall:.1f} s wall "
          f"({args.duration / wall:.1f}x real time); logs in {args.out}: "
          f"{'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
