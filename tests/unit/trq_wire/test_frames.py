"""The one-struct fast path of the hot messages (trq_wire.frames, issue 18) against pymavlink
itself: the target's frame byte for byte as pymavlink packs it (signed and unsigned, truncated
payloads), the telemetry decoded into the same objects as pymavlink's decode (every attribute,
header included), everything it must not vouch for left to pymavlink, and the controller's two
receive paths (UDP, a stream) delivering and counting the same with the fast path as without."""

from __future__ import annotations

import math
import re
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.link import wire
from trq_offboard.link.stream import MavlinkStream
from trq_offboard.link.udp import Connection, MavlinkUdp
from trq_offboard.records import ActuatorCommand
from trq_wire import frames
from trq_wire.signing import now_10us, sign_outgoing

from conftest import examples

FUZZ = settings(max_examples=examples(200), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
KEY = bytes(range(32))
ODOMETRY = mavlink.MAVLink_odometry_message
OUTPUTS = mavlink.MAVLink_actuator_output_status_message
TARGET = mavlink.MAVLink_set_actuator_control_target_message

u8 = st.integers(0, 255)
f32 = st.floats(width=32)                        # NaN and infinities included
# zeros often, so that MAVLink 2 truncates the payload's tail
control = st.one_of(st.just(0.0), st.just(-0.0), f32, st.floats(-1.0, 1.0, width=32))


def same(a, b) -> bool:
    """Equal values, NaN equal to NaN and -0.0 told from 0.0 (repr of floats and lists)."""
    return repr(a) == repr(b)


def assert_same_message(fast, slow) -> None:
    """Every attribute of the two objects (the header's too), the class and the methods the
    controller uses."""
    assert type(fast) is type(slow)
    a, b = vars(fast), vars(slow)
    assert sorted(a) == sorted(b)
    for k in a:
        if k == "_header":
            assert vars(a[k]) == vars(b[k])
        else:
            assert same(a[k], b[k]), k
            assert type(a[k]) is type(b[k]), k
    assert (fast.get_type(), fast.get_srcSystem(), fast.get_srcComponent(), fast.get_seq(),
            fast.get_msgId(), bytes(fast.get_msgbuf()), fast.get_crc(), fast.get_signed()) == \
        (slow.get_type(), slow.get_srcSystem(), slow.get_srcComponent(), slow.get_seq(),
         slow.get_msgId(), bytes(slow.get_msgbuf()), slow.get_crc(), slow.get_signed())


def x25(data: bytes) -> int:
    return mavlink.x25crc(data).crc                # pymavlink's, not the code under test


def frame(cls, payload: bytes, *, seq=0, system=1, component=1, flags=0, compat=0,
          signature=b"", truncate=True, crc_delta=0) -> bytes:
    """A MAVLink 2 frame around `payload` (trailing zeros dropped as MAVLink 2 does, unless
    told not to), with a right checksum (plus `crc_delta`) and `signature` appended."""
    if truncate:
        payload = payload.rstrip(b"\x00") or payload[:1]
    head = struct.pack("<BBBBBBHB", len(payload), flags, compat, seq, system, component,
                       cls.id & 0xFFFF, cls.id >> 16)
    crc = (x25(head + payload + bytes((cls.crc_extra,))) + crc_delta) & 0xFFFF
    return b"\xfd" + head + payload + struct.pack("<H", crc) + signature


def pymavlink_decode(data: bytes):
    return mavlink.MAVLink(None).decode(bytearray(data))


# --- the target's frame: byte for byte pymavlink's ----------------------------------------------

def encoders(signed: bool, link_id: int, stamp: int, system: int, component: int):
    pair = [mavlink.MAVLink(None, srcSystem=system, srcComponent=component) for _ in range(2)]
    if signed:
        for mav in pair:
            sign_outgoing(mav, KEY, link_id, clock_10us=lambda: stamp)
    return pair


@FUZZ
@given(st.lists(st.tuples(st.integers(0, 2**64 - 1), u8, u8, u8,
                          st.lists(control, min_size=8, max_size=8)), min_size=1, max_size=8),
       st.booleans(), u8, st.integers(0, 2**48 - 100), u8, u8, u8)
def test_target_frames_are_pymavlinks(targets, signed, link_id, stamp, seq, system, component):
    """Many random targets in a row on one encoder each: the same bytes, and both encoders'
    sequence and signing clocks stay in step (pymavlink packs and this path may take turns)."""
    ours, theirs = encoders(signed, link_id, stamp, system, component)
    ours.seq = theirs.seq = seq
    for stamp_us, group, ts, tc, controls in targets:
        a = frames.ActuatorTarget(stamp_us, group, ts, tc, controls).pack(ours)
        b = TARGET(stamp_us, group, ts, tc, controls).pack(theirs)
        assert a == b
        assert isinstance(a, bytes)
        ours.seq = theirs.seq = (ours.seq + 1) % 256
        assert ours.signing.timestamp == theirs.signing.timestamp
        heartbeat = mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
        assert heartbeat.pack(ours) == heartbeat.pack(theirs)   # pymavlink's pack in between


@pytest.mark.parametrize("signed", [False, True])
def test_target_message_after_pack_is_pymavlinks(signed):
    ours, theirs = encoders(signed, 2, 10_000, 1, 191)
    a = frames.ActuatorTarget(1_000, 0, 1, 1, [0.5, 0.5, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0])
    b = TARGET(1_000, 0, 1, 1, [0.5, 0.5, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0])
    assert isinstance(a, TARGET) and a.get_type() == "SET_ACTUATOR_CONTROL_TARGET"
    a.pack(ours)
    b.pack(theirs)
    assert bytes(a.get_msgbuf()) == bytes(b.get_msgbuf()) and a.get_crc() == b.get_crc()
    assert a.to_dict() == b.to_dict()


def test_target_all_zero_keeps_one_payload_byte_and_mavlink1_is_pymavlinks():
    ours, theirs = encoders(False, 0, 0, 1, 191)
    a = frames.ActuatorTarget(0, 0, 0, 0, [0.0] * 8).pack(ours)
    assert a == TARGET(0, 0, 0, 0, [0.0] * 8).pack(theirs)
    assert a[1] == 1 and len(a) == 10 + 1 + 2
    v1 = frames.ActuatorTarget(5, 0, 1, 1, [0.1] * 8).pack(ours, force_mavlink1=True)
    assert v1 == TARGET(5, 0, 1, 1, [0.1] * 8).pack(theirs, force_mavlink1=True)
    assert v1[0] == 0xFE


def test_target_pack_refuses_what_pymavlink_refuses():
    mav = mavlink.MAVLink(None)
    for bad in (frames.ActuatorTarget(-1, 0, 1, 1, [0.0] * 8),
                frames.ActuatorTarget(0, 256, 1, 1, [0.0] * 8)):
        with pytest.raises(struct.error):
            bad.pack(mav)


def test_wire_target_is_the_fast_one_with_its_checks():
    cmd = ActuatorCommand((50.0, 50.0, 50.0, 50.0), (0.1, -0.1, 0.0, 0.0))
    msg = wire.actuator_target(123, cmd, math.radians(30.0))
    assert isinstance(msg, frames.ActuatorTarget) and isinstance(msg, TARGET)
    with pytest.raises(ValueError):
        wire.actuator_target(123, ActuatorCommand((math.nan, 0, 0, 0), (0, 0, 0, 0)), 0.5)


# --- telemetry: pymavlink's decode, one struct --------------------------------------------------

def random_payload(cls, data) -> bytes:
    """Random field values of `cls` (any bit patterns, NaN included), with runs of zeros at the
    tail so that MAVLink 2's truncation shows."""
    size = cls.unpacker.size
    body = data.draw(st.binary(min_size=size, max_size=size), label="payload")
    zeros = data.draw(st.integers(0, size), label="trailing zeros")
    return body[:size - zeros] + bytes(zeros)


def valid_values(cls, data) -> bytes:
    """A message of `cls` with sensible float values, packed by pymavlink (its payload)."""
    size = cls.unpacker.size
    fmt = cls.unpacker.format
    values = []
    for code, count in _format_items(fmt):
        for _ in range(count):
            if code == "f":
                values.append(data.draw(st.one_of(st.just(0.0), st.floats(-1e6, 1e6, width=32),
                                                  st.just(math.nan))))
            else:
                bits = 8 * struct.calcsize("<" + code)
                lo, hi = (-(1 << bits - 1), (1 << bits - 1) - 1) if code.islower() \
                    else (0, (1 << bits) - 1)
                values.append(data.draw(st.integers(lo, hi)))
    payload = cls.unpacker.pack(*values)
    assert len(payload) == size
    return payload


def _format_items(fmt: str):
    """A struct format's (code, count) items: '<Q4fB' -> [('Q', 1), ('f', 4), ('B', 1)]."""
    return [(code, int(n) if n else 1) for n, code in re.findall(r"(\d*)([a-zA-Z])", fmt)]


@FUZZ
@given(st.sampled_from(frames.HOT), st.booleans(), u8, u8, u8, st.booleans(),
       st.booleans(), st.data())
def test_decode_is_pymavlinks(cls, random_bits, seq, system, component, signed, compat, data):
    payload = random_payload(cls, data) if random_bits else valid_values(cls, data)
    signature = data.draw(st.binary(min_size=13, max_size=13)) if signed else b""
    f = frame(cls, payload, seq=seq, system=system, component=component, flags=int(signed),
              compat=0x5A if compat else 0, signature=signature)
    fast = frames.decode(f)
    assert fast is not None
    assert_same_message(fast, pymavlink_decode(f))


@pytest.mark.parametrize("cls", [ODOMETRY, OUTPUTS])
def test_decode_full_and_truncated_payloads(cls):
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    if cls is ODOMETRY:
        msgs = [ODOMETRY(1_230_000, 1, 1, 1.5, -2.0, -3.25, [1.0, 0.0, 0.0, 0.0], 0.5, -0.25,
                         0.125, 0.01, -0.02, 0.03, [math.nan] * 21, [math.nan] * 21, 0, 1, 100),
                ODOMETRY(7, 1, 1, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0,
                         0.0, 0.0, [0.0] * 21, [0.0] * 21, 0, 0, 0)]
    else:
        msgs = [OUTPUTS(10_000, 8, [0.5] * 8 + [math.nan] * 24),
                OUTPUTS(10_000, 8, [0.5, 0.5, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0] + [0.0] * 24)]
    for msg in msgs:
        f = bytes(msg.pack(tx))
        fast, slow = frames.decode(f), pymavlink_decode(f)
        assert_same_message(fast, slow)
        if cls is ODOMETRY:
            assert isinstance(fast.q, list) and len(fast.q) == 4
            assert len(fast.pose_covariance) == 21 and len(fast.velocity_covariance) == 21
            assert wire.parse_odometry(fast) == wire.parse_odometry(slow)
        else:
            assert isinstance(fast.actuator, list) and len(fast.actuator) == 32
            assert wire.parse_actuator_outputs(fast, 0.5) == wire.parse_actuator_outputs(slow, 0.5)
    assert f[1] < cls.unpacker.size                 # the last one was truncated


@pytest.mark.parametrize("cls", frames.HOT)
def test_decode_of_an_empty_payload_is_pymavlinks(cls):
    """A sender may cut an all-zero payload to nothing (pymavlink keeps one byte; the format
    allows none)."""
    f = frame(cls, b"", truncate=False, seq=3)
    assert f[1] == 0
    assert_same_message(frames.decode(f), pymavlink_decode(f))


def test_decode_leaves_to_pymavlink_what_it_cannot_vouch_for():
    payload = bytes(range(1, OUTPUTS.unpacker.size + 1))
    good = frame(OUTPUTS, payload)
    assert frames.decode(good) is not None
    heartbeat_v1 = bytes(mav1.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3).pack(
        mav1.MAVLink(None, srcSystem=1, srcComponent=1)))
    ack = bytes(mavlink.MAVLink_command_ack_message(400, 0).pack(mavlink.MAVLink(None)))
    unknown = good[:7] + bytes((0xDE, 0xBC, 0x0A)) + good[10:]
    refused = {
        "bad checksum": frame(OUTPUTS, payload, crc_delta=1),
        "another incompat flag": frame(OUTPUTS, payload, flags=2),
        "MAVLink 1": heartbeat_v1,
        "not a hot message": ack,
        "unknown id": unknown,
        "longer payload than the message's": frame(OUTPUTS, payload + b"\x01"),
        "cut": good[:-1],
        "a byte too many": good + b"\x00",
        "signed flag without a signature": frame(OUTPUTS, payload, flags=1),
        "empty": b"",
        "garbage": b"\x00\x01\x02" + good,
    }
    for what, data in refused.items():
        assert frames.decode(data) is None, what


def test_decode_leading_stops_at_the_first_frame_it_does_not_vouch_for():
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = bytes(mavlink.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3).pack(tx))
    out = frame(OUTPUTS, bytes(range(1, 41)))
    ack = bytes(mavlink.MAVLink_command_ack_message(400, 0).pack(tx))
    msgs, done = frames.decode_leading(hb + out + ack + hb)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "ACTUATOR_OUTPUT_STATUS"]
    assert done == len(hb) + len(out)
    assert frames.decode_leading(b"") == ([], 0)


def test_crc_is_x25_with_the_crc_extra():
    for data in (b"", b"\x00", bytes(range(256)), b"123456789"):
        for extra in (0, 91, 255):
            assert frames.crc(data, extra) == x25(data + bytes((extra,)))
            assert frames.crc(memoryview(bytearray(data)), extra) == x25(data + bytes((extra,)))


# --- the controller's receive paths, with and without the fast path -----------------------------

VEHICLE = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


@st.composite
def telemetry_frames(draw) -> bytes:
    cls = draw(st.sampled_from(frames.HOT))
    payload = random_payload(cls, draw(st.data()))
    signed = draw(st.booleans())
    return frame(cls, payload, seq=draw(u8), system=draw(st.sampled_from([1, 1, 2])),
                 component=draw(st.sampled_from([1, 1, 190])), flags=int(signed),
                 signature=draw(st.binary(min_size=13, max_size=13)) if signed else b"",
                 crc_delta=draw(st.sampled_from([0, 0, 0, 0, 1])))


def signed_by_the_vehicle(cls, stamp: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sign_outgoing(mav, KEY, 0, clock_10us=lambda: stamp)
    return bytes(cls(10_000, 8, [0.5] * 8 + [0.0] * 24).pack(mav))


others = st.one_of(
    st.binary(max_size=40),
    st.just(bytes(mavlink.MAVLink_command_ack_message(400, 0).pack(VEHICLE))),
    st.just(bytes(mavlink.MAVLink_statustext_message(6, b"hello").pack(VEHICLE))),
    st.just(bytes(mav1.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3).pack(
        mav1.MAVLink(None, srcSystem=1, srcComponent=1)))))
parts = st.lists(st.one_of(telemetry_frames(), telemetry_frames().map(lambda f: f[:-3]),
                           others), max_size=6)


def _record(link_cls, connection: str, key: bytes | None):
    got = []
    link = link_cls(Connection.parse(connection), got.append, signing_key=key)
    return link, got


def _same_traffic(fast_link, fast_got, slow_link, slow_got) -> None:
    assert vars(fast_link.stats) == vars(slow_link.stats)
    assert len(fast_got) == len(slow_got)
    for a, b in zip(fast_got, slow_got):
        assert_same_message(a, b)


@FUZZ
@given(parts, st.booleans(), st.booleans())
def test_udp_link_delivers_and_counts_as_pymavlink_alone(datagrams, signed, whole):
    """The same datagrams (each part alone, or all in one) to a link with and one without the
    fast path: the same messages, equal to the last attribute, and the same counters."""
    key = KEY if signed else None
    fast, fast_got = _record(MavlinkUdp, "udpin:127.0.0.1:14540", key)
    slow, slow_got = _record(MavlinkUdp, "udpin:127.0.0.1:14540", key)
    slow.fast_path = False
    sent = [b"".join(datagrams)] if whole else datagrams
    if signed:                                       # and one the check lets through
        sent = sent + [signed_by_the_vehicle(OUTPUTS, now_10us())]
    for d in sent:
        fast.datagram_received(d, ("127.0.0.1", 14580))
        slow.datagram_received(d, ("127.0.0.1", 14580))
    _same_traffic(fast, fast_got, slow, slow_got)
    if signed:
        assert fast_got and all(m.get_signed() is False for m in fast_got)   # checked by us


@FUZZ
@given(parts, st.booleans(), st.lists(st.integers(1, 64), min_size=1, max_size=8))
def test_stream_link_delivers_and_counts_as_pymavlink_alone(chunks, signed, cuts):
    """The same byte stream, cut into reads anywhere, to a stream link with and one without the
    fast path."""
    key = KEY if signed else None
    if signed:                                       # first: nothing before it to swallow it
        chunks = [signed_by_the_vehicle(OUTPUTS, now_10us())] + chunks
    data = b"".join(chunks)
    fast, fast_got = _record(MavlinkStream, "tcpout://127.0.0.1:9", key)
    slow, slow_got = _record(MavlinkStream, "tcpout://127.0.0.1:9", key)
    slow.fast_path = False
    i, k = 0, 0
    while i < len(data):
        n = cuts[k % len(cuts)]
        for link in (fast, slow):
            link.bytes_received(data[i:i + n])
        i, k = i + n, k + 1
    _same_traffic(fast, fast_got, slow, slow_got)
    if signed:
        assert fast_got


# the ids the receive paths see in these tests: what a link may be told it reads
SEEN_IDS = sorted({cls.id for cls in frames.HOT} | {mavlink.MAVLINK_MSG_ID_COMMAND_ACK,
                                                    mavlink.MAVLINK_MSG_ID_STATUSTEXT})


def _logged(link) -> list:
    got = []
    link.on_frame = got.append
    return got


@FUZZ
@given(parts, st.booleans(), st.booleans(), st.frozensets(st.sampled_from(SEEN_IDS)))
def test_a_link_builds_only_the_messages_it_reads(datagrams, signed, whole, wanted):
    """A link told the ids it reads (`wanted`): the messages of those ids delivered as without
    it, every other frame counted and logged as before (on_frame: the same bytes in the same
    order), its message never built nor handed to on_message."""
    key = KEY if signed else None
    fast, fast_got = _record(MavlinkUdp, "udpin:127.0.0.1:14540", key)
    slow, slow_got = _record(MavlinkUdp, "udpin:127.0.0.1:14540", key)
    fast.wanted = wanted
    slow.fast_path = False
    fast_log, slow_log = _logged(fast), _logged(slow)
    sent = [b"".join(datagrams)] if whole else datagrams
    if signed:
        sent = sent + [signed_by_the_vehicle(OUTPUTS, now_10us())]
    for d in sent:
        fast.datagram_received(d, ("127.0.0.1", 14580))
        slow.datagram_received(d, ("127.0.0.1", 14580))
    assert vars(fast.stats) == vars(slow.stats)
    assert fast_log == slow_log
    read = [m for m in slow_got if m.get_msgId() in wanted]
    assert len(fast_got) == len(read)
    for a, b in zip(fast_got, read):
        assert_same_message(a, b)


def test_an_unread_frame_is_checked_and_kept_as_bytes():
    """A frame outside `wanted` (a text-carrying message too, which the fast path never
    unpacks): its bytes, system, component, id and name; a bad checksum or a cut refused."""
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=7)
    text = bytes(mavlink.MAVLink_named_value_float_message(5, b"wind", 3.5).pack(tx))
    odo = frame(ODOMETRY, bytes(range(1, 200)), system=1, component=1)
    hb = bytes(mavlink.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3).pack(tx))
    wanted = frozenset({mavlink.MAVLINK_MSG_ID_HEARTBEAT})
    msgs, done = frames.decode_leading(text + odo + hb, wanted)
    assert done == len(text) + len(odo) + len(hb)
    unread = [m for m in msgs if isinstance(m, frames.Unread)]
    assert [(m.get_type(), m.get_srcSystem(), m.get_srcComponent(), m.get_msgId())
            for m in unread] == [("NAMED_VALUE_FLOAT", 1, 7, mavlink.MAVLINK_MSG_ID_NAMED_VALUE_FLOAT),
                                 ("ODOMETRY", 1, 1, mavlink.MAVLINK_MSG_ID_ODOMETRY)]
    assert [bytes(m.get_msgbuf()) for m in unread] == [text, odo]
    assert msgs[2].get_type() == "HEARTBEAT" and not isinstance(msgs[2], frames.Unread)
    bad = frame(ODOMETRY, bytes(range(1, 200)), crc_delta=1)
    assert frames.decode(bad, wanted) is None
    assert frames.decode(odo[:-1], wanted) is None
    assert frames.decode_leading(hb + bad, wanted)[1] == len(hb)


def test_the_wire_bench_measures_every_pair():
    from trq_lab.bench import wire as bench

    figures = bench.measure(repeat=1, number=1)
    assert set(figures) == set(bench.LABELS)
    for f in figures.values():
        assert f["pymavlink_us"] > 0 and f["fast_us"] > 0
    assert figures["control_period"]["datagrams_per_period"] >= 1
