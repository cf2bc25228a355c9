"""The links on a byte stream, in one process: the pty pair of trq_lab.ptypair is a raw cable;
the controller's MavlinkStream over it and over TCP delivers what a MavlinkUdp would (split
frames joined, garbage skipped and counted, other systems and unsigned frames refused, a second
TCP client turned away); the vehicle's stream link decodes, answers on the stream, counts as on
UDP and routes onto a stream."""

from __future__ import annotations

import asyncio
import os
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.daemon import VehicleDaemon, _StreamLink
from trq_lab.ptypair import PtyPair
from trq_offboard.link.stream import MavlinkStream
from trq_wire.connection import Connection
from trq_wire.signing import sign_outgoing
from trq_wire.stream import SerialStream

KEY = bytes(range(32))


def packer(system=1, component=1, key=None):
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        sign_outgoing(mav, key)
    return mav


def pack(mav, msg) -> bytes:
    data = bytes(msg.pack(mav))
    mav.seq = (mav.seq + 1) % 256
    return data


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(2, 0, 0, 0, 3, 3)


def odometry(t_us):
    nan21 = [float("nan")] * 21
    return mavlink.MAVLink_odometry_message(t_us, 1, 1, 0.0, 0.0, -1.0, [1, 0, 0, 0], 0, 0, 0,
                                            0, 0, 0, nan21, nan21, 0, 0, 100)


def read_all(fd: int, n: int, timeout_s: float = 5.0) -> bytes:
    out = b""
    end = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < end:
        try:
            out += os.read(fd, n - len(out))
        except BlockingIOError:
            time.sleep(0.001)
    return out


# --- the pty pair ------------------------------------------------------------------------------

def test_ptypair_is_a_raw_cable_both_ways():
    every_byte = bytes(range(256)) * 8       # \n, \r, ^C, ^S, ^Q, DEL: nothing translated
    with PtyPair() as pair:
        a = os.open(pair.a, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        b = os.open(pair.b, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            os.write(a, every_byte)
            assert read_all(b, len(every_byte)) == every_byte
            os.write(b, b"back\n")
            assert read_all(a, 5) == b"back\n"
            assert read_all(a, 1, timeout_s=0.2) == b""       # no echo of what a wrote
        finally:
            os.close(a)
            os.close(b)
        assert pair.copied == {pair.a: len(every_byte), pair.b: 5}


def test_ptypair_survives_an_end_closed_and_reopened():
    with PtyPair() as pair:
        for _ in range(2):
            a = os.open(pair.a, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            b = os.open(pair.b, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            os.write(a, b"ping")
            assert read_all(b, 4) == b"ping"
            os.close(a)
            os.close(b)


def test_ptypair_holds_no_backlog_for_an_end_opened_late():
    """Bytes for an end nobody reads are dropped once its queue is full; a program opening
    that end late (pyserial empties the queue) reads the line from then on."""
    import serial

    with PtyPair() as pair:
        a = os.open(pair.a, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            sent = 0
            for _ in range(100):
                try:
                    sent += os.write(a, b"x" * 8192)
                except BlockingIOError:
                    time.sleep(0.001)
            end = time.monotonic() + 5
            while pair.copied[pair.a] < sent and time.monotonic() < end:
                time.sleep(0.01)
            assert pair.copied[pair.a] == sent and pair.dropped[pair.b] > 0
            with serial.Serial(pair.b, 921600, timeout=0) as b:
                os.write(a, b"fresh")
                got, end = b"", time.monotonic() + 5
                while len(got) < 5 and time.monotonic() < end:
                    got += b.read(100)
                    time.sleep(0.001)
                time.sleep(0.05)
                assert got + b.read(100) == b"fresh"
        finally:
            os.close(a)


# --- the controller's stream link --------------------------------------------------------------

async def until(predicate, timeout_s=5.0):
    end = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError("timed out")
        await asyncio.sleep(0.002)


def test_controller_serial_link_joins_split_frames_and_skips_garbage():
    async def main():
        with PtyPair() as pair:
            got = []
            vehicle_end = SerialStream(pair.a, 921600, lambda data: None)
            vehicle_end.open()
            link = MavlinkStream(Connection.parse(f"serial://{pair.b}:921600"), got.append)
            await link.open()
            mav = packer()
            stream = (b"junk" + pack(mav, heartbeat()) + pack(mav, odometry(10))
                      + pack(packer(system=2), heartbeat())            # another system
                      + b"\xfd\x10garbage" + pack(mav, odometry(20)))
            for i in range(0, len(stream), 7):                   # split everywhere
                vehicle_end.write(stream[i:i + 7])
                await asyncio.sleep(0)
            await until(lambda: len(got) == 3)
            assert [m.get_type() for m in got] == ["HEARTBEAT", "ODOMETRY", "ODOMETRY"]
            assert link.stats.messages == 3 and link.stats.bad == 2
            # and the other way: what the controller sends arrives whole
            echoed = []
            vehicle_end.on_bytes = echoed.append
            assert link.send(heartbeat())
            await until(lambda: sum(map(len, echoed)) >= 21)
            msg = mavlink.MAVLink(None).decode(bytearray(b"".join(echoed)))
            assert (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 191)
            link.close()
            vehicle_end.close()

    asyncio.run(main())


def test_controller_stream_link_with_a_key_trusts_only_signed_frames():
    async def main():
        with PtyPair() as pair:
            got = []
            vehicle_end = SerialStream(pair.a, 921600, lambda data: None)
            vehicle_end.open()
            link = MavlinkStream(Connection.parse(f"{pair.b},921600"), got.append,
                                 signing_key=KEY)
            await link.open()
            signed = packer(key=KEY)
            vehicle_end.write(pack(packer(), odometry(10)) + pack(signed, odometry(20)))
            await until(lambda: len(got) == 1)
            assert got[0].time_usec == 20 and link.stats.bad == 1
            link.close()
            vehicle_end.close()

    asyncio.run(main())


def test_controller_tcp_links_connect_and_refuse_a_second_vehicle():
    async def main():
        got = []
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        server = MavlinkStream(Connection.parse(f"tcpin://127.0.0.1:{port}"), got.append)
        await server.open()
        client_got = []
        client = MavlinkStream(Connection.parse(f"tcpout://127.0.0.1:{port}"), client_got.append)
        await client.open()
        await until(lambda: client.ready and server.ready)
        # a second vehicle is turned away while the first is connected
        _, intruder = await asyncio.open_connection("127.0.0.1", port)
        await until(lambda: server.stats.other_peer == 1)
        assert client.send(heartbeat())      # system 1 (a component of the vehicle's system)
        await until(lambda: len(got) == 1)
        intruder.close()
        client.close()
        server.close()

    asyncio.run(main())


def test_tcpout_waits_for_the_server_and_says_so_by_send():
    async def main():
        link = MavlinkStream(Connection.parse("tcp:127.0.0.1:9"), lambda m: None)
        await link.open()
        await asyncio.sleep(0.05)
        assert not link.ready and link.send(heartbeat()) is False
        link.close()

    asyncio.run(main())


# --- the vehicle's stream link -----------------------------------------------------------------

class _Stream:
    connected = True
    peer = None

    def __init__(self) -> None:
        self.written: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))


def stream_vehicle(sim, key=None):
    d = VehicleDaemon(sim, None, signing_key=key)
    d.transports = {}
    sl = d.streams["offboard"] = _StreamLink()
    sl.stream = _Stream()
    return d, sl.stream


def decode_all(chunks: list[bytes]) -> list:
    from trq_wire.framing import StreamFramer
    rx = mavlink.MAVLink(None)
    return [rx.decode(bytearray(f)) for f in StreamFramer().feed(b"".join(chunks))]


def test_vehicle_stream_link_answers_on_the_stream_and_counts_as_on_udp(sim):
    d, stream = stream_vehicle(sim)
    mav = packer(component=191)
    request = pack(mav, mavlink.MAVLink_command_long_message(
        1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
        0, 0, 0, 0, 0, 0))
    data = b"\x00\xfd\x05noise" + request
    for i in range(0, len(data), 5):
        d._on_stream_bytes("offboard", data[i:i + 5])
    kinds = [m.get_type() for m in decode_all(stream.written)]
    assert kinds == ["COMMAND_ACK", "AUTOPILOT_VERSION"]
    c = d.sitl.counters["offboard"]
    assert c.messages == 1 and c.bad_frames == 1 and c.datagrams == -(-len(data) // 5)


def test_vehicle_stream_link_with_a_key_refuses_unsigned_frames(sim):
    d, stream = stream_vehicle(sim, key=KEY)
    d._on_stream_bytes("offboard", pack(packer(component=191), mavlink.MAVLink_command_long_message(
        1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
        0, 0, 0, 0, 0, 0)))
    assert stream.written == [] and d.sitl.counters["offboard"].unauthenticated == 1


def test_vehicle_routes_a_ground_station_request_onto_the_stream(sim):
    d, stream = stream_vehicle(sim)

    class _Udp:
        def __init__(self):
            self.sent = []

        def sendto(self, data, addr):
            self.sent.append(bytes(data))

    d.transports = {"gcs": _Udp()}
    gcs = pack(packer(system=255, component=190),
               mavlink.MAVLink_command_long_message(1, 191, 31000, 0, 0, 0, 0, 0, 0, 0, 0))
    d.on_datagram("gcs", gcs, ("127.0.0.1", 14550))
    assert gcs in stream.written and d.routed["offboard"] == 1
    # and the controller's broadcast from the stream reaches the ground station
    nvf = pack(packer(component=191),
               mavlink.MAVLink_named_value_float_message(1000, b"MOT1_EFF", 0.5))
    d._on_stream_bytes("offboard", nvf)
    assert nvf in d.transports["gcs"].sent



# --- the ground-station tools' client ----------------------------------------------------------

def test_gcs_client_over_a_serial_line():
    from trq_lab.gcs.client import MavClient

    with PtyPair() as pair:
        far = os.open(pair.a, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            with MavClient(f"serial://{pair.b}:57600") as client:
                data = b"\x00noise" + pack(packer(), heartbeat())
                os.write(far, data[:9])
                assert client.poll(0.05) == []
                os.write(far, data[9:])
                msg = client.wait(lambda m: m.get_type() == "HEARTBEAT", 2.0, "heartbeat")
                assert msg.get_srcSystem() == 1
                client.send(heartbeat())
                sent = read_all(far, 21)
                assert mavlink.MAVLink(None).decode(bytearray(sent)).get_srcComponent() == 190
        finally:
            os.close(far)


def test_gcs_client_over_tcp():
    from trq_lab.gcs.client import MavClient

    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        with MavClient(f"tcpout://127.0.0.1:{port}") as client:
            conn, _ = server.accept()
            with conn:
                frame = pack(packer(), heartbeat())
                conn.sendall(frame[:5])
                conn.sendall(frame[5:] + frame)
                got = client.poll(1.0) + client.poll(0.2)
                assert [m.get_type() for m in got] == ["HEARTBEAT", "HEARTBEAT"]


def test_gcs_tools_refuse_a_bad_connection_string(capsys):
    from trq_lab.gcs.monitor import main

    with pytest.raises(SystemExit) as exc:
        main(["--connect", "udpin:nowhere"])
    assert exc.value.code == 2 and "udpin:nowhere" in capsys.readouterr().err


def test_a_paced_serial_stream_writes_what_the_line_has_carried_and_drops_past_a_second():
    from trq_wire.framing import LinePacer

    class Clock:
        ns = 0

        def __call__(self):
            return self.ns

    async def main():
        clock = Clock()
        with PtyPair() as pair:
            got = []
            far = SerialStream(pair.b, 921600, got.append)
            far.open()
            paced = SerialStream(pair.a, 921600, lambda d: None,
                                 pacer=LinePacer(1000, clock))   # 1000 bytes a second
            paced.open()
            paced.write(b"a" * 100)            # carried at 100 ms
            paced.write(b"b" * 100)            # at 200 ms
            await asyncio.sleep(0.05)
            assert got == []                   # the clock has not moved: nothing left
            clock.ns = 100_000_000
            paced._flush()
            await until(lambda: b"".join(got) == b"a" * 100)
            paced.write(b"c" * 950)            # 100 + 950 queued: past a second of line
            assert paced.dropped_bytes == 950
            clock.ns = 200_000_000
            paced._flush()
            await until(lambda: b"".join(got) == b"a" * 100 + b"b" * 100)
            paced.close()
            far.close()

    asyncio.run(main())


def _serial_sim(sim, device, baud, mode):
    import dataclasses

    from sil_vehicle.config import Endpoint, SerialPort
    links = tuple(dataclasses.replace(link, bind=Endpoint("127.0.0.1", 0))
                  if link.name == "gcs" else
                  dataclasses.replace(link, serial=SerialPort(device, baud))
                  for link in sim.links)
    return sim.with_changes(links=links, clock_mode=mode)


@pytest.mark.parametrize("baud, mode, warned, paced", [
    (921600, "lockstep", False, False), (921600, "realtime", False, True),
    (57600, "realtime", True, True)])
def test_the_vehicle_prints_its_serial_budget_and_paces_only_in_real_time(
        sim, capsys, caplog, baud, mode, warned, paced):
    from sil_vehicle.daemon import serial_budget

    with PtyPair() as pair:
        d = VehicleDaemon(_serial_sim(sim, pair.a, baud, mode), None)

        async def main():
            await d.open()
            stream = d.streams["offboard"].stream
            d.close()
            return stream

        stream = asyncio.run(main())
    needed, available = serial_budget(d.sim.link("offboard"), False)
    line = capsys.readouterr().out
    assert (f"offboard link serial {pair.a} at {baud} baud: {needed} B/s needed of "
            f"{available} ({100 * needed / available:.0f} %)") in line
    assert ("more than 80 %" in caplog.text) is warned
    assert (stream.pacer is not None) is paced


def test_the_vehicles_tcp_server_serves_one_client_and_turns_a_second_away(sim):
    import dataclasses

    from sil_vehicle.config import Endpoint
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    links = tuple(dataclasses.replace(link, bind=Endpoint("127.0.0.1", 0)) if link.name == "gcs"
                  else dataclasses.replace(link, tcp=Endpoint("127.0.0.1", port))
                  for link in sim.links)
    d = VehicleDaemon(sim.with_changes(links=links), None)

    async def main():
        await d.open()
        assert d.bound("offboard") == ("127.0.0.1", port)
        r1, w1 = await asyncio.open_connection("127.0.0.1", port)
        await until(lambda: d.streams["offboard"].stream is not None)
        r2, w2 = await asyncio.open_connection("127.0.0.1", port)
        assert await asyncio.wait_for(r2.read(100), 5) == b""      # closed at once
        assert d.streams["offboard"].refused == 1
        d.send(d.sitl.telemetry_due(everything=True))
        data = await asyncio.wait_for(r1.read(4096), 5)
        assert any(m.get_type() == "HEARTBEAT" for m in decode_all([data]))
        # the first client goes: the next one is served
        w1.close()
        await until(lambda: d.streams["offboard"].stream is None)
        r3, w3 = await asyncio.open_connection("127.0.0.1", port)
        await until(lambda: d.streams["offboard"].stream is not None)
        for w in (w2, w3):
            w.close()
        d.close()

    asyncio.run(main())
