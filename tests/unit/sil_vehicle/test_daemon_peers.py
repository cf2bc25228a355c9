"""The vehicle daemon's peer table (sil_vehicle/daemon.py): who gets a link's telemetry besides its
configured target. Only senders of valid messages become peers, a peer silent for
PEER_TIMEOUT_S gets nothing more, and a full table drops its longest-silent peer, so junk
senders can never lock a ground station out. No sockets: a fake transport and an injected clock."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.daemon import MAX_PEERS, PEER_TIMEOUT_S, VehicleDaemon


class FakeTransport:
    def __init__(self) -> None:
        self.sent: list[tuple[bytes, tuple[str, int]]] = []

    def sendto(self, data: bytes, addr) -> None:
        self.sent.append((data, tuple(addr)))


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def heartbeat_bytes(system: int = 255) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=190)
    return bytes(mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3).pack(mav))


def daemon(sim):
    clock = Clock()
    d = VehicleDaemon(sim, None, monotonic=clock)
    d.transports = {"gcs": FakeTransport(), "offboard": FakeTransport()}
    return d, clock


def telemetry_destinations(d) -> set[tuple[str, int]]:
    d.transports["gcs"].sent.clear()
    d.send(d.sitl.telemetry_due(everything=True))
    return {addr for _, addr in d.transports["gcs"].sent}


def test_only_senders_of_valid_messages_become_peers(sim):
    d, _ = daemon(sim)
    target = (sim.link("gcs").target.host, sim.link("gcs").target.port)
    d.on_datagram("gcs", b"\x00garbage\xfd\x09", ("127.0.0.1", 40001))
    assert telemetry_destinations(d) == {target}
    d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 40002))
    assert telemetry_destinations(d) == {target, ("127.0.0.1", 40002)}


def test_a_silent_peer_expires(sim):
    d, clock = daemon(sim)
    d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 40002))
    clock.t += PEER_TIMEOUT_S - 0.5
    assert ("127.0.0.1", 40002) in telemetry_destinations(d)
    clock.t += 1.0
    assert ("127.0.0.1", 40002) not in telemetry_destinations(d)
    # it speaks again: it is served again
    d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 40002))
    assert ("127.0.0.1", 40002) in telemetry_destinations(d)


def test_a_full_table_drops_its_longest_silent_peer(sim):
    d, clock = daemon(sim)
    for i in range(MAX_PEERS):
        d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 41000 + i))
        clock.t += 0.01
    d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 41000))     # the first one again
    clock.t += 0.01
    d.on_datagram("gcs", heartbeat_bytes(), ("127.0.0.1", 42000))     # a newcomer
    dests = telemetry_destinations(d)
    assert ("127.0.0.1", 42000) in dests and ("127.0.0.1", 41000) in dests
    assert ("127.0.0.1", 41001) not in dests                          # the longest silent
    assert len(d.peers["gcs"]) == MAX_PEERS
