"""MAVLink 2 signing, shared by both daemons (trq_wire.signing): the key file, the signing clock,
what a signed frame carries, and the check of received frames: only correctly signed, fresh
frames pass; a forged frame, whatever its timestamp or link id, cannot lock out the legitimate
signed stream."""

from __future__ import annotations

import hashlib

import pytest
from pymavlink.dialects.v20 import common as mavlink

from trq_wire.signing import (EPOCH_2015_S, ONE_MINUTE, READ_ONLY_IDS, SignatureCheck,
                              SigningKeyError, load_key, now_10us, sign_outgoing)

KEY = hashlib.sha256(b"the legitimate key").digest()
WRONG = hashlib.sha256(b"an attacker's guess").digest()
NOW = 300_000_000_000            # 10 us units since 2015: a fixed clock for the tests


def sender(key: bytes | None, link_id: int = 0, stamp: int = NOW, system: int = 255):
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=190)
    if key is not None:
        sign_outgoing(mav, key, link_id, clock_10us=lambda: stamp)
    return mav


def arm_frame(mav) -> bytes:
    return bytes(mavlink.MAVLink_command_long_message(
        1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav))


def heartbeat_frame(mav) -> bytes:
    return bytes(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav))


def check(**kw) -> SignatureCheck:
    return SignatureCheck(KEY, clock_10us=lambda: NOW, **kw)


# --- the signing clock ---------------------------------------------------------------------

def test_signing_clock_counts_10us_since_2015():
    assert EPOCH_2015_S == ((2015 - 1970) * 365 + 11) * 86_400     # 11 leap days 1972..2012
    assert now_10us(lambda: float(EPOCH_2015_S)) == 0
    assert now_10us(lambda: EPOCH_2015_S + 1.5) == 150_000
    assert now_10us(lambda: EPOCH_2015_S + 86_400.0) == 8_640_000_000
    assert ONE_MINUTE == 6_000_000


# --- what a signed frame carries -----------------------------------------------------------

def test_signed_frame_layout():
    """Link id, 48-bit little-endian timestamp, then SHA-256(key + all before it)[:6]."""
    frame = heartbeat_frame(sender(KEY, link_id=3, stamp=0x0102030405))
    assert frame[2] & mavlink.MAVLINK_IFLAG_SIGNED
    assert frame[-13] == 3
    assert frame[-12:-6] == bytes([0x05, 0x04, 0x03, 0x02, 0x01, 0x00])
    assert frame[-6:] == hashlib.sha256(KEY + frame[:-6]).digest()[:6]


def test_the_timestamp_advances_per_frame():
    mav = sender(KEY, stamp=NOW)
    a, b = heartbeat_frame(mav), heartbeat_frame(mav)
    assert int.from_bytes(b[-12:-6], "little") > int.from_bytes(a[-12:-6], "little") >= NOW


# --- the check of received frames ----------------------------------------------------------

def test_signed_frames_pass_and_unsigned_or_wrong_key_do_not():
    c = check()
    assert c.accept(arm_frame(sender(KEY)))
    assert not c.accept(arm_frame(sender(None)))
    assert not c.accept(arm_frame(sender(WRONG)))
    assert (c.unsigned, c.bad_signature, c.replayed, c.rejected) == (1, 1, 0, 2)


def test_replayed_frame_is_rejected():
    c = check()
    frame = arm_frame(sender(KEY))
    assert c.accept(frame)
    assert not c.accept(frame)                        # the very same bytes again
    assert c.replayed == 1


def test_streams_are_told_apart_by_link_system_and_component():
    c = check()
    assert c.accept(arm_frame(sender(KEY, link_id=1)))
    assert c.accept(arm_frame(sender(KEY, link_id=2)))          # same stamp, another link
    assert c.accept(arm_frame(sender(KEY, link_id=1, system=254)))
    assert c.replayed == 0


def test_forged_future_timestamp_does_not_lock_out_the_real_stream():
    c = check()
    legit = sender(KEY, link_id=1)
    assert c.accept(arm_frame(legit))
    forged = sender(WRONG, link_id=1, stamp=NOW + 10**9)     # far in the future, wrong key
    assert not c.accept(arm_frame(forged))
    assert c.accept(arm_frame(legit))                         # the real sender flies on


def test_pymavlink_own_check_would_be_locked_out():
    """Why the check verifies before it records: pymavlink's check records the timestamp of a
    forged frame first (documented here so that a change in pymavlink is noticed)."""
    rx = mavlink.MAVLink(None)
    rx.signing.secret_key = KEY
    rx.signing.timestamp = NOW
    legit = sender(KEY)
    rx.decode(bytearray(arm_frame(legit)))
    with pytest.raises(mavlink.MAVError):
        rx.decode(bytearray(arm_frame(sender(WRONG, stamp=NOW + 10**9, system=255))))
    with pytest.raises(mavlink.MAVError):                     # locked out
        rx.decode(bytearray(arm_frame(legit)))


def test_changing_the_link_id_breaks_the_signature():
    frame = bytearray(arm_frame(sender(KEY, link_id=0)))
    frame[-13] = 7                                           # replay as another stream
    c = check()
    assert not c.accept(bytes(frame)) and c.bad_signature == 1


def test_a_new_stream_may_be_a_minute_behind_the_clock_and_no_more():
    assert check().accept(arm_frame(sender(KEY, stamp=NOW - ONE_MINUTE)))
    c = check()
    assert not c.accept(arm_frame(sender(KEY, stamp=NOW - ONE_MINUTE - 1)))
    assert c.replayed == 1


def test_unsigned_read_only_allowed_only_when_configured():
    strict, lenient = check(), check(allow_unsigned_read_only=True)
    assert mavlink.MAVLINK_MSG_ID_HEARTBEAT in READ_ONLY_IDS
    assert mavlink.MAVLINK_MSG_ID_COMMAND_LONG not in READ_ONLY_IDS
    assert not strict.accept(heartbeat_frame(sender(None)))
    assert lenient.accept(heartbeat_frame(sender(None)))
    assert not lenient.accept(arm_frame(sender(None)))       # never a command


def test_mavlink1_frames_are_unsigned():
    frame = bytes(mavlink.MAVLink_command_long_message(
        1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(sender(None), force_mavlink1=True))
    c = check()
    assert not c.accept(frame) and c.unsigned == 1


@pytest.mark.parametrize("frame", [b"", b"\xfd", b"\xfd\x00\x01", b"\xfd\x00\x01" + bytes(20),
                                   b"\xfe\x00"])
def test_short_and_truncated_frames_are_refused_without_raising(frame):
    c = check(allow_unsigned_read_only=True)
    assert not c.accept(frame) and c.rejected == 1


def test_the_key_is_never_shown():
    c = check()
    assert KEY.hex() not in repr(c) and str(list(KEY)) not in repr(c)


# --- keys ----------------------------------------------------------------------------------

@pytest.mark.parametrize("text,ok", [("ab" * 32, True), ("AB" * 32 + "\n", True),
                                     ("  " + "0f" * 32 + "\n\n", True),
                                     ("ab" * 31, False), ("ab" * 33, False), ("ab" * 31 + "a",
                                                                             False),
                                     ("zz" * 32, False), ("0x" + "ab" * 31, False),
                                     ("ab" * 16 + " " + "ab" * 16, False), ("", False)])
def test_key_files(tmp_path, text, ok):
    path = tmp_path / "key.hex"
    path.write_text(text)
    if ok:
        assert load_key(path) == bytes.fromhex(text.strip())
        assert len(load_key(path)) == 32
    else:
        with pytest.raises(SigningKeyError) as info:
            load_key(path)
        assert "key.hex" in str(info.value) and "64 hexadecimal" in str(info.value)
        assert isinstance(info.value, ValueError)


def test_key_file_hand_decoded(tmp_path):
    path = tmp_path / "key.hex"
    path.write_text("00" * 31 + "ff")
    assert load_key(path) == bytes(31) + b"\xff"


def test_missing_or_binary_key_file_is_named_not_shown(tmp_path):
    with pytest.raises(SigningKeyError, match="nokey.*cannot be read"):
        load_key(tmp_path / "nokey")
    path = tmp_path / "binary"
    path.write_bytes(b"\xff" * 64)
    with pytest.raises(SigningKeyError, match="binary.*cannot be read"):
        load_key(path)


@pytest.mark.parametrize("key", [b"", bytes(16), bytes(31), bytes(33), bytes(64)])
def test_wrong_key_length_is_refused(key):
    with pytest.raises(SigningKeyError, match="32 bytes"):
        SignatureCheck(key)
    with pytest.raises(SigningKeyError, match="32 bytes"):
        sign_outgoing(mavlink.MAVLink(None), key, 0)
