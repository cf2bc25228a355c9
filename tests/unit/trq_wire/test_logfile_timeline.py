"""The controller's offboard.tlog stamps (issue 20): the vehicle's own time from its ODOMETRY,
anchored at the wall time of the first, so that a lockstep flight reads on its own timeline
in MAVExplorer or mavlogdump.py, as the vehicle's vehicle.tlog does."""

from __future__ import annotations

import math
import struct

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.logfile import Tlog, VehicleTimeline

NAN21 = [math.nan] * 21


def _frame(msg, component: int = 1) -> bytes:
    return bytes(msg.pack(mavlink.MAVLink(None, srcSystem=1, srcComponent=component)))


def _odometry(t_us: int, component: int = 1) -> bytes:
    return _frame(mavlink.MAVLink_odometry_message(
        t_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0.0, 0.0, -1.0,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, NAN21, NAN21, 0, 0, 100),
        component)


def _stamps(path) -> list[int]:
    data, out, i = path.read_bytes(), [], 0
    while i < len(data):
        out.append(struct.unpack_from(">Q", data, i)[0])
        i += 8 + 12 + data[i + 9]               # stamp, header + checksum, payload (unsigned)
    return out


class _Wall:
    def __init__(self, us: int) -> None:
        self.us = us

    def __call__(self) -> int:
        return self.us


def test_the_wall_clock_until_the_vehicle_speaks_then_the_vehicles_time():
    wall = _Wall(1_700_000_000_000_000)
    tl = VehicleTimeline(wall)
    assert tl.now_us() == wall.us
    tl.heard(_odometry(5_000_000))
    anchor = wall.us
    assert tl.now_us() == anchor
    wall.us += 7_000_000                            # a slow lockstep run: 7 s of wall ...
    tl.heard(_odometry(5_010_000))                  # ... for 10 ms of flight
    assert tl.now_us() == anchor + 10_000


def test_only_the_autopilots_odometry_moves_it_and_never_backwards():
    wall = _Wall(10**15)
    tl = VehicleTimeline(wall)
    tl.heard(_odometry(2_000_000))
    tl.heard(_odometry(9_000_000, component=191))   # not the autopilot
    heartbeat = _frame(mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))
    tl.heard(heartbeat)
    tl.heard(b"\xfd\x01garbage")
    assert tl.now_us() == 10**15
    tl.heard(_odometry(2_500_000))
    tl.heard(_odometry(2_400_000))                  # late, reordered: the time stands
    assert tl.now_us() == 10**15 + 500_000


def test_a_restarted_vehicle_is_anchored_again():
    wall = _Wall(10**15)
    tl = VehicleTimeline(wall)
    tl.heard(_odometry(30_000_000))
    wall.us += 40_000_000
    tl.heard(_odometry(0))                          # a new vehicle process, time 0
    assert tl.now_us() == wall.us


def test_a_tlog_on_the_timeline(tmp_path):
    wall = _Wall(1_700_000_000_000_000)
    tl = VehicleTimeline(wall)
    log = Tlog(tmp_path / "offboard.tlog", clock=tl.now_us)
    for k in range(3):
        frame = _odometry(1_000_000 + 10_000 * k)
        tl.heard(frame)
        log(frame)
        wall.us += 3_000_000                        # each period three wall seconds
    log.close()
    t = _stamps(tmp_path / "offboard.tlog")
    assert [b - t[0] for b in t] == [0, 10_000, 20_000]
