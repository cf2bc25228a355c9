#!/usr/bin/env python3
"""Benchmark of the wire's part of a control period: pymavlink's path against trq_wire.frames'.

    trq-bench-wire [--repeat 7] [--number 2000] [--json out/bench_wire.json]

In one run, each pair measured alternately (pymavlink's, then the fast one, `--repeat` times),
the minimum over the repeats of the microseconds per call (timeit; the minimum is the figure
least disturbed by a shared machine), and the ratio of the two:
(1) an ODOMETRY datagram through the controller's UDP receive as far as the message object
    (pymavlink: a fresh parser and parse_buffer, as MavlinkUdp did; fast: decode_leading);
(2) one ODOMETRY frame decoded (pymavlink's MAVLink.decode, as MavlinkStream did; fast: decode);
(3) (1) for ACTUATOR_OUTPUT_STATUS;
(4) the target built and packed (wire.actuator_target's message: pymavlink's class, or
    frames.ActuatorTarget), unsigned and (5) signed;
(6) MavlinkUdp.datagram_received of an ODOMETRY datagram, the whole receive (system check,
    .tlog callback and a callback that does nothing), fast_path off and on;
(7) one control period's wire on the controller's side: the receive of the vehicle's offboard
    telemetry at the default sim's rates (params/sim/default.yaml: every stream's datagrams
    over one second, one datagram per message as the vehicle sends them, divided by the
    control rate's periods) and one target built and packed.
The ODOMETRY and ACTUATOR_OUTPUT_STATUS frames are the vehicle's own kind (a hover, unknown
covariances, unused outputs NaN); the other streams' frames carry seeded random field values.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import timeit
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import PARAMS_DIR, load_sim
from trq_lab.bench.nmpc import machine_line
from trq_offboard.link.udp import Connection, MavlinkUdp, parse_datagram
from trq_wire import frames
from trq_wire.signing import sign_outgoing

__all__ = ["measure", "main"]

NAN21 = [math.nan] * 21
CONTROLS = [0.55, 0.61, 0.58, 0.6, 0.12, -0.08, 0.0, 0.0]


def _frames() -> tuple[bytes, bytes]:
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    odo = mavlink.MAVLink_odometry_message(
        12_340_000, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0.012, -0.034,
        -1.002, [0.9999, 0.0051, -0.0032, 0.0101], 0.021, -0.013, 0.004, 0.011, -0.007, 0.002,
        NAN21, NAN21, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100)
    out = mavlink.MAVLink_actuator_output_status_message(
        12_340_000, 8, [0.55, 0.61, 0.58, 0.6, 0.12, -0.08, 0.0, 0.0] + [math.nan] * 24)
    return bytes(odo.pack(tx)), bytes(out.pack(tx))


def _period_traffic(odo: bytes, out: bytes) -> tuple[list[bytes], int]:
    """One second of the default sim's offboard telemetry (datagrams in send order: stream by
    stream, which does not change the cost) and the control periods in that second."""
    sim = load_sim(PARAMS_DIR / "sim" / "default.yaml")
    rates = dict(next(link for link in sim.links if link.name == "offboard").rates_hz)
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    rng = random.Random(18)
    own = {"ODOMETRY": odo, "ACTUATOR_OUTPUT_STATUS": out}
    datagrams = []
    for name, hz in sorted(rates.items()):
        if not hz:
            continue
        if name in own:
            frame = own[name]
        else:
            cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
            if cls not in frames.HOT:
                raise ValueError(f"{name}: not one of trq_wire.frames.HOT")
            values = cls.unpacker.unpack(bytes(rng.randrange(1, 256)
                                               for _ in range(cls.unpacker.size)))
            frame = frames.Packer(cls).pack(tx, *values)
        datagrams += [frame] * hz
    return datagrams, sim.control_rate_hz


def _pair(slow, fast, repeat: int, number: int) -> dict:
    slow_s, fast_s = [], []
    for _ in range(repeat):                   # alternately, so that a drift hits both
        slow_s.append(timeit.timeit(slow, number=number))
        fast_s.append(timeit.timeit(fast, number=number))
    s, f = min(slow_s) / number * 1e6, min(fast_s) / number * 1e6
    return {"pymavlink_us": s, "fast_us": f, "ratio": s / f}


def measure(repeat: int = 7, number: int = 2000) -> dict:
    odo, out = _frames()
    rx = mavlink.MAVLink(None)
    figures = {
        "odometry_datagram": _pair(lambda: parse_datagram(odo),
                                   lambda: frames.decode_leading(odo), repeat, number),
        "odometry_frame": _pair(lambda: rx.decode(bytearray(odo)),
                                lambda: frames.decode(odo), repeat, number),
        "output_status_datagram": _pair(lambda: parse_datagram(out),
                                        lambda: frames.decode_leading(out), repeat, number),
    }
    for signed in (False, True):
        tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        if signed:
            sign_outgoing(tx, bytes(range(32)))
        figures["target_signed" if signed else "target"] = _pair(
            lambda: mavlink.MAVLink_set_actuator_control_target_message(
                12_340_000, 0, 1, 1, CONTROLS).pack(tx),
            lambda: frames.ActuatorTarget(12_340_000, 0, 1, 1, CONTROLS).pack(tx),
            repeat, number)
    links = []
    for fast in (False, True):
        link = MavlinkUdp(Connection.parse("udpout:127.0.0.1:14580"), lambda msg: None)
        link.fast_path = fast
        link.on_frame = lambda data: None
        links.append(link)
    peer = ("127.0.0.1", 14580)
    figures["udp_receive_odometry"] = _pair(lambda: links[0].datagram_received(odo, peer),
                                            lambda: links[1].datagram_received(odo, peer),
                                            repeat, number)
    traffic, periods = _period_traffic(odo, out)
    tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)

    def second(link, target) -> None:
        for d in traffic:
            link.datagram_received(d, peer)
        for _ in range(periods):
            target(12_340_000, 0, 1, 1, CONTROLS).pack(tx)

    per_period = _pair(lambda: second(links[0], mavlink.MAVLink_set_actuator_control_target_message),
                       lambda: second(links[1], frames.ActuatorTarget),
                       repeat, max(1, number // 100))
    for k in ("pymavlink_us", "fast_us"):
        per_period[k] /= periods
    per_period["datagrams_per_period"] = len(traffic) / periods
    figures["control_period"] = per_period
    return figures


LABELS = {
    "odometry_datagram": "ODOMETRY datagram to message (UDP)",
    "odometry_frame": "ODOMETRY frame decode (stream)",
    "output_status_datagram": "ACTUATOR_OUTPUT_STATUS datagram (UDP)",
    "target": "target build + pack",
    "target_signed": "target build + pack, signed",
    "udp_receive_odometry": "MavlinkUdp receive of ODOMETRY",
    "control_period": "a control period: telemetry in, one target out",
}


def table(figures: dict) -> str:
    rows = ["| what | pymavlink µs | fast µs | ratio |", "|---|---:|---:|---:|"]
    for key, f in figures.items():
        rows.append(f"| {LABELS[key]} | {f['pymavlink_us']:.2f} | {f['fast_us']:.2f} | "
                    f"{f['ratio']:.2f} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-wire", description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="alternate repeats (the minimum)")
    ap.add_argument("--number", type=int, default=2000, help="calls per repeat")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.number < 1:
        ap.error("--repeat and --number must be at least 1")
    print(machine_line(), flush=True)
    figures = measure(args.repeat, args.number)
    print(f"µs per call, minimum of {args.repeat} alternate repeats of {args.number} calls:")
    print(table(figures))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine_line(), "figures": figures},
                                        indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
