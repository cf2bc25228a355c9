#!/usr/bin/env python3
"""Hostile and malformed traffic against the SIL vehicle (and, with --fly, a flying controller),
at a large size: what was thrown, what the vehicle says it dropped, what it applied, whether its
telemetry kept its rate, whether anything crashed, and how the flight ended.

    trq-stress                       # starts a real-time vehicle, 10 s of attack
    trq-stress --seconds 60 --rate 20000 --kinds random,flood
    trq-stress --fly                 # a trq_nmpc controller hovering under attack
    trq-stress --vehicle-port 14580 --gcs-port 18570     # a vehicle already running

Kinds of traffic (--kinds, comma separated; default all), sent alternately to the vehicle's
ground-station and offboard ports:

    random        random bytes (never starting with a frame marker)  -> bad frame (errors_count1)
    truncated     a valid ARM command cut short                       -> bad frame (errors_count1)
    bad_crc       a valid ARM command with a wrong checksum           -> bad frame (errors_count1)
    mavlink1      MAVLink 1 heartbeats and parameter reads    -> decoded (the protocol allows them)
    unknown_id    a well-formed frame with an id not in the dialect  -> unknown id (errors_count2)
    other_system  arm, force-disarm, motor-off PARAM_SET, a valid target, all for system 2
                                                                    -> other system (errors_count3)
    bad_target    SET_ACTUATOR_CONTROL_TARGET for system 1 with NaN, inf, 5.0 or group 1
                                                              -> rejected target (errors_count4)
    flood         valid heartbeats and PARAM_REQUEST_READs, --batch frames per datagram, at
                  --rate messages per second (0: as fast as a tight loop sends)

The bad kinds share --bad-rate datagrams per second. SYS_STATUS counters are 16-bit and saturate
at 65535; the vehicle's exit line (when this tool started it) has the exact totals. Exit status
0 when everything survived (alive, nothing bad applied, counters at least what was detectable,
telemetry >= 80 % of its quiet rate, a flight flown to the end), 1 otherwise.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import trq_params
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import common as mavlink

from trq_lab import procs

ENV = dict(os.environ)
BAD_KINDS = ("random", "truncated", "bad_crc", "mavlink1", "unknown_id", "other_system",
             "bad_target")
KINDS = BAD_KINDS + ("flood",)
# which SYS_STATUS counter each kind must raise, per datagram sent (at least)
COUNTED = {"random": "errors_count1", "truncated": "errors_count1", "bad_crc": "errors_count1",
           "unknown_id": "errors_count2", "other_system": "errors_count3",
           "bad_target": "errors_count4"}
MARKERS = (0xFD, 0xFE)
HOVER_ALT_M = 1.0
RATE_KEEP = 0.8                  # telemetry under attack must keep this share of its quiet rate


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# --- what is thrown ----------------------------------------------------------------------------

def frame_v2(msg_id: int, payload: bytes, crc_extra: int, seq: int = 0, system: int = 255,
             component: int = 190) -> bytes:
    """A MAVLink 2 frame with a correct checksum (for the CRC extra given) around any payload."""
    header = struct.pack("<BBBBBBB", len(payload), 0, 0, seq, system, component,
                         msg_id & 0xFF) + struct.pack("<H", msg_id >> 8)
    crc = mavlink.x25crc(header + payload + bytes([crc_extra])).crc
    return b"\xfd" + header + payload + struct.pack("<H", crc)


class Arsenal:
    """Pools of ready datagrams per kind (randomised, seeded), so that sending is only sendto."""

    POOL = 256

    def __init__(self, seed: int = 0, batch: int = 50) -> None:
        rng = random.Random(seed)
        mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        mav_1 = mav1.MAVLink(None, srcSystem=255, srcComponent=190)

        def pack(msg) -> bytes:
            data = bytes(msg.pack(mav))
            mav.seq = (mav.seq + 1) % 256
            return data

        def arm(target=1, p1=1.0, p2=0.0):
            return mavlink.MAVLink_command_long_message(
                target, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, p1, p2, 0, 0, 0, 0, 0)

        def target(system, controls, group=0):
            return mavlink.MAVLink_set_actuator_control_target_message(
                rng.randrange(2**40), group, system, 1, list(controls))

        unknown = [i for i in range(0x700000, 0x701000) if i not in mavlink.mavlink_map]
        pools: dict[str, list[bytes]] = {k: [] for k in KINDS}
        for _ in range(self.POOL):
            junk = bytearray(os.urandom(rng.randint(1, 300)))
            while junk[0] in MARKERS:
                junk[0] = rng.randrange(256)
            pools["random"].append(bytes(junk))
            whole = pack(arm())
            pools["truncated"].append(whole[:rng.randint(1, len(whole) - 1)])
            whole = pack(arm())
            pools["bad_crc"].append(whole[:-2] + bytes([whole[-2] ^ rng.randint(1, 255),
                                                        whole[-1]]))
            v1 = (mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3) if rng.random() < 0.5 else
                  mav1.MAVLink_param_request_read_message(1, 1, b"SIM_WIND_SPD", -1))
            pools["mavlink1"].append(bytes(v1.pack(mav_1)))
            pools["unknown_id"].append(frame_v2(rng.choice(unknown),
                                                os.urandom(rng.randint(0, 60)), rng.randrange(256)))
            spoof = rng.choice([arm(2), arm(2, 0.0, 21196.0),
                                mavlink.MAVLink_param_set_message(2, 1, b"SIM_MOT1_OFF", 1.0, 9),
                                target(2, [0.9] * 4 + [0.5] * 4)])
            pools["other_system"].append(pack(spoof))
            bad = rng.choice([[math.nan] + [0.5] * 7, [5.0] * 8, [0.5] * 4 + [-math.inf] * 4,
                              [0.5] * 4 + [1.5] * 4, [-0.1] * 8])
            pools["bad_target"].append(pack(target(1, bad, group=rng.choice([0, 0, 0, 1]))))
        for _ in range(16):
            frames = [pack(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
                      if rng.random() < 0.75 else
                      pack(mavlink.MAVLink_param_request_read_message(1, 1, b"SIM_WIND_SPD", -1))
                      for _ in range(batch)]
            pools["flood"].append(b"".join(frames))
        self.pools = pools
        self.batch = batch


@dataclass
class Sent:
    datagrams: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS})
    messages: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS})
    errors: int = 0                 # sendto failures (a full socket buffer)
    seconds: float = 0.0

    @property
    def flood_rate(self) -> float:
        return self.messages["flood"] / self.seconds if self.seconds else 0.0

    def total_rate(self) -> float:
        return sum(self.messages.values()) / self.seconds if self.seconds else 0.0


def attack(ports: list[int], seconds: float, kinds: list[str], rate: float, bad_rate: float,
           arsenal: Arsenal, stop: threading.Event | None = None,
           extra: list[int] | None = None) -> Sent:
    """Throw `kinds` at 127.0.0.1:ports for `seconds`: the flood at `rate` messages per second
    (0: unbounded), the bad kinds round robin at `bad_rate` datagrams per second. `extra` ports
    (a controller) get the malformed kinds only."""
    sent = Sent()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
    sock.setblocking(False)
    bad = [k for k in kinds if k in BAD_KINDS]
    malformed = [k for k in bad if k in ("random", "truncated", "bad_crc", "unknown_id")]
    flood = "flood" in kinds
    pools = arsenal.pools
    dests = [("127.0.0.1", p) for p in ports]
    extra_dests = [("127.0.0.1", p) for p in extra or []]
    per_flood = arsenal.batch
    i = j = 0
    t0 = time.monotonic()
    end = t0 + seconds
    try:
        while True:
            now = time.monotonic()
            if now >= end or (stop is not None and stop.is_set()):
                break
            elapsed = now - t0
            busy = False
            if flood and (rate <= 0 or sent.messages["flood"] + per_flood <= rate * elapsed
                          + per_flood):
                data = pools["flood"][i % len(pools["flood"])]
                try:
                    sock.sendto(data, dests[i % len(dests)])
                    sent.datagrams["flood"] += 1
                    sent.messages["flood"] += per_flood
                except OSError:
                    sent.errors += 1
                i += 1
                busy = True
            n_bad = sum(sent.datagrams[k] for k in bad)
            if bad and n_bad < bad_rate * elapsed:
                kind = bad[j % len(bad)]
                data = pools[kind][(j // len(bad)) % len(pools[kind])]
                try:
                    sock.sendto(data, dests[j % len(dests)])
                    sent.datagrams[kind] += 1
                    sent.messages[kind] += 1
                except OSError:
                    sent.errors += 1
                if extra_dests and malformed:
                    k2 = malformed[j % len(malformed)]
                    for d in extra_dests:
                        try:
                            sock.sendto(pools[k2][j % len(pools[k2])], d)
                        except OSError:
                            sent.errors += 1
                j += 1
                busy = True
            if not busy:
                time.sleep(0.0005)
    finally:
        sent.seconds = time.monotonic() - t0
        sock.close()
    return sent


# --- what is watched ---------------------------------------------------------------------------

class Watcher(threading.Thread):
    """A ground station: receives the vehicle's telemetry in a thread and keeps what the report
    needs (arrival times of ATTITUDE, every SYS_STATUS, armed flags, the largest displacement)."""

    def __init__(self, bind_port: int | None = None, vehicle_gcs_port: int | None = None) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", bind_port or 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.vehicle = ("127.0.0.1", vehicle_gcs_port) if vehicle_gcs_port else None
        self.mav = mavlink.MAVLink(None, srcSystem=254, srcComponent=190)
        self.lock = threading.Lock()
        self.attitude_t: list[float] = []
        self.sys_status: list[tuple[float, object]] = []
        self.heartbeats: list[tuple[float, object]] = []
        self.positions: list[tuple[float, float, float, float]] = []
        self.param_values: dict[int, object] = {}
        self.statustexts: list[str] = []
        self.first = threading.Event()
        self._halt = threading.Event()

    def send(self, msg) -> None:
        if self.vehicle is not None:
            self.sock.sendto(bytes(msg.pack(self.mav)), self.vehicle)

    def run(self) -> None:
        while not self._halt.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except (socket.timeout, ConnectionRefusedError):
                continue
            except OSError:
                return
            if self.vehicle is None:
                self.vehicle = addr[:2]
            now = time.monotonic()
            rx = mavlink.MAVLink(None)
            rx.robust_parsing = True
            try:
                msgs = rx.parse_buffer(data) or []
            except Exception:
                continue
            with self.lock:
                for m in msgs:
                    if isinstance(m, mavlink.MAVLink_bad_data) or m.get_srcSystem() != 1:
                        continue
                    self.first.set()
                    kind = m.get_type()
                    if kind == "ATTITUDE":
                        self.attitude_t.append(now)
                    elif kind == "SYS_STATUS":
                        self.sys_status.append((now, m))
                    elif kind == "HEARTBEAT":
                        self.heartbeats.append((now, m))
                    elif kind == "LOCAL_POSITION_NED":
                        self.positions.append((now, m.x, m.y, m.z))
                    elif kind == "PARAM_VALUE":
                        self.param_values[m.param_index] = m
                    elif kind == "STATUSTEXT":
                        self.statustexts.append(m.text)

    def close(self) -> None:
        self._halt.set()
        self.join(timeout=1.0)
        self.sock.close()

    def rate(self, t0: float, t1: float) -> float:
        with self.lock:
            n = sum(1 for t in self.attitude_t if t0 <= t < t1)
        return n / (t1 - t0) if t1 > t0 else 0.0

    def status_after(self, t: float, timeout_s: float = 3.0):
        """The first SYS_STATUS that arrives after wall time t (waits for it)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                for when, m in self.sys_status:
                    if when > t:
                        return m
            time.sleep(0.05)
        return None

    def status_before(self, t: float):
        """The last SYS_STATUS that arrived before wall time t."""
        with self.lock:
            earlier = [m for when, m in self.sys_status if when < t]
        return earlier[-1] if earlier else None

    def armed_ever(self, t0: float = 0.0) -> bool:
        with self.lock:
            return any(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
                       for t, m in self.heartbeats if t >= t0)

    def max_displacement(self, t0: float = 0.0) -> float:
        with self.lock:
            return max((math.sqrt(x * x + y * y + z * z) for t, x, y, z in self.positions
                        if t >= t0), default=0.0)

    def param_list(self, timeout_s: float = 3.0) -> tuple[int, int | None]:
        """PARAM_REQUEST_LIST: (parameters received, count announced)."""
        with self.lock:
            self.param_values.clear()
        self.send(mavlink.MAVLink_param_request_list_message(1, 1))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                count = next(iter(self.param_values.values())).param_count \
                    if self.param_values else None
                if count is not None and len(self.param_values) >= count:
                    return len(self.param_values), count
            time.sleep(0.05)
        with self.lock:
            count = next(iter(self.param_values.values())).param_count \
                if self.param_values else None
            return len(self.param_values), count


# --- processes ---------------------------------------------------------------------------------

@dataclass
class Vehicle:
    proc: subprocess.Popen | None
    gcs_port: int
    offboard_port: int
    log_dir: Path | None
    out_path: Path | None

    def alive(self) -> bool:
        return self.proc is None or self.proc.poll() is None

    def stop(self) -> str:
        """SIGTERM; the vehicle's exit line (its own totals of what it dropped)."""
        if self.proc is None:
            return ""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        text = self.out_path.read_text(errors="replace") if self.out_path else ""
        lines = [ln for ln in text.splitlines() if ln.startswith("trq-sil-vehicle:")]
        return lines[-1] if lines else ""


def start_vehicle(out: Path, gcs_target: int, offboard_target: int, *extra: str) -> Vehicle:
    gcs, off = free_port(), free_port()
    log_dir = out / "vehicle"
    log_dir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "sil_vehicle", "--mode", "realtime",
           "--gcs-bind", f"127.0.0.1:{gcs}", "--gcs-target", f"127.0.0.1:{gcs_target}",
           "--offboard-bind", f"127.0.0.1:{off}",
           "--offboard-target", f"127.0.0.1:{offboard_target}",
           "--log-dir", str(log_dir), *extra]
    out_path = out / "vehicle.out"
    with open(out_path, "wb") as f:
        proc = subprocess.Popen(cmd, cwd=out, env=ENV, stdout=f, stderr=subprocess.STDOUT)
    return Vehicle(proc, gcs, off, log_dir, out_path)


def write_overlay(out: Path, controller: str, reference: dict) -> Path:
    """A controller file extending params/controller/<controller>.yaml with the reference."""
    from trq_lab.overlays import write_controller_overlay

    return write_controller_overlay(controller, reference, out)


def check_flight_log(path: Path, tilt_min: float, tilt_max: float) -> dict:
    """What the vehicle applied, from its flight.csv: commands finite and in range, crashes."""
    import numpy as np

    from trq_lab import metrics

    _, cols = metrics.read_csv(path)
    thr = np.column_stack([cols[f"cmd_throttle{i}_pct"] for i in range(1, 5)])
    tilt = np.column_stack([cols[f"cmd_tilt{i}_rad"] for i in range(1, 5)])
    finite = bool(np.all(np.isfinite(thr)) and np.all(np.isfinite(tilt)))
    in_range = bool(finite and thr.min() >= 0.0 and thr.max() <= 100.0
                    and tilt.min() >= tilt_min - 1e-9 and tilt.max() <= tilt_max + 1e-9)
    return {"rows": len(cols["t_us"]), "finite": finite, "in_range": in_range,
            "throttle": (float(np.nanmin(thr)), float(np.nanmax(thr))) if len(thr) else (0, 0),
            "tilt_deg": (math.degrees(float(np.nanmin(tilt))), math.degrees(float(np.nanmax(tilt))))
            if len(tilt) else (0, 0),
            "crashed": bool(np.any(cols["crashed"] > 0.5)),
            "armed_rows": int(np.sum(cols["armed"] > 0.5)),
            "max_alt_m": max(0.0, float(-np.min(cols["pos_d_m"]))) if len(cols["t_us"]) else 0.0}


# --- the run -----------------------------------------------------------------------------------

def kernel_drops(ports: list[int]) -> int | None:
    """Datagrams the kernel dropped unread for the sockets bound to these 127.0.0.1 ports (full
    receive buffers; Linux /proc/net/udp, the last column), None where unavailable."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    wanted = {f"0100007F:{p:04X}" for p in ports}
    total = 0
    for line in lines:
        cols = line.split()
        if len(cols) > 12 and cols[1] in wanted:
            total += int(cols[-1])
    return total


def counters(m) -> dict[str, int]:
    return {k: int(getattr(m, k)) for k in ("errors_comm", "errors_count1", "errors_count2",
                                            "errors_count3", "errors_count4")}


def expected_counts(sent: Sent) -> dict[str, int]:
    """The least each SYS_STATUS counter must have grown by (one per bad datagram detected)."""
    want = {k: 0 for k in ("errors_comm", "errors_count1", "errors_count2", "errors_count3",
                           "errors_count4")}
    for kind, counter in COUNTED.items():
        want[counter] += sent.datagrams[kind]
        want["errors_comm"] += sent.datagrams[kind]
    return want


def run(args: argparse.Namespace) -> int:
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        print(f"stress: unknown kinds {unknown}; choose from {', '.join(KINDS)}", file=sys.stderr)
        return 2
    out = Path(args.out or tempfile.mkdtemp(prefix="stress-"))
    out.mkdir(parents=True, exist_ok=True)
    arsenal = Arsenal(args.seed, args.batch)
    problems: list[str] = []
    controller = None
    attached = args.vehicle_port is not None or args.gcs_port is not None
    if attached:
        if args.vehicle_port is None or args.gcs_port is None or args.fly:
            print("stress: --vehicle-port and --gcs-port go together, without --fly",
                  file=sys.stderr)
            return 2
        watcher = Watcher(vehicle_gcs_port=args.gcs_port)
        vehicle = Vehicle(None, args.gcs_port, args.vehicle_port, None, None)
    else:
        watcher = Watcher()
        ctrl_port = free_port()
        if args.fly:
            reference = {"kind": "hover", "altitude_m": HOVER_ALT_M, "hold_s": 1.0,
                         "duration_s": args.seconds + args.quiet_s + 3.0, "ramp_s": 0.5}
            overlay = write_overlay(out, args.controller, reference)
            ccmd = [sys.executable, "-m", "trq_offboard", "--controller", str(overlay),
                    "--connect", f"udpin:127.0.0.1:{ctrl_port}", "--log-dir",
                    str(out / "controller"), "--applied-delay-s", "0.005"]
            with open(out / "controller.out", "wb") as f:
                controller = subprocess.Popen(ccmd, cwd=out, env=ENV, stdout=f,
                                              stderr=subprocess.STDOUT)
            if not procs.wait_bound(ctrl_port, controller, 90.0):
                print(f"stress: the controller did not start (see {out / 'controller.out'})",
                      file=sys.stderr)
                controller.kill()
                return 1
        vehicle = start_vehicle(out, watcher.port, ctrl_port)
    watcher.start()
    try:
        if attached:
            watcher.send(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
        if not watcher.first.wait(30.0):
            print("stress: no telemetry from the vehicle", file=sys.stderr)
            return 1
        if args.fly:                  # attack once it flies
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and controller.poll() is None:
                with watcher.lock:
                    up = watcher.positions and watcher.positions[-1][3] < -0.8 * HOVER_ALT_M
                if up:
                    break
                time.sleep(0.05)
            else:
                problems.append("the controller never got the vehicle airborne")
        t_quiet = time.monotonic()
        time.sleep(args.quiet_s)
        vports = [vehicle.gcs_port, vehicle.offboard_port]
        drops0 = kernel_drops(vports)
        t_attack = time.monotonic()
        quiet_rate = watcher.rate(t_quiet, t_attack)
        before = watcher.status_before(t_attack)
        print(f"stress: {args.seconds:g} s of {', '.join(kinds)} at the vehicle "
              f"(gcs {vehicle.gcs_port}, offboard {vehicle.offboard_port})"
              + (f" and garbage at the flying controller ({ctrl_port})" if args.fly else ""),
              flush=True)
        sent = attack([vehicle.gcs_port, vehicle.offboard_port], args.seconds, kinds,
                      args.rate, args.bad_rate, arsenal,
                      extra=[ctrl_port] if args.fly else None)
        t_end = time.monotonic()
        time.sleep(0.2)
        drops1 = kernel_drops(vports)
        unread = drops1 - drops0 if drops0 is not None and drops1 is not None else None
        attack_rate = watcher.rate(t_attack, t_end)
        after = watcher.status_after(t_end + 0.2, timeout_s=3.0)
        alive = vehicle.alive()
        n_params, n_count = watcher.param_list() if alive else (0, None)

        # --- thrown
        print("\nthrown (datagrams / messages):")
        for k in kinds:
            print(f"  {k:13s} {sent.datagrams[k]:9d} / {sent.messages[k]:9d}")
        print(f"  achieved: {sent.total_rate():,.0f} messages/s in all, flood "
              f"{sent.flood_rate:,.0f} messages/s ({args.batch} per datagram), "
              f"{sent.seconds:.2f} s, {sent.errors} send errors")
        if "flood" in kinds and args.rate > 0 and sent.flood_rate < 0.95 * args.rate:
            problems.append(f"this machine sent the flood at only {sent.flood_rate:,.0f} "
                            f"messages/s, below the {args.rate:,.0f} asked")
        # --- dropped
        want = expected_counts(sent)
        print("\ndropped (vehicle SYS_STATUS, growth during the attack / least expected):")
        if before is None or after is None:
            problems.append("no SYS_STATUS before or after the attack")
            print("  no SYS_STATUS")
        else:
            b, a = counters(before), counters(after)
            names = {"errors_comm": "all dropped", "errors_count1": "bad frames",
                     "errors_count2": "unknown ids", "errors_count3": "other system",
                     "errors_count4": "rejected/stale targets"}
            for k, label in names.items():
                grown = a[k] - b[k]
                sat = " (saturated at 65535)" if a[k] >= 65535 else ""
                print(f"  {k:14s} {label:24s} {grown:9d} / {want[k]:9d}{sat}")
                if grown < want[k] - (unread or 0) and not sat:
                    problems.append(f"SYS_STATUS {k} grew by {grown}, expected >= {want[k]}")
            print(f"  drop_rate_comm {after.drop_rate_comm / 100:.1f} % of received datagrams")
        print(f"  unread: {'unknown' if unread is None else unread} datagrams dropped by the "
              f"kernel (the vehicle's receive buffers full; it never saw them, so the least "
              f"expected above is lowered by as many)")
        # --- telemetry
        print(f"\ntelemetry (gcs ATTITUDE): quiet {quiet_rate:.1f} Hz, under attack "
              f"{attack_rate:.1f} Hz ({100 * attack_rate / max(quiet_rate, 1e-9):.0f} %)")
        if attack_rate < RATE_KEEP * quiet_rate:
            problems.append(f"telemetry fell to {attack_rate:.1f} Hz from {quiet_rate:.1f} Hz")
        # --- applied
        print("\napplied:")
        if not args.fly:
            armed = watcher.armed_ever()
            moved = watcher.max_displacement()
            print(f"  armed at any time: {'YES' if armed else 'no'}; largest displacement "
                  f"{moved:.3f} m")
            if armed or moved > 0.05:
                problems.append("the vehicle armed or moved: a bad command was applied")
        print(f"  parameters after the attack: {n_params} of {n_count}")
        if n_count is None or n_params < n_count:
            problems.append("the parameter list did not come back whole")
        # --- processes and the flight
        flight_line = ""
        if controller is not None:
            try:
                controller.wait(timeout=args.seconds + 60.0)
                procs.controller_csv(out / "controller")      # its ULog, on the ground
            except subprocess.TimeoutExpired:
                problems.append("the controller did not finish its flight")
            text = (out / "controller.out").read_text(errors="replace")
            lines = [ln for ln in text.splitlines() if ln.startswith("trq-offboard:")]
            flight_line = lines[-1] if lines else "(no summary)"
            if controller.returncode != 0 or "Traceback" in text:
                problems.append(f"the controller exited {controller.returncode}")
        vehicle_alive = vehicle.alive()
        exit_line = vehicle.stop() if not attached else ""
        print(f"\ncrashes: vehicle process {'alive' if vehicle_alive else 'DEAD'} after the "
              f"attack" + (f", controller rc {controller.returncode}" if controller else ""))
        if not vehicle_alive:
            problems.append("the vehicle process died")
        if vehicle.out_path is not None:
            vtext = vehicle.out_path.read_text(errors="replace")
            if "Traceback" in vtext:
                problems.append("the vehicle logged a traceback (an exception on traffic)")
                print("  the vehicle logged a traceback: see", vehicle.out_path)
        if exit_line:
            print(f"  vehicle log: {exit_line}")
        if vehicle.log_dir is not None and (vehicle.log_dir / "flight.csv").exists():
            from sil_vehicle.config import load_sim
            vp = load_sim(trq_params.builtin("sim", "default")).vehicle
            f = check_flight_log(vehicle.log_dir / "flight.csv", vp.tilt_min_rad, vp.tilt_max_rad)
            print(f"  flight.csv: {f['rows']} rows, commands finite: {f['finite']}, in range: "
                  f"{f['in_range']} (throttle {f['throttle'][0]:.1f}..{f['throttle'][1]:.1f} %, "
                  f"tilt {f['tilt_deg'][0]:.1f}..{f['tilt_deg'][1]:.1f} deg), crashed column: "
                  f"{'SET' if f['crashed'] else 'never'}, max altitude {f['max_alt_m']:.2f} m")
            if not f["in_range"]:
                problems.append("flight.csv holds a command out of range or not finite")
            if f["crashed"]:
                problems.append("the vehicle crashed")
            if not args.fly and f["armed_rows"]:
                problems.append("flight.csv shows the vehicle armed")
        if args.fly:
            print(f"\nflight outcome: {flight_line}")
        print(f"\nlogs in {out}")
    finally:
        watcher.close()
        if controller is not None and controller.poll() is None:
            controller.kill()
            controller.wait(timeout=5)
        if not attached:
            vehicle.stop()
    if problems:
        print("\nFAILED:\n  " + "\n  ".join(problems))
        return 1
    print("\nsurvived: everything above held")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="trq-stress", description=__doc__.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(__doc__.splitlines()[1:]))
    p.add_argument("--seconds", type=float, default=10.0, help="attack duration (default 10)")
    p.add_argument("--rate", type=float, default=10_000.0,
                   help="flood messages per second (default 10000; 0: as fast as possible)")
    p.add_argument("--bad-rate", type=float, default=1000.0,
                   help="malformed/hostile datagrams per second, all bad kinds (default 1000)")
    p.add_argument("--batch", type=int, default=50, help="flood frames per datagram (default 50)")
    p.add_argument("--kinds", default=",".join(KINDS),
                   help=f"comma-separated kinds (default all: {','.join(KINDS)})")
    p.add_argument("--quiet-s", type=float, default=2.0,
                   help="seconds of quiet telemetry measured before the attack (default 2)")
    p.add_argument("--vehicle-port", type=int, default=None,
                   help="offboard port of a vehicle already running (with --gcs-port)")
    p.add_argument("--gcs-port", type=int, default=None,
                   help="ground-station port of a vehicle already running")
    p.add_argument("--fly", action="store_true",
                   help="start a controller hovering the vehicle, attack it in flight")
    p.add_argument("--controller", default="trq_nmpc",
                   help="controller for --fly (params/controller/NAME.yaml, default trq_nmpc)")
    p.add_argument("--seed", type=int, default=0, help="seed of the traffic generator")
    p.add_argument("--out", type=Path, default=None, help="directory for the logs (default tmp)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.seconds <= 0 or args.batch < 1 or args.rate < 0 or args.bad_rate < 0:
        print("stress: --seconds and --batch must be positive, rates >= 0", file=sys.stderr)
        return 2
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
