#!/usr/bin/env python3
"""Inject faults and wind into a running SIL vehicle over MAVLink, and wait for its answer.

    trq-inject-fault motor 1 off            motor 1 stops (MAV_CMD_INJECT_FAILURE)
    trq-inject-fault motor 1 on             motor 1 restored
    trq-inject-fault motor 1 eff 0.5        motor 1 effectiveness 0.5 (parameter SIM_MOT1_EFF)
    trq-inject-fault motor 1 tv 0.8 0.2 0.01 [PHI]   effectiveness 0.8 - 0.2 sin(0.01 t + PHI)
    trq-inject-fault servo 2 stuck 10       tilt servo 2 stuck at 10 deg ("here": where it is)
    trq-inject-fault servo 2 free
    trq-inject-fault wind 8 [DIR_DEG] [--gusts on|off] [--sigma S]
    trq-inject-fault sensor mocap off       the motion capture stops (MAV_CMD_INJECT_FAILURE,
                                            unit VIO); sensors gyro accel mag baro gnss mocap,
                                            failures ok off stuck garbage
    trq-inject-fault sensor gnss wrong 5    GNSS positions 5 m north of the truth (wrong SIZE:
                                            the error in the unit's SI unit, or degrees for mag)
    trq-inject-fault clear                  every motor, servo and sensor healthy
    trq-inject-fault script params/faults/motor1_50.yaml   timed events, in vehicle time

Each action waits for the vehicle's acknowledgement (COMMAND_ACK ACCEPTED, or the PARAM_VALUE
that confirms the new value); without one the tool exits 1 with the reason. Script times
(`at_s`) are vehicle time, read from the telemetry stamps, so scripts work in lockstep and in
real time alike. Bad arguments or scripts exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import trq_params
from pymavlink.dialects.v20 import common as mavlink
from trq_params import ConfigError

from sil_vehicle.faultscript import (
    MOTOR,
    SERVO,
    TYPE_OFF,
    TYPE_OK,
    TYPE_STUCK,
    Event,
    InjectAction,
    ParamAction,
    load_script,
)
from sil_vehicle.sensors import faults as sensor_faults
from trq_lab.gcs.client import MavClient, NoAnswer, gcs_parser
from trq_wire.signing import SigningKeyError, load_key

RESULTS = {v.name.removeprefix("MAV_RESULT_"): k for k, v in mavlink.enums["MAV_RESULT"].items()}


def actions_from_args(args: argparse.Namespace) -> tuple[tuple, str]:
    """The actions of a one-shot command, and what it does in words."""
    if args.what == "motor":
        n = _instance(args.n)
        if args.action == "off":
            return (InjectAction(MOTOR, TYPE_OFF, n),), f"motor {n} off"
        if args.action == "on":
            return (InjectAction(MOTOR, TYPE_OK, n),), f"motor {n} restored"
        if args.action == "eff":
            e = _number(args.values, 1, "eff E", 0.0, 1.0)[0]
            return (ParamAction(f"SIM_MOT{n}_EFF", e), ParamAction(f"SIM_MOT{n}_TVB", 0.0)), \
                f"motor {n} effectiveness {e:g}"
        if args.action == "tv":
            if len(args.values) not in (3, 4):
                raise SystemExit2("motor N tv A B W [PHI]: expected 3 or 4 numbers")
            v = [float(x) for x in args.values] + ([0.0] if len(args.values) == 3 else [])
            return (ParamAction(f"SIM_MOT{n}_EFF", v[0]), ParamAction(f"SIM_MOT{n}_TVB", v[1]),
                    ParamAction(f"SIM_MOT{n}_TVW", v[2]), ParamAction(f"SIM_MOT{n}_TVP", v[3])), \
                f"motor {n} effectiveness {v[0]:g} - {v[1]:g} sin({v[2]:g} t + {v[3]:g})"
        raise SystemExit2(f"motor: unknown action {args.action!r} (off, on, eff, tv)")
    if args.what == "servo":
        n = _instance(args.n)
        if args.action == "free":
            return (InjectAction(SERVO, TYPE_OK, n),), f"servo {n} freed"
        if args.action == "stuck":
            if args.values == ["here"]:
                return (InjectAction(SERVO, TYPE_STUCK, n),), f"servo {n} stuck where it is"
            angle = _number(args.values, 1, "stuck ANGLE_DEG", -90.0, 90.0)[0]
            return (InjectAction(SERVO, TYPE_STUCK, n, angle),), f"servo {n} stuck at {angle:g} deg"
        raise SystemExit2(f"servo: unknown action {args.action!r} (stuck, free)")
    if args.what == "sensor":
        name = args.n
        if name not in sensor_faults.UNIT_OF:
            raise SystemExit2(f"sensor {name!r}: expected one of "
                              f"{', '.join(sensor_faults.UNIT_OF)}")
        kind = sensor_faults.KIND_OF.get(args.action)
        if kind is None:
            raise SystemExit2(f"sensor {name}: unknown failure {args.action!r} "
                              f"({', '.join(sensor_faults.KIND_OF)})")
        size = float("nan")
        if kind == sensor_faults.WRONG and args.values:
            size = _number(args.values, 1, f"sensor {name} wrong SIZE", -1e4, 1e4)[0]
        elif args.values:
            raise SystemExit2(f"sensor {name} {args.action}: takes no value, got {args.values}")
        text = f"sensor {name} {args.action}" + ("" if size != size else f" by {size:g}")
        return (InjectAction(sensor_faults.UNIT_OF[name], kind, 1, size),), text
    raise SystemExit2(f"unknown target {args.what!r}")


class SystemExit2(Exception):
    """A usage error: exit status 2."""


def _instance(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 4:
        raise SystemExit2(f"instance {text!r}: expected 1..4")
    return int(text)


def _number(values: list[str], n: int, usage: str, lo: float, hi: float) -> list[float]:
    if len(values) != n:
        raise SystemExit2(f"{usage}: expected {n} number(s), got {values}")
    try:
        out = [float(v) for v in values]
    except ValueError:
        raise SystemExit2(f"{usage}: not a number: {values}") from None
    for v in out:
        if not lo <= v <= hi:
            raise SystemExit2(f"{usage}: {v:g} out of [{lo:g}, {hi:g}]")
    return out


def apply(client: MavClient, actions) -> None:
    """Send each action and wait for its acknowledgement; raises NoAnswer on refusal."""
    for action in actions:
        if isinstance(action, ParamAction):
            client.param_set(action.name, action.value)
        else:
            result = client.command(mavlink.MAV_CMD_INJECT_FAILURE, action.unit, action.kind,
                                    action.instance, action.param4)
            if result != mavlink.MAV_RESULT_ACCEPTED:
                name = mavlink.enums["MAV_RESULT"][result].name if result in \
                    mavlink.enums["MAV_RESULT"] else str(result)
                raise NoAnswer(f"MAV_CMD_INJECT_FAILURE {action}: {name}")


def play(client: MavClient, events: tuple[Event, ...], *, timeout_s: float = 30.0,
         log=print) -> None:
    """Apply each event once the vehicle's clock (telemetry stamps) has reached its time."""
    for event in events:
        last_progress = time.monotonic()
        seen = client.vehicle_time_us
        while client.vehicle_time_us < event.at_us:
            client.poll(0.2)
            if client.vehicle_time_us != seen:
                seen, last_progress = client.vehicle_time_us, time.monotonic()
            elif time.monotonic() - last_progress > timeout_s:
                raise NoAnswer(f"vehicle time stuck at {seen / 1e6:.2f} s for {timeout_s:g} s "
                               f"before the event at {event.at_us / 1e6:g} s")
        apply(client, event.actions)
        log(f"t={client.vehicle_time_us / 1e6:.2f} s: {event.text}")


def build_parser() -> argparse.ArgumentParser:
    p = gcs_parser("trq-inject-fault", __doc__)
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the vehicle")
    p.add_argument("--signing-key-file", type=Path, default=None,
                   help="sign the commands (MAVLink 2 signing, 64 hex characters)")
    p.add_argument("what", choices=("motor", "servo", "wind", "sensor", "clear", "script"))
    p.add_argument("n", nargs="?", help="motor or servo number 1..4; wind speed m/s; sensor: "
                                        "gyro|accel|mag|baro|gnss|mocap; script: a built-in "
                                        "name (motor1_50, tour, ...) or a path")
    p.add_argument("action", nargs="?", help="motor: off|on|eff|tv; servo: stuck|free; "
                                             "wind: direction deg; sensor: "
                                             "ok|off|stuck|garbage|wrong")
    p.add_argument("values", nargs="*")
    p.add_argument("--gusts", choices=("on", "off"), default=None)
    p.add_argument("--sigma", type=float, default=None, help="gust intensity m/s")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.what == "script":
            if not args.n:
                raise SystemExit2("script FILE: a fault script is needed")
            events = load_script(trq_params.resolve("faults", args.n))
            actions, text = None, f"script {args.n} ({len(events)} events)"
        elif args.what == "clear":
            events = load_script_from_text("clear")
            actions, text = events[0].actions, "all faults cleared"
        elif args.what == "wind":
            speed = _number([args.n] if args.n else [], 1, "wind SPEED", 0.0, 40.0)[0]
            actions = [ParamAction("SIM_WIND_SPD", speed)]
            text = f"wind {speed:g} m/s"
            if args.action is not None:
                d = _number([args.action], 1, "wind SPEED DIR", -360.0, 360.0)[0]
                actions.append(ParamAction("SIM_WIND_DIR", d))
                text += f" from {d:g} deg"
            if args.gusts:
                actions.append(ParamAction("SIM_GUST_EN", 1.0 if args.gusts == "on" else 0.0))
                text += f", gusts {args.gusts}"
            if args.sigma is not None:
                actions.append(ParamAction("SIM_GUST_SIG", args.sigma))
        else:
            if args.n is None or args.action is None:
                raise SystemExit2(f"{args.what} N ACTION: missing arguments")
            actions, text = actions_from_args(args)
    except (SystemExit2, ConfigError) as exc:
        print(f"inject_fault: {exc}", file=sys.stderr)
        return 2
    try:
        key = load_key(args.signing_key_file) if args.signing_key_file else None
    except SigningKeyError as exc:
        print(f"inject_fault: {exc}", file=sys.stderr)
        return 2
    try:
        with MavClient(args.connect, signing_key=key) as client:
            client.hello(args.timeout)
            if actions is None:
                play(client, events, log=lambda s: print(f"inject_fault: {s}"))
            else:
                apply(client, actions)
                print(f"inject_fault: {text}: acknowledged")
    except NoAnswer as exc:
        print(f"inject_fault: FAILED: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"inject_fault: cannot open {args.connect}: {exc}", file=sys.stderr)
        return 1
    return 0


def load_script_from_text(kind: str) -> tuple[Event, ...]:
    from sil_vehicle.faultscript import parse_event
    return (parse_event({"at_s": 0.0, kind: True}, file="command line"),)


if __name__ == "__main__":
    sys.exit(main())
