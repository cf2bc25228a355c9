"""The controller's link over a byte stream, for asyncio (connection strings: trq_wire.connection):

    serial://DEVICE:BAUD   a serial line to the flight controller (a UART, a USB adapter)
    tcpout://HOST:PORT     connect to the vehicle's TCP server; reconnect if it goes away
    tcpin://HOST:PORT      accept the vehicle's connection: one at a time, a second is refused
                           while the first is open

The same object as the UDP link for OffboardFlight (open, close, send, on_message, on_frame,
stats, signing, the system-1 filter). One persistent parser (trq_wire.framing.StreamFramer)
makes frames of the stream: it re-synchronises after garbage or a cut; skipped runs count as
bad, as a datagram's garbage does on UDP. The vehicle's telemetry frames are unpacked by
trq_wire.frames (one struct each), every other frame by pymavlink's decode.
"""

from __future__ import annotations

import asyncio
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.link.endpoint import MavlinkEndpoint, log
from trq_wire import frames
from trq_wire.connection import Connection
from trq_wire.stream import OneStream, SerialStream, TcpStream

RECONNECT_S = 0.5          # tcpout: wall time between attempts to reach the vehicle


class MavlinkStream(MavlinkEndpoint):
    fast_path = True           # False: every frame through pymavlink's decode (tests, benches)

    def __init__(self, connection: Connection, on_message: Callable[[object], None],
                 system_id: int = 1, component_id: int = 191,
                 signing_key: bytes | None = None, monotonic=time.monotonic) -> None:
        if not connection.is_stream:
            raise ValueError(f"MavlinkStream: {connection} is not a TCP or serial connection")
        super().__init__(connection, on_message, system_id, component_id, signing_key,
                         monotonic)
        self._rx = mavlink.MAVLink(None)
        self._one = OneStream(str(connection))     # the stream held, and its framer
        self._server: asyncio.base_events.Server | None = None
        self._connecting: asyncio.Task | None = None
        self._closed = False
        self.peer: tuple[str, int] | str | None = None

    # --- opening ---------------------------------------------------------------------------
    async def open(self) -> None:
        c = self.connection
        loop = asyncio.get_running_loop()
        if c.mode == "serial":
            stream = SerialStream(c.device, c.baud, self.bytes_received, on_lost=self._serial_lost)
            stream.open()
            self._one.stream, self.peer = stream, c.device
        elif c.mode == "tcpin":
            self._server = await loop.create_server(
                lambda: TcpStream(self.bytes_received, self._accepted, self._disconnected),
                c.host, c.port)
        else:
            self._connecting = asyncio.ensure_future(self._connect())

    async def _connect(self) -> None:
        """tcpout: reach the vehicle's server, and again whenever the connection ends."""
        loop = asyncio.get_running_loop()
        c = self.connection
        warned = False
        while not self._closed:
            if not self._one.connected:
                try:
                    await loop.create_connection(
                        lambda: TcpStream(self.bytes_received, self._accepted,
                                          self._disconnected), c.host, c.port)
                except OSError as exc:
                    if not warned:
                        log.info("%s: %s; trying again every %g s", c, exc, RECONNECT_S)
                        warned = True
            await asyncio.sleep(RECONNECT_S)

    def _accepted(self, stream: TcpStream) -> None:
        if self._one.made(stream):
            self.peer = stream.peer
        else:
            self.stats.other_peer += 1

    def _disconnected(self, stream: TcpStream) -> None:
        self._one.lost(stream)

    def _serial_lost(self) -> None:
        log.warning("%s: the serial device went away", self.connection)
        self._one.stream = None

    def close(self) -> None:
        self._closed = True
        if self._connecting is not None:
            self._connecting.cancel()
        if self._one.stream is not None:
            self._one.stream.close()
            self._one.stream = None
        if self._server is not None:
            self._server.close()

    # --- bytes in and out ------------------------------------------------------------------
    def bytes_received(self, data: bytes) -> None:
        self.stats.datagrams += 1
        found, skipped = self._one.frames(data)
        self.stats.bad += skipped
        for frame in found:
            msg = frames.decode(frame, self.wanted) if self.fast_path else None
            if msg is None:
                try:
                    msg = self._rx.decode(bytearray(frame))
                except Exception:  # the framer checked the checksum; a payload may be odd
                    self.stats.bad += 1
                    continue
            if self._trusted(msg):
                self._deliver(msg)

    @property
    def ready(self) -> bool:
        return self._one.connected

    def _write(self, data: bytes) -> bool:
        self._one.stream.write(data)
        return True
