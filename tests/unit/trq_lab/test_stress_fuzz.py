"""Fuzzing the two MAVLink receive paths (issue 6, hostile and malformed traffic), at CI size.

(a) the vehicle's codec (`Codec.decode`) on arbitrary bytes, bit-flipped and truncated frames and
    concatenations of valid frames and garbage: it never raises, never turns a corrupted frame
    into another message, recovers every valid frame next to marker-free garbage, and its
    counters account for every datagram;
(b) the simulated autopilot (`Sitl.handle`) on decodable messages of the whole common dialect
    with random field values, and on the messages it acts on with hostile values (NaN, inf, out
    of range, other systems): it never raises, every reply packs, the command it holds stays
    finite and inside the actuator ranges and every parameter inside its declared range;
(c) the controller's link (`MavlinkUdp.datagram_received`) on arbitrary bytes, with and without
    signing: it never raises and hands on only whole messages from the vehicle.

The large-size version of the same traffic over real sockets is trq-stress.
"""

from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sitl import Sitl
from trq_lab.stress import frame_v2
from trq_offboard.link.udp import Connection, MavlinkUdp

from conftest import examples

FUZZ = settings(max_examples=examples(150), deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
CLIENT = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
CLIENT_V1 = mav1.MAVLink(None, srcSystem=255, srcComponent=190)
MARKERS = (0xFD, 0xFE)

# --- strategies --------------------------------------------------------------------------------

u8 = st.integers(0, 255)
u16 = st.integers(0, 0xFFFF)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
# hostile floats: the special values and the edges of the ranges, more often than chance would
edgy = st.one_of(f32, st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, 1.0, -1.0,
                                        1.0000001, -1.0000001, 5.0, -5.0, 1e30, -1e30, 21196.0,
                                        101.0, 102.0, 400.0, 4.0, 6.0]))
target_sys = st.sampled_from([0, 1, 1, 1, 2, 255])
PARAM_NAMES = ["SIM_WIND_SPD", "SIM_WIND_DIR", "SIM_GUST_EN", "SIM_GUST_SIG", "SIM_GUST_LEN",
               "SIM_MOT1_EFF", "SIM_MOT2_TVB", "SIM_MOT3_TVW", "SIM_MOT4_TVP", "SIM_MOT1_OFF",
               "SIM_SRV1_STK", "SIM_SRV2_ANG", "COM_OF_LOSS_T"]
param_id = st.one_of(st.sampled_from([n.encode() for n in PARAM_NAMES]),
                     st.binary(min_size=0, max_size=16))
commands = st.one_of(st.sampled_from([
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_DO_SET_MODE,
    mavlink.MAV_CMD_INJECT_FAILURE, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
    mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
    mavlink.MAV_CMD_NAV_TAKEOFF]), u16)


DIALECT = sorted(mavlink.mavlink_map.items())


@st.composite
def random_payload_frames(draw) -> bytes:
    """Any message of the common dialect, every field random bytes (a valid frame)."""
    msg_id, cls = draw(st.sampled_from(DIALECT))
    size = cls.unpacker.size
    payload = draw(st.binary(min_size=size, max_size=size))
    return frame_v2(msg_id, payload, cls.crc_extra, seq=draw(u8))


def _pack(msg) -> bytes:
    return bytes(msg.pack(CLIENT))


semantic_messages = st.one_of(
    st.builds(lambda ts, tc, cmd, conf, p: mavlink.MAVLink_command_long_message(ts, tc, cmd, conf, *p),
              target_sys, u8, commands, u8, st.lists(edgy, min_size=7, max_size=7)),
    st.builds(lambda ts, cmd, p: mavlink.MAVLink_command_int_message(ts, 1, 0, cmd, 0, 0, *p[:4],
                                                                      0, 0, p[4]),
              target_sys, commands, st.lists(edgy, min_size=5, max_size=5)),
    st.builds(lambda ts, name, value, ptype: mavlink.MAVLink_param_set_message(ts, 1, name, value,
                                                                               ptype),
              target_sys, param_id, edgy, u8),
    st.builds(lambda ts, name, index: mavlink.MAVLink_param_request_read_message(ts, 1, name, index),
              target_sys, param_id, st.integers(-32768, 32767)),
    st.builds(lambda ts: mavlink.MAVLink_param_request_list_message(ts, 1), target_sys),
    st.builds(lambda stamp, group, ts, controls: mavlink.MAVLink_set_actuator_control_target_message(
        stamp, group, ts, 1, controls),
        st.one_of(st.just(0), st.integers(0, 2**64 - 1)), st.sampled_from([0, 0, 0, 1, 3]),
        target_sys, st.lists(st.one_of(edgy, st.floats(-1.0, 1.0, width=32)),
                             min_size=8, max_size=8)),
    st.builds(lambda ts, base, custom: mavlink.MAVLink_set_mode_message(ts, base, custom),
              target_sys, u8, st.integers(0, 2**32 - 1)),
    st.builds(lambda ts, mt: mavlink.MAVLink_mission_request_list_message(ts, 1, mt), target_sys, u8),
    st.builds(lambda ts, n: mavlink.MAVLink_mission_count_message(ts, 1, n), target_sys, u16),
    st.builds(lambda ts: mavlink.MAVLink_mission_clear_all_message(ts, 1), target_sys),
    st.builds(lambda ts, seq: mavlink.MAVLink_mission_set_current_message(ts, 1, seq),
              target_sys, u16),
    st.builds(lambda ts, seq, x, y, z: mavlink.MAVLink_mission_item_int_message(
        ts, 1, seq, 0, 16, 0, 1, 0.0, 0.0, 0.0, 0.0, x, y, z),
        target_sys, u16, st.integers(-2**31, 2**31 - 1), st.integers(-2**31, 2**31 - 1), edgy),
    st.builds(lambda t, a, b, c, d: mavlink.MAVLink_heartbeat_message(t, a, b, c, d, 3),
              u8, u8, u8, st.integers(0, 2**32 - 1), u8),
).map(_pack)

valid_frames = st.one_of(semantic_messages, random_payload_frames())
garbage = st.binary(min_size=1, max_size=64)
marker_free_garbage = garbage.map(lambda b: bytes(x for x in b if x not in MARKERS) or b"\x00")


# --- (a) the vehicle's codec -----------------------------------------------------------------------

def _events(c) -> int:
    return c.messages + c.bad_frames + c.unknown_ids + c.unauthenticated


def _decode_checked(codec: Codec, data: bytes) -> list:
    before = _events(codec.counters)
    msgs_before = codec.counters.messages
    datagrams_before = codec.counters.datagrams
    out = codec.decode(data)
    c = codec.counters
    assert c.datagrams == datagrams_before + 1
    assert c.messages - msgs_before == len(out)
    assert c.mavlink1 <= c.messages
    if data:                      # every non-empty datagram leaves a trace in the counters
        assert _events(c) > before
    for m in out:
        assert not isinstance(m, (mavlink.MAVLink_bad_data, mavlink.MAVLink_unknown))
    return out


@FUZZ
@given(st.binary(max_size=600))
def test_codec_random_bytes(data):
    _decode_checked(Codec(), data)


@FUZZ
@given(st.lists(st.tuples(marker_free_garbage, valid_frames), min_size=1, max_size=6),
       st.booleans())
def test_codec_recovers_valid_frames_between_garbage(parts, garbage_first):
    """Garbage without a frame marker between valid frames: every frame is recovered, each
    piece of garbage is counted as one bad frame, and nothing else is made up."""
    data = b"".join((g + f) if garbage_first else f for g, f in parts)
    codec = Codec()
    out = _decode_checked(codec, data)
    assert [bytes(m.get_msgbuf()) for m in out] == [f for _, f in parts]
    assert codec.counters.bad_frames == (len(parts) if garbage_first else 0)
    assert codec.counters.unknown_ids == 0 and codec.counters.other_system == 0


@FUZZ
@given(valid_frames, st.data())
def test_codec_bit_flip_never_makes_another_message(frame, data):
    bit = data.draw(st.integers(0, 8 * len(frame) - 1), label="bit")
    flipped = bytearray(frame)
    flipped[bit // 8] ^= 1 << (bit % 8)
    codec = Codec()
    out = _decode_checked(codec, bytes(flipped))
    # the checksum covers everything but the marker; an id flipped to one the dialect does not
    # have is counted as unknown (its CRC extra is unknown, so the CRC cannot be checked)
    for m in out:
        assert bytes(m.get_msgbuf()) in frame, "a corrupted frame became another message"
    assert len(out) <= 1


@FUZZ
@given(valid_frames, st.data())
def test_codec_truncated_frame(frame, data):
    cut = data.draw(st.integers(0, len(frame) - 1), label="cut")
    codec = Codec()
    out = _decode_checked(codec, frame[:cut])
    assert out == [] and (cut == 0 or codec.counters.bad_frames >= 1)


@FUZZ
@given(st.lists(st.one_of(valid_frames, garbage,
                          valid_frames.map(lambda f: f[:-1]),                  # truncated
                          valid_frames.map(lambda f: f[:-2] + bytes([f[-2] ^ 0x5A, f[-1]])),
                          st.builds(lambda m: bytes(m.pack(CLIENT_V1)),         # MAVLink 1
                                    st.just(mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)))),
                max_size=8))
def test_codec_concatenations(parts):
    codec = Codec()
    _decode_checked(codec, b"".join(parts))
    # the same bytes again, as many datagrams: still nothing raises, counts keep adding up
    for p in parts:
        _decode_checked(codec, p)


KEY = bytes(range(32))


@FUZZ
@given(st.lists(st.one_of(garbage, valid_frames, st.binary(min_size=1, max_size=40).map(
    lambda b: b"\xfd" + bytes([len(b), 1]) + b)), max_size=6), st.booleans(), st.data())
def test_codec_with_signing_never_raises_nor_trusts_unsigned(parts, read_only, data):
    """Signing on: anything unsigned (or signed with another key, or truncated) is refused,
    except read-only requests where allowed; nothing raises."""
    from trq_wire.signing import READ_ONLY_IDS, SignatureCheck, sign_outgoing

    forger = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    sign_outgoing(forger, bytes(32), 0)                  # the wrong key
    forged = bytes(mavlink.MAVLink_command_long_message(
        1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(forger))
    if data.draw(st.booleans(), label="append a forged ARM"):
        parts = parts + [forged]
    codec = Codec(check=SignatureCheck(KEY, allow_unsigned_read_only=read_only))
    out = _decode_checked(codec, b"".join(parts))
    for m in out:
        assert read_only and m.get_msgId() in READ_ONLY_IDS


def test_codec_counts_each_kind():
    codec = Codec()
    good = _pack(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3))
    bad_crc = good[:-2] + bytes([good[-2] ^ 0xFF, good[-1]])
    unknown = frame_v2(0xABCDE, b"\x01\x02\x03", 0)
    v1 = bytes(mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(CLIENT_V1))
    for data in (good, bad_crc, unknown, v1, good[:5], b"\x00\x01\x02"):
        codec.decode(data)
    c = codec.counters
    assert (c.datagrams, c.messages, c.mavlink1, c.unknown_ids) == (6, 2, 1, 1)
    assert c.bad_frames == 3          # bad CRC, truncated header, garbage


# --- (b) the simulated autopilot ----------------------------------------------------------------

def _check_vehicle(sitl: Sitl) -> None:
    vp = sitl.sim.vehicle
    cmd = sitl.vehicle.command
    assert len(cmd.throttle_pct) == 4 and len(cmd.tilt_rad) == 4
    for v in cmd.throttle_pct:
        assert math.isfinite(v) and 0.0 <= v <= 100.0, cmd
    for a in cmd.tilt_rad:
        assert math.isfinite(a) and vp.tilt_min_rad - 1e-9 <= a <= vp.tilt_max_rad + 1e-9, cmd
    s = sitl.state
    assert all(math.isfinite(v) for v in s.x) and all(math.isfinite(v) for v in s.motor_pct)
    for i, p in enumerate(sitl.params.params):
        value = sitl.params.value(i)
        assert math.isfinite(value) and p.lo <= value <= p.hi, (p.name, value)


_REPLY_CODEC = Codec()


def _feed(sitl: Sitl, frame: bytes, link: str) -> None:
    msgs = Codec().decode(frame)
    for msg in msgs:
        out = sitl.handle(link, msg, ("127.0.0.1", 14555))
        for o in out:                  # every reply packs (names fit, values in range)
            _REPLY_CODEC.encode(o.msg)
        _check_vehicle(sitl)
    for _ in range(3):
        for o in sitl.step():
            _REPLY_CODEC.encode(o.msg)
    _check_vehicle(sitl)


def _sitl(sim, mode: str) -> Sitl:
    sitl = Sitl(sim.with_changes(clock_mode=mode))
    sitl.telemetry_due()
    return sitl


ARM = _pack(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                                 1.0, 0, 0, 0, 0, 0, 0))


@FUZZ
@given(st.lists(st.tuples(st.one_of(semantic_messages, random_payload_frames()),
                          st.sampled_from(["offboard", "gcs"])), min_size=1, max_size=12),
       st.sampled_from(["realtime", "lockstep"]), st.booleans())
def test_sitl_handles_any_message(sim, messages, mode, armed):
    sitl = _sitl(sim, mode)
    if armed:
        _feed(sitl, ARM, "gcs")
    for frame, link in messages:
        _feed(sitl, frame, link)


@FUZZ
@given(st.lists(st.one_of(edgy, st.floats(-1.5, 1.5, width=32)), min_size=8, max_size=8),
       st.sampled_from([0, 0, 1]), st.sampled_from([0, 1, 2]))
def test_sitl_applies_only_valid_targets(sim, controls, group, ts):
    sitl = _sitl(sim, "realtime")
    _feed(sitl, ARM, "gcs")
    before = sitl.vehicle.command
    applied = sitl.targets_applied
    rejected = sitl.counters["offboard"].rejected_targets
    other = sitl.counters["offboard"].other_system
    msg = mavlink.MAVLink_set_actuator_control_target_message(10, group, ts, 1, controls)
    (decoded,) = Codec().decode(_pack(msg))
    sitl.handle("offboard", decoded, ("127.0.0.1", 14555))
    wire = decoded.controls                  # float32 on the wire
    valid = (group == 0 and ts in (0, 1) and all(math.isfinite(v) for v in wire)
             and all(0.0 <= v <= 1.0 for v in wire[:4]) and all(-1.0 <= v <= 1.0 for v in wire[4:]))
    if valid:
        assert sitl.targets_applied == applied + 1
        assert sitl.vehicle.command.throttle_pct == tuple(100.0 * v for v in wire[:4])
    else:
        assert sitl.targets_applied == applied and sitl.vehicle.command == before
        if ts == 2:
            assert sitl.counters["offboard"].other_system == other + 1
        else:
            assert sitl.counters["offboard"].rejected_targets == rejected + 1
    _check_vehicle(sitl)


# --- (c) the controller's link ------------------------------------------------------------------

VEHICLE = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


def _vehicle_frame() -> bytes:
    return bytes(mavlink.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3).pack(VEHICLE))


@FUZZ
@given(st.lists(st.one_of(garbage, st.binary(max_size=300), valid_frames,
                          st.just(_vehicle_frame()), st.just(_vehicle_frame()[:-3])),
                max_size=6),
       st.booleans(), st.booleans())
def test_controller_link_random_bytes(parts, signed, raising):
    got = []

    def on_message(msg):
        got.append(msg)
        if raising:
            raise RuntimeError("a callback that fails")

    link = MavlinkUdp(Connection.parse("udpin:127.0.0.1:14540"), on_message,
                      signing_key=bytes(range(32)) if signed else None)
    link.datagram_received(b"".join(parts), ("127.0.0.1", 14580))
    for p in parts:
        link.datagram_received(p, ("127.0.0.1", 14580))
    assert link.stats.datagrams == len(parts) + 1
    for m in got:
        assert m.get_srcSystem() == 1 and not isinstance(m, mavlink.MAVLink_bad_data)
    if signed:
        assert got == []               # nothing unsigned is trusted
    assert link.stats.messages == len(got)


def test_controller_link_locks_onto_the_vehicle_that_talks():
    """udpin: the first sender of valid vehicle messages is the peer; a second address with the
    same system id neither receives the commands nor feeds states while the first one talks;
    after PEER_TIMEOUT_S of silence a vehicle restarted on another port is taken."""
    from trq_offboard.link.udp import PEER_TIMEOUT_S

    now = [0.0]
    got = []
    link = MavlinkUdp(Connection.parse("udpin:127.0.0.1:14540"),
                      lambda m: got.append(m), monotonic=lambda: now[0])
    vehicle, intruder = ("127.0.0.1", 14580), ("127.0.0.1", 9999)
    link.datagram_received(_vehicle_frame(), vehicle)
    assert link.peer == vehicle and len(got) == 1
    now[0] += PEER_TIMEOUT_S / 2
    link.datagram_received(_vehicle_frame(), intruder)
    assert link.peer == vehicle and len(got) == 1 and link.stats.other_peer == 1
    link.datagram_received(_vehicle_frame(), vehicle)           # the vehicle talks on
    now[0] += PEER_TIMEOUT_S * 0.9
    link.datagram_received(_vehicle_frame(), intruder)
    assert link.peer == vehicle and link.stats.other_peer == 2
    now[0] += PEER_TIMEOUT_S                                      # the vehicle went silent
    link.datagram_received(_vehicle_frame(), intruder)
    assert link.peer == intruder and len(got) == 3
