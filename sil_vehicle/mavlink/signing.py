"""MAVLink 2 message signing: the vehicle's check of what it receives, and the key file.

The signature is the first 6 bytes of SHA-256(secret key + frame up to and including the link
id and the 48-bit timestamp). A frame is accepted only if (1) its signature is right, and then
(2) its timestamp is newer than the last accepted one of its stream (link id, system,
component), and a new stream's is not more than a minute old. The order matters: pymavlink's
own check records a stream's timestamp *before* it verifies the signature, so a forged frame
with a timestamp far in the future would lock the legitimate sender out; here an unverified
frame changes nothing. Unsigned frames are refused, except read-only requests on a link that is
configured to serve unsigned ground stations. Keys are never logged or printed.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from pathlib import Path
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.clock import signing_now_10us as now_10us

ONE_MINUTE = 60 * 100_000

READ_ONLY_IDS = frozenset({
    mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
    mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ, mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST})


class SigningKeyError(ValueError):
    """A signing key file is unusable (the message says why, never what the key is)."""


def load_key(path: Path | str) -> bytes:
    """The 32-byte secret of a key file holding 64 hexadecimal characters."""
    try:
        text = Path(path).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise SigningKeyError(f"signing key file {path}: cannot be read ({exc.__class__.__name__})") \
            from None
    if not re.fullmatch(r"[0-9a-fA-F]{64}", text):
        raise SigningKeyError(f"signing key file {path}: expected 64 hexadecimal characters "
                        f"(a 32-byte secret), found {len(text)} characters")
    return bytes.fromhex(text)


class SignatureCheck:
    """The receive side of one link: verify, then check and record the stream timestamp."""

    def __init__(self, key: bytes, *, allow_unsigned_read_only: bool = False,
                 clock_10us: Callable[[], int] = now_10us) -> None:
        self._key = key
        self.allow_unsigned_read_only = allow_unsigned_read_only
        self._clock = clock_10us
        self._streams: dict[tuple[int, int, int], int] = {}
        self.unsigned = 0
        self.bad_signature = 0
        self.replayed = 0

    def __repr__(self) -> str:                     # never show the key
        return f"SignatureCheck(streams={len(self._streams)})"

    def accept(self, frame: bytes) -> bool:
        """Is this whole MAVLink frame to be trusted?"""
        if frame[0] != 0xFD or not frame[2] & mavlink.MAVLINK_IFLAG_SIGNED:
            msg_id = (frame[7] | frame[8] << 8 | frame[9] << 16) if frame[0] == 0xFD \
                else frame[5]
            if self.allow_unsigned_read_only and msg_id in READ_ONLY_IDS:
                return True
            self.unsigned += 1
            return False
        expected = hashlib.sha256(self._key + frame[:-6]).digest()[:6]
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


def sign_outgoing(mav: mavlink.MAVLink, key: bytes, link_id: int,
                  clock_10us: Callable[[], int] = now_10us) -> None:
    """Make a pymavlink encoder sign everything it packs from now on."""
    mav.signing.secret_key = key
    mav.signing.link_id = link_id
    mav.signing.timestamp = clock_10us()
    mav.signing.sign_outgoing = True
