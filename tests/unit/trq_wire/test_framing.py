"""MAVLink on a byte stream (trq_wire.framing): frames split over reads, garbage, cuts mid-frame,
bad checksums and false magics; the serial line's pace with an injected clock; the vehicle's
serial budget against hand-computed frame sizes."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink
from trq_params import builtin

from sil_vehicle.config import LinkParams, SerialPort, load_sim
from sil_vehicle.daemon import serial_budget
from trq_wire.framing import LinePacer, StreamFramer, frame_size, line_bytes_per_s
from trq_wire.signing import sign_outgoing

from conftest import examples

KEY = bytes(range(32))


def frames(n: int, signed: bool = False) -> list[bytes]:
    """n real frames of several sizes (ODOMETRY, HEARTBEAT, STATUSTEXT, a target)."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    if signed:
        sign_outgoing(mav, KEY)
    out = []
    for i in range(n):
        msg = [mavlink.MAVLink_odometry_message(i, 1, 1, 0.1 * i, 2.0, -1.0, [1, 0, 0, 0], 0.5,
                                                0, 0, 0.01, 0, 0, [float("nan")] * 21,
                                                [float("nan")] * 21, 0, 0, 100),
               mavlink.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3),
               mavlink.MAVLink_statustext_message(4, b"motor 1 at 52 %"),
               mavlink.MAVLink_set_actuator_control_target_message(
                   i, 0, 1, 1, [0.5] * 4 + [0.0] * 4)][i % 4]
        data = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        out.append(data)
    return out


def feed_all(framer: StreamFramer, chunks) -> list[bytes]:
    got = []
    for chunk in chunks:
        got += framer.feed(chunk)
    return got


def test_whole_frames_in_one_read():
    fs = frames(12)
    f = StreamFramer()
    assert f.feed(b"".join(fs)) == fs and f.bad == 0 and f.pending == 0


@pytest.mark.parametrize("signed", [False, True])
def test_a_frame_split_over_reads_at_every_byte(signed):
    fs = frames(4, signed)
    stream = b"".join(fs)
    for cut in range(1, len(stream)):
        f = StreamFramer()
        assert feed_all(f, [stream[:cut], stream[cut:]]) == fs and f.bad == 0, cut


def test_one_byte_at_a_time():
    fs = frames(8, signed=True)
    stream = b"".join(fs)
    f = StreamFramer()
    assert feed_all(f, [stream[i:i + 1] for i in range(len(stream))]) == fs and f.bad == 0


def test_garbage_before_between_and_after_frames_is_skipped_and_counted_once_a_run():
    fs = frames(3)
    junk = b"\x00\x01booting PX4...\r\n\xff\x55"
    f = StreamFramer()
    got = f.feed(junk + fs[0] + junk + fs[1] + fs[2] + junk)
    assert got == fs and f.bad == 3


def test_garbage_full_of_false_magics_never_hides_the_next_frame():
    # bytes that look like MAVLink headers (magics, plausible lengths, real message ids)
    rng = random.Random(7)
    fs = frames(20)
    junk = bytes(rng.choice([0xFD, 0xFE, 0x00, 0x21, 0x4B, 0x01]) for _ in range(600))
    f = StreamFramer()
    got = f.feed(junk + b"".join(fs))
    assert got == fs and f.bad >= 1


def test_a_cut_mid_frame_costs_that_frame_only():
    fs = frames(6)
    for cut in range(1, len(fs[2])):          # frame 2 loses its tail at every length
        f = StreamFramer()
        got = f.feed(b"".join(fs[:2]) + fs[2][:cut] + b"".join(fs[3:]))
        assert got == fs[:2] + fs[3:] and f.bad == 1, cut


def test_a_bad_checksum_drops_that_frame_and_resynchronises():
    fs = frames(3)
    broken = bytearray(fs[1])
    broken[12] ^= 0x40                        # a payload bit flipped on the line
    f = StreamFramer()
    assert f.feed(fs[0] + bytes(broken) + fs[2]) == [fs[0], fs[2]] and f.bad == 1


def test_an_unknown_message_id_is_garbage_on_a_stream():
    fs = frames(2)
    unknown = bytearray(fs[1])
    unknown[7:10] = (0xFFFFFE).to_bytes(3, "little")
    f = StreamFramer()
    assert f.feed(fs[0] + bytes(unknown) + fs[0]) == [fs[0], fs[0]] and f.bad == 1


def test_an_incomplete_frame_waits_for_the_next_read():
    fs = frames(1)
    f = StreamFramer()
    assert f.feed(fs[0][:-1]) == [] and f.pending == len(fs[0]) - 1 and f.bad == 0
    assert f.feed(fs[0][-1:]) == fs and f.pending == 0


def test_random_cuts_and_noise_keep_every_intact_frame():
    rng = random.Random(11)
    fs = frames(200)
    stream, intact = bytearray(), []
    for fr in fs:
        r = rng.random()
        if r < 0.1:
            stream += fr[:rng.randrange(1, len(fr))]               # cut
        elif r < 0.2:
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
            stream += fr
            intact.append(fr)
        else:
            stream += fr
            intact.append(fr)
    f = StreamFramer()
    chunks, i = [], 0
    while i < len(stream):
        n = rng.randrange(1, 300)
        chunks.append(bytes(stream[i:i + n]))
        i += n
    assert feed_all(f, chunks) == intact


def test_a_cut_in_a_signature_costs_the_next_frame_too():
    """The checksum does not cover the signature: a frame cut inside its 13 signature bytes
    looks whole and takes the next frame's first bytes as its signature (the receiver's
    signature check then refuses it); the frame after that is whole again."""
    fs = frames(4, signed=True)
    f = StreamFramer()
    got = f.feed(fs[0] + fs[1][:-5] + fs[2] + fs[3])
    assert got[0] == fs[0] and got[-1] == fs[3] and fs[2] not in got


# --- frame sizes and the budget --------------------------------------------------------------

def test_frame_sizes_by_hand():
    # ODOMETRY's payload: 233 bytes with its extensions; MAVLink 2: 10 header + 2 checksum
    assert frame_size(mavlink.MAVLink_odometry_message) == 10 + 233 + 2
    assert frame_size(mavlink.MAVLink_heartbeat_message, signed=True) == 10 + 9 + 2 + 13
    # a packed frame is at most that long (MAVLink 2 drops the payload's trailing zeros)
    for fr in frames(4) + frames(4, signed=True):
        kind = mavlink.mavlink_map[int.from_bytes(fr[7:10], "little")]
        assert len(fr) <= frame_size(kind, signed=bool(fr[2] & 1))


def test_line_rate_is_baud_over_ten():
    assert line_bytes_per_s(921600) == 92160 and line_bytes_per_s(57600) == 5760


def test_serial_budget_by_hand():
    sim = load_sim(builtin("sim", "default"))
    rates = dict(sim.link("offboard").rates_hz)
    link = LinkParams("offboard", sim.link("offboard").bind, sim.link("offboard").target,
                      sim.link("offboard").rates_hz, serial=SerialPort("/dev/null", 921600))
    size = {"HEARTBEAT": 9, "SYS_STATUS": 43, "ODOMETRY": 233, "ATTITUDE": 28,
            "LOCAL_POSITION_NED": 28, "SERVO_OUTPUT_RAW": 37, "ACTUATOR_OUTPUT_STATUS": 140,
            "GLOBAL_POSITION_INT": 28, "GPS_RAW_INT": 52, "HOME_POSITION": 60,
            "HIGHRES_IMU": 63, "ATT_POS_MOCAP": 120, "ESTIMATOR_STATUS": 42,
                "EXTENDED_SYS_STATE": 2}
    for signed in (False, True):
        expected = sum(rates[s] * (size[s] + 12 + (13 if signed else 0)) for s in rates)
        assert serial_budget(link, signed) == (expected, 92160)
    slow = LinkParams("offboard", link.bind, link.target, link.rates_hz,
                      serial=SerialPort("/dev/null", 57600))
    needed, available = serial_budget(slow, False)
    assert available == 5760 and needed > 0.8 * available      # too rich for 57600 baud


# --- the pacer ---------------------------------------------------------------------------------

class Clock:
    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def __call__(self) -> int:
        return self.ns


def test_pacer_releases_bytes_when_the_line_has_carried_them():
    clock = Clock()
    p = LinePacer(1000, clock)                  # 1000 bytes a second: 1 ms a byte
    t0 = clock.ns
    assert p.push(b"a" * 10) == t0 + 10_000_000
    assert p.push(b"b" * 5) == t0 + 15_000_000  # behind the first
    assert p.due() == b"" and p.wait_ns() == 10_000_000
    clock.ns = t0 + 9_999_999
    assert p.due() == b""
    clock.ns = t0 + 10_000_000
    assert p.due() == b"a" * 10 and p.wait_ns() == 5_000_000
    clock.ns = t0 + 20_000_000
    assert p.due() == b"b" * 5 and p.next_due_ns() is None and p.queued_bytes == 0


def test_an_idle_line_starts_afresh():
    clock = Clock()
    p = LinePacer(1000, clock)
    p.push(b"x" * 4)
    clock.ns += 1_000_000_000                   # long idle: no credit is saved up
    t = clock.ns
    assert p.push(b"y" * 2) == t + 2_000_000


def test_a_too_rich_stream_shows_as_growing_latency():
    clock = Clock()
    p = LinePacer(92160, clock)
    latencies = []
    for _ in range(100):                        # 100 ms of 1.5 times what the line carries
        release = p.push(b"z" * 138)            # 138 bytes a millisecond: 138000 B/s
        latencies.append(release - clock.ns)
        clock.ns += 1_000_000
        p.due()
    # the line stays busy: the 100th push leaves when 13800 bytes have been carried
    assert latencies == sorted(latencies)
    assert latencies[-1] == -(-13800 * 1_000_000_000 // 92160) - 99_000_000
    assert p.max_latency_ns == latencies[-1]


def test_no_rounding_accumulates():
    clock = Clock()
    p = LinePacer(3, clock)                     # a third of a second a byte: not exact in ns
    t0 = clock.ns
    for _ in range(3000):
        last = p.push(b"q")
    assert last == t0 + 1000 * 1_000_000_000    # 3000 bytes at 3 a second: exactly 1000 s


def test_pacer_refuses_a_zero_rate():
    with pytest.raises(ValueError, match="positive"):
        LinePacer(0, Clock())


@settings(max_examples=examples(300), deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=300), st.sampled_from(frames(4) + frames(4, True))),
                max_size=30), st.lists(st.integers(1, 400), min_size=1, max_size=20))
def test_any_bytes_in_any_chunks_never_raise_and_give_only_checksummed_frames(parts, sizes):
    # then the line goes on idle (zero bytes, no magic): a plausible header in the garbage waits
    # for the bytes that complete or refute it (its checksum), as on a live line, where the
    # frames behind it come out with the next read
    stream = b"".join(parts) + bytes(300)
    f, got, i, k = StreamFramer(), [], 0, 0
    while i < len(stream):
        n = sizes[k % len(sizes)]
        got += f.feed(stream[i:i + n])
        i, k = i + n, k + 1
    rx = mavlink.MAVLink(None)
    for fr in got:
        rx.decode(bytearray(fr))                 # a real frame: decodes, checksum right
    # every whole frame is found, in order (garbage may at worst add a frame of its own, if
    # its bytes happen to form a header and a right checksum)
    real = set(frames(4) + frames(4, True))
    found = iter(got)
    assert all(any(fr == g for g in found) for fr in parts if fr in real)
