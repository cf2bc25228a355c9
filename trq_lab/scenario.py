#!/usr/bin/env python3
"""Run a scenario: the SIL vehicle and the offboard controller as separate processes over UDP,
a serial pair or TCP, once per controller under the same wind, faults and seed; then metrics,
report and figures.

    trq-scenario paper_fault50 --out out/paper_fault50
    trq-scenario SCENARIO.yaml --out DIR [--realtime] [--jobs N] [--only NAME]
                 [--link udp|serial|tcp] [--sensing NAME|PATH]

Writes DIR/metrics.json, DIR/report.md, DIR/*.png and, per controller, DIR/<controller>/ with
flight.csv and vehicle.tlog (the vehicle), controller.csv and offboard.tlog (the controller) and
the processes' output. Lockstep by default (deterministic, faster than real time); --realtime flies
against the wall clock. Run i's vehicle sends its ground-station telemetry to UDP 14550 + i, so
QGroundControl on 14550 shows the first flight. --link serial flies the offboard link over a
pair of pseudo-terminals at 921600 baud (trq_lab.ptypair, as a companion computer's UART; paced
at the line's rate in real time), --link tcp over the vehicle's TCP server. Exit status: 0 when
every run finished and every target of the scenario is met, 1 otherwise, 2 on a bad scenario file.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import trq_params
from trq_params import ConfigError
from trq_params.loader import dump as dump_yaml
from trq_params.loader import read_yaml, validate
from trq_params.schema import ScenarioFile

from sil_vehicle.config import load_vehicle, sensing_profile
from sil_vehicle.faultscript import load_script
from trq_lab import metrics as metrics_mod
from trq_lab import procs
from trq_lab.overlays import run_dir, write_controller_overlay
from trq_lab.reporting import scenario as report
from trq_wire.ulog import LogTail

# what a command waits in real time, about one NMPC step (docs/decisions/
# 2026-12-02-shorter-applied-delay.md: what else was tried)
REALTIME_LATENCY_S = 0.005



@dataclass(frozen=True)
class Scenario:
    name: str
    file: Path
    description: str
    seed: int
    wind_speed_m_s: float
    wind_from_deg: float
    gusts: bool
    faults: Path | None
    reference: dict
    controllers: tuple[str, ...]
    recovery_threshold_m: float
    timeout_s: float
    targets: dict[str, dict[str, object]]
    better: tuple[tuple[str, str, str], ...]     # (better, worse, metric)
    offboard_impair: dict[str, float]            # links.offboard.impair of the vehicle
    sensing: str | None = None      # the vehicle's sensing profile (a built-in name or an
                                    # absolute path); None: the sim file's


# a scenario's sensing profile when its file names none: what the prototype sees indoors (a
# motion capture through the autopilot's estimator), never the truth (issue 33)
SENSING_DEFAULT = "mocap"


def _physics_rate_hz() -> int:
    """The physics rate of the sim file every flight of a scenario extends."""
    from trq_params.loader import load
    from trq_params.schema import SimFile
    return load(trq_params.builtin("sim", "default"), SimFile).physics_rate_hz


def sensing_flown(scenario: Scenario) -> str:
    """The sensing profile a scenario's vehicles carry: its own (or --sensing's), else the sim
    file's that every flight extends (a built-in name, or an absolute path)."""
    if scenario.sensing is not None:
        return scenario.sensing
    from trq_params.loader import load
    from trq_params.schema import SimFile
    return load(trq_params.builtin("sim", "default"), SimFile).sensing


def check_sensing(value: str, where: str, key: str) -> str:
    """A sensing profile given to a scenario, as the vehicle will get it (a name, or a path made
    absolute), loaded once to fail early: a ConfigError naming `where`, `key` and `value`."""
    resolved = value if trq_params.is_name(value) else str(Path(value).resolve())
    sensing_profile(resolved, _physics_rate_hz(), where, key)
    return resolved


def rates_lowpass_hz(sensing: str) -> float:
    """The low-pass the vehicle puts on the body rates it publishes under the sensing profile
    `sensing` (a name or an absolute path): its estimator's IMU_GYRO_CUTOFF, none under
    `truth` (the true rates go out). The controller's rates_lowpass_hz, as a user sets it from
    their autopilot's parameter."""
    profile = sensing_profile(sensing, _physics_rate_hz(), "sensing")
    return 0.0 if profile is None or profile.is_truth else float(profile.estimator.IMU_GYRO_CUTOFF)


def command_delay_s(impair: dict[str, float], realtime: bool) -> float:
    """How long a command takes to act after the state it answers was measured: the offboard
    link's round trip (its delay and mean jitter, each way: the telemetry going down, the
    target coming up), plus in real time about one solve. The controller's applied_delay_s."""
    one_way_s = (impair.get("delay_ms", 0.0) + 0.5 * impair.get("jitter_ms", 0.0)) * 1e-3
    return 2.0 * one_way_s + (REALTIME_LATENCY_S if realtime else 0.0)


def load_scenario(path: Path) -> Scenario:
    """A scenario file, validated (ConfigError naming the file and the key), its fault script
    loaded once to fail early with the script's own message."""
    path = Path(path)
    sc = validate(ScenarioFile, read_yaml(path), path)
    faults = None
    if sc.faults is not None:
        faults = (trq_params.builtin("faults", sc.faults) if trq_params.is_name(sc.faults)
                  else (path.parent / sc.faults).resolve())
        load_script(faults)     # fail now, with the script's own message, if it is bad
    impair = sc.offboard_link.model_dump(exclude_none=True) if sc.offboard_link else {}
    named = SENSING_DEFAULT if sc.sensing is None else sc.sensing
    value = named if trq_params.is_name(named) else str(path.parent / named)
    sensing = check_sensing(value, str(path), "sensing")
    targets = {c: t.model_dump(exclude_none=True) for c, t in sc.targets.items()}
    better = tuple((b.better, b.worse, b.metric) for b in sc.better)
    return Scenario(sc.name, path, sc.description, sc.seed, sc.wind.speed_m_s,
                    sc.wind.direction_deg, sc.wind.gusts, faults, dict(sc.reference),
                    tuple(sc.controllers), sc.recovery_threshold_m, sc.timeout_s, targets,
                    better, impair, sensing)


LINKS = ("udp", "serial", "tcp")
SERIAL_BAUD = 921600


def free_ports(n: int, kind: int = socket.SOCK_DGRAM) -> list[int]:
    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, kind)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports



@dataclass
class Run:
    controller: str                 # its name in the results (a file's stem)
    index: int
    out: Path
    source: str = ""                # the controller as given: a built-in name or a YAML path
    status: str = "pending"
    t_s: float = 0.0
    wall_s: float = 0.0
    returncode: int | None = None
    summary: str = ""


def prepare(scenario: Scenario, controller: str, out: Path) -> tuple[Path, Path, Path, int]:
    """Write the run's controller and sim overlays; return (controller yaml, sim yaml, vehicle
    file, control rate)."""
    from trq_offboard.config import load_controller

    cfg = load_controller(trq_params.resolve("controller", controller))
    # valid before anything starts (raises otherwise)
    ctrl_yaml = write_controller_overlay(controller, scenario.reference, out,
                                         f"written by trq-scenario for {scenario.name}")
    rate = cfg.control_rate_hz
    sim_yaml = out / "sim.yaml"
    sim_overlay = {"extends": str(trq_params.builtin("sim", "default")),
                   "control_rate_hz": rate, "telemetry": {"offboard": {"ODOMETRY": rate}}}
    if scenario.offboard_impair:
        sim_overlay["links"] = {"offboard": {"impair": dict(scenario.offboard_impair)}}
    sim_yaml.write_text(dump_yaml(sim_overlay))
    return ctrl_yaml, sim_yaml, Path(cfg.vehicle.file).resolve(), rate


def serial_delay_s(signed: bool) -> float:
    """How long the vehicle's paced serial line takes to carry one ODOMETRY (its full frame at
    SERIAL_BAUD, 8N1): the state's extra age on that link in real time."""
    from pymavlink.dialects.v20 import common as mavlink

    from trq_wire.framing import frame_size, line_bytes_per_s
    return frame_size(mavlink.MAVLink_odometry_message, signed) / line_bytes_per_s(SERIAL_BAUD)


def offboard_link(link: str, p_vehicle: int, p_ctrl: int, pair=None
                  ) -> tuple[list[str], str]:
    """(the vehicle's offboard-link options, the controller's --connect) for `link`: UDP on
    two ports, the two ends of a pty pair, or the vehicle's TCP server on p_vehicle."""
    if link == "serial":
        return ["--offboard-serial", f"{pair.a}:{SERIAL_BAUD}"], f"serial://{pair.b}:{SERIAL_BAUD}"
    if link == "tcp":
        return ["--offboard-tcp", f"127.0.0.1:{p_vehicle}"], f"tcp:127.0.0.1:{p_vehicle}"
    return (["--offboard-bind", f"127.0.0.1:{p_vehicle}", "--offboard-target",
             f"127.0.0.1:{p_ctrl}"], f"udpin:127.0.0.1:{p_ctrl}")


# trq-offboard's options that every flight of a scenario sets itself (--controller-args may not)
SCENARIO_SETS = ("controller", "connect", "log_dir", "no_log", "applied_delay_s",
                 "signing_key_file", "reference")


def fly(scenario: Scenario, run: Run, realtime: bool, lock: threading.Lock,
        signing_key_file: Path | None = None, controller_prefix: tuple[str, ...] = (),
        vehicle_prefix: tuple[str, ...] = (), link: str = "udp",
        controller_args: tuple[str, ...] = ()) -> None:
    from trq_lab.ptypair import PtyPair

    ctrl_yaml, sim_yaml, vehicle_file, _ = prepare(scenario, run.source or run.controller,
                                                   run.out)
    p_ctrl, p_gcs = free_ports(2)
    p_vehicle, = free_ports(1, socket.SOCK_STREAM if link == "tcp" else socket.SOCK_DGRAM)
    pair = PtyPair() if link == "serial" else None
    try:
        vlink, connect = offboard_link(link, p_vehicle, p_ctrl, pair)
        _fly(scenario, run, realtime, ctrl_yaml, sim_yaml, vehicle_file, vlink, connect, p_gcs,
             signing_key_file, controller_prefix, vehicle_prefix, controller_args)
    finally:
        if pair is not None:
            pair.close()


def vehicle_command(scenario: Scenario, run: Run, realtime: bool, sim_yaml: Path,
                    vehicle_file: Path, vlink: list[str], p_gcs: int) -> list[str]:
    """The vehicle process of one run: the scenario's seed, wind, faults and sensing."""
    vcmd = [sys.executable, "-m", "sil_vehicle", "--sim", str(sim_yaml), "--vehicle",
            str(vehicle_file), "--seed", str(scenario.seed), "--wind-speed",
            str(scenario.wind_speed_m_s), "--wind-dir", str(scenario.wind_from_deg),
            *vlink, "--gcs-bind", f"127.0.0.1:{p_gcs}", "--gcs-target",
            f"127.0.0.1:{14550 + run.index}", "--log-dir", str(run.out),
            "--mode", "realtime" if realtime else "lockstep"]
    if scenario.gusts:
        vcmd.append("--gusts")
    if scenario.faults:
        vcmd += ["--faults", str(scenario.faults)]
    if scenario.sensing is not None:
        vcmd += ["--sensing", scenario.sensing]
    return vcmd


def _fly(scenario: Scenario, run: Run, realtime: bool, ctrl_yaml: Path, sim_yaml: Path,
         vehicle_file: Path, vlink: list[str], connect: str, p_gcs: int,
         signing_key_file: Path | None, controller_prefix: tuple[str, ...],
         vehicle_prefix: tuple[str, ...], controller_args: tuple[str, ...] = ()) -> None:
    vcmd = vehicle_command(scenario, run, realtime, sim_yaml, vehicle_file, vlink, p_gcs)
    # how long a command takes to act: the link's round trip, plus in real time about a solve
    # (and on a paced serial line, the time the line takes to carry an ODOMETRY)
    delay_s = command_delay_s(scenario.offboard_impair, realtime) + (
        serial_delay_s(signing_key_file is not None) if realtime and "--offboard-serial" in vlink
        else 0.0)
    # the vehicle's published rates' low-pass, as the user sets it from the autopilot's
    # IMU_GYRO_CUTOFF (without a scenario profile: the controller file's)
    lowpass = ([] if scenario.sensing is None
               else ["--rates-lowpass-hz", f"{rates_lowpass_hz(scenario.sensing):g}"])
    ccmd = [sys.executable, "-m", "trq_offboard", "--controller", str(ctrl_yaml), "--connect",
            connect, "--log-dir", str(run.out),
            "--applied-delay-s", f"{delay_s:g}", *lowpass, *controller_args]
    if signing_key_file is not None:
        vcmd += ["--signing-key-file", str(signing_key_file)]
        ccmd += ["--signing-key-file", str(signing_key_file)]
    vcmd, ccmd = [*vehicle_prefix, *vcmd], [*controller_prefix, *ccmd]
    env = dict(os.environ)
    (run.out / "command.txt").write_text(" ".join(vcmd) + "\n" + " ".join(ccmd) + "\n")
    wall0 = time.monotonic()
    with open(run.out / "vehicle.out", "w") as vout, open(run.out / "controller.out", "w") as cout:
        vehicle = subprocess.Popen(vcmd, stdout=vout, stderr=subprocess.STDOUT, env=env)
        controller = subprocess.Popen(ccmd, stdout=cout, stderr=subprocess.STDOUT, env=env)
        run.status = "flying"
        tail = LogTail(run.out / "controller.ulg")
        try:
            while controller.poll() is None:
                run.wall_s = time.monotonic() - wall0
                row = tail.last()            # the controller's ULog, as it flies
                run.t_s = row["t_s"] if row else 0.0
                if run.wall_s > scenario.timeout_s:
                    run.status = "timeout"
                    controller.send_signal(signal.SIGINT)
                    try:
                        controller.wait(10)
                    except subprocess.TimeoutExpired:
                        controller.kill()
                    break
                if vehicle.poll() is not None:
                    run.status = "vehicle died"
                    controller.send_signal(signal.SIGINT)
                    controller.wait(10)
                    break
                time.sleep(0.5)
        finally:
            for proc in (controller, vehicle):
                procs.stop(proc)
    run.returncode = controller.returncode
    run.wall_s = time.monotonic() - wall0
    procs.controller_csv(run.out)            # the controller's ULog on the ground
    run.t_s = _last_time(run.out / "controller.csv")
    lines = (run.out / "controller.out").read_text(errors="replace").strip().splitlines()
    run.summary = next((ln for ln in reversed(lines) if ln.startswith("trq-offboard:")), "")
    if run.status == "flying":
        # a crash is an outcome of the flight (the metrics say so), not a failure of the run
        run.status = ("done" if controller.returncode == 0 else
                      "crashed" if "CRASHED" in run.summary else f"exit {controller.returncode}")


def _last_time(path: Path) -> float:
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 4096))
            tail = f.read().decode(errors="replace").strip().splitlines()
        done = tail and not tail[-1].startswith(("#", "t_s"))
        return float(tail[-1].split(",")[0]) if done else 0.0
    except (OSError, ValueError, IndexError):
        return 0.0


def progress(runs: list[Run], stop: threading.Event, stream=sys.stdout) -> None:
    while not stop.wait(2.0):
        parts = []
        for r in runs:
            rtf = r.t_s / r.wall_s if r.wall_s > 0 else 0.0
            parts.append(f"{r.controller}: {r.status} t={r.t_s:5.1f} s ({rtf:4.1f}x)")
        print("  " + " | ".join(parts), file=stream, flush=True)


def evaluate(scenario: Scenario, runs: list[Run]) -> tuple[list[dict], list[str]]:
    onset = None
    if scenario.faults:
        events = load_script(scenario.faults)
        onset = events[0].at_us if events else None
    results, failures = [], []
    for r in runs:
        try:
            _, truth = metrics_mod.read_csv(r.out / "flight.csv")
            _, steps = metrics_mod.read_csv(r.out / "controller.csv")
            vehicle = Path(load_vehicle(prepare_vehicle_file(r)).file).stem
            m = metrics_mod.compute(r.controller, vehicle, truth, steps, onset,
                                    scenario.recovery_threshold_m).as_dict()
        except (OSError, KeyError, ValueError, IndexError) as exc:
            m = {"controller": r.controller, "error": f"no usable logs: {exc}"}
            failures.append(f"{r.controller}: no usable logs ({exc})")
        m["status"] = r.status
        m["wall_s"] = round(r.wall_s, 2)
        results.append(m)
    by_name = {m["controller"]: m for m in results}
    for name, targets in scenario.targets.items():
        if name not in by_name:
            continue                       # not flown (--only)
        m = by_name[name]
        for key, want in targets.items():
            got = m.get(key)
            ok = (got == want) if isinstance(want, bool) else (got is not None and got <= want)
            if not ok:
                op = "=" if isinstance(want, bool) else "<="
                failures.append(f"{name}: {key} = {got} (target {op} {want})")
    for better, worse, metric in scenario.better:
        if better not in by_name or worse not in by_name:
            continue
        a, b = by_name.get(better, {}).get(metric), by_name.get(worse, {}).get(metric)
        if a is None or b is None or not a < b:
            failures.append(f"{better} not better than {worse} on {metric} ({a} vs {b})")
    return results, failures


def worst_motor_factors(scenario: Scenario) -> list[float]:
    """The smallest effectiveness each motor reaches in the fault script (a - b for a
    time-varying fault, 0 for a motor switched off)."""
    from sil_vehicle.faultscript import InjectAction, ParamAction
    factors = [1.0] * 4
    if scenario.faults is None:
        return factors
    eff, tvb = [1.0] * 4, [0.0] * 4
    for event in load_script(scenario.faults):
        for a in event.actions:
            if isinstance(a, ParamAction) and a.name.startswith("SIM_MOT"):
                i = int(a.name[7]) - 1
                if a.name.endswith("_EFF"):
                    eff[i] = a.value
                elif a.name.endswith("_TVB"):
                    tvb[i] = a.value
            elif isinstance(a, InjectAction) and a.unit == 101 and a.kind == 1:
                eff[a.instance - 1], tvb[a.instance - 1] = 0.0, 0.0
            for i in range(4):
                factors[i] = min(factors[i], max(0.0, eff[i] - tvb[i]))
    return factors


def envelope_of(scenario: Scenario, runs: list[Run]) -> list[dict]:
    """The hover trim and wrench margins of each airframe flown, under the scenario's wind and
    its worst fault (trq-envelope)."""
    from trq_lab.analysis import envelope
    out = []
    seen = set()
    factors = worst_motor_factors(scenario)
    for r in runs:
        try:
            vehicle_file = prepare_vehicle_file(r)
        except (OSError, KeyError):
            continue
        if vehicle_file in seen:
            continue
        seen.add(vehicle_file)
        out.append(envelope.analyse(load_vehicle(vehicle_file), factors,
                                    scenario.wind_speed_m_s, scenario.wind_from_deg))
    return out


def prepare_vehicle_file(run: Run) -> Path:
    for line in (run.out / "flight.csv").open():
        if line.startswith("# vehicle_file: "):
            return Path(line.split(": ", 1)[1].strip())
    raise KeyError("vehicle_file")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-scenario", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", help="a built-in scenario by name (" + ", ".join(
        trq_params.names("scenarios")) + ") or a scenario YAML file by path")
    ap.add_argument("--out", type=Path, required=True, help="output directory")
    ap.add_argument("--realtime", action="store_true", help="fly against the wall clock")
    ap.add_argument("--jobs", type=int, default=None,
                    help="flights in parallel (default: the number of CPUs, at most the runs)")
    ap.add_argument("--only", action="append", default=None,
                    help="fly only this controller of the scenario's (repeatable)")
    ap.add_argument("--controller", action="append", default=None,
                    help="fly this controller instead of the scenario's: a built-in name or a "
                         "controller YAML path, e.g. a file of your own that extends a built-in "
                         "one (repeatable; the scenario's targets apply to the names it has)")
    ap.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    ap.add_argument("--controller-prefix", default=None, metavar="CMD",
                    help="run each controller process under this command, e.g. 'taskset -c 1' "
                         "or 'nice -n 10' (trq-bench-cpu-budget uses it for a CPU quota)")
    ap.add_argument("--vehicle-prefix", default=None, metavar="CMD",
                    help="run each vehicle process under this command, e.g. 'taskset -c 0'")
    ap.add_argument("--controller-args", default=None, metavar="ARGS",
                    help="more options for each controller process (trq-offboard's), given "
                         "with '=': --controller-args='--connect-timeout 60 -v'")
    ap.add_argument("--signing-key-file", type=Path, default=None,
                    help="fly with MAVLink 2 signing (both daemons get the key file)")
    ap.add_argument("--link", choices=LINKS, default="udp",
                    help="the offboard link: udp (default), serial (a pty pair at 921600 baud, "
                         "paced at the line's rate in real time) or tcp (the vehicle's server)")
    ap.add_argument("--sensing", default=None, metavar="NAME|PATH",
                    help="the sensors each vehicle carries, overriding the scenario's and the "
                         "sim file's: a sensing profile by built-in name (" + ", ".join(
                             trq_params.names("sensing")) + ") or a YAML path")
    args = ap.parse_args(argv)
    try:
        scenario = load_scenario(trq_params.resolve("scenarios", args.scenario))
        if args.sensing is not None:
            scenario = dataclasses.replace(
                scenario, sensing=check_sensing(args.sensing, "command line", "--sensing"))
    except ConfigError as exc:
        print(f"trq-scenario: {exc}", file=sys.stderr)
        return 2
    if args.controller_args:        # checked by the controller's own parser before any flight
        from trq_offboard.daemon import build_parser
        parser = build_parser()
        try:
            given = parser.parse_args(shlex.split(args.controller_args))
        except SystemExit:
            print(f"trq-scenario: --controller-args {args.controller_args!r}: not options of "
                  "trq-offboard (its error above)", file=sys.stderr)
            return 2
        # what the scenario sets itself (abbreviations included: compared by value)
        taken = [dest for dest in SCENARIO_SETS if getattr(given, dest) != parser.get_default(dest)]
        if taken:
            print(f"trq-scenario: --controller-args {args.controller_args!r}: sets "
                  f"{', '.join('--' + d.replace('_', '-') for d in taken)}, which every flight "
                  "of the scenario sets itself", file=sys.stderr)
            return 2
    sources = args.controller or list(scenario.controllers)
    sources = [c for c in sources if not args.only or c in args.only]
    names = [Path(c).stem if not trq_params.is_name(c) else c for c in sources]
    if len(set(names)) != len(names):
        print(f"trq-scenario: --controller: two controllers named alike: {sources}",
              file=sys.stderr)
        return 2
    try:    # every run's settings must be valid before anything starts
        from trq_offboard.config import load_controller
        for c in sources:
            vp = load_vehicle(load_controller(trq_params.resolve("controller", c))
                              .vehicle.file)
            if scenario.faults:
                load_script(scenario.faults, (math.degrees(vp.tilt_min_rad),
                                              math.degrees(vp.tilt_max_rad)))
    except ConfigError as exc:
        print(f"trq-scenario: {exc}", file=sys.stderr)
        return 2
    if not names:
        print(f"trq-scenario: --only {args.only} matches none of {scenario.controllers}",
              file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    runs = [Run(c, i, run_dir(args.out, c), s) for i, (c, s) in enumerate(zip(names, sources))]
    jobs = max(1, min(args.jobs or os.cpu_count() or 1, len(runs)))
    print(f"trq-scenario: {scenario.name}: {scenario.description}")
    print(f"  {len(runs)} flight(s) {'in real time' if args.realtime else 'in lockstep'} "
          f"over {args.link}, "
          f"{jobs} at a time, seed {scenario.seed}, wind {scenario.wind_speed_m_s:g} m/s from "
          f"{scenario.wind_from_deg:g} deg{' with gusts' if scenario.gusts else ''}, faults "
          f"{scenario.faults.name if scenario.faults else 'none'}"
          + (f", sensing {scenario.sensing}" if scenario.sensing is not None else ""))
    lock = threading.Lock()
    stop = threading.Event()
    reporter = threading.Thread(target=progress, args=(runs, stop), daemon=True)
    reporter.start()
    pending = list(runs)
    active: list[threading.Thread] = []
    interrupted = False
    try:
        while pending or active:
            active = [t for t in active if t.is_alive()]
            while pending and len(active) < jobs:
                run = pending.pop(0)
                t = threading.Thread(target=fly, args=(
                    scenario, run, args.realtime, lock, args.signing_key_file,
                    tuple(shlex.split(args.controller_prefix or "")),
                    tuple(shlex.split(args.vehicle_prefix or "")), args.link,
                    tuple(shlex.split(args.controller_args or ""))))
                t.start()
                active.append(t)
            time.sleep(0.2)
    except KeyboardInterrupt:
        interrupted = True
        print("trq-scenario: interrupted, stopping the flights", file=sys.stderr)
        for t in active:
            t.join()
    finally:
        stop.set()
    for r in runs:
        print(f"  {r.controller}: {r.status}, {r.t_s:.1f} s simulated in {r.wall_s:.1f} s wall. "
              f"{r.summary}")
    results, failures = evaluate(scenario, runs)
    doc = {"scenario": scenario.name, "sensing": sensing_flown(scenario), "runs": results}
    (args.out / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
    figures = [] if args.no_figures else report.figures(scenario, runs, args.out)
    envelopes = envelope_of(scenario, runs)
    doc["envelope"] = envelopes
    (args.out / "metrics.json").write_text(json.dumps(doc, indent=2) + "\n")
    text = report.markdown(scenario, results, failures, figures, envelopes,
                           report.period_rows(runs), sensing=doc["sensing"])
    (args.out / "report.md").write_text(text)
    print()
    print(report.table(results))
    print()
    for f in failures:
        print(f"  TARGET MISSED: {f}")
    print(f"trq-scenario: metrics {args.out / 'metrics.json'}, report {args.out / 'report.md'}"
          + (f", figures {', '.join(str(p) for p in figures)}" if figures else ""))
    return 1 if (failures or interrupted
                 or any(r.status not in ("done", "crashed") for r in runs)) else 0


if __name__ == "__main__":
    sys.exit(main())
