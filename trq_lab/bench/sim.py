#!/usr/bin/env python3
"""Benchmark of the SIL vehicle: how fast the plant and the daemon run on this machine.

    trq-bench-sim [--steps 20000] [--sim-seconds 20] [--sensing NAME|PATH]
                  [--core compiled|python] [--json out/bench_sim.json]

Each figure for both physics cores (`physics_core`: the compiled tick and the Python reference,
which give bit-identical flights), with their ratio:
(1) Vehicle.step: physics ticks per second, armed, in the air at (a hair above) the hover
    throttle, median of 5 runs;
(2) Sitl.step: the same with telemetry due at the default rates, every message encoded to bytes
    (the daemon's work per tick, without sockets), median of 5 runs;
(3) the daemon (`python -m sil_vehicle`, a subprocess) in lockstep with a trivial responder that
    answers every ODOMETRY with a target, control rate 100 Hz: the real-time factor (simulated
    seconds per wall second, from the first ODOMETRY to the last), median of 3 runs; and the
    daemon's CPU time per simulated second (its whole process, start-up included), which is
    what bounds it when the responder is free; and the same without start-up (from as many
    runs of STARTUP_SIM_S: the difference of the medians' CPU over the difference of simulated
    time), a steadier figure on a shared machine, where wall time swings with the other
    processes.
(2) and (3) fly the sim file's sensing profile (truth: no sensor) or `--sensing`'s, whose
sensors then sample every tick: run it with and without to see their cost.
The target is 20x real time with the default core under `truth`, 25x under a sensing profile
(issue 33: the sensors and the estimator included). Numbers are measured, never estimated.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink
from trq_params.loader import dump as dump_yaml

from sil_vehicle import compiled
from sil_vehicle.config import PARAMS_DIR, load_sim, sensing_profile
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sitl import LINKS, Sitl
from sil_vehicle.vehicle import ActuatorCommand, Vehicle

TARGET_RTF = 20.0             # under truth (no sensor)
TARGET_RTF_SENSING = 25.0     # under a sensing profile (issue 33)
STARTUP_SIM_S = 2.0     # the short run whose CPU, less its simulated seconds' share, is start-up
SIM_DEFAULT = PARAMS_DIR / "sim" / "default.yaml"
VEHICLE = PARAMS_DIR / "vehicle" / "trq.yaml"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def airborne(vehicle: Vehicle, throttle_pct: float) -> None:
    """Armed, 50 m up, motors at the given throttle: every tick runs the full RK4."""
    x = list(vehicle.state.x)
    x[2] = -50.0
    vehicle.state = dataclasses.replace(vehicle.state, x=tuple(x), landed=False,
                                        motor_pct=(throttle_pct,) * 4)
    vehicle.armed = True
    # tilts centred: a tilt pattern is an open-loop torque that tips the vehicle over within a
    # second, and a crashed vehicle resting on the ground skips the RK4 (an earlier version
    # measured that, twice too fast)
    vehicle.command = ActuatorCommand((throttle_pct,) * 4, (0.0,) * 4)


def check_flying(vehicle: Vehicle, what: str) -> None:
    """A benchmark of the physics must have measured a flying vehicle (full RK4 every tick)."""
    s = vehicle.state
    if s.landed or s.crashed:
        raise RuntimeError(f"{what}: the vehicle ended {'crashed' if s.crashed else 'landed'} "
                           f"({s.crash_reason or 'on the ground'}): not a measurement of flight")


def bench_vehicle(steps: int, core: str, runs: int = 5) -> float:
    sim = load_sim(SIM_DEFAULT).with_changes(physics_core=core)
    rates = []
    for _ in range(runs):
        v = Vehicle(sim, np.random.default_rng(0))
        airborne(v, sim.vehicle.hover_throttle_pct + 0.5)
        t0 = time.perf_counter()
        for _ in range(steps):
            v.step()
        rates.append(steps / (time.perf_counter() - t0))
        check_flying(v, "Vehicle.step")
    return statistics.median(rates)


def bench_sitl(steps: int, core: str, runs: int = 5,
               sensing: str | None = None) -> tuple[float, float]:
    """(steps/s, messages encoded per simulated second)."""
    sim = load_sim(SIM_DEFAULT).with_changes(clock_mode="realtime", physics_core=core)
    if sensing is not None:
        sim = sim.with_changes(sensing=sensing_profile(sensing, sim.physics_rate_hz,
                                                       "command line", "--sensing"))
    rates, per_s = [], 0.0
    for _ in range(runs):
        s = Sitl(sim)
        airborne(s.vehicle, sim.vehicle.hover_throttle_pct + 0.5)
        codecs = {name: Codec() for name in LINKS}
        n_msgs = 0
        zeta = (sim.vehicle.hover_throttle_pct + 0.5) / 100.0
        controller = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        t0 = time.perf_counter()
        for k in range(steps):
            if k % s.lockstep_ticks() == 0:      # a controller's target every control period
                raw = mavlink.MAVLink_set_actuator_control_target_message(
                    s.t_us, 0, 1, 1, [zeta] * 4 + [0.0] * 4).pack(controller)
                for msg in codecs["offboard"].decode(bytes(raw)):
                    s.handle("offboard", msg)
            for item in s.step():
                codecs[item.link].encode(item.msg)
                n_msgs += 1
        rates.append(steps / (time.perf_counter() - t0))
        check_flying(s.vehicle, "Sitl.step")
        per_s = n_msgs / (steps * sim.dt_us * 1e-6)
    return statistics.median(rates), per_s


ODOMETRY_ID = mavlink.MAVLINK_MSG_ID_ODOMETRY


def odometry_frames(data: bytes) -> bytes:
    """The ODOMETRY frames of a datagram, found by their MAVLink 2 headers (a datagram of the
    vehicle holds whole frames): the trivial responder decodes only what it answers, so that
    the lockstep figure measures the vehicle rather than pymavlink's parsing of telemetry nobody
    reads. Anything that is not a well-formed MAVLink 2 frame sequence goes to the full parser."""
    out, i, n = [], 0, len(data)
    while i < n:
        if data[i] != 0xFD or i + 10 > n:
            return data                       # not the expected framing: parse it all
        length = data[i + 1]
        end = i + 12 + length + (13 if data[i + 2] & 0x01 else 0)
        if int.from_bytes(data[i + 7:i + 10], "little") == ODOMETRY_ID:
            out.append(data[i:end])
        i = end
    return b"".join(out)


def lockstep_run(sim_yaml: Path, sim_seconds: float, log_dir: Path,
                 sensing: str | None = None) -> tuple[float, float, float]:
    """One daemon run answered by a trivial responder: (real-time factor, the daemon's CPU
    seconds per simulated second, the responder's)."""
    trim = load_sim(sim_yaml).vehicle.hover_throttle_pct
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.05)             # short: the loop must notice the exit promptly
    off_port = free_port()
    cmd = [sys.executable, "-m", "sil_vehicle", "--sim", str(sim_yaml), "--mode", "lockstep",
           "--offboard-bind", f"127.0.0.1:{off_port}",
           "--offboard-target", f"127.0.0.1:{sock.getsockname()[1]}",
           "--gcs-bind", f"127.0.0.1:{free_port()}", "--gcs-target", "127.0.0.1:9",
           "--log-dir", str(log_dir), "--duration", str(sim_seconds)]
    if sensing is not None:
        cmd += ["--sensing", sensing]
    env = dict(os.environ)
    usage0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    rx = mavlink.MAVLink(None)
    dest = ("127.0.0.1", off_port)
    answered: set[int] = set()
    wall0 = wall_end = None
    end_us = int(round(sim_seconds * 1e6))
    zeta = (trim + 0.5) / 100.0                  # climbs slowly: airborne, full RK4 every tick
    responder_cpu0 = time.process_time()
    try:
        while proc.poll() is None:
            try:
                data, _ = sock.recvfrom(65535)
            except socket.timeout:
                continue
            for msg in rx.parse_buffer(odometry_frames(data)) or []:
                if msg.get_type() != "ODOMETRY" or msg.time_usec in answered:
                    continue
                answered.add(msg.time_usec)
                if msg.time_usec >= end_us and wall_end is None:
                    wall_end = time.perf_counter()      # the last stamp: simulation done
                out = b""
                if wall0 is None:
                    wall0 = time.perf_counter()
                    out += bytes(mavlink.MAVLink_command_long_message(
                        1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0,
                        0).pack(mav))
                out += bytes(mavlink.MAVLink_set_actuator_control_target_message(
                    msg.time_usec, 0, 1, 1, [zeta] * 4 + [0.0] * 4).pack(mav))
                sock.sendto(out, dest)
        responder_cpu1 = time.process_time()
        proc.wait(timeout=30)
        if wall_end is None:
            wall_end = time.perf_counter()
        wall = wall_end - wall0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sock.close()
    if proc.returncode != 0:
        raise RuntimeError(f"the vehicle exited with {proc.returncode}")
    usage1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (usage1.ru_utime - usage0.ru_utime) + (usage1.ru_stime - usage0.ru_stime)
    return sim_seconds / wall, cpu / sim_seconds, (responder_cpu1 - responder_cpu0) / sim_seconds


def steady_cpu_per_s(cpu_per_s: float, sim_s: float, short_cpu_per_s: float,
                     short_sim_s: float) -> float:
    """CPU seconds per simulated second without start-up, from a run of sim_s and a shorter
    one of short_sim_s (each given as CPU per simulated second): the difference of their CPU
    over the difference of their simulated time."""
    if not sim_s > short_sim_s:
        raise ValueError(f"the long run ({sim_s} s) must be longer than the short one "
                         f"({short_sim_s} s)")
    return (cpu_per_s * sim_s - short_cpu_per_s * short_sim_s) / (sim_s - short_sim_s)


def bench_lockstep(sim_seconds: float, core: str, runs: int = 3,
                   sensing: str | None = None) -> tuple[float, float, float, float | None]:
    """Medians of lockstep_run's figures, and the daemon's CPU per simulated second without
    start-up (None when sim_seconds is not longer than STARTUP_SIM_S)."""
    with tempfile.TemporaryDirectory(prefix="bench_sim_") as tmp:
        sim_yaml = Path(tmp) / "bench_100hz.yaml"
        # `vehicle:` absolute: a relative one inherited through `extends:` would be resolved
        # against this temporary file's folder
        sim_yaml.write_text(dump_yaml({
            "extends": str(SIM_DEFAULT), "vehicle": str(VEHICLE), "control_rate_hz": 100,
            "physics_core": core, "telemetry": {"offboard": {"ODOMETRY": 100}}}),
            encoding="utf-8")
        runs_ = [lockstep_run(sim_yaml, sim_seconds, Path(tmp) / f"run{i}", sensing)
                 for i in range(runs)]
        shorts = ([lockstep_run(sim_yaml, STARTUP_SIM_S, Path(tmp) / f"short{i}", sensing)
                   for i in range(runs)] if sim_seconds > STARTUP_SIM_S else [])
    rtf, cpu, responder = (statistics.median(r[i] for r in runs_) for i in range(3))
    steady = (steady_cpu_per_s(cpu, sim_seconds, statistics.median(r[1] for r in shorts),
                               STARTUP_SIM_S) if shorts else None)
    return rtf, cpu, responder, steady


def machine() -> dict[str, object]:
    return {"platform": platform.platform(), "processor": platform.processor() or
            platform.machine(), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "implementation": platform.python_implementation(),
            "mavlink_crc": "fastcrc" if mavlink.x25crc.__name__ == "_x25crc_fast" else
            "pure Python (fastcrc not installed)"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-sim", description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=20_000, help="ticks per run of (1) and (2)")
    ap.add_argument("--sim-seconds", type=float, default=20.0,
                    help="simulated seconds per daemon run of (3)")
    ap.add_argument("--sensing", default=None, metavar="NAME|PATH",
                    help="the vehicle's sensing profile in (2) and (3): a built-in name or a "
                         "YAML path (default: the sim file's, truth)")
    ap.add_argument("--core", choices=("compiled", "python"), default=None,
                    help="measure this physics core only (default: both, when compiled)")
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    args = ap.parse_args(argv)

    sim = load_sim(SIM_DEFAULT)
    if args.sensing is not None:    # a bad profile fails here, before any measurement
        sensing_profile(args.sensing, sim.physics_rate_hz, "command line", "--sensing")
    sensing = args.sensing if args.sensing is not None else sim.sensing.name
    physics_hz = sim.physics_rate_hz
    if compiled.load_core() is None:
        print("no compiled physics core on this machine (no C compiler): Python only")
        cores = ["python"]
    else:
        cores = ["compiled", "python"]
    default = "compiled" if sim.physics_core != "python" and "compiled" in cores else "python"
    if args.core is not None:
        if args.core not in cores:
            ap.error(f"--core {args.core}: not available on this machine (no C compiler)")
        cores, default = [args.core], args.core
    per_core: dict[str, dict[str, float]] = {}
    for core in cores:
        vehicle_sps = bench_vehicle(args.steps, core)
        sitl_sps, msgs_per_s = bench_sitl(args.steps, core, sensing=args.sensing)
        rtf, cpu_per_s, responder_per_s, steady_per_s = bench_lockstep(
            args.sim_seconds, core, sensing=args.sensing)
        per_core[core] = {
            "vehicle_step_per_s": round(vehicle_sps, 1),
            "vehicle_step_rtf_bound": round(vehicle_sps / physics_hz, 2),
            "sitl_step_with_telemetry_per_s": round(sitl_sps, 1),
            "sitl_messages_per_sim_s": round(msgs_per_s, 1),
            "sitl_step_rtf_bound": round(sitl_sps / physics_hz, 2),
            "lockstep_rtf_100hz": round(rtf, 2),
            "lockstep_daemon_cpu_s_per_sim_s": round(cpu_per_s, 4),
            "lockstep_daemon_steady_cpu_s_per_sim_s": (round(steady_per_s, 4)
                                                       if steady_per_s is not None else None),
            "lockstep_responder_cpu_s_per_sim_s": round(responder_per_s, 4),
        }
    rtf = per_core[default]["lockstep_rtf_100hz"]
    target = TARGET_RTF if sensing in (None, "truth") else TARGET_RTF_SENSING
    result = {
        "machine": machine(),
        "physics_rate_hz": physics_hz,
        "sensing": sensing,
        "default_core": default,
        "cores": per_core,
        "lockstep_sim_seconds": args.sim_seconds,
        "target_rtf": target,
        "lockstep_rtf_over_target": round(rtf / target, 2),
        "runs": {"vehicle": 5, "sitl": 5, "lockstep": 3, "steps": args.steps,
                 "lockstep_short_sim_s": STARTUP_SIM_S},
    }
    m = result["machine"]
    print(f"machine: {m['platform']}, {m['processor']}, {m['cpu_count']} CPUs, "
          f"{m['implementation']} {m['python']}, MAVLink CRC: {m['mavlink_crc']}")
    rows = [("(1) Vehicle.step, steps/s", "vehicle_step_per_s", "{:10.0f}"),
            ("(2) Sitl.step + encoding, steps/s", "sitl_step_with_telemetry_per_s", "{:10.0f}"),
            ("(3) daemon lockstep 100 Hz, x real time", "lockstep_rtf_100hz", "{:10.1f}"),
            ("    daemon CPU ms per simulated s", "lockstep_daemon_cpu_s_per_sim_s", None),
            ("    the same without start-up", "lockstep_daemon_steady_cpu_s_per_sim_s", None),
            ("    responder CPU ms per simulated s", "lockstep_responder_cpu_s_per_sim_s", None)]
    print(f"{'':42s}" + "".join(f"{c:>12s}" for c in cores)
          + ("       ratio" if len(cores) == 2 else ""))
    for label, key, fmt in rows:
        vals = [per_core[c][key] for c in cores]
        if any(v is None for v in vals):
            continue                    # no start-up-free figure (a run as short as its start)
        cells = [f"{1000 * v:12.1f}" if fmt is None else f"  {fmt.format(v)}" for v in vals]
        ratio = ""
        if len(cores) == 2:
            r = vals[0] / vals[1] if fmt is not None else vals[1] / vals[0]
            ratio = f"{r:11.2f}x"
        print(f"{label:42s}" + "".join(cells) + ratio)
    print(f"(1), (2): median of 5 x {args.steps} ticks at {physics_hz} Hz; (3): "
          f"{args.sim_seconds:g} simulated s, median of 3; sensing {sensing}; "
          f"{per_core[cores[0]]['sitl_messages_per_sim_s']:.0f} messages per simulated s")
    print(f"target: {target:g}x real time in lockstep with the default core ({default}), sensing "
          f"{sensing or 'truth'}: {rtf:.1f}x, {rtf / target:.2f} of it, "
          f"{'met' if rtf >= target else 'NOT met'}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
        print(f"written to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
