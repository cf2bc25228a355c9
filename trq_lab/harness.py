#!/usr/bin/env python3
"""One lockstep flight in ONE process: the SIL vehicle's autopilot core (`sil_vehicle.sitl.Sitl`)
and the offboard controller's flight loop (`trq_offboard.loop.OffboardFlight`), joined by an
in-memory link that carries the same MAVLink 2 bytes the two daemons exchange over UDP.

    trq-inprocess smoke --out out/smoke_inprocess
    trq_lab.harness SCENARIO.yaml --out DIR [--only CONTROLLER]

Nothing here is a second implementation of either side: the vehicle is `Sitl` (the code the
vehicle daemon drives), the controller is `Controller` + `Reference` driven by `OffboardFlight`
(the code the controller daemon drives). What replaces the sockets:

- controller -> vehicle: `OffboardFlight` calls `link.send(msg)`; the message is packed to bytes
  with pymavlink (system 1, component 191, as `MavlinkUdp`), decoded by the vehicle's own
  `Codec` for the offboard link and handed to `sitl.handle('offboard', msg, sender)`;
- vehicle -> controller: every `Outgoing` of the offboard link is encoded by that `Codec` and
  parsed back by a fresh pymavlink parser (as `MavlinkUdp` parses a datagram), then delivered to
  `flight.on_message` as a separate event-loop callback (as a datagram would be);
- the clock: a 'vehicle' task advances `sitl.lockstep_ticks()` physics ticks each time
  `sitl.answered` becomes true (PROTOCOL.md, lockstep handshake). As in the daemon, an answer
  that does not come within the sim's resend_s (loop time) gets the latest telemetry sent again,
  bypassing a simulated impairment (on a lossy link a lost first HEARTBEAT would otherwise keep
  the controller waiting while time stands still); the daemon's free-run never happens here.

The ground-station link's messages are still built every tick (they consume the same sensor
noise draws as in the daemon) but are not encoded: nobody listens.

The flight ends when `OffboardFlight.run()` returns (landed and disarmed), or `crash_grace_s`
simulated seconds after a crash, or at `timeout_s` of simulated time. It writes `flight.csv`
(`trq_wire.logfile.CsvLog`, columns `Sitl.log_columns`: `sil_vehicle.sitl.LOG_COLUMNS`, and a
position source's) and `controller.csv`
(`trq_offboard.log.ControllerLog`) in `out_dir`, so `trq_lab.metrics` computes the same metrics
as for a scenario run. The flight loop calls the controller's step and preparation in its own
thread, as in the daemon.

The same loop serves the tests and the benchmark (`trq_lab.bench.nmpc`):

- `controller` may be an already built `Controller` (a test's, with a wrapped solver), flown as
  it is (its `cfg` gives the reference and the rates);
- `out_dir=None` writes no logs;
- `trace=True` returns a `Trace`: one `StepSample` per controller step (what the controller
  saw, its command, its StepInfo with the SolveInfo, and the wall and CPU time of
  `Controller.step`, of `Controller.prepare` and of the controller's whole period), the
  vehicle's truth state after every lockstep period (for tracking errors against the
  reference), and the events the vehicle played; `on_step` is called with each sample as it
  is complete (after `prepare`);
- the times come from an injected `Timer` (default `PerfTimer`: perf_counter, thread_time),
  the harness's only clock in the loop (OffboardFlight's summary and asyncio's timeouts keep
  their own). The controller's period runs from the vehicle's hand-over
  (the end of its ticks) to the end of `prepare`, less the time the vehicle spends inside the
  controller's sends (decoding and handling the target): the telemetry's parse, the flight
  loop's turn, the step, the target's encode, the log and `prepare`, measured in the loop's
  thread;
- scripted events (`script`: the mappings of a fault script's `events`, wind or faults at a
  time) are played by the vehicle itself, as `--faults` files are.

Measuring changes nothing that is flown: a traced flight is bit for bit the untraced one.
"""

from __future__ import annotations

import asyncio
import dataclasses
import hashlib
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Protocol

import trq_params
from pymavlink.dialects.v20 import common as mavlink

from trq_wire.mocap import MOCAP_SYSTEM_ID

if TYPE_CHECKING:
    from sil_vehicle.vehicle import VehicleState
    from trq_offboard.loop import FlightController
    from trq_offboard.records import ActuatorCommand, ReferenceSample, StateEstimate, StepInfo

PARAMS = trq_params.DIR
SIM_DEFAULT = PARAMS / "sim" / "default.yaml"
SENDER = ("in-process", 0)          # the controller's 'address' as the vehicle sees it


# --- the in-memory link ----------------------------------------------------------------------

@dataclass(frozen=True)
class _Connection:
    """What `OffboardFlight` prints about its link in an error message."""
    mode: str = "inprocess"
    host: str = "memory"
    port: int = 0

    def __str__(self) -> str:
        return "inprocess:memory"


class Timer(Protocol):
    """What a traced flight measures its times with (seconds, any origin)."""

    def wall_s(self) -> float: ...        # monotonic wall-clock time

    def cpu_s(self) -> float: ...         # CPU time of the calling thread


class PerfTimer:
    """`time.perf_counter` and `time.thread_time`."""

    def wall_s(self) -> float:
        return time.perf_counter()

    def cpu_s(self) -> float:
        return time.thread_time()


@dataclass(frozen=True)
class StepSample:
    """One controller step of a traced flight (times in seconds of the Timer)."""
    t_s: float                   # the controller's time (0 at the first state after arming)
    stamp_us: int                # the ODOMETRY stamp it answered (vehicle time)
    state: StateEstimate         # what the controller saw
    ref: ReferenceSample         # the reference at t_s
    cmd: ActuatorCommand         # what it sent
    applied: ActuatorCommand | None   # what the vehicle reported flying
    info: StepInfo               # source, SolveInfo, disturbance, ...
    step_wall_s: float           # Controller.step
    step_cpu_s: float
    prepare_wall_s: float        # Controller.prepare after the command was sent
    prepare_cpu_s: float
    period_wall_s: float         # the controller's whole period (see the module docstring)
    period_cpu_s: float


@dataclass
class Trace:
    """What a traced flight returns besides its logs."""
    steps: list[StepSample]
    truth: list[VehicleState]    # at t = 0 and after every lockstep period
    events_played: list[tuple[int, str]]     # (vehicle time us, text) of the scripted events
    _by_t_us: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._by_t_us = {s.t_us: s for s in self.truth}

    def truth_at(self, stamp_us: int) -> VehicleState:
        """The truth state at a lockstep stamp (every ODOMETRY stamp is one)."""
        return self._by_t_us[stamp_us]


class _Meter:
    """The timing of a traced flight: the controller's step and prepare (through
    `_MeteredController`), the vehicle's share of the controller's sends (`InMemoryLink`), the
    period's opening (the vehicle's hand-over); builds a StepSample at the end of prepare."""

    def __init__(self, timer: Timer, samples: list | None, on_step) -> None:
        self.timer = timer
        self.samples = samples
        self.on_step = on_step
        self.open = (math.nan, math.nan)
        self.vehicle = [0.0, 0.0]            # wall, cpu of the vehicle inside the window
        self.step = (math.nan, math.nan)
        self.record = None                   # the flight's StepRecord of the step

    def hand_over(self) -> None:
        self.open = (self.timer.wall_s(), self.timer.cpu_s())
        self.vehicle = [0.0, 0.0]

    def close(self, prep_wall: float, prep_cpu: float, end: tuple[float, float]) -> None:
        r, self.record = self.record, None
        if r is None:
            return
        period = (end[0] - self.open[0] - self.vehicle[0],
                  end[1] - self.open[1] - self.vehicle[1])
        sample = StepSample(r.t_s, r.stamp_us, r.state, r.ref, r.cmd, r.applied, r.info,
                            self.step[0], self.step[1], prep_wall, prep_cpu, *period)
        if self.samples is not None:
            self.samples.append(sample)
        if self.on_step is not None:
            self.on_step(sample)


class _MeteredController:
    """A controller as `OffboardFlight` sees it (loop.FlightController), timing its step and
    its preparation: the sample is complete after the preparation."""

    def __init__(self, inner: FlightController, meter: _Meter) -> None:
        self.inner = inner
        self._meter = meter

    @property
    def last_prepare_cpu_ns(self) -> int:
        return self.inner.last_prepare_cpu_ns

    @property
    def sensor_streams(self) -> dict[str, int]:
        return self.inner.sensor_streams

    def solver_line(self) -> str:
        return self.inner.solver_line()

    @property
    def landed(self) -> bool:
        return self.inner.landed

    @landed.setter
    def landed(self, value: bool) -> None:      # the loop's, for the controller it wraps
        self.inner.landed = value

    def reset(self, *args, **kwargs):
        return self.inner.reset(*args, **kwargs)

    def step(self, *args):
        timer = self._meter.timer
        w0, c0 = timer.wall_s(), timer.cpu_s()
        out = self.inner.step(*args)
        w1, c1 = timer.wall_s(), timer.cpu_s()
        self._meter.step = (w1 - w0, c1 - c0)
        return out

    def prepare(self, reference) -> None:
        timer = self._meter.timer
        w0, c0 = timer.wall_s(), timer.cpu_s()
        self.inner.prepare(reference)
        w1, c1 = timer.wall_s(), timer.cpu_s()
        self._meter.close(w1 - w0, c1 - c0, (w1, c1))


class InMemoryLink:
    """The controller's end of the link (`.send`, `.connection`, `.on_message`), wired to the
    vehicle's `Sitl` through MAVLink bytes."""

    def __init__(self, sitl, codec, on_answer, meter: _Meter | None = None) -> None:
        self.connection = _Connection()
        self.on_message = lambda msg: None
        self.on_frame = None
        self._sitl = sitl
        self._codec = codec                     # the vehicle's codec of the offboard link
        self._on_answer = on_answer
        # the controller's packer: the system and component MavlinkUdp uses
        self._tx = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        self.sent = 0
        self.received = 0
        self.bytes = 0
        self._meter = meter
        # the simulated mocap PC's sender (its own system and component ids, trq_wire.mocap)
        self._sources: dict[tuple[int, int], object] = {}

    # controller -> vehicle
    def send(self, msg) -> bool:
        data = bytes(msg.pack(self._tx))
        self._tx.seq = (self._tx.seq + 1) % 256
        self.sent += 1
        self.bytes += len(data)
        meter = self._meter
        if meter is not None:                   # the vehicle's share of the send
            w0, c0 = meter.timer.wall_s(), meter.timer.cpu_s()
        for decoded in self._codec.decode(data):
            self.deliver(self._sitl.handle("offboard", decoded, SENDER))
        if meter is not None:
            meter.vehicle[0] += meter.timer.wall_s() - w0
            meter.vehicle[1] += meter.timer.cpu_s() - c0
        if self._sitl.answered:
            self._on_answer()
        return True

    # vehicle -> controller
    def deliver(self, outgoing: Iterable) -> None:
        loop = asyncio.get_running_loop()
        for item in outgoing:
            if item.link != "offboard":
                continue
            if item.source is None:
                data = self._codec.encode(item.msg)
            else:
                tx = self._sources.get(item.source)
                if tx is None:
                    tx = self._sources[item.source] = mavlink.MAVLink(
                        None, srcSystem=item.source[0], srcComponent=item.source[1])
                data = bytes(item.msg.pack(tx))
                tx.seq = (tx.seq + 1) % 256
            self.bytes += len(data)
            loop.call_soon(self._receive, data)

    def _receive(self, data: bytes) -> None:
        rx = mavlink.MAVLink(None)              # a fresh parse per 'datagram', as MavlinkUdp
        rx.robust_parsing = True
        for msg in rx.parse_buffer(data) or []:
            if isinstance(msg, mavlink.MAVLink_bad_data) or msg.get_type() == "UNKNOWN":
                continue
            if msg.get_srcSystem() not in (1, MOCAP_SYSTEM_ID):
                continue
            self.received += 1
            self.on_message(msg)


# --- configuration, as trq-scenario prepares it ------------------------------------------


def prepare_controller(controller: str | Path, reference: dict | None, out_dir: Path) -> Path:
    """Write the flight's controller overlay (the base file with `reference` over it) exactly as
    run_scenario.prepare does, and return its path. Raises ConfigError if it is invalid."""
    from trq_lab.overlays import controller_file, write_controller_overlay

    return write_controller_overlay(controller_file(controller), reference, out_dir,
                                    "written by trq_lab.harness")


def sim_params(vehicle_file: Path | str, control_rate_hz: int, *, seed: int,
               wind_speed_m_s: float = 0.0, wind_from_deg: float = 0.0, gusts: bool = False,
               gust_sigma_m_s: float | None = None, sim_file: Path | str = SIM_DEFAULT,
               offboard_impair: dict[str, float] | None = None, sensing: str | None = None):
    """The vehicle's settings as trq-scenario gives them to the daemon: the default sim file,
    the control rate (and offboard ODOMETRY rate) of the controller, its airframe, the seed and
    the wind (the daemon's --seed, --wind-speed, --wind-dir, --gusts), a scenario's
    offboard_link impairment and its sensing profile (--sensing; None: the sim file's)."""
    from sil_vehicle.config import load_sim, sensing_profile
    from sil_vehicle.impair import ImpairParams

    sim = load_sim(sim_file, vehicle_file)
    links = []
    for link in sim.links:
        if link.name == "offboard":
            rates = tuple((s, control_rate_hz if s == "ODOMETRY" else hz)
                          for s, hz in link.rates_hz)
            link = dataclasses.replace(link, rates_hz=rates)
            if offboard_impair:
                link = dataclasses.replace(link, impair=ImpairParams(**offboard_impair))
        links.append(link)
    if sim.physics_rate_hz % control_rate_hz:
        raise trq_params.ConfigError(f"control_rate_hz {control_rate_hz} does not divide the "
                                     f"physics rate {sim.physics_rate_hz}")
    changes = dict(control_rate_hz=control_rate_hz, links=tuple(links), seed=int(seed),
                   wind_speed_m_s=float(wind_speed_m_s), wind_from_deg=float(wind_from_deg))
    if gusts:
        changes["gusts_enabled"] = True
    if gust_sigma_m_s is not None:
        changes["gust_sigma_m_s"] = float(gust_sigma_m_s)
    if sensing is not None:
        changes["sensing"] = sensing_profile(sensing, sim.physics_rate_hz, "sim_params",
                                             "sensing")
    return sim.with_changes(**changes)


# --- controllers are built once per process ---------------------------------------------------

_CONTROLLERS: dict[str, object] = {}


def build_controller(cfg):
    """A `Controller` for `cfg`, reused across flights of this process (building the NMPC takes
    a second or two). Reuse is safe: `OffboardFlight` calls `reset()` at take-over, which clears
    the plan, the observer and the counters; the SQP's multipliers (used only by the exact
    Hessian) are zeroed here as well."""
    from trq_offboard.controller import Controller

    key = repr(dataclasses.replace(cfg, file="", reference=None))
    ctl = _CONTROLLERS.get(key)
    if ctl is None:
        ctl = _CONTROLLERS[key] = Controller(cfg)
    ctl.solver.zero_multipliers()
    return ctl


# --- scripted events -------------------------------------------------------------------------

def script(*events: dict, tilt_range_deg: tuple[float, float] = (-90.0, 90.0)) -> tuple:
    """sil_vehicle.faultscript Events from mappings written as a fault script's `events`, e.g.
    script({"at_s": 2.0, "wind": {"speed_m_s": 8.0, "direction_deg": 0.0}},
           {"at_s": 6.0, "motor": 1, "effectiveness": 0.5});
    sorted by time as load_script does. Raises ConfigError naming the event and the key."""
    from sil_vehicle.faultscript import parse_event

    parsed = [parse_event(e, tilt_range_deg, file="trq_lab.harness.script", key=f"events[{i}]")
              for i, e in enumerate(events)]
    return tuple(sorted(parsed, key=lambda e: e.at_us))


# --- one flight ------------------------------------------------------------------------------

@dataclass
class FlightResult:
    status: str              # done | crashed | timeout | not landed | failed: ...
    sim_s: float             # simulated time at the end
    wall_s: float
    steps: int               # controller steps recorded
    summary: str             # OffboardFlight's summary line (or why there is none)
    out_dir: Path | None
    flight_csv: Path | None          # None: flown without logs (out_dir None)
    controller_csv: Path | None
    messages: tuple[int, int, int]   # (controller -> vehicle, vehicle -> controller, bytes)
    trace: Trace | None = None       # with trace=True


async def _fly(sitl, flight, link, *, timeout_us: int, crash_grace_us: int,
               meter: _Meter | None = None, truth: list | None = None) -> tuple[str, str]:
    answered = asyncio.Event()
    link._on_answer = answered.set
    loop = asyncio.get_running_loop()
    flight_task = loop.create_task(flight.run())
    ticks = sitl.lockstep_ticks()
    ended = ""

    async def vehicle() -> None:
        nonlocal ended
        link.deliver(sitl.telemetry_due())          # as the daemon does before its loop
        if truth is not None:
            truth.append(sitl.state)
        if meter is not None:
            meter.hand_over()
        crash_us = None
        while True:
            if not sitl.answered:       # wait for the answer to the latest stamp (an answer to
                try:                    # an older one, or another message: keep waiting); on
                    # an impaired link a stamp the vehicle dropped needs none. asyncio.timeout,
                    # not wait_for: wait_for can swallow the cancellation that ends the flight
                    async with asyncio.timeout(sitl.sim.resend_s):
                        await answered.wait()
                except TimeoutError:
                    # the daemon's recovery from a lost message (a controller that never saw
                    # the vehicle's first HEARTBEAT waits for it, and time stands still): after
                    # resend_s the latest telemetry again, bypassing the simulated impairment
                    link.deliver(sitl.telemetry_due(everything=True, resend=True))
                    if meter is not None:
                        meter.hand_over()
                answered.clear()
                continue
            for _ in range(ticks):
                link.deliver(sitl.step())
            if truth is not None:
                truth.append(sitl.state)
            if meter is not None:
                meter.hand_over()
            if sitl.state.crashed and crash_us is None:
                crash_us = sitl.t_us
            if crash_us is not None and sitl.t_us - crash_us >= crash_grace_us:
                ended = "crashed"
                return
            if sitl.t_us >= timeout_us:
                ended = "timeout"
                return
            await asyncio.sleep(0)

    vehicle_task = loop.create_task(vehicle())
    try:
        done, _ = await asyncio.wait({flight_task, vehicle_task},
                                     return_when=asyncio.FIRST_COMPLETED)
        if flight_task in done:
            summary = flight_task.result()           # raises FlightError if it could not fly
            status = "done" if summary.disarmed else ("not landed" if not summary.landed
                                                      else "not disarmed")
            if sitl.state.crashed:
                status = "crashed"
            return status, summary.line()
        vehicle_task.result()
        return ended, f"{flight.name}: stopped by the campaign ({ended}) at " \
                      f"t={sitl.t_us * 1e-6:.2f} s, {flight.summary.steps} steps"
    finally:
        for task in (flight_task, vehicle_task):
            if not task.done():
                task.cancel()
        await asyncio.gather(flight_task, vehicle_task, return_exceptions=True)


def fly_inprocess(controller, sim, fault_events=(), seed: int | None = None, *,
                  out_dir: Path | None = None, reference: dict | None = None,
                  timeout_s: float = 600.0, crash_grace_s: float = 1.0,
                  name: str | None = None, trace: bool = False,
                  on_step: Callable[[StepSample], None] | None = None,
                  timer: Timer | None = None) -> FlightResult:
    """Fly one lockstep flight in this process; with out_dir, write out_dir/flight.csv and
    controller.csv.

    controller: a built Controller (flown as it is: its cfg gives reference and rates), a
        ControllerConfig (its Controller is built once per process, `build_controller`), or a
        controller YAML path / name in params/controller/ (then `reference`, a mapping of
        reference settings, is laid over it as trq-scenario does);
    sim: the vehicle's SimParams (see `sim_params`); `seed` replaces its seed if given;
    fault_events: sil_vehicle.faultscript Events (`script`, `load_script`), played by the
        vehicle in its own time;
    trace: return a Trace in FlightResult.trace; on_step: called with each StepSample;
    timer: what the samples' times and FlightResult.wall_s are measured with (PerfTimer).
    """
    import tempfile

    from sil_vehicle.mavlink.codec import Codec
    from sil_vehicle.sitl import Sitl
    from trq_offboard.config import ControllerConfig, load_controller
    from trq_offboard.controller import Controller
    from trq_offboard.log import ControllerLog, solver_header
    from trq_offboard.loop import OffboardFlight
    from trq_offboard.reference import Reference
    from trq_wire.actuators import tilt_half_range
    from trq_wire.logfile import CsvLog as FlightLog

    timer = timer if timer is not None else PerfTimer()
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
    built = None
    if isinstance(controller, ControllerConfig):
        cfg = controller
        if reference:
            raise ValueError("reference: give it in the ControllerConfig")
    elif isinstance(controller, Controller):
        built, cfg = controller, controller.cfg
        if reference:
            raise ValueError("reference: give it in the Controller's config")
    elif out_dir is None:
        with tempfile.TemporaryDirectory(prefix="trq-harness-") as tmp:
            cfg = load_controller(prepare_controller(controller, reference, Path(tmp)))
    else:
        cfg = load_controller(prepare_controller(controller, reference, out_dir))
    if seed is not None:
        sim = sim.with_changes(seed=int(seed))
    if sim.control_rate_hz != cfg.control_rate_hz:
        raise ValueError(f"sim control_rate_hz {sim.control_rate_hz} != controller's "
                         f"{cfg.control_rate_hz}")
    wall0 = timer.wall_s()
    if built is None:
        ctl = build_controller(cfg)
    else:
        ctl = built
        ctl.solver.zero_multipliers()
    sitl = Sitl(sim)
    flight_log = clog = None
    if out_dir is not None:
        meta = {"vehicle": sim.vehicle.name, "vehicle_file": sim.vehicle.file,
                "sim_file": sim.file, "seed": sim.seed, "physics_rate_hz": sim.physics_rate_hz,
                "clock": sim.clock_mode, "frames": "world NED, body FRD, quaternion wxyz",
                "link": "in-process MAVLink bytes", "physics_core": sitl.vehicle.core_name}
        if sim.senses:
            meta["sensing"] = sim.sensing.file
        flight_log = FlightLog(out_dir / "flight.csv", sitl.log_columns, meta,
                               flush_every=max(1, sim.log_rate_hz))
        clog = ControllerLog(out_dir / "controller.csv",
                             {"controller": cfg.name, "controller_file": cfg.file,
                              "vehicle_file": cfg.vehicle.file, "connect": "in-process",
                              "frames": "world NED, body FRD", **solver_header(ctl)})
    samples: list[StepSample] | None = [] if trace else None
    truth: list | None = [] if trace else None
    meter = _Meter(timer, samples, on_step) if trace or on_step is not None else None
    record = clog
    if meter is not None:

        def record(r) -> None:
            if clog is not None:
                clog(r)
            meter.record = r
    try:
        sitl.log_sink = flight_log
        sitl.schedule(fault_events)
        link = InMemoryLink(sitl, Codec(counters=sitl.counters["offboard"]), lambda: None,
                            meter)
        flight = OffboardFlight(
            link, ctl if meter is None else _MeteredController(ctl, meter),
            lambda state, airborne=False: Reference(
                cfg.reference, state.pos_ned_m, state.euler_rad[2], airborne=airborne,
                ground_down_m=0.0 if airborne else None),
            name=name or cfg.name,
            tilt_limit_rad=tilt_half_range(cfg.vehicle.tilt_min_rad, cfg.vehicle.tilt_max_rad),
            # nobody to yield the core to (the vehicle is this thread)
            record=record, yield_core=False,
            gnss_delay_s=cfg.fused.gnss_delay_s if cfg.fused is not None else 0.0)

        async def main() -> tuple[str, str]:
            return await _fly(sitl, flight, link, timeout_us=int(round(timeout_s * 1e6)),
                              crash_grace_us=int(round(crash_grace_s * 1e6)), meter=meter,
                              truth=truth)

        status, summary = asyncio.run(main())
    finally:
        if flight_log is not None:
            flight_log.close()
        if clog is not None:
            clog.close()
    logs = (out_dir / "flight.csv", out_dir / "controller.csv") if out_dir is not None \
        else (None, None)
    return FlightResult(status, sitl.t_us * 1e-6, timer.wall_s() - wall0,
                        flight.summary.steps, summary, out_dir, *logs,
                        (link.sent, link.received, link.bytes),
                        Trace(samples, truth, list(sitl.events_played)) if trace else None)


def flight_metrics(log_dir: Path, controller: str, fault_onset_us: int | None,
                   recovery_threshold_m: float, *,
                   outage_us: tuple[int, int] | None = None) -> dict:
    """The scenario runner's metrics (trq_lab.metrics) of a flight, from the two logs in
    log_dir (flight.csv and controller.csv, in process or from the daemons); `outage_us`, a
    sensor outage's (start, end) in vehicle microseconds, for the metrics of its window."""
    from sil_vehicle.config import load_vehicle
    from trq_lab import metrics as metrics_mod

    meta, truth = metrics_mod.read_csv(Path(log_dir) / "flight.csv")
    _, steps = metrics_mod.read_csv(Path(log_dir) / "controller.csv")
    vehicle = Path(load_vehicle(meta["vehicle_file"]).file).stem
    return metrics_mod.compute(controller, vehicle, truth, steps, fault_onset_us,
                               recovery_threshold_m, outage_us=outage_us).as_dict()


def fingerprint(path: Path) -> str:
    """sha256 of a file's bytes (short): to see whether two logs are bit-identical."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


# --- command line: a scenario file, flown in process ----------------------------------------------

def main(argv: list[str] | None = None) -> int:
    import argparse

    from sil_vehicle.faultscript import load_script
    from trq_lab import scenario as run_scenario
    from trq_lab.overlays import run_dir
    from trq_offboard.config import load_controller, with_rates_lowpass

    ap = argparse.ArgumentParser(prog="trq-inprocess", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", help="a built-in scenario by name or a scenario YAML by path")
    ap.add_argument("--out", type=Path, required=True, help="output directory")
    ap.add_argument("--only", action="append", default=None,
                    help="fly only this controller (repeatable)")
    args = ap.parse_args(argv)
    try:
        sc = run_scenario.load_scenario(trq_params.resolve("scenarios", args.scenario))
        events = load_script(sc.faults) if sc.faults else ()
    except trq_params.ConfigError as exc:
        print(f"inprocess: {exc}", file=sys.stderr)
        return 2
    onset = events[0].at_us if events else None
    runs = []
    for c in sc.controllers:
        if args.only and c not in args.only:
            continue
        cfg = load_controller(prepare_controller(c, sc.reference, run_dir(args.out, c)))
        cfg = dataclasses.replace(
            cfg, applied_delay_s=run_scenario.command_delay_s(sc.offboard_impair, False))
        cfg = with_rates_lowpass(cfg, run_scenario.rates_lowpass_hz(sc.sensing), sc.name)
        sim = sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=sc.seed,
                         wind_speed_m_s=sc.wind_speed_m_s, wind_from_deg=sc.wind_from_deg,
                         gusts=sc.gusts, offboard_impair=sc.offboard_impair,
                         sensing=sc.sensing)
        vp = sim.vehicle        # the daemon checks stuck angles against the airframe's range
        ev = load_script(sc.faults, (math.degrees(vp.tilt_min_rad),
                                     math.degrees(vp.tilt_max_rad))) if sc.faults else ()
        res = fly_inprocess(cfg, sim, ev, out_dir=run_dir(args.out, c),
                            timeout_s=sc.timeout_s, name=c)
        m = flight_metrics(res.out_dir, c, onset, sc.recovery_threshold_m)
        m.update(status=res.status, wall_s=round(res.wall_s, 2), sim_s=round(res.sim_s, 3),
                 flight_csv_sha=fingerprint(res.flight_csv))
        print(f"  {c}: {res.status}, {res.sim_s:.2f} s simulated in {res.wall_s:.1f} s wall "
              f"({res.sim_s / max(res.wall_s, 1e-9):.1f}x). {res.summary}")
        runs.append(m)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "metrics.json").write_text(json.dumps({"scenario": sc.name, "runs": runs},
                                                      indent=2) + "\n")
    from trq_lab.reporting import scenario as report
    print(report.table(runs))
    return 0 if all(r["status"] == "done" for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
