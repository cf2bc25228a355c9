"""A MAVLink endpoint over UDP for asyncio, with connection strings as in MAVProxy / MAVSDK:

    udpin:HOST:PORT    listen on HOST:PORT; answer the vehicle that sends (PX4's offboard API
                       port 14540): the first sender of a valid system-1 message, locked while
                       it talks (PEER_TIMEOUT_S)
    udpout:HOST:PORT   send to HOST:PORT from an ephemeral port

Incoming datagrams are parsed frame by frame (a fresh parse per datagram: frames never span
datagrams, and garbage in one datagram cannot corrupt the next) and handed to a callback.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.signing import SignatureCheck, sign_outgoing

log = logging.getLogger("trq_offboard.link")

PEER_TIMEOUT_S = 2.0       # udpin: silence after which another address may become the peer


@dataclass(frozen=True)
class Connection:
    mode: str           # udpin | udpout
    host: str
    port: int

    @staticmethod
    def parse(text: str) -> "Connection":
        mode, _, rest = text.partition(":")
        host, _, port = rest.rpartition(":")
        if mode not in ("udpin", "udpout") or not host or not port.isascii() \
                or not port.isdigit() or not 1 <= int(port) <= 65535:
            raise ValueError(f"connection {text!r}: expected udpin:HOST:PORT or udpout:HOST:PORT")
        return Connection(mode, host, int(port))


@dataclass
class LinkStats:
    datagrams: int = 0
    messages: int = 0
    bad: int = 0
    sent: int = 0
    other_peer: int = 0      # udpin: valid messages from an address other than the vehicle's


class MavlinkUdp(asyncio.DatagramProtocol):
    def __init__(self, connection: Connection, on_message: Callable[[object], None],
                 system_id: int = 1, component_id: int = 191,
                 signing_key: bytes | None = None, monotonic=time.monotonic) -> None:
        self.connection = connection
        self._monotonic = monotonic
        self._peer_heard = -math.inf
        self.on_message = on_message
        self.stats = LinkStats()
        self._tx = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._verifier = SignatureCheck(signing_key) if signing_key is not None else None
        if signing_key is not None:
            sign_outgoing(self._tx, signing_key)
        self._transport: asyncio.DatagramTransport | None = None
        self.peer: tuple[str, int] | None = (
            (connection.host, connection.port) if connection.mode == "udpout" else None)
        self.on_frame: Callable[[bytes], None] | None = None   # raw frames in and out (.tlog)

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
        rx = mavlink.MAVLink(None)
        rx.robust_parsing = True
        try:
            msgs = rx.parse_buffer(data) or []
        except Exception:  # malformed traffic never stops the controller
            self.stats.bad += 1
            return
        for msg in msgs:
            if isinstance(msg, mavlink.MAVLink_bad_data) or msg.get_type() == "UNKNOWN":
                self.stats.bad += 1
                continue
            if msg.get_srcSystem() != 1:
                continue
            if self._verifier is not None and not self._verifier.accept(bytes(msg.get_msgbuf())):
                self.stats.bad += 1            # unsigned, forged or replayed: not trusted
                continue
            if self.connection.mode == "udpin" and not self._from_peer(tuple(addr[:2])):
                self.stats.other_peer += 1
                continue
            self.stats.messages += 1
            if self.on_frame:
                self.on_frame(bytes(msg.get_msgbuf()))
            try:
                self.on_message(msg)
            except Exception:
                log.exception("error handling %s", msg.get_type())

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

    def send(self, msg) -> bool:
        if self._transport is None or self.peer is None:
            return False
        data = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        self._transport.sendto(data, self.peer)
        self.stats.sent += 1
        if self.on_frame:
            self.on_frame(bytes(data))
        return True
