#!/usr/bin/env python3
"""A live terminal view of a running SIL vehicle (or any vehicle speaking sil_vehicle/PROTOCOL.md)
from its ground-station port.

    trq-monitor                                   udpout:127.0.0.1:18570, about 5 frames a second
    trq-monitor --once                            one snapshot, no escape codes (tests, logs)
    trq-monitor --duration 30 --vehicle params/vehicle/quad.yaml

Shows the vehicle time, armed / on the ground / crashed (HEARTBEAT), position and velocity NED
(LOCAL_POSITION_NED), attitude in degrees (ATTITUDE), the eight actuator outputs
(SERVO_OUTPUT_RAW: throttle % = (pwm - 1000) / 10 for motors 1-4, tilt deg = (pwm - 1500) / 500 x
half-range for servos 1-4, the half-range read from the vehicle YAML), the active faults and the
wind (the SIM_* parameters, read at start and again whenever a STATUSTEXT mentions faults, a
script or a SIM_ parameter), link statistics (messages per second by type, datagrams, the
vehicle's SYS_STATUS drop rate and error counts), what the offboard controller says through the
vehicle's routing (its HEARTBEAT as component 191 and its NAMED_VALUE_FLOATs, MOT1_EFF..MOT4_EFF:
the motor effectiveness it estimates) and the last five STATUSTEXTs, each with its sender when it
is not the autopilot.

It says hello (a GCS heartbeat, once a second) so the vehicle adds it as a peer. Plain ANSI
(clear screen and home), no curses. Exit status 0; 1 if no heartbeat within --timeout; 2 on bad
arguments or a bad vehicle file.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import deque

import trq_params
from pymavlink.dialects.v20 import common as mavlink
from trq_params import ConfigError

from sil_vehicle.config import load_vehicle
from trq_lab.gcs.client import MavClient, NoAnswer, gcs_parser

CLEAR_HOME = "\x1b[2J\x1b[H"
RATE_WINDOW_S = 2.0
FAULT_WORDS = ("fault", "script", "SIM_")
STATES = {v: k.removeprefix("MAV_STATE_") for k, v in vars(mavlink).items()
          if k.startswith("MAV_STATE_") and isinstance(v, int)}
SEVERITIES = ("EMERGENCY", "ALERT", "CRITICAL", "ERROR", "WARNING", "NOTICE", "INFO", "DEBUG")


def throttle_pct(pwm: int) -> float:
    """Motor output of SERVO_OUTPUT_RAW (1000 stopped, 2000 full) in percent."""
    return (pwm - 1000) / 10.0


def tilt_deg(pwm: int, half_range_deg: float) -> float:
    """Tilt servo output of SERVO_OUTPUT_RAW (1500 centre, +-500 the half-range) in degrees."""
    return (pwm - 1500) / 500.0 * half_range_deg


class Monitor:
    """What the vehicle has said, kept up to date by `on_message`; `render()` draws it."""

    def __init__(self, client: MavClient, half_range_deg: float, connect: str) -> None:
        self.client = client
        self.half_range_deg = half_range_deg
        self.connect = connect
        self.params: dict[str, float] = {}
        self.param_count: int | None = None
        self.texts: deque[str] = deque(maxlen=5)
        self.arrivals: deque[tuple[float, str]] = deque()
        self.datagrams: deque[float] = deque()
        self.datagrams_total = 0
        self.messages_total = 0
        self.last_heartbeat = time.monotonic()
        # other components of the vehicle (the companion computer): (system, component) ->
        # name -> value of its NAMED_VALUE_FLOATs, and when its last HEARTBEAT came
        self.named: dict[tuple[int, int], dict[str, float]] = {}
        self.component_heard: dict[tuple[int, int], float] = {}
        self.refresh_wanted = False
        self.started = time.monotonic()
        client.on_message = self.on_message

    # --- input -----------------------------------------------------------------------------
    def on_message(self, msg) -> None:
        now = time.monotonic()
        kind = msg.get_type()
        self.messages_total += 1
        self.arrivals.append((now, kind))
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        vehicle = self.client.is_vehicle(msg)
        if kind == "HEARTBEAT":
            if vehicle:
                self.last_heartbeat = now
            elif src[0] == self.client.target[0]:
                self.component_heard[src] = now
        elif kind == "NAMED_VALUE_FLOAT":
            name = msg.name if isinstance(msg.name, str) else msg.name.decode(errors="replace")
            self.named.setdefault(src, {})[name.rstrip("\0")] = float(msg.value)
        elif kind == "PARAM_VALUE":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            self.params[name] = float(msg.param_value)
            self.param_count = msg.param_count
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
            severity = SEVERITIES[msg.severity] if msg.severity < len(SEVERITIES) else "?"
            sender = "" if vehicle else f"[{src[0]}/{src[1]}] "
            self.texts.append(f"{severity:<8} {sender}{text}")
            if any(w.lower() in text.lower() for w in FAULT_WORDS):
                self.refresh_wanted = True

    def poll(self, duration_s: float) -> None:
        """Read whatever arrives for `duration_s` of wall time."""
        end = time.monotonic() + duration_s
        while (left := end - time.monotonic()) > 0:
            if self.client.poll(min(left, 0.05)):    # one datagram of valid frames
                self.datagrams_total += 1
                self.datagrams.append(time.monotonic())

    def request_params(self) -> None:
        self.refresh_wanted = False
        self.client.send(mavlink.MAVLink_param_request_list_message(*self.client.target))

    def params_complete(self) -> bool:
        return self.param_count is not None and len(self.params) >= self.param_count

    def hello(self) -> None:
        self.client.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    # --- output ----------------------------------------------------------------------------
    def rates(self) -> tuple[dict[str, float], float]:
        now = time.monotonic()
        while self.arrivals and self.arrivals[0][0] < now - RATE_WINDOW_S:
            self.arrivals.popleft()
        while self.datagrams and self.datagrams[0] < now - RATE_WINDOW_S:
            self.datagrams.popleft()
        window = min(RATE_WINDOW_S, max(now - self.started, 1e-3))
        counts: dict[str, int] = {}
        for _, kind in self.arrivals:
            counts[kind] = counts.get(kind, 0) + 1
        return {k: n / window for k, n in sorted(counts.items())}, len(self.datagrams) / window

    def faults(self) -> list[str]:
        p = self.params
        out = []
        for n in range(1, 5):
            eff, tvb = p.get(f"SIM_MOT{n}_EFF", 1.0), p.get(f"SIM_MOT{n}_TVB", 0.0)
            parts = []
            if p.get(f"SIM_MOT{n}_OFF", 0.0) >= 0.5:
                parts.append("OFF")
            if tvb != 0.0:
                w, phi = p.get(f"SIM_MOT{n}_TVW", 0.0), p.get(f"SIM_MOT{n}_TVP", 0.0)
                parts.append(f"effectiveness {eff:g} - {tvb:g} sin({w:g} t + {phi:g})")
            elif eff != 1.0:
                parts.append(f"effectiveness {eff:g}")
            if parts:
                out.append(f"motor {n}: " + ", ".join(parts))
        for n in range(1, 5):
            if p.get(f"SIM_SRV{n}_STK", 0.0) >= 0.5:
                out.append(f"servo {n}: stuck at {p.get(f'SIM_SRV{n}_ANG', math.nan):.1f} deg")
        return out

    def components(self) -> list[str]:
        """A line per other component heard (the offboard controller: component 191): how long
        since its heartbeat and its named values, MOTn_EFF in motor order first."""
        now = time.monotonic()
        lines = []
        for src in sorted(set(self.named) | set(self.component_heard)):
            heard = self.component_heard.get(src)
            beat = "no heartbeat" if heard is None else f"heartbeat {now - heard:.1f} s ago"
            values = self.named.get(src, {})
            names = sorted(values, key=lambda n: (not n.startswith("MOT"), n))
            shown = "  ".join(f"{n} {values[n]:.2f}" for n in names) or "(no named values)"
            lines.append(f"component   {src[0]}/{src[1]} ({beat})  {shown}")
        if not lines:
            lines.append("component   (no offboard controller heard)")
        return lines

    def render(self) -> str:
        c = self.client
        last = c.last
        lines = [f"trq-ftc monitor  {self.connect}  vehicle time "
                 f"{c.vehicle_time_us / 1e6:8.2f} s"]
        hb = last.get("HEARTBEAT")
        silent = time.monotonic() - self.last_heartbeat
        if hb is None:
            lines.append("state       no heartbeat yet")
        else:
            armed = bool(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            status = STATES.get(hb.system_status, str(hb.system_status))
            where = {"STANDBY": "on the ground", "ACTIVE": "active (armed or flying)",
                     "EMERGENCY": "CRASHED"}.get(status, status.lower())
            lines.append(f"state       {'ARMED' if armed else 'disarmed'}, {where} "
                         f"(system_status {status})"
                         + (f"   LINK LOST: no heartbeat for {silent:.1f} s" if silent > 3.0
                            else ""))
        pos = last.get("LOCAL_POSITION_NED")
        lines += ["position    (no LOCAL_POSITION_NED yet)"] if pos is None else [
            f"position    NED m    n {pos.x:+8.3f}  e {pos.y:+8.3f}  d {pos.z:+8.3f}"
            f"   (altitude {-pos.z:.2f} m)",
            f"velocity    NED m/s  n {pos.vx:+8.3f}  e {pos.vy:+8.3f}  d {pos.vz:+8.3f}"]
        att = last.get("ATTITUDE")
        deg = math.degrees
        lines += ["attitude    (no ATTITUDE yet)"] if att is None else [
            f"attitude    deg      roll {deg(att.roll):+7.2f}  pitch {deg(att.pitch):+7.2f}  "
            f"yaw {deg(att.yaw):+7.2f}",
            f"rates       deg/s    p {deg(att.rollspeed):+7.1f}  q {deg(att.pitchspeed):+7.1f}  "
            f"r {deg(att.yawspeed):+7.1f}"]
        raw = last.get("SERVO_OUTPUT_RAW")
        if raw is None:
            lines.append("outputs     (no SERVO_OUTPUT_RAW yet)")
        else:
            pwm = [getattr(raw, f"servo{i}_raw") for i in range(1, 9)]
            head = "".join(f"{f'M{i}':>8}" for i in range(1, 5)) + \
                "".join(f"{f'S{i}':>8}" for i in range(1, 5))
            motors = "".join(f"{throttle_pct(v):7.1f}%" for v in pwm[:4])
            servos = "".join(f"{tilt_deg(v, self.half_range_deg):+6.1f}dg" for v in pwm[4:])
            lines.append(f"outputs   {head}")
            lines.append(f"  (% / deg){motors}{servos}")
        faults = self.faults()
        known = self.params_complete()
        lines.append("faults      " + ("; ".join(faults) if faults else
                                       "none" if known else "(parameters not read yet)"))
        p = self.params
        if "SIM_WIND_SPD" in p:
            gusts = p.get("SIM_GUST_EN", 0.0) >= 0.5
            lines.append(f"wind        {p['SIM_WIND_SPD']:g} m/s from "
                         f"{p.get('SIM_WIND_DIR', 0.0):g} deg, gusts "
                         + (f"on (sigma {p.get('SIM_GUST_SIG', math.nan):g} m/s, length "
                            f"{p.get('SIM_GUST_LEN', math.nan):g} m)" if gusts else "off"))
        else:
            lines.append("wind        (parameters not read yet)")
        rates, dgram_rate = self.rates()
        lines.append(f"link        {dgram_rate:.1f} datagrams/s ({self.datagrams_total} total), "
                     f"{self.messages_total} messages")
        lines.append("  msgs/s    " + "  ".join(f"{k} {v:.1f}" for k, v in rates.items()))
        st = last.get("SYS_STATUS")
        if st is not None:
            lines.append(f"  vehicle   drop rate {st.drop_rate_comm / 100:.2f} %, errors_comm "
                         f"{st.errors_comm}, bad frames {st.errors_count1}, unknown ids "
                         f"{st.errors_count2}, other system {st.errors_count3}, rejected/stale "
                         f"targets {st.errors_count4}")
            lines.append(f"  health    {health_line(st)}")
        lines += self.components()
        lines.append("statustext  " + ("(none yet)" if not self.texts else ""))
        lines += [f"  {t}" for t in self.texts]
        return "\n".join(lines) + "\n"


# SYS_STATUS's sensor bits the vehicle reports (sil_vehicle/PROTOCOL.md, the health report)
HEALTH_BITS = (("gyro", mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO),
               ("accel", mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL),
               ("mag", mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG),
               ("baro", mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE),
               ("gps", mavlink.MAV_SYS_STATUS_SENSOR_GPS),
               ("vision", mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION),
               ("attitude", mavlink.MAV_SYS_STATUS_AHRS),
               ("position", mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL))


def health_line(st) -> str:
    """SYS_STATUS's present sensors, each ok or FAILING (its health bit clear)."""
    present, health = st.onboard_control_sensors_present, st.onboard_control_sensors_health
    parts = [f"{name} {'ok' if health & bit else 'FAILING'}" for name, bit in HEALTH_BITS
             if present & bit]
    return ", ".join(parts) if parts else "(no sensor reported)"


def build_parser() -> argparse.ArgumentParser:
    p = gcs_parser("trq-monitor", __doc__)
    p.add_argument("--vehicle", default="trq",
                   help="airframe, for the tilt servos' half-range: a built-in name (trq, quad) "
                        "or a vehicle YAML path (default trq)")
    p.add_argument("--once", action="store_true", help="print one snapshot and exit")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    p.add_argument("--timeout", type=float, default=5.0,
                   help="seconds to wait for the first heartbeat (default 5)")
    p.add_argument("--rate", type=float, default=5.0, help="frames per second (default 5)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.rate <= 0 or args.timeout <= 0 or (args.duration is not None and args.duration < 0):
        print("monitor: --rate and --timeout must be positive, --duration not negative",
              file=sys.stderr)
        return 2
    try:
        vp = load_vehicle(trq_params.resolve("vehicle", args.vehicle))
        client = MavClient(args.connect)
    except (ConfigError, ValueError) as exc:
        print(f"monitor: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"monitor: cannot open {args.connect}: {exc}", file=sys.stderr)
        return 1
    half_range = math.degrees(vp.tilt_limit_rad)       # max(|tilt.min_deg|, tilt.max_deg)
    with client:
        mon = Monitor(client, half_range, args.connect)
        try:
            client.hello(args.timeout)
        except NoAnswer:
            print(f"monitor: no heartbeat from the vehicle at {args.connect} within "
                  f"{args.timeout:g} s (is it running? is that its ground-station port?)",
                  file=sys.stderr)
            return 1
        mon.request_params()
        if args.once:
            # a second of traffic: every gcs stream (SYS_STATUS is 1 Hz) and the parameters
            end = time.monotonic() + max(args.timeout, 1.2)
            first = time.monotonic()
            wanted = ("LOCAL_POSITION_NED", "ATTITUDE", "SERVO_OUTPUT_RAW", "SYS_STATUS")
            asked = time.monotonic()
            while time.monotonic() < end:
                mon.poll(0.1)
                complete = mon.params_complete() and all(k in client.last for k in wanted)
                if complete and time.monotonic() - first >= 1.2:
                    break
                if not mon.params_complete() and time.monotonic() - asked > 1.0:
                    mon.request_params()          # a lost datagram: ask again
                    asked = time.monotonic()
            sys.stdout.write(mon.render())
            return 0
        period = 1.0 / args.rate
        stop_at = None if args.duration is None else time.monotonic() + args.duration
        next_hello = time.monotonic() + 1.0
        last_request = time.monotonic()
        try:
            while stop_at is None or time.monotonic() < stop_at:
                mon.poll(period if stop_at is None else max(0.0, min(period,
                                                                     stop_at - time.monotonic())))
                now = time.monotonic()
                if now >= next_hello:
                    mon.hello()
                    next_hello = now + 1.0
                # on a fault STATUSTEXT at most twice a second; while incomplete (a lost
                # datagram, or a vehicle without SIM_* parameters) every 2 s
                if (mon.refresh_wanted and now - last_request > 0.5) or \
                        (not mon.params_complete() and now - last_request > 2.0):
                    mon.request_params()
                    last_request = now
                sys.stdout.write(CLEAR_HOME + mon.render())
                sys.stdout.flush()
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
