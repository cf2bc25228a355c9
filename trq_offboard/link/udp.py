"""The controller's link over UDP, for asyncio (connection strings: trq_wire.connection):

    udpin:HOST:PORT    listen on HOST:PORT; answer the vehicle that sends (PX4's offboard API
                       port 14540): the first sender of a valid system-1 message, locked while
                       it talks (PEER_TIMEOUT_S)
    udpout:HOST:PORT   send to HOST:PORT from an ephemeral port

Incoming datagrams are parsed frame by frame (a fresh parse per datagram: frames never span
datagrams, and garbage in one datagram cannot corrupt the next) and handed to a callback. The
frames of the vehicle's telemetry at the start of a datagram are unpacked by trq_wire.frames
(one struct each, into pymavlink's own message objects); pymavlink's parser takes whatever that
path does not vouch for, from there to the datagram's end, so counters and refusals are its.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.link.endpoint import LinkStats, MavlinkEndpoint, log
from trq_wire import frames
from trq_wire.connection import Connection

__all__ = ["Connection", "LinkStats", "MavlinkUdp", "PEER_TIMEOUT_S"]

PEER_TIMEOUT_S = 2.0       # udpin: silence after which another address may become the peer


def parse_datagram(data: bytes) -> list:
    """pymavlink's parse of one datagram (a fresh parser): messages, MAVLink_bad_data for
    garbage and refused frames, MAVLink_unknown for ids outside the dialect. Raises on what
    even its robust parsing cannot take."""
    rx = mavlink.MAVLink(None)
    rx.robust_parsing = True
    return rx.parse_buffer(data) or []


class MavlinkUdp(MavlinkEndpoint, asyncio.DatagramProtocol):
    fast_path = True           # False: every frame through pymavlink's parser (tests, benches)

    def __init__(self, connection: Connection, on_message: Callable[[object], None],
                 system_id: int = 1, component_id: int = 191,
                 signing_key: bytes | None = None, monotonic=time.monotonic) -> None:
        if connection.mode not in ("udpin", "udpout"):
            raise ValueError(f"MavlinkUdp: {connection} is not a UDP connection")
        super().__init__(connection, on_message, system_id, component_id, signing_key,
                         monotonic)
        self._peer_heard = -math.inf
        self._transport: asyncio.DatagramTransport | None = None
        self.peer: tuple[str, int] | None = (
            (connection.host, connection.port) if connection.mode == "udpout" else None)

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        c = self.connection
        local = (c.host, c.port) if c.mode == "udpin" else ("0.0.0.0", 0)
        self._transport, _ = await loop.create_datagram_endpoint(lambda: self, local_addr=local)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    def datagram_received(self, data: bytes, addr) -> None:
        self.stats.datagrams += 1
        # the fast path's messages are whole, checked frames of the dialect; pymavlink's may be
        # garbage or unknown ids
        msgs, done = frames.decode_leading(data, self.wanted) if self.fast_path else ([], 0)
        if done < len(data):
            try:
                parsed = parse_datagram(data[done:] if done else data)
            except Exception:  # malformed traffic never stops the controller
                self.stats.bad += 1
                return
            for msg in parsed:
                if isinstance(msg, mavlink.MAVLink_bad_data) or msg.get_type() == "UNKNOWN":
                    self.stats.bad += 1
                else:
                    msgs.append(msg)
        # whether the sender is the peer: asked once a datagram, at its first trusted message
        peer = None if self.connection.mode == "udpin" else True
        for msg in msgs:
            if not self._trusted(msg):
                continue
            if peer is None:
                peer = self._from_peer(tuple(addr[:2]))
            if not peer:
                self.stats.other_peer += 1
                continue
            self._deliver(msg)

    def _from_peer(self, addr: tuple[str, int]) -> bool:
        """udpin: the first sender of a valid system-1 message becomes the peer (where the
        commands go) and stays it while it talks; another address takes over only after the
        peer has been silent for PEER_TIMEOUT_S (a vehicle restarted on another port), so a
        second sender cannot divert the commands or feed states from elsewhere."""
        now = self._monotonic()
        if self.peer is not None and addr != self.peer \
                and now - self._peer_heard <= PEER_TIMEOUT_S:
            return False
        if addr != self.peer:
            log.info("vehicle peer is %s:%d", *addr)
        self.peer, self._peer_heard = addr, now
        return True

    def error_received(self, exc: Exception) -> None:
        log.debug("link error: %s", exc)

    @property
    def ready(self) -> bool:
        return self._transport is not None and self.peer is not None

    def _write(self, data: bytes) -> bool:
        self._transport.sendto(data, self.peer)
        return True
