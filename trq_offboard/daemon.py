"""The offboard controller daemon.

    python -m trq_offboard [--controller params/controller/trq_nmpc_eso.yaml]
                           [--connect udpin:127.0.0.1:14540] [--log-dir DIR]

--connect takes the ecosystem's connection strings (trq_wire.connection): udpin:, udpout:,
tcpin:, tcp: (tcpout), serial://DEVICE:BAUD, DEVICE,BAUD and their MAVSDK spellings.

It listens like a PX4 offboard API client, waits for the vehicle's heartbeat, arms, takes off,
flies the reference of the controller file, lands, disarms and exits 0 with a one-line summary
(1 when the flight could not be flown, 2 on a bad configuration). It knows the vehicle only
through MAVLink (sil_vehicle/PROTOCOL.md): pointed at a real prototype it is the same program.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time
from pathlib import Path
from typing import Callable

import trq_params

from trq_offboard.config import ConfigError, ControllerConfig, load_controller, with_rates_lowpass
from trq_offboard.link.stream import MavlinkStream
from trq_offboard.link.udp import MavlinkUdp
from trq_offboard.link.wire import HOME_GROUND_DOWN_M
from trq_offboard.log import ControllerLog, solver_header
from trq_offboard.loop import FlightError, OffboardFlight
from trq_wire.actuators import tilt_half_range
from trq_wire.connection import FORMS, Connection
from trq_wire.logfile import Tlog, VehicleTimeline
from trq_wire.signing import load_key

log = logging.getLogger("trq_offboard")


def resolve_controller(text: str) -> Path:
    """A path, or the name of a built-in controller file (trq_nmpc_eso, trq_nmpc, quad_nmpc)."""
    return trq_params.resolve("controller", text)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="trq-offboard",
        description="Offboard NMPC + ESO controller of the tilt-rotor quadcopter, over MAVLink 2.")
    p.add_argument("--controller", default="trq_nmpc_eso",
                   help="controller YAML or its name in params/controller/ "
                        "(trq_nmpc_eso, trq_nmpc, quad_nmpc); default trq_nmpc_eso")
    p.add_argument("--connect", default="udpin:127.0.0.1:14540",
                   help="the vehicle's link, one of " + ", ".join(FORMS) + " (udp: listens "
                        "as udpin:, tcp: connects as tcpout:, BAUD 921600 if left out); default "
                        "udpin:127.0.0.1:14540, PX4's offboard port")
    p.add_argument("--reference", default=None,
                   choices=("hover", "step", "circle", "helix", "figure8"),
                   help="override the reference kind of the controller file")
    p.add_argument("--log-dir", type=Path, default=None,
                   help="directory for the controller's log and offboard.tlog "
                        "(default: logs/offboard-<time>)")
    p.add_argument("--log-format", choices=("ulog", "csv"), default="ulog",
                   help="the controller's log: controller.ulg, its rows packed as PX4 logs on "
                        "board (trq-log-csv writes controller.csv from it on the ground), or "
                        "controller.csv formatted during the flight (the formatting costs the "
                        "control period); default ulog")
    p.add_argument("--no-log", action="store_true", help="write no logs")
    p.add_argument("--applied-delay-s", type=float, default=None,
                   help="how long a command takes to act after the state it answers was "
                        "measured (the observer's b0 and, from one control period on, the "
                        "delay predictor): 0 in lockstep on a clean link (the default of the "
                        "controller file), the link's round trip on a slow one, plus about "
                        "the solve time in real time")
    p.add_argument("--rates-lowpass-hz", type=float, default=None,
                   help="the low-pass the autopilot puts on the body rates it publishes (PX4's "
                        "IMU_GYRO_CUTOFF, Hz; 0: raw rates), which the body-rate observer "
                        "carries; default the controller file's rates_lowpass_hz")
    p.add_argument("--signing-key-file", type=Path, default=None,
                   help="MAVLink 2 signing: a file with the 32-byte secret as 64 hex characters; "
                        "everything sent is signed and only signed, fresh telemetry is trusted")
    p.add_argument("--connect-timeout", type=float, default=30.0,
                   help="seconds to wait for the vehicle's heartbeat")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return p


def main(argv: list[str] | None = None,
         make_controller: Callable[[ControllerConfig], object] | None = None) -> int:
    """The daemon (`argv`: its options, default sys.argv's). `make_controller(cfg)` builds the
    object the flight steps (step, reset, optional prepare: trq_offboard/loop.py's contract)
    from the loaded configuration; None, the default: `Controller(cfg)`, the NMPC + ESO. Another
    one is for measurement devices (trq_lab/bench/period_floor.py's replay)."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = load_controller(resolve_controller(args.controller))
        if args.reference:
            import dataclasses
            cfg = dataclasses.replace(cfg, reference=dataclasses.replace(cfg.reference,
                                                                         kind=args.reference))
        if args.applied_delay_s is not None:
            if not 0.0 <= args.applied_delay_s <= 1.0:
                raise ValueError(f"--applied-delay-s: got {args.applied_delay_s}, expected "
                                 "a number of seconds in [0, 1]")
            import dataclasses
            cfg = dataclasses.replace(cfg, applied_delay_s=args.applied_delay_s)
        if args.rates_lowpass_hz is not None:
            cfg = with_rates_lowpass(cfg, args.rates_lowpass_hz, "--rates-lowpass-hz")
        connection = Connection.parse(args.connect)
        key = load_key(args.signing_key_file) if args.signing_key_file else None
    except (ConfigError, ValueError) as exc:
        print(f"trq-offboard: {exc}", file=sys.stderr)
        return 2

    # building the NMPC takes a moment: do it before listening
    from trq_offboard.reference import Reference
    if make_controller is None:
        from trq_offboard.controller import Controller
        make_controller = Controller
    controller = make_controller(cfg)

    log_dir = None if args.no_log else (
        args.log_dir or Path("logs") / time.strftime(f"offboard-{cfg.name}-%Y%m%d-%H%M%S"))
    clog = tlog = None
    if log_dir is not None:
        name = "controller.ulg" if args.log_format == "ulog" else "controller.csv"
        clog = ControllerLog(log_dir / name,
                             {"controller": cfg.name, "controller_file": cfg.file,
                              "vehicle_file": cfg.vehicle.file, "connect": args.connect,
                              "frames": "world NED, body FRD",
                              **solver_header(controller)})
        timeline = VehicleTimeline()
        tlog = Tlog(log_dir / "offboard.tlog", clock=timeline.now_us)

    transport = MavlinkStream if connection.is_stream else MavlinkUdp
    link = transport(connection, on_message=lambda msg: None, signing_key=key)
    if connection.listens and connection.host not in ("127.0.0.1", "localhost", "::1") \
            and key is None:
        log.warning("listening on %s without a signing key: anyone on the network can feed "
                    "this controller telemetry (use --signing-key-file)", connection.host)
    if tlog:
        def log_frame(frame: bytes) -> None:
            timeline.heard(frame)
            tlog(frame)
        link.on_frame = log_frame
    flight = OffboardFlight(
        link, controller, lambda state, airborne=False: Reference(
            cfg.reference, state.pos_ned_m, state.euler_rad[2], airborne=airborne,
            ground_down_m=HOME_GROUND_DOWN_M if airborne else None),
        name=cfg.name,
        tilt_limit_rad=tilt_half_range(cfg.vehicle.tilt_min_rad, cfg.vehicle.tilt_max_rad),
        record=clog,
        connect_timeout_s=args.connect_timeout,
        gnss_delay_s=cfg.fused.gnss_delay_s if cfg.fused is not None else 0.0)

    async def _main() -> int:
        await link.open()
        loop = asyncio.get_running_loop()
        flying = asyncio.ensure_future(flight.run())
        received: list[int] = []

        def interrupt(sig: int) -> None:
            received.append(sig)
            cancel_until_done()

        def cancel_until_done() -> None:
            # asyncio.wait_for of Python 3.11 can swallow a cancellation that meets its inner
            # future's completion (CPython gh-86296): ask again until the flight has stopped
            if not flying.done():
                flying.cancel()
                loop.call_later(0.05, cancel_until_done)

        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, interrupt, sig)
        try:
            summary = await flying
        except FlightError as exc:
            print(f"trq-offboard: {exc}", file=sys.stderr)
            return 1
        except asyncio.CancelledError:
            name = signal.Signals(received[0]).name if received else "cancelled"
            done = await flight.hand_over()
            print(f"trq-offboard: interrupted by {name}: {done}; logs complete"
                  + (f" in {log_dir}" if log_dir else ""), file=sys.stderr)
            return 128 + (received[0] if received else signal.SIGINT)
        finally:
            link.close()
        st = link.stats
        print(f"trq-offboard: {summary.line()}" + (f"; logs in {log_dir}" if log_dir else ""))
        unit = "reads" if connection.is_stream else "datagrams"
        print(f"trq-offboard link: {st.messages} messages in {st.datagrams} {unit}, "
              f"{st.bad} bad or untrusted, {st.other_peer} from another address, "
              f"{st.sent} sent", file=sys.stderr)
        return 0 if summary.disarmed and not summary.crashed else 1

    try:
        return asyncio.run(_main())
    except OSError as exc:
        print(f"trq-offboard: cannot open {args.connect}: {exc}", file=sys.stderr)
        return 1
    finally:
        if clog:
            clog.close()
        if tlog:
            tlog.close()


if __name__ == "__main__":
    sys.exit(main())
