"""MAVLink over a byte stream (a serial line, TCP): framing, frame sizes and a serial line's pace.

A datagram holds whole frames; a stream does not: a frame may be split over reads, a line may
carry garbage (noise, a device's boot banner) or lose bytes (a cut). `StreamFramer` is the one
persistent parser of a stream: it keeps the bytes of an incomplete frame for the next read and
accepts a frame only when its header is plausible (a MAVLink 1 or 2 magic, known incompat flags,
a message id of the `common` dialect with a payload no longer than that message's) and its
checksum (with the message's CRC_EXTRA) is right; otherwise it skips one byte and looks for the
next magic, so it re-synchronises after garbage or a cut. Garbage that looks like a plausible
header waits, as a real frame's start would, for the bytes that complete or refute it (its
checksum): a frame right behind it comes out once the stream has carried that many more bytes
(at most one frame's length). A message id outside the dialect cannot
have its checksum checked and is skipped as garbage on a stream. Signatures are checked by the
receiver (trq_wire.signing), not here.

`frame_size` is the encoded size of a message on the wire; `LinePacer` holds bytes back until a
line of a given rate would have carried them (8N1: BAUD / 10 bytes a second).
"""

from __future__ import annotations

from collections import deque
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.frames import crc as frame_crc

MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
HEADER_V2, HEADER_V1, CHECKSUM, SIGNATURE = 10, 6, 2, 13
NS_PER_S = 1_000_000_000


def line_bytes_per_s(baud: int) -> int:
    """A serial line at `baud`, 8N1: each byte is 10 bits on the line (start, 8 data, stop)."""
    return baud // 10


def frame_size(message_class, signed: bool = False) -> int:
    """Bytes of one MAVLink 2 frame of this message at its full payload (MAVLink 2 drops the
    payload's trailing zero bytes, so a frame is at most this long): header, payload, checksum
    and, signed, the 13-byte signature."""
    return (HEADER_V2 + message_class.unpacker.size + CHECKSUM
            + (SIGNATURE if signed else 0))


class StreamFramer:
    """Whole, checksummed MAVLink frames out of a byte stream, read by read.

    `feed(data)` returns the frames completed by `data`, in order. `bad` counts the runs of
    bytes skipped (garbage, a cut frame, a bad checksum): one per loss of synchronisation, as a
    datagram's garbage counts once."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._in_sync = True
        self.bad = 0
        self.frames = 0

    def _lost(self) -> None:
        if self._in_sync:
            self.bad += 1
            self._in_sync = False

    def feed(self, data: bytes) -> list[bytes]:
        buf = self._buf
        buf += data
        out: list[bytes] = []
        i, n = 0, len(buf)
        while i < n:
            b = buf[i]
            if b != MAGIC_V2 and b != MAGIC_V1:
                j2, j1 = buf.find(MAGIC_V2, i), buf.find(MAGIC_V1, i)
                j = min(j for j in (j2, j1, n) if j >= 0)
                self._lost()
                i = j
                continue
            header = HEADER_V2 if b == MAGIC_V2 else HEADER_V1
            if n - i < header:
                break                                   # the rest of the header is to come
            length = buf[i + 1]
            if b == MAGIC_V2:
                flags = buf[i + 2]
                msgid = buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16
                signature = SIGNATURE if flags & mavlink.MAVLINK_IFLAG_SIGNED else 0
                plausible = not flags & ~mavlink.MAVLINK_IFLAG_SIGNED
            else:
                msgid, signature, plausible = buf[i + 5], 0, True
            kind = mavlink.mavlink_map.get(msgid) if plausible else None
            if kind is None or length > kind.unpacker.size:
                self._lost()
                i += 1
                continue
            end = i + header + length + CHECKSUM
            total = end + signature
            if total > n:
                break                                   # the rest of the frame is to come
            if frame_crc(buf[i + 1:end - CHECKSUM], kind.crc_extra) \
                    != buf[end - 2] | buf[end - 1] << 8:
                self._lost()
                i += 1
                continue
            out.append(bytes(buf[i:total]))
            self.frames += 1
            self._in_sync = True
            i = total
        del buf[:i]
        return out

    @property
    def pending(self) -> int:
        """Bytes held for the next read (an incomplete frame, or the start of one)."""
        return len(self._buf)


class LinePacer:
    """A serial line's pace in real time: bytes queued with `push` leave (`due`) when a line of
    `bytes_per_s` would have carried their last byte, behind everything queued before, so a
    configuration richer than the line shows as a growing latency, as on hardware. Integer
    nanoseconds from the injected clock `now_ns`; while the line is busy its schedule counts
    bytes from the moment it became busy, so no rounding accumulates."""

    def __init__(self, bytes_per_s: int, now_ns: Callable[[], int]) -> None:
        if bytes_per_s <= 0:
            raise ValueError(f"a line's rate must be positive, got {bytes_per_s} bytes/s")
        self.bytes_per_s = bytes_per_s
        self._now_ns = now_ns
        self._busy_from_ns = 0
        self._busy_bytes = 0
        self._queue: deque[tuple[int, bytes]] = deque()
        self.queued_bytes = 0
        self.max_latency_ns = 0          # the longest wait of a push until its bytes left

    def _free_at_ns(self) -> int:
        # ceil(bytes * 1e9 / rate): the instant the line's last byte so far is through
        return self._busy_from_ns + -(-self._busy_bytes * NS_PER_S // self.bytes_per_s)

    def push(self, data: bytes) -> int:
        """Queue `data`; return when it will have been carried (ns of the clock)."""
        now = self._now_ns()
        if self._free_at_ns() <= now:                  # the line is idle: a new busy spell
            self._busy_from_ns, self._busy_bytes = now, 0
        self._busy_bytes += len(data)
        release = self._free_at_ns()
        self._queue.append((release, bytes(data)))
        self.queued_bytes += len(data)
        self.max_latency_ns = max(self.max_latency_ns, release - now)
        return release

    def due(self) -> bytes:
        """The queued bytes the line has carried by now, in order."""
        now = self._now_ns()
        parts = []
        q = self._queue
        while q and q[0][0] <= now:
            parts.append(q.popleft()[1])
        data = b"".join(parts)
        self.queued_bytes -= len(data)
        return data

    def next_due_ns(self) -> int | None:
        return self._queue[0][0] if self._queue else None

    def wait_ns(self) -> int | None:
        """How long until the next queued bytes are due (0 if they are); None if none are."""
        due = self.next_due_ns()
        return None if due is None else max(0, due - self._now_ns())
