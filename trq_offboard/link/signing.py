"""MAVLink 2 signing on the controller's link: sign what it sends, trust only what is signed.

A received frame is trusted when its 6-byte signature, SHA-256 of the secret key and the frame
up to its timestamp, is right, and only then when its 48-bit timestamp is newer than the last
one trusted from the same (link id, system, component); a new sender may be at most a minute
behind the clock. Verifying before recording the timestamp means a forged frame cannot move a
stream's clock forward and lock out the real sender. The key is never logged.
"""

from __future__ import annotations

import hashlib
import hmac
import string
import time
from pathlib import Path
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

SIGNED_FLAG = mavlink.MAVLINK_IFLAG_SIGNED
MINUTE_10US = 6_000_000
EPOCH_2015 = 1_420_070_400.0


def read_key_file(path: Path | str) -> bytes:
    try:
        text = Path(path).read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"signing key file {path}: unreadable ({type(exc).__name__})") from None
    if len(text) != 64 or any(ch not in string.hexdigits for ch in text):
        raise ValueError(f"signing key file {path}: expected 64 hexadecimal characters, "
                         f"found {len(text)}")
    return bytes.fromhex(text)


def clock_10us(wall: Callable[[], float] = time.time) -> int:
    return int((wall() - EPOCH_2015) * 1e5)


class Verifier:
    def __init__(self, key: bytes, clock: Callable[[], int] = clock_10us) -> None:
        self._key, self._clock = key, clock
        self._last: dict[tuple[int, int, int], int] = {}
        self.rejected = 0

    def __repr__(self) -> str:
        return "Verifier(<key hidden>)"

    def trusted(self, frame: bytes) -> bool:
        if len(frame) < 25 or frame[0] != 0xFD or not frame[2] & SIGNED_FLAG:
            self.rejected += 1
            return False
        body, signature = frame[:-6], frame[-6:]
        if not hmac.compare_digest(hashlib.sha256(self._key + body).digest()[:6], signature):
            self.rejected += 1
            return False
        stamp = int.from_bytes(frame[-12:-6], "little")
        key = (frame[-13], frame[5], frame[6])
        previous = self._last.get(key)
        fresh = stamp > previous if previous is not None else stamp >= self._clock() - MINUTE_10US
        if not fresh:
            self.rejected += 1
            return False
        self._last[key] = stamp
        return True


def enable_signing(encoder: mavlink.MAVLink, key: bytes, link_id: int = 0,
                   clock: Callable[[], int] = clock_10us) -> None:
    encoder.signing.secret_key = key
    encoder.signing.link_id = link_id
    encoder.signing.timestamp = clock()
    encoder.signing.sign_outgoing = True
