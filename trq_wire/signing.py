"""MAVLink 2 signing, for both ends of a link: the key file, the signing clock, signing what is
sent (pymavlink's own signing of packed frames, and `append_signature`, the same bytes, for
the frames trq_wire.frames packs) and the check of what is received.

The signature is the first 6 bytes of SHA-256(secret key + frame up to and including the link
id and the 48-bit timestamp). A frame is accepted only if (1) its signature is right, and then
(2) its timestamp is newer than the last accepted one of its stream (link id, system,
component), and a new stream's is not more than a minute old. The order matters: pymavlink's
own check records a stream's timestamp *before* it verifies the signature, so a forged frame
with a timestamp far in the future would lock the legitimate sender out; here an unverified
frame changes nothing. Unsigned frames are refused, except read-only requests on a check that
is configured to serve unsigned ground stations. Keys are never logged or printed.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import time
from pathlib import Path
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["EPOCH_2015_S", "ONE_MINUTE", "READ_ONLY_IDS", "SignatureCheck", "SigningKeyError",
           "append_signature", "load_key", "now_10us", "sign_outgoing"]

EPOCH_2015_S = 1_420_070_400     # 2015-01-01 00:00:00 UTC in UNIX seconds
ONE_MINUTE = 60 * 100_000        # in the signing clock's 10 us units
# the smallest signed MAVLink 2 frame: 10 header bytes, no payload, 2 checksum, 13 signature
_MIN_SIGNED = 10 + 2 + 13

READ_ONLY_IDS = frozenset({
    mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
    mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST})


def now_10us(wall: Callable[[], float] = time.time) -> int:
    """MAVLink signing time: 10 us units since 2015-01-01 00:00:00 UTC (the wall clock, as the
    signing specification asks; it never enters the simulation)."""
    return int((wall() - EPOCH_2015_S) * 100_000)


def _signature(key: bytes, signed_part) -> bytes:
    """The 6 signature bytes of a frame whose signed part (up to and including the link id and
    the timestamp) is `signed_part`."""
    return hashlib.sha256(key + signed_part).digest()[:6]


def append_signature(frame: bytearray, key: bytes, link_id: int, stamp_10us: int) -> None:
    """Sign a packed MAVLink 2 frame (its signed flag already set) in place: the link id, the
    48-bit timestamp and the signature, the 13 bytes pymavlink's own signing appends."""
    frame.append(link_id)
    frame += (stamp_10us & 0xFFFF_FFFF_FFFF).to_bytes(6, "little")
    frame += _signature(key, frame)


class SigningKeyError(ValueError):
    """A signing key file is unusable (the message says why, never what the key is)."""


def load_key(path: Path | str) -> bytes:
    """The 32-byte secret of a key file holding 64 hexadecimal characters (surrounding
    whitespace, such as a final newline, is ignored)."""
    try:
        text = Path(path).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise SigningKeyError(f"signing key file {path}: cannot be read "
                              f"({exc.__class__.__name__})") from None
    if not re.fullmatch(r"[0-9a-fA-F]{64}", text):
        raise SigningKeyError(f"signing key file {path}: expected 64 hexadecimal characters "
                              f"(a 32-byte secret), found {len(text)} characters")
    return bytes.fromhex(text)


class SignatureCheck:
    """The receive side of one link: verify, then check and record the stream timestamp.

    Counters: `unsigned` (no signature, MAVLink 1 included), `bad_signature` (wrong key,
    altered or truncated frame), `replayed` (not newer than its stream, or a new stream more
    than a minute behind the clock); `rejected` is their sum."""

    def __init__(self, key: bytes, *, allow_unsigned_read_only: bool = False,
                 clock_10us: Callable[[], int] = now_10us) -> None:
        if len(key) != 32:
            raise SigningKeyError(f"a signing key is 32 bytes, got {len(key)}")
        self._key = key
        self.allow_unsigned_read_only = allow_unsigned_read_only
        self._clock = clock_10us
        self._streams: dict[tuple[int, int, int], int] = {}
        self.unsigned = 0
        self.bad_signature = 0
        self.replayed = 0

    def __repr__(self) -> str:                     # never show the key
        return f"SignatureCheck(streams={len(self._streams)})"

    @property
    def rejected(self) -> int:
        return self.unsigned + self.bad_signature + self.replayed

    def accept(self, frame: bytes) -> bool:
        """Is this whole MAVLink frame to be trusted?"""
        if not frame:
            self.unsigned += 1
            return False
        if frame[0] != 0xFD or len(frame) < 3 or not frame[2] & mavlink.MAVLINK_IFLAG_SIGNED:
            msg_id = (frame[7] | frame[8] << 8 | frame[9] << 16) if frame[0] == 0xFD \
                and len(frame) >= 10 else frame[5] if len(frame) >= 6 else -1
            if self.allow_unsigned_read_only and msg_id in READ_ONLY_IDS:
                return True
            self.unsigned += 1
            return False
        if len(frame) < _MIN_SIGNED:
            self.bad_signature += 1
            return False
        expected = _signature(self._key, frame[:-6])
        if not hmac.compare_digest(expected, frame[-6:]):
            self.bad_signature += 1
            return False
        link_id = frame[-13]
        stamp = int.from_bytes(frame[-12:-6], "little")
        stream = (link_id, frame[5], frame[6])
        last = self._streams.get(stream)
        if (last is not None and stamp <= last) or \
                (last is None and stamp + ONE_MINUTE < self._clock()):
            self.replayed += 1
            return False
        self._streams[stream] = stamp
        return True


def sign_outgoing(mav: mavlink.MAVLink, key: bytes, link_id: int = 0,
                  clock_10us: Callable[[], int] = now_10us) -> None:
    """Make a pymavlink encoder sign everything it packs from now on (its own signing: the
    timestamp starts at the clock and pymavlink advances it per frame)."""
    if len(key) != 32:
        raise SigningKeyError(f"a signing key is 32 bytes, got {len(key)}")
    mav.signing.secret_key = key
    mav.signing.link_id = link_id
    mav.signing.timestamp = clock_10us()
    mav.signing.sign_outgoing = True
