"""A small blocking MAVLink client for the tools (fault injection, monitoring, tests).

    client = MavClient("udpout:127.0.0.1:18570")    # the vehicle's ground-station port
    client.param_set("SIM_MOT1_EFF", 0.5)           # waits for the PARAM_VALUE that confirms it
    client.command(mavlink.MAV_CMD_INJECT_FAILURE, 101, 1, 1)   # waits for COMMAND_ACK

`udpout:HOST:PORT` sends to the vehicle from an ephemeral port (the vehicle answers any peer),
so it works beside a ground station that holds 14550; `udpin:HOST:PORT` listens instead. Any
connection string of trq_wire.connection works: `tcp:HOST:PORT`, `tcpin:HOST:PORT`,
`serial:///dev/ttyUSB0:57600` (a telemetry radio), their MAVSDK spellings. Every wait has a
timeout and raises `NoAnswer` with what was expected.
"""

from __future__ import annotations

import argparse
import math
import socket
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.connection import FORMS, Connection
from trq_wire.framing import StreamFramer


class NoAnswer(RuntimeError):
    """The vehicle did not answer as expected in time."""


class MavClient:
    def __init__(self, connect: str = "udpout:127.0.0.1:18570", *, system_id: int = 255,
                 component_id: int = 190, target_system: int = 1, target_component: int = 1,
                 signing_key: bytes | None = None, link_id: int = 2) -> None:
        c = self.connection = Connection.parse(connect)
        self.sock: socket.socket | None = None     # UDP, or the TCP connection
        self._listener: socket.socket | None = None
        self._serial = None
        self._framer = StreamFramer() if c.is_stream else None
        self.peer = None
        if c.mode == "serial":
            import serial  # pyserial

            try:
                self._serial = serial.Serial(c.device, c.baud, timeout=0)
            except (serial.SerialException, ValueError) as exc:
                raise OSError(f"{c}: {exc}") from None
            self.peer = c.device
        elif c.mode == "tcpout":
            self.sock = socket.create_connection((c.host, c.port), timeout=5.0)
            self.peer = (c.host, c.port)
        elif c.mode == "tcpin":
            self._listener = socket.create_server((c.host, c.port))
        else:
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            if c.mode == "udpin":
                self.sock.bind((c.host, c.port))
            else:
                self.sock.bind(("0.0.0.0", 0))
                self.peer = (c.host, c.port)
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        if signing_key is not None:            # MAVLink 2 signing of everything this tool sends
            from trq_wire.signing import sign_outgoing
            sign_outgoing(self.mav, signing_key, link_id)
        self.target = (target_system, target_component)
        self.vehicle_time_us = 0
        self.last: dict[str, object] = {}            # the vehicle's (target's) latest, by type
        # what other components say (a companion computer routed through the vehicle: its
        # HEARTBEAT must not read as the vehicle's): (system, component) -> type -> message
        self.others: dict[tuple[int, int], dict[str, object]] = {}
        self.statustexts: list[str] = []
        self.on_message: Callable[[object], None] | None = None

    def close(self) -> None:
        for end in (self.sock, self._listener, self._serial):
            if end is not None:
                end.close()

    def __enter__(self) -> "MavClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- raw I/O ---------------------------------------------------------------------------
    def send(self, msg) -> None:
        if self.peer is None:
            raise NoAnswer(f"{self.connection}: no vehicle has sent anything or connected yet, "
                           "nowhere to send to")
        data = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        if self._serial is not None:
            self._serial.write(data)
        elif self.connection.is_stream:
            self.sock.sendall(data)
        else:
            self.sock.sendto(data, self.peer)

    def _receive(self, timeout_s: float) -> list:
        """The messages of one datagram, or of what a stream brought, within timeout_s."""
        timeout_s = max(timeout_s, 1e-3)
        if self._serial is not None:
            end = time.monotonic() + timeout_s
            data = b""
            while not data and time.monotonic() < end:
                data = self._serial.read(65536)
                if not data:
                    time.sleep(0.005)
            return self._frames(data)
        if self._listener is not None and self.sock is None:
            self._listener.settimeout(timeout_s)
            try:
                self.sock, addr = self._listener.accept()
            except socket.timeout:
                return []
            self.peer = addr[:2]
        self.sock.settimeout(timeout_s)
        try:
            if self.connection.is_stream:
                data = self.sock.recv(65536)
                if not data:
                    raise NoAnswer(f"{self.connection}: the vehicle closed the connection")
                return self._frames(data)
            data, addr = self.sock.recvfrom(65535)
        except (socket.timeout, ConnectionRefusedError):
            return []
        if self.peer is None:
            self.peer = addr[:2]
        rx = mavlink.MAVLink(None)
        rx.robust_parsing = True
        return [m for m in rx.parse_buffer(data) or []
                if not isinstance(m, mavlink.MAVLink_bad_data)]

    def _frames(self, data: bytes) -> list:
        rx = mavlink.MAVLink(None)
        out = []
        for frame in self._framer.feed(data):
            try:
                out.append(rx.decode(bytearray(frame)))
            except Exception:    # checksummed, but a payload may still be odd
                continue
        return out

    def poll(self, timeout_s: float) -> list:
        """Messages of the datagram (or stream bytes) that arrive within `timeout_s` (at least
        one wait)."""
        out = []
        for msg in self._receive(timeout_s):
            kind = msg.get_type()
            mine = self.is_vehicle(msg)
            if mine:
                self.last[kind] = msg
            else:
                self.others.setdefault((msg.get_srcSystem(), msg.get_srcComponent()),
                                       {})[kind] = msg
            if kind == "ODOMETRY" and mine:
                self.vehicle_time_us = max(self.vehicle_time_us, int(msg.time_usec))
            elif kind in _BOOT_MS_STAMPED and mine:
                self.vehicle_time_us = max(self.vehicle_time_us, int(msg.time_boot_ms) * 1000)
            if kind == "STATUSTEXT":
                text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
                self.statustexts.append(text)
            if self.on_message:
                self.on_message(msg)
            out.append(msg)
        return out

    def wait(self, predicate: Callable[[object], bool], timeout_s: float, what: str):
        end = time.monotonic() + timeout_s
        while (left := end - time.monotonic()) > 0:
            for msg in self.poll(min(left, 0.2)):
                if predicate(msg):
                    return msg
        raise NoAnswer(f"no {what} within {timeout_s:g} s")

    def hello(self, timeout_s: float = 5.0):
        """Make the vehicle know this peer and wait for its heartbeat."""
        if self.peer is not None:
            self.send(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        return self.wait(lambda m: m.get_type() == "HEARTBEAT" and self.is_vehicle(m),
                         timeout_s, "HEARTBEAT from the vehicle")

    def is_vehicle(self, msg) -> bool:
        """Sent by the vehicle's autopilot (the target), not by another component of it."""
        return (msg.get_srcSystem(), msg.get_srcComponent()) == self.target

    # --- protocol helpers ------------------------------------------------------------------
    def command(self, command: int, *params: float, timeout_s: float = 1.0,
                retries: int = 3) -> int:
        """COMMAND_LONG; returns the MAV_RESULT of its COMMAND_ACK."""
        p = list(params) + [0.0] * (7 - len(params))
        for attempt in range(retries):
            self.send(mavlink.MAVLink_command_long_message(*self.target, command, attempt, *p))
            try:
                ack = self.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command,
                                timeout_s, f"COMMAND_ACK for command {command}")
                return ack.result
            except NoAnswer:
                continue
        raise NoAnswer(f"no COMMAND_ACK for command {command} after {retries} tries")

    def param_set(self, name: str, value: float, timeout_s: float = 1.0, retries: int = 3) -> float:
        """PARAM_SET; returns the value the vehicle confirms. Raises NoAnswer if it never
        confirms the value asked for (a refused value is confirmed unchanged)."""
        for _ in range(retries):
            self.send(mavlink.MAVLink_param_set_message(*self.target, name.encode(), value,
                                                        mavlink.MAV_PARAM_TYPE_REAL32))
            try:
                reply = self.wait(lambda m: m.get_type() == "PARAM_VALUE"
                                  and _name(m.param_id) == name, timeout_s,
                                  f"PARAM_VALUE {name}")
            except NoAnswer:
                continue
            if not math.isclose(reply.param_value, value, rel_tol=1e-6, abs_tol=1e-6):
                raise NoAnswer(f"{name}: the vehicle kept {reply.param_value:g}, refused {value:g}"
                               + (f" ({self.statustexts[-1]})" if self.statustexts else ""))
            return reply.param_value
        raise NoAnswer(f"no PARAM_VALUE for {name} after {retries} tries")

    def params(self, timeout_s: float = 3.0) -> dict[str, float]:
        self.send(mavlink.MAVLink_param_request_list_message(*self.target))
        values: dict[str, float] = {}
        count = None
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and (count is None or len(values) < count):
            for m in self.poll(0.2):
                if m.get_type() == "PARAM_VALUE":
                    values[_name(m.param_id)] = m.param_value
                    count = m.param_count
        if count is None or len(values) < count:
            raise NoAnswer(f"got {len(values)} of {count} parameters in {timeout_s:g} s")
        return values


_BOOT_MS_STAMPED = ("ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT")


def _name(param_id) -> str:
    return param_id if isinstance(param_id, str) else param_id.decode(errors="replace")


def gcs_parser(prog: str, doc: str) -> argparse.ArgumentParser:
    """The command line every ground-station tool starts with: its docstring as description and
    epilog, and --connect (the vehicle's ground-station port, as MavClient takes it)."""
    p = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n".join(doc.splitlines()[2:]))
    p.add_argument("--connect", default="udpout:127.0.0.1:18570", type=connection_arg,
                   help="the vehicle's ground-station port (default udpout:127.0.0.1:18570); "
                        "any of " + ", ".join(FORMS))
    return p


def connection_arg(text: str) -> str:
    """argparse's check of a connection string (the string itself goes to MavClient)."""
    try:
        Connection.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text
