"""The SIL vehicle daemon: the only loop. It wires the clock, the simulated autopilot (`Sitl`) and
two links (ground station, offboard) the way PX4 SITL does, and writes the logs. Both links are
UDP by default; the offboard link may instead be a serial line (`--offboard-serial`, as a
companion computer's UART) or a TCP server (`--offboard-tcp`).

    python -m sil_vehicle [--sim params/sim/default.yaml] [--vehicle params/vehicle/quad.yaml] ...

Lockstep: at every offboard ODOMETRY (stamp t) the vehicle waits for the SET_ACTUATOR_CONTROL_TARGET
whose time_usec is t, then advances one period. Real time: it advances with the wall clock (times
a speed-up factor), applying the latest valid target. See PROTOCOL.md.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import logging
import math
import signal
import sys
import time
from pathlib import Path

import trq_params
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.clock import RealTimePacer
from sil_vehicle.config import (
    ConfigError,
    LinkParams,
    SimParams,
    load_sim,
    parse_endpoint,
    parse_serial,
    sensing_profile,
)
from sil_vehicle.faultscript import load_script
from sil_vehicle.mavlink.codec import COMPONENT_ID, SYSTEM_ID, Codec
from sil_vehicle.sitl import LINKS, Outgoing, Sitl
from trq_wire.framing import NS_PER_S, LinePacer, frame_size, line_bytes_per_s
from trq_wire.logfile import CsvLog, Tlog
from trq_wire.signing import SignatureCheck, SigningKeyError, load_key, sign_outgoing
from trq_wire.stream import OneStream, SerialStream, TcpStream

log = logging.getLogger("sil_vehicle")

MAX_PEERS = 16
PEER_TIMEOUT_S = 10.0      # a peer silent this long (wall clock) gets no more telemetry
MAVLINK2_MAGIC, IFLAG_SIGNED = 0xFD, 0x01     # a MAVLink 2 frame, and its "signed" flag
MAX_DATAGRAM = 1400          # bytes: frames to one address are packed up to this (below the MTU)
SERIAL_WARN_FRACTION = 0.8   # of a serial line's bytes per second: above, the start warns


def serial_budget(link: LinkParams, signed: bool) -> tuple[int, int]:
    """(bytes per second the link's configured telemetry needs at most, bytes per second its
    serial line carries): each stream's rate times its frame's full encoded size (MAVLink 2
    header, payload, checksum, and the signature when signing), against BAUD / 10 (8N1)."""
    needed = sum(hz * frame_size(getattr(mavlink, f"MAVLink_{stream.lower()}_message"), signed)
                 for stream, hz in link.rates_hz)
    return needed, line_bytes_per_s(link.serial.baud)


class _StreamLink(OneStream):
    """A link on a byte stream: the stream it currently has (the serial line, or the TCP
    server's one client; others are refused) with its framer, and the server."""

    def __init__(self, name: str = "offboard link") -> None:
        super().__init__(name)
        self.server: asyncio.base_events.Server | None = None

    @property
    def peer(self) -> tuple[str, int] | None:
        s = self.stream
        return s.peer if isinstance(s, TcpStream) else None

    def write(self, data: bytes) -> None:
        if self.connected:
            self.stream.write(data)

    def write_frames(self, frames: list[bytes]) -> None:
        """Frames of one instant: on a paced line one by one (each arrives when its own last
        byte is through, as on a UART), else in one write."""
        if getattr(self.stream, "pacer", None) is None:
            self.write(b"".join(frames))
            return
        for frame in frames:
            self.write(frame)


def _expire(answer: asyncio.Future) -> None:
    """The lockstep wait's timer: no answer in time (result None)."""
    if not answer.done():
        answer.set_result(None)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, daemon: "VehicleDaemon", link: str) -> None:
        self.daemon, self.link = daemon, link

    def datagram_received(self, data: bytes, addr) -> None:
        try:
            self.daemon.on_datagram(self.link, data, addr)
        except Exception:  # a daemon never dies on traffic: log it and go on
            log.exception("error while handling a datagram on %s from %s", self.link, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable when nobody listens on a target: normal for a SITL
        pass


class VehicleDaemon:
    def __init__(self, sim: SimParams, log_dir: Path | None, *,
                 monotonic=time.monotonic, wall_us=lambda: time.time_ns() // 1000,
                 signing_key: bytes | None = None, allow_unsigned_gcs: bool = False) -> None:
        self.sim = sim
        self.log_dir = log_dir
        self.flight_log = None
        self.tlog = None
        self.sitl = Sitl(sim)
        if log_dir is not None:
            meta = {"vehicle": sim.vehicle.name, "vehicle_file": sim.vehicle.file,
                    "sim_file": sim.file, "seed": sim.seed, "physics_rate_hz": sim.physics_rate_hz,
                    "physics_core": self.sitl.vehicle.core_name,
                    "clock": sim.clock_mode, "frames": "world NED, body FRD, quaternion wxyz"}
            if sim.senses:           # under truth the header stays as it has always been
                meta["sensing"] = sim.sensing.file
            self.flight_log = CsvLog(log_dir / "flight.csv", self.sitl.log_columns, meta,
                                     flush_every=max(1, sim.log_rate_hz))
            self.tlog = Tlog(log_dir / "vehicle.tlog")
            self.sitl.log_sink = self.flight_log
        self.codecs = {name: Codec(counters=self.sitl.counters[name]) for name in LINKS}
        # other senders the vehicle process hosts (the simulated mocap PC): their own system
        # and component ids and sequence numbers, on the link's port
        self._source_codecs: dict[tuple[str, tuple[int, int]], Codec] = {}
        self._signing_key = signing_key
        self.signed = signing_key is not None
        if signing_key is not None:
            for link_id, name in enumerate(LINKS):
                codec = self.codecs[name]
                codec.check = SignatureCheck(
                    signing_key, allow_unsigned_read_only=allow_unsigned_gcs and name == "gcs")
                sign_outgoing(codec.mav, signing_key, link_id)
        self.transports: dict[str, asyncio.DatagramTransport] = {}
        self.streams: dict[str, _StreamLink] = {}      # links on a serial line or TCP
        # per link: address -> wall time of its last valid message (insertion-ordered)
        self.peers: dict[str, dict[tuple[str, int], float]] = {name: {} for name in LINKS}
        self._answer: asyncio.Future | None = None   # resolved when the lockstep target arrives
        self._stop = asyncio.Event()
        self._monotonic = monotonic
        self._wall_us = wall_us
        self._start_wall_us = wall_us()
        self.exit_reason = ""
        self.free_runs = 0
        self.routed = {name: 0 for name in LINKS}     # frames forwarded onto each link

    def _log_us(self) -> int:
        """The .tlog's stamp: in lockstep the start's wall time plus the simulated time (so a
        log viewer shows the flight on its own timeline, as PX4's lockstep logs do, however
        long the run took); in real time the wall clock."""
        if self.sim.clock_mode == "lockstep":
            return self._start_wall_us + self.sitl.t_us
        return self._wall_us()

    # --- transport -------------------------------------------------------------------------
    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        for link in self.sim.links:
            if link.transport != "udp":
                await self._open_stream(link)
                continue
            transport, _ = await loop.create_datagram_endpoint(
                lambda name=link.name: _Protocol(self, name),
                local_addr=(link.bind.host, link.bind.port))
            self.transports[link.name] = transport
            if link.bind.host not in ("127.0.0.1", "localhost", "::1") and not self.signed:
                log.warning("link %s bound to %s without a signing key: anyone on the network "
                            "can command the vehicle (use --signing-key-file)", link.name,
                            link.bind)

    async def _open_stream(self, link: LinkParams) -> None:
        loop = asyncio.get_running_loop()
        sl = self.streams[link.name] = _StreamLink(f"{link.name} link")
        on_bytes = lambda data, name=link.name: self._on_stream_bytes(name, data)  # noqa: E731
        if link.serial is not None:
            port = link.serial
            needed, available = serial_budget(link, self.signed)
            line = (f"{link.name} link serial {port.device} at {port.baud} baud: {needed} B/s "
                    f"needed of {available} ({100.0 * needed / available:.0f} %)")
            print(line, flush=True)
            if needed > SERIAL_WARN_FRACTION * available:
                log.warning("%s: more than %.0f %% of the line; in real time the telemetry "
                            "will queue (latency) as on hardware", line,
                            100 * SERIAL_WARN_FRACTION)
            # real time: writes leave at the line's rate; lockstep: the link is transparent
            pacer = (LinePacer(available, lambda: round(self._monotonic() * NS_PER_S))
                     if self.sim.clock_mode == "realtime" else None)
            sl.stream = SerialStream(port.device, port.baud, on_bytes, pacer=pacer,
                                     on_lost=lambda: log.warning(
                                         "%s link: serial %s went away", link.name, port.device))
            sl.stream.open()
            return

        sl.server = await loop.create_server(lambda: TcpStream(on_bytes, sl.made, sl.lost),
                                             link.tcp.host, link.tcp.port)
        if link.tcp.host not in ("127.0.0.1", "localhost", "::1") and not self.signed:
            log.warning("link %s serves TCP on %s without a signing key: anyone on the "
                        "network can command the vehicle (use --signing-key-file)", link.name,
                        link.tcp)

    def bound(self, link: str) -> tuple[str, int] | None:
        """The address a UDP link or a TCP server listens on (None for a serial line)."""
        if link in self.streams:
            server = self.streams[link].server
            return None if server is None else server.sockets[0].getsockname()[:2]
        return self.transports[link].get_extra_info("sockname")[:2]

    def send(self, outgoing: list[Outgoing]) -> None:
        """Encode and send; the frames of one call that go to the same address share datagrams
        (up to MAX_DATAGRAM bytes), as MAVLink over UDP allows: far fewer system calls on both
        sides of a lockstep exchange."""
        batches: dict[tuple[str, tuple[str, int]], list[bytes]] = {}
        live: dict[str, list[tuple[str, int]]] = {}
        streamed: dict[str, list[bytes]] = {}
        for item in outgoing:
            on_stream = item.link in self.streams
            if not on_stream and item.link not in self.transports:
                continue
            data = (self.codecs[item.link] if item.source is None
                    else self._source_codec(item.link, item.source)).encode(item.msg)
            if self.tlog:
                self.tlog.write(self._log_us(), data)
            if on_stream:                 # one peer, the stream: in order
                streamed.setdefault(item.link, []).append(data)
                continue
            if item.to is not None:
                dests = [item.to]
            else:
                if item.link not in live:
                    live[item.link] = self._live_peers(item.link)
                target = self.sim.link(item.link).target
                dests = list(dict.fromkeys([(target.host, target.port), *live[item.link]]))
            for dest in dests:
                batches.setdefault((item.link, dest), []).append(data)
        for (link, dest), frames in batches.items():
            transport = self.transports[link]
            chunk = b""
            for frame in frames:
                if chunk and len(chunk) + len(frame) > MAX_DATAGRAM:
                    transport.sendto(chunk, dest)
                    chunk = b""
                chunk += frame
            if chunk:
                transport.sendto(chunk, dest)
        for link, frames in streamed.items():
            self.streams[link].write_frames(frames)

    def _source_codec(self, link: str, source: tuple[int, int]) -> Codec:
        codec = self._source_codecs.get((link, source))
        if codec is None:
            codec = Codec(*source)
            if self._signing_key is not None:
                sign_outgoing(codec.mav, self._signing_key, LINKS.index(link))
            self._source_codecs[(link, source)] = codec
        return codec

    def _live_peers(self, link: str) -> list[tuple[str, int]]:
        peers = self.peers[link]
        if not peers:
            return []
        now = self._monotonic()
        return [a for a, t in peers.items() if now - t <= PEER_TIMEOUT_S]

    def _heard(self, link: str, addr: tuple[str, int]) -> None:
        """A valid (and, with a key, authenticated) message came from addr: it gets the link's
        telemetry until it has been silent for PEER_TIMEOUT_S. Garbage makes nobody a peer;
        a full table makes room by dropping its longest-silent peer, so that junk senders can
        never lock a ground station out."""
        now = self._monotonic()
        peers = self.peers[link]
        peers.pop(addr, None)
        for old in [a for a, t in peers.items() if now - t > PEER_TIMEOUT_S]:
            del peers[old]
        if len(peers) >= MAX_PEERS:
            del peers[min(peers, key=peers.get)]
        peers[addr] = now

    def on_datagram(self, link: str, data: bytes, addr) -> None:
        addr = tuple(addr[:2])
        msgs = self.codecs[link].decode(data)
        if msgs:
            self._heard(link, addr)
        self._on_messages(link, msgs, addr)

    def _on_stream_bytes(self, link: str, data: bytes) -> None:
        """A read of a stream link: the framer's whole, checksummed frames go through the codec
        (signing, counters) as one datagram would; what the framer skipped counts as bad
        frames, as a datagram's garbage does."""
        try:
            sl = self.streams[link]
            frames, skipped = sl.frames(data)
            codec = self.codecs[link]
            codec.counters.bad_frames += skipped
            self._on_messages(link, codec.decode(b"".join(frames)), sl.peer)
        except Exception:  # a daemon never dies on traffic: log it and go on
            log.exception("error while handling bytes on %s", link)

    def _on_messages(self, link: str, msgs: list, addr) -> None:
        for msg in msgs:
            frame = bytes(msg.get_msgbuf())
            if self.tlog:
                self.tlog.write(self._log_us(), frame)
            self.send(self.sitl.handle(link, msg, addr))
            self.route(link, msg, frame)
        if self.sitl.answered and self._answer is not None and not self._answer.done():
            self._answer.set_result(True)

    def route(self, link: str, msg, frame: bytes) -> None:
        """Forward between the links what is not the vehicle's alone, as an autopilot routes
        for its companion computer: from the offboard link to the ground station every
        message not addressed to the vehicle (the controller's HEARTBEAT, NAMED_VALUE_FLOAT,
        STATUSTEXT: broadcasts, or addressed to another component or system); from the ground
        station to the offboard link only what is addressed to another component of this
        system (a ground station's own broadcasts, its HEARTBEAT above all, would read to a
        controller as the vehicle's). Never back onto the link it came from; the frame as it
        came (its sender and signature); with a signing key, only signed frames (the codec has
        already refused the others on the offboard link; the ground station's unsigned
        read-only requests stay here)."""
        system, component = getattr(msg, "target_system", 0), getattr(msg, "target_component", 0)
        if link == "offboard":
            to = "gcs"
            if (system, component) == (SYSTEM_ID, COMPONENT_ID):
                return                                  # the vehicle's alone
        else:
            to = "offboard"
            if system != SYSTEM_ID or component in (0, COMPONENT_ID):
                return
        if self.signed and not (frame[0] == MAVLINK2_MAGIC and frame[2] & IFLAG_SIGNED):
            return
        if to in self.streams:
            self.streams[to].write(frame)
            self.routed[to] += 1
            return
        if to not in self.transports:
            return
        peer = self.sim.link(to).target
        for dest in dict.fromkeys([(peer.host, peer.port), *self._live_peers(to)]):
            self.transports[to].sendto(frame, dest)
        self.routed[to] += 1

    # --- loops -----------------------------------------------------------------------------
    def stop(self, reason: str = "stopped") -> None:
        self.exit_reason = self.exit_reason or reason
        self._stop.set()
        if self._answer is not None and not self._answer.done():
            self._answer.set_result(False)

    async def run(self, duration_s: float | None = None) -> None:
        await self.open()
        end_us = None if duration_s is None else int(duration_s * 1e6)
        try:
            self.send(self.sitl.telemetry_due())
            if self.sim.clock_mode == "lockstep":
                await self._lockstep(end_us)
            else:
                await self._realtime(end_us)
        finally:
            self.close()

    async def _lockstep(self, end_us: int | None) -> None:
        """Wait for the answer to the latest stamp, then advance one period. With no answer
        for `free_run_after_s` of wall time, time runs on in real time (so that the vehicle's
        offboard failsafe can act on a dead controller) until an answer arrives again."""
        sitl = self.sitl
        loop = asyncio.get_running_loop()
        period_s = sitl.lockstep_ticks() * self.sim.dt_us * 1e-6 / self.sim.speed_up
        free_run = False
        while not self._stop.is_set():
            waited = 0.0
            while not sitl.answered and not self._stop.is_set():
                # a bare future and one timer (no task, no wait_for): this exchange runs
                # hundreds of times a second. Its result: True answered, False stopped, None
                # the timer ran out
                answer = self._answer = loop.create_future()
                wall0 = self._monotonic()
                timer = loop.call_later(period_s if free_run else self.sim.resend_s,
                                        _expire, answer)
                try:
                    await answer
                finally:
                    timer.cancel()
                    self._answer = None
                if answer.result() is None:
                    waited += self._monotonic() - wall0
                    if free_run:
                        break              # no controller: one period in real time
                    self.send(sitl.telemetry_due(everything=True, resend=True))
                    # only a controller that was there and went away: before the first
                    # answer the vehicle waits (a controller may take seconds to build)
                    if waited >= self.sim.free_run_after_s and sitl.had_offboard:
                        free_run = True
                        self.free_runs += 1
                        self.send(sitl.announce(6, "no offboard answer: time runs in real time"))
            if self._stop.is_set():
                break
            if free_run and sitl.answered:
                free_run = False           # the controller is back: lockstep again
                self.send(sitl.announce(6, "offboard answers again: lockstep"))
            # one period's telemetry leaves together (in order, packed into as few datagrams as
            # fit): in lockstep nothing waits for it before the period's last ODOMETRY anyway
            out: list = []
            for _ in range(sitl.lockstep_ticks()):
                out += sitl.step()
            self.send(out)
            if end_us is not None and sitl.t_us >= end_us:
                self.stop("duration reached")
            if sitl.answered:
                # no stamp left this period (a lost or delayed ODOMETRY): let the loop breathe
                # before the next period; otherwise the wait for the answer yields anyway
                await asyncio.sleep(0)

    async def _realtime(self, end_us: int | None) -> None:
        sitl = self.sitl
        pacer = RealTimePacer(self.sim.speed_up, self._monotonic)
        pacer.start(sitl.t_us)
        dt = self.sim.dt_us
        while not self._stop.is_set():
            due = pacer.due_us()
            batch = 0
            while sitl.t_us + dt <= due and batch < 200:
                self.send(sitl.step())
                batch += 1
            if end_us is not None and sitl.t_us >= end_us:
                self.stop("duration reached")
                break
            await asyncio.sleep(max(0.0, pacer.wait_s(sitl.t_us + dt)))

    def close(self) -> None:
        for transport in self.transports.values():
            transport.close()
        for sl in self.streams.values():
            if sl.stream is not None:
                sl.stream.close()
            if sl.server is not None:
                sl.server.close()
        if self.flight_log:
            self.flight_log.close()
        if self.tlog:
            self.tlog.close()


# --- command line ------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="trq-sil-vehicle",
        description="SIL tilt-rotor (or fixed-rotor) vehicle speaking MAVLink 2 over UDP like a "
                    "PX4 SITL autopilot (system 1, component 1). See sil_vehicle/PROTOCOL.md.")
    p.add_argument("--sim", default="default",
                   help="simulation settings: a built-in name (default) or a YAML path")
    p.add_argument("--vehicle", default=None,
                   help="airframe, overriding the one the settings name: a built-in name "
                        "(trq, quad) or a YAML path")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default=None,
                   help="clock mode (default: from the settings)")
    p.add_argument("--speed-up", type=float, default=None,
                   help="real time only: simulated seconds per wall second")
    p.add_argument("--seed", type=int, default=None, help="random seed (gusts, sensor noise)")
    p.add_argument("--sensing", default=None, metavar="NAME|PATH",
                   help="the sensors the vehicle carries: a sensing profile by built-in name ("
                        + ", ".join(trq_params.names("sensing")) + ") or a YAML path (default: "
                        "the sim file's, truth: no sensor, the state stream alone)")
    p.add_argument("--physics-core", choices=("auto", "compiled", "python"), default=None,
                   help="the physics tick: compiled C (built once, cached) or the Python "
                        "reference; bit-identical results (default: the sim file's, auto)")
    p.add_argument("--gcs-bind", default=None, help="HOST:PORT the ground-station link listens on "
                   "(default 127.0.0.1:18570)")
    p.add_argument("--gcs-target", default=None, help="HOST:PORT telemetry is sent to "
                   "(default 127.0.0.1:14550, QGroundControl)")
    p.add_argument("--offboard-bind", default=None, help="HOST:PORT the offboard link listens on "
                   "(default 127.0.0.1:14580)")
    p.add_argument("--offboard-target", default=None, help="HOST:PORT of the offboard controller "
                   "(default 127.0.0.1:14540)")
    stream = p.add_mutually_exclusive_group()
    stream.add_argument("--offboard-serial", default=None, metavar="DEVICE[:BAUD]",
                        help="serve the offboard link on this serial device instead of UDP, "
                             "8N1 at BAUD (default 921600); in real time writes are paced at "
                             "the line's rate (the controller: --connect serial://DEVICE:BAUD)")
    stream.add_argument("--offboard-tcp", default=None, metavar="HOST:PORT",
                        help="serve the offboard link as a TCP server on HOST:PORT instead of "
                             "UDP, one client at a time (the controller: --connect tcp:HOST:PORT)")
    p.add_argument("--wind-speed", type=float, default=None, help="mean wind speed, m/s")
    p.add_argument("--wind-dir", type=float, default=None,
                   help="direction the wind blows from, deg clockwise from north")
    p.add_argument("--signing-key-file", type=Path, default=None,
                   help="MAVLink 2 signing: a file with the 32-byte secret as 64 hex characters; "
                        "then only correctly signed, fresh messages are obeyed")
    p.add_argument("--allow-unsigned-gcs", action="store_true",
                   help="with a key: still serve unsigned read-only requests (heartbeat, "
                        "parameter reads) on the ground-station link")
    p.add_argument("--gusts", action="store_true", help="turn Dryden gusts on")
    p.add_argument("--faults", default=None,
                   help="fault script played in vehicle time: a built-in name (motor1_50, ...) "
                        "or a YAML path")
    p.add_argument("--log-dir", type=Path, default=None,
                   help="directory for flight.csv and vehicle.tlog (default: logs/vehicle-<time>)")
    p.add_argument("--no-log", action="store_true", help="write no logs")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many simulated seconds (default: run until signalled)")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


# option -> (SimParams field, lowest, highest, what the range means)
_NUMERIC_OVERRIDES = {"speed_up": ("speed_up", 0.01, 1000.0, "a number in [0.01, 1000]"),
                      "seed": ("seed", 0, math.inf, "an integer >= 0"),
                      "wind_speed": ("wind_speed_m_s", 0.0, 40.0, "[0, 40] m/s"),
                      "wind_dir": ("wind_from_deg", -360.0, 360.0, "[-360, 360] deg")}


def apply_overrides(sim: SimParams, args: argparse.Namespace) -> SimParams:
    changes: dict[str, object] = {}
    if args.mode:
        changes["clock_mode"] = args.mode
    if args.physics_core is not None:
        changes["physics_core"] = args.physics_core
    if getattr(args, "sensing", None) is not None:
        changes["sensing"] = sensing_profile(args.sensing, sim.physics_rate_hz,
                                             "command line", "--sensing")
    for option, (field, lo, hi, expected) in _NUMERIC_OVERRIDES.items():
        value = getattr(args, option)
        if value is None:
            continue
        if not lo <= value <= hi:
            raise ConfigError(f"--{option.replace('_', '-')}: got {value}, expected {expected}")
        changes[field] = value
    if args.gusts:
        changes["gusts_enabled"] = True
    links = []
    for link in sim.links:
        updates = {}
        for end in ("bind", "target"):
            text = getattr(args, f"{link.name}_{end}")
            if text is not None:
                updates[end] = parse_endpoint(text, f"command line: --{link.name}-{end}")
        if getattr(args, f"{link.name}_serial", None) is not None:
            updates["serial"] = parse_serial(getattr(args, f"{link.name}_serial"),
                                             f"command line: --{link.name}-serial")
        if getattr(args, f"{link.name}_tcp", None) is not None:
            updates["tcp"] = parse_endpoint(getattr(args, f"{link.name}_tcp"),
                                            f"command line: --{link.name}-tcp")
        links.append(dataclasses.replace(link, **updates))
    changes["links"] = tuple(links)
    return sim.with_changes(**changes)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        sim = apply_overrides(load_sim(trq_params.resolve("sim", args.sim),
                                       None if args.vehicle is None else
                                       trq_params.resolve("vehicle", args.vehicle)), args)
        events = ()
        if args.faults is not None:
            vp = sim.vehicle
            events = load_script(trq_params.resolve("faults", args.faults),
                                 (math.degrees(vp.tilt_min_rad), math.degrees(vp.tilt_max_rad)))
        key = load_key(args.signing_key_file) if args.signing_key_file else None
    except (ConfigError, SigningKeyError, trq_params.UnknownName) as exc:
        print(f"trq-sil-vehicle: {exc}", file=sys.stderr)
        return 2
    log_dir = None
    if not args.no_log:
        log_dir = args.log_dir or Path(sim.log_dir) / time.strftime("vehicle-%Y%m%d-%H%M%S")
    daemon = VehicleDaemon(sim, log_dir, signing_key=key,
                           allow_unsigned_gcs=args.allow_unsigned_gcs)
    daemon.sitl.schedule(events)

    signalled: list[int] = []

    def on_signal(sig: int) -> None:
        signalled.append(sig)
        # the process ends: an armed vehicle is disarmed (it would fall anyway), said in the log
        if daemon.sitl.vehicle.armed:
            daemon.sitl.vehicle.force_disarm()
            daemon.send(daemon.sitl.announce(2, f"{signal.Signals(sig).name}: disarmed"))
        daemon.stop(signal.Signals(sig).name)

    async def _main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, on_signal, sig)
        await daemon.run(args.duration)

    try:
        asyncio.run(_main())
    except OSError as exc:
        print(f"trq-sil-vehicle: cannot open a link: {exc}", file=sys.stderr)
        return 1
    s = daemon.sitl.state
    print(f"trq-sil-vehicle: {daemon.exit_reason or 'stopped'} at t={s.t_us / 1e6:.2f} s, "
          f"{'crashed: ' + s.crash_reason if s.crashed else 'no crash'}, "
          f"{daemon.sitl.targets_applied} targets applied, "
          f"dropped {sum(c.dropped for c in daemon.sitl.counters.values())} messages "
          f"({sum(c.unauthenticated for c in daemon.sitl.counters.values())} unauthenticated, "
          f"{sum(c.bad_frames for c in daemon.sitl.counters.values())} malformed)"
          + (f", logs in {log_dir}" if log_dir else ""))
    # the exit status says what happened: 0 the duration ran out, 128 + N stopped by signal N
    return 128 + signalled[0] if signalled else 0


if __name__ == "__main__":
    sys.exit(main())
