"""What every transport of the controller's link shares: the packer (system 1, component 191,
signing), the checks on what arrives (system 1 only; with a key, signed and fresh only), the
counters and the callbacks. A transport (udp.MavlinkUdp, stream.MavlinkStream) supplies the bytes
and writes them; OffboardFlight sees the same object whichever it is."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.mocap import MOCAP_SYSTEM_ID
from trq_wire.connection import Connection
from trq_wire.signing import SignatureCheck, sign_outgoing

log = logging.getLogger("trq_offboard.link")


@dataclass
class LinkStats:
    datagrams: int = 0       # datagrams (UDP) or reads (a stream) received
    messages: int = 0
    bad: int = 0
    sent: int = 0
    other_peer: int = 0      # valid messages from, or connections of, another peer than the vehicle


class MavlinkEndpoint:
    """The common part of a link; subclasses implement open, close and `_write(data) -> bool`."""

    def __init__(self, connection: Connection, on_message: Callable[[object], None],
                 system_id: int = 1, component_id: int = 191,
                 signing_key: bytes | None = None, monotonic=time.monotonic) -> None:
        self.connection = connection
        self._monotonic = monotonic
        self.on_message = on_message
        self.stats = LinkStats()
        self._tx = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._verifier = SignatureCheck(signing_key) if signing_key is not None else None
        if signing_key is not None:
            sign_outgoing(self._tx, signing_key)
        self.on_frame: Callable[[bytes], None] | None = None   # raw frames in and out (.tlog)
        # the message ids on_message reads (None: all): another message's frame is checked,
        # counted and handed to on_frame only, its message not built where the fast path
        # takes it (trq_wire.frames.Unread)
        self.wanted: frozenset[int] | None = None

    def _trusted(self, msg) -> bool:
        """A message of the vehicle's system or of the motion-capture system (trq_wire.mocap),
        and with a key a signed, fresh one."""
        if msg.get_srcSystem() not in (1, MOCAP_SYSTEM_ID):
            return False
        if self._verifier is not None and not self._verifier.accept(bytes(msg.get_msgbuf())):
            self.stats.bad += 1            # unsigned, forged or replayed: not trusted
            return False
        return True

    def _deliver(self, msg) -> None:
        self.stats.messages += 1
        if self.on_frame:
            self.on_frame(bytes(msg.get_msgbuf()))
        if self.wanted is not None and msg.get_msgId() not in self.wanted:
            return                         # an Unread, or a message pymavlink's path built
        try:
            self.on_message(msg)
        except Exception:
            log.exception("error handling %s", msg.get_type())

    def _write(self, data: bytes) -> bool:
        raise NotImplementedError

    def send(self, msg) -> bool:
        """Pack and send; False when there is nobody to send to yet (not connected, or udpin
        before the vehicle spoke)."""
        if not self.ready:
            return False
        data = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        if not self._write(bytes(data)):
            return False
        self.stats.sent += 1
        if self.on_frame:
            self.on_frame(bytes(data))
        return True

    @property
    def ready(self) -> bool:
        raise NotImplementedError
