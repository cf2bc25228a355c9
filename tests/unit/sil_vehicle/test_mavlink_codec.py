"""The MAVLink codec (sil_vehicle.mavlink.codec): framing, error counting, target decoding and
the telemetry fields' integer scalings, against hand-computed values. The actuator scalings
are trq_wire.actuators' (tests/unit/trq_wire/test_actuators.py), signing trq_wire.signing's
(tests/unit/trq_wire/test_signing.py); here only how the codec uses them."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v10 import common as mav1
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.frames import euler_to_quat
from sil_vehicle.mavlink import codec
from sil_vehicle.mavlink.codec import Codec, Measured
from trq_wire.signing import SignatureCheck, sign_outgoing

from conftest import examples

LIMIT = math.radians(30.0)


def target_msg(controls, stamp=1234, group=0):
    return mavlink.MAVLink_set_actuator_control_target_message(stamp, group, 1, 1, list(controls))


def client_bytes(msg, system=255, component=190) -> bytes:
    return bytes(msg.pack(mavlink.MAVLink(None, srcSystem=system, srcComponent=component)))


MEASURED = Measured(2_500_000, (10.0, -20.0, -5.0), (1.0, -2.0, 0.5),
                    euler_to_quat(0.1, -0.2, 1.0), (0.3, -0.4, 0.5))


# --- framing ----------------------------------------------------------------------------------

def test_round_trip_of_several_messages():
    tx, rx = Codec(), Codec()
    sent = [
        codec.heartbeat(True, False, True),
        codec.odometry(MEASURED),
        codec.param_value("SIM_WIND_SPD", 3.5, 33, 0),
        codec.statustext(mavlink.MAV_SEVERITY_INFO, "armed"),
        codec.command_ack(400, mavlink.MAV_RESULT_ACCEPTED, 255, 190),
        target_msg([0.5, 0.6, 0.7, 0.8, -1.0, -0.5, 0.5, 1.0]),
    ]
    got = []
    for msg in sent:
        got += rx.decode(tx.encode(msg))
    assert [m.get_type() for m in got] == [m.get_type() for m in sent]
    assert [m.get_seq() for m in got] == list(range(len(sent)))          # sequence advances
    assert all(m.get_srcSystem() == 1 and m.get_srcComponent() == 1 for m in got)
    hb, odo, pv, st_, ack, tgt = got
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink.MAV_STATE_ACTIVE
    assert odo.time_usec == 2_500_000 and (odo.x, odo.y, odo.z) == (10.0, -20.0, -5.0)
    assert odo.frame_id == odo.child_frame_id == mavlink.MAV_FRAME_LOCAL_NED
    assert odo.q == pytest.approx(MEASURED.quat_wxyz, abs=1e-7)
    assert (odo.vx, odo.vy, odo.vz) == (1.0, -2.0, 0.5)
    assert odo.yawspeed == pytest.approx(0.5)
    assert math.isnan(odo.pose_covariance[0])
    assert pv.param_id == "SIM_WIND_SPD" and pv.param_value == 3.5 and pv.param_count == 33
    assert pv.param_type == mavlink.MAV_PARAM_TYPE_REAL32
    assert st_.text == "armed"
    assert ack.command == 400 and ack.target_system == 255
    assert tgt.controls == pytest.approx([0.5, 0.6, 0.7, 0.8, -1.0, -0.5, 0.5, 1.0])
    assert rx.counters.messages == len(sent) and rx.counters.datagrams == len(sent)
    assert rx.counters.dropped == 0


def test_several_frames_in_one_datagram_and_mavlink1():
    a = client_bytes(mavlink.MAVLink_param_request_list_message(1, 1))
    b = bytes(mav1.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav1.MAVLink(None, 255, 190)))
    assert b[0] == 0xFE
    c = Codec()
    msgs = c.decode(a + b + a)
    assert [m.get_type() for m in msgs] == ["PARAM_REQUEST_LIST", "HEARTBEAT", "PARAM_REQUEST_LIST"]
    assert c.counters.mavlink1 == 1 and c.counters.messages == 3 and c.counters.datagrams == 1


def test_truncated_frames_are_counted():
    frame = client_bytes(target_msg([0.5] * 4 + [0.0] * 4))
    for cut in range(1, len(frame)):
        c = Codec()
        assert c.decode(frame[:cut]) == []
        assert c.counters.bad_frames >= 1 and c.counters.messages == 0


def test_bad_crc_is_counted_and_the_next_frame_survives():
    frame = bytearray(client_bytes(mavlink.MAVLink_param_request_list_message(1, 1)))
    frame[-1] ^= 0xFF
    good = client_bytes(mavlink.MAVLink_param_request_list_message(1, 1))
    c = Codec()
    assert c.decode(bytes(frame)) == []
    assert c.counters.bad_frames == 1
    msgs = c.decode(b"\x00garbage" + bytes(frame) + good)
    assert [m.get_type() for m in msgs] == ["PARAM_REQUEST_LIST"]
    assert c.counters.bad_frames >= 3 and c.counters.messages == 1


def test_unknown_message_id_is_counted():
    frame = bytearray(client_bytes(mavlink.MAVLink_param_request_list_message(1, 1)))
    frame[7:10] = bytes([0x00, 0xF0, 0xFF])            # message id 0xFFF000: not in the dialect
    c = Codec()
    assert c.decode(bytes(frame)) == []
    assert c.counters.unknown_ids == 1 and c.counters.bad_frames == 0


@settings(max_examples=examples(300), deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_never_raise(data):
    c = Codec()
    msgs = c.decode(data)
    assert c.counters.datagrams == 1
    assert c.counters.messages == len(msgs)
    if data and data[0] not in (0xFD, 0xFE):
        assert c.counters.bad_frames >= 1


@settings(max_examples=examples(200), deadline=None)
@given(st.binary(min_size=1, max_size=64), st.integers(0, 400))
def test_corrupted_valid_frames_never_raise(noise, where):
    frame = bytearray(client_bytes(target_msg([0.5] * 4 + [0.0] * 4)))
    where %= len(frame)
    frame[where:where + len(noise)] = noise
    c = Codec()
    c.decode(bytes(frame))
    assert c.counters.datagrams == 1


def test_empty_datagram():
    c = Codec()
    assert c.decode(b"") == []
    assert c.counters.datagrams == 1 and c.counters.dropped == 0


# --- actuator targets -------------------------------------------------------------------------

def test_decode_target_scales():
    t = codec.decode_target(target_msg([0.0, 0.25, 0.5, 1.0, -1.0, -0.5, 0.0, 1.0], 777), LIMIT)
    assert t.stamp_us == 777
    assert t.throttle_pct == pytest.approx((0.0, 25.0, 50.0, 100.0))
    assert t.tilt_rad == pytest.approx((-LIMIT, -LIMIT / 2, 0.0, LIMIT))


def test_decode_target_rejects_the_whole_message():
    """One bad value (trq_wire.actuators.controls_in_range) and nothing of it is applied."""
    assert codec.decode_target(target_msg([0.5] * 4 + [0.2, 0.2, math.nan, 0.2]), LIMIT) is None
    assert codec.decode_target(target_msg([0.5, 1.01] + [0.5] * 2 + [0.2] * 4), LIMIT) is None


def test_decode_target_rejects_other_groups():
    assert codec.decode_target(target_msg([0.5] * 8, group=1), LIMIT) is None
    assert codec.decode_target(target_msg([0.5] * 8, group=3), LIMIT) is None


def test_decode_target_after_the_wire():
    c = Codec()
    (msg,) = c.decode(client_bytes(target_msg([0.5, 0.5, 0.5, 0.5, 0.1, 0.2, 0.3, 0.4], 20_000)))
    t = codec.decode_target(msg, LIMIT)
    assert t.stamp_us == 20_000 and t.throttle_pct[0] == pytest.approx(50.0)
    assert t.tilt_rad[3] == pytest.approx(0.4 * LIMIT, rel=1e-6)         # float32 on the wire


# --- actuator outputs ------------------------------------------------------------------------

def test_servo_output_raw_and_actuator_output_status():
    msg = codec.servo_output_raw(5_000_000_123, (0.0, 50.0, 100.0, 10.0),
                                 (0.0, LIMIT, -LIMIT, LIMIT / 2), LIMIT)
    assert msg.time_usec == 5_000_000_123 & 0xFFFFFFFF
    raw = [getattr(msg, f"servo{i}_raw") for i in range(1, 9)]
    assert raw == [1000, 1500, 2000, 1100, 1500, 2000, 1000, 1750]
    Codec().encode(msg)                                   # packs: the fields fit
    st_ = codec.actuator_output_status(7, (0.0, 50.0, 100.0, 10.0), (0.0, LIMIT, -LIMIT, 0.0),
                                       LIMIT)
    assert st_.active == 8
    assert st_.actuator[:8] == pytest.approx([0.0, 0.5, 1.0, 0.1, 0.0, 1.0, -1.0, 0.0])


def test_global_position_int_scalings():
    home = (51.5246, -0.134, 30.0)
    msg = codec.global_position_int(MEASURED, home)
    # 10 m north: 10 / 6378137 rad; -20 m east at 51.5246 deg
    lat = 51.5246 + math.degrees(10.0 / 6_378_137.0)
    lon = -0.134 + math.degrees(-20.0 / (6_378_137.0 * math.cos(math.radians(51.5246))))
    assert msg.lat == round(lat * 1e7) and msg.lon == round(lon * 1e7)
    assert msg.alt == 35_000 and msg.relative_alt == 5_000                # mm
    assert (msg.vx, msg.vy, msg.vz) == (100, -200, 50)                    # cm/s
    assert msg.hdg == round(math.degrees(1.0) * 100)                      # cdeg
    assert msg.time_boot_ms == 2500
    Codec().encode(msg)


def test_attitude_and_local_position():
    att = codec.attitude(MEASURED)
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.1, -0.2, 1.0), abs=1e-12)
    assert att.time_boot_ms == 2500 and att.yawspeed == 0.5
    lp = codec.local_position_ned(MEASURED)
    assert (lp.x, lp.y, lp.z, lp.vx, lp.vy, lp.vz) == (10.0, -20.0, -5.0, 1.0, -2.0, 0.5)


def test_heartbeat_states():
    assert codec.heartbeat(False, False, False).system_status == mavlink.MAV_STATE_STANDBY
    assert codec.heartbeat(False, True, False).system_status == mavlink.MAV_STATE_EMERGENCY
    assert not codec.heartbeat(False, False, False).base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_statustext_truncated_to_50():
    msg = codec.statustext(mavlink.MAV_SEVERITY_INFO, "x" * 80)
    (back,) = Codec().decode(Codec().encode(msg))
    assert back.text == "x" * 50


def test_signing_check_counts_unauthenticated_frames():
    key, now = bytes(range(32)), 300_000_000_000
    c = Codec(check=SignatureCheck(key, clock_10us=lambda: now))
    signed = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    sign_outgoing(signed, key, 0, clock_10us=lambda: now)
    msg = mavlink.MAVLink_param_request_list_message(1, 1)
    assert len(c.decode(bytes(msg.pack(signed)))) == 1
    assert c.decode(client_bytes(msg)) == []
    assert c.counters.unauthenticated == 1 and c.counters.messages == 1
