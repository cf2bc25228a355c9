"""Byte-stream transports for asyncio, shared by the vehicle and the controller: a serial line
(opened and configured by pyserial, then driven on the event loop with `add_reader` and
non-blocking writes: no thread per message) and a TCP connection (asyncio's own transport).

Both deliver what arrives to `on_bytes(data)` as it comes (frames may be split: a
trq_wire.framing.StreamFramer makes frames of it) and take bytes with `write(data)`. A serial
line may be paced (trq_wire.framing.LinePacer): its writes then leave at the line's rate.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import os
from typing import Callable

from trq_wire.framing import NS_PER_S, LinePacer, StreamFramer

log = logging.getLogger("trq_wire.stream")

MAX_BACKLOG = 1 << 20      # bytes a stalled reader may leave in our write buffer before drops
READ_SIZE = 65536


class SerialStream:
    """A serial device (a UART, a USB serial adapter, one end of a pty pair) at `baud`, 8N1, raw.
    A read error (the device went away) closes it and calls `on_lost`. POSIX (the event loop
    watches the device's file descriptor), as on a companion computer's Linux."""

    def __init__(self, device: str, baud: int, on_bytes: Callable[[bytes], None], *,
                 pacer: LinePacer | None = None, on_lost: Callable[[], None] | None = None
                 ) -> None:
        self.device, self.baud = device, baud
        self.on_bytes = on_bytes
        self.on_lost = on_lost
        self.pacer = pacer
        self._port = None
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._out = bytearray()
        self._writing = False
        self._flush_timer: asyncio.TimerHandle | None = None
        self.bytes_in = self.bytes_out = self.dropped_bytes = 0

    @property
    def connected(self) -> bool:
        return self._fd is not None

    def open(self) -> None:
        import serial  # pyserial: opening and configuring the port (termios)

        self._loop = asyncio.get_running_loop()
        try:
            self._port = serial.Serial(self.device, self.baud, bytesize=serial.EIGHTBITS,
                                       parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                       timeout=0, write_timeout=0)
        except (serial.SerialException, ValueError) as exc:
            raise OSError(f"serial {self.device} at {self.baud} baud: {exc}") from None
        self._fd = self._port.fileno()
        os.set_blocking(self._fd, False)
        self._loop.add_reader(self._fd, self._readable)

    def close(self) -> None:
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
            if self._writing:
                self._loop.remove_writer(self._fd)
        if self._flush_timer is not None:
            self._flush_timer.cancel()
            self._flush_timer = None
        self._fd, self._writing = None, False
        self._out.clear()
        if self._port is not None:
            self._port.close()
            self._port = None

    def _readable(self) -> None:
        try:
            data = os.read(self._fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:            # EIO: the other end of a pty closed; a USB unplug
            log.warning("serial %s: %s", self.device, exc)
            self._lost()
            return
        if not data:
            return
        self.bytes_in += len(data)
        self.on_bytes(data)

    def _lost(self) -> None:
        self.close()
        if self.on_lost is not None:
            self.on_lost()

    # --- writing ---------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        if self._fd is None or not data:
            return
        if self.pacer is None:
            self._write_now(data)
            return
        if self.pacer.queued_bytes + len(data) > self.pacer.bytes_per_s:
            self.dropped_bytes += len(data)    # a second of the line is queued: the buffer
            return                             # is full, as a UART driver's overflows
        # what is due by now leaves now, even while the caller keeps the loop busy (a vehicle
        # catching up several ticks); the timer covers the rest
        due = self.pacer.due()
        if due:
            self._write_now(due)
        self.pacer.push(data)
        if self._flush_timer is None:
            self._flush()

    def _flush(self) -> None:
        """Write what the paced line has carried by now; come back when the next is due."""
        self._flush_timer = None
        if self._fd is None:
            return
        data = self.pacer.due()
        if data:
            self._write_now(data)
        wait_ns = self.pacer.wait_ns()
        if wait_ns is not None and self._flush_timer is None:
            self._flush_timer = self._loop.call_later(wait_ns / NS_PER_S, self._flush)

    def _write_now(self, data: bytes) -> None:
        if self._out:
            if len(self._out) + len(data) > MAX_BACKLOG:
                self.dropped_bytes += len(data)       # nobody reads: a real UART drops too
                return
            self._out += data
            return
        try:
            n = os.write(self._fd, data)
        except (BlockingIOError, InterruptedError):
            n = 0
        except OSError as exc:
            if exc.errno != errno.EAGAIN:
                log.warning("serial %s: %s", self.device, exc)
                self._lost()
                return
            n = 0
        self.bytes_out += n
        if n < len(data):
            self._out += data[n:]
            if not self._writing:
                self._loop.add_writer(self._fd, self._writable)
                self._writing = True

    def _writable(self) -> None:
        try:
            n = os.write(self._fd, self._out)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            log.warning("serial %s: %s", self.device, exc)
            self._lost()
            return
        self.bytes_out += n
        del self._out[:n]
        if not self._out:
            self._loop.remove_writer(self._fd)
            self._writing = False


class TcpStream(asyncio.Protocol):
    """One TCP connection's bytes to `on_bytes`; `on_lost` when it ends."""

    def __init__(self, on_bytes: Callable[[bytes], None],
                 on_made: Callable[["TcpStream"], None] | None = None,
                 on_lost: Callable[["TcpStream"], None] | None = None) -> None:
        self.on_bytes, self.on_made, self.on_lost = on_bytes, on_made, on_lost
        self.transport: asyncio.Transport | None = None
        self.peer: tuple[str, int] | None = None
        self.bytes_in = self.bytes_out = 0

    @property
    def connected(self) -> bool:
        return self.transport is not None and not self.transport.is_closing()

    def connection_made(self, transport) -> None:
        self.transport = transport
        self.peer = tuple(transport.get_extra_info("peername")[:2])
        if self.on_made is not None:
            self.on_made(self)

    def data_received(self, data: bytes) -> None:
        self.bytes_in += len(data)
        self.on_bytes(data)

    def connection_lost(self, exc) -> None:
        if self.on_lost is not None:
            self.on_lost(self)
        self.transport = None

    def write(self, data: bytes) -> None:
        if self.connected:
            self.transport.write(data)
            self.bytes_out += len(data)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


class OneStream:
    """The one stream a link holds at a time (a serial line, a TCP server's client, a TCP
    client's connection) and its framer. While one is connected another TCP connection is
    refused: closed at once, without its `on_lost`, and counted in `refused`. A connection
    taken on starts a fresh StreamFramer (a new byte stream). `name` labels the log lines."""

    def __init__(self, name: str = "link") -> None:
        self.name = name
        self.stream: SerialStream | TcpStream | None = None
        self.framer = StreamFramer()
        self.refused = 0

    @property
    def connected(self) -> bool:
        return self.stream is not None and self.stream.connected

    def made(self, stream: TcpStream) -> bool:
        """A TCP connection came up: taken on (True), or refused while another is open."""
        if self.connected:
            log.warning("%s: refused a connection from %s:%d (%s:%d is connected)",
                        self.name, *stream.peer, *self.stream.peer)
            self.refused += 1
            stream.on_lost = None
            stream.close()
            return False
        log.info("%s: connected to %s:%d", self.name, *stream.peer)
        self.stream, self.framer = stream, StreamFramer()
        return True

    def lost(self, stream: TcpStream) -> None:
        """A TCP connection ended: forgotten if it was the one held."""
        if stream is self.stream:
            log.info("%s: %s:%d went away", self.name, *stream.peer)
            self.stream = None

    def frames(self, data: bytes) -> tuple[list[bytes], int]:
        """The whole frames `data` completes, and how many runs of bytes it made the framer
        skip (counted as bad, as a datagram's garbage is)."""
        bad_before = self.framer.bad
        frames = self.framer.feed(data)
        return frames, self.framer.bad - bad_before
