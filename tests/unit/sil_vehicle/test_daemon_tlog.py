"""The vehicle's .tlog stamps (issue 20): in lockstep the start's wall time plus the simulated
time, so that a log viewer shows the flight on its own timeline however long the run took; in
real time the wall clock. The wall clock is injected, so the stamps are checked exactly."""

from __future__ import annotations

import struct

from sil_vehicle.daemon import VehicleDaemon
from sil_vehicle.sitl import LINKS

START_US = 1_700_000_000_000_000


class _Transport:
    """A datagram transport that swallows what is sent (no sockets in a unit test)."""

    def sendto(self, data, addr) -> None:
        pass


def daemon(sim, log_dir, walls):
    d = VehicleDaemon(sim, log_dir, wall_us=lambda: next(walls))
    d.transports = {name: _Transport() for name in LINKS}
    return d


def frames(path):
    """The stamp (us) of every record of a .tlog of unsigned MAVLink 2 frames."""
    data, out, i = path.read_bytes(), [], 0
    while i < len(data):
        (stamp,) = struct.unpack(">Q", data[i:i + 8])
        length = data[i + 9]                       # MAVLink 2: magic, then payload length
        out.append(stamp)
        i += 8 + 12 + length                       # header 10 + checksum 2, unsigned frames
    return out


def test_lockstep_tlog_runs_on_the_simulated_clock(sim, tmp_path):
    walls = iter(range(START_US, START_US + 10**9, 7_919))    # a wall clock far from sim time
    d = daemon(sim, tmp_path, walls)
    assert sim.clock_mode == "lockstep"
    d.send(d.sitl.telemetry_due())                 # t = 0
    for _ in range(250):
        d.send(d.sitl.step())
    d.flight_log.close()
    d.tlog.close()
    stamps = frames(tmp_path / "vehicle.tlog")
    assert stamps[0] == START_US                   # the start's wall time
    assert stamps[-1] == START_US + d.sitl.t_us    # plus exactly the simulated time
    assert d.sitl.t_us == 250 * 1_000_000 // sim.physics_rate_hz
    assert stamps == sorted(stamps)


def test_realtime_tlog_runs_on_the_wall_clock(sim, tmp_path):
    rt = sim.with_changes(clock_mode="realtime")
    walls = iter(range(START_US, START_US + 10**9, 7_919))
    d = daemon(rt, tmp_path, walls)
    d.send(d.sitl.telemetry_due())
    d.tlog.close()
    d.flight_log.close()
    stamps = frames(tmp_path / "vehicle.tlog")
    assert stamps and all(s > START_US for s in stamps)          # fresh wall readings
    assert len(set(stamps)) == len(stamps)                       # one reading per frame
