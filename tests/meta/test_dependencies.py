"""The installed environment is the one pyproject.toml promises."""

from __future__ import annotations


def test_pymavlink_uses_the_fast_crc():
    """fastcrc (a dependency) is what pymavlink's CRC runs on: without it every MAVLink frame is
    checksummed byte by byte in Python (an ODOMETRY: about 56 us to pack, 61 us to parse,
    against 6 and 14 us), which both daemons pay on every message."""
    from pymavlink.dialects.v20 import common

    assert common.x25crc is common._x25crc_fast
    frame = common.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(
        common.MAVLink(None, srcSystem=1, srcComponent=1))
    # the fast CRC agrees with the reference implementation on a real frame
    body = bytes(frame[1:-2])
    slow, fast = common._x25crc_slow(body), common._x25crc_fast(body)
    slow.accumulate(bytes([common.MAVLink_heartbeat_message.crc_extra]))
    fast.accumulate(bytes([common.MAVLink_heartbeat_message.crc_extra]))
    assert fast.crc == slow.crc == int.from_bytes(frame[-2:], "little")
