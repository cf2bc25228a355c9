"""MAVLink 2 signing on the vehicle's links (sil_vehicle.mavlink.signing) and the controller's
(trq_offboard.link.signing): only correctly signed, fresh frames are obeyed; a forged frame,
whatever its timestamp or link id, cannot lock out the legitimate signed stream."""

from __future__ import annotations

import hashlib

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.mavlink.signing import SignatureCheck, SigningKeyError, load_key, sign_outgoing
from trq_offboard.link.signing import Verifier, enable_signing, read_key_file

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


def codec(**kw) -> Codec:
    return Codec(check=SignatureCheck(KEY, clock_10us=lambda: NOW, **kw))


def test_signed_frames_pass_and_unsigned_or_wrong_key_do_not():
    c = codec()
    assert len(c.decode(arm_frame(sender(KEY)))) == 1
    assert c.decode(arm_frame(sender(None))) == []
    assert c.decode(arm_frame(sender(WRONG))) == []
    assert c.counters.unauthenticated == 2 and c.check.unsigned == 1
    assert c.check.bad_signature == 1


def test_replayed_frame_is_rejected():
    c = codec()
    frame = arm_frame(sender(KEY))
    assert len(c.decode(frame)) == 1
    assert c.decode(frame) == []                   # the very same bytes again
    assert c.check.replayed == 1


def test_forged_future_timestamp_does_not_lock_out_the_real_stream():
    c = codec()
    legit = sender(KEY, link_id=1)
    assert len(c.decode(arm_frame(legit))) == 1
    forged = sender(WRONG, link_id=1, stamp=NOW + 10**9)     # far in the future, wrong key
    assert c.decode(arm_frame(forged)) == []
    assert len(c.decode(arm_frame(legit))) == 1               # the real sender flies on


def test_pymavlink_own_check_would_be_locked_out():
    """Why the vehicle verifies before it records: pymavlink's check records the timestamp of a
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
    c = codec()
    assert c.decode(bytes(frame)) == [] and c.check.bad_signature == 1


def test_old_new_stream_is_rejected():
    c = codec()
    assert c.decode(arm_frame(sender(KEY, stamp=NOW - 2 * 6_000_000))) == []   # 2 min old
    assert c.check.replayed == 1


def test_unsigned_read_only_allowed_only_when_configured():
    strict, lenient = codec(), codec(allow_unsigned_read_only=True)
    assert strict.decode(heartbeat_frame(sender(None))) == []
    assert len(lenient.decode(heartbeat_frame(sender(None)))) == 1
    assert lenient.decode(arm_frame(sender(None))) == []      # never a command


def test_mavlink1_frames_are_unsigned():
    frame = bytes(mavlink.MAVLink_command_long_message(
        1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(sender(None), force_mavlink1=True))
    c = codec()
    assert c.decode(frame) == [] and c.check.unsigned == 1


def test_controller_verifier_agrees():
    v = Verifier(KEY, clock=lambda: NOW)
    assert v.trusted(heartbeat_frame(sender(KEY, system=1)))
    assert not v.trusted(heartbeat_frame(sender(None, system=1)))
    assert not v.trusted(heartbeat_frame(sender(WRONG, system=1)))
    assert "Verifier(<key hidden>)" == repr(v)
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=191)
    enable_signing(mav, KEY, clock=lambda: NOW + 1)
    c = codec()
    assert len(c.decode(arm_frame(mav))) == 1                 # the vehicle trusts the controller


@pytest.mark.parametrize("text,ok", [("ab" * 32, True), ("AB" * 32 + "\n", True),
                                     ("ab" * 31, False), ("zz" * 32, False), ("", False)])
def test_key_files(tmp_path, text, ok):
    path = tmp_path / "key.hex"
    path.write_text(text)
    for load, error in ((load_key, SigningKeyError), (read_key_file, ValueError)):
        if ok:
            assert load(path) == bytes.fromhex(text.strip())
        else:
            with pytest.raises(error) as info:
                load(path)
            assert "key.hex" in str(info.value) and "64 hexadecimal" in str(info.value)


def test_missing_key_file_is_named(tmp_path):
    with pytest.raises(SigningKeyError, match="nokey"):
        load_key(tmp_path / "nokey")
