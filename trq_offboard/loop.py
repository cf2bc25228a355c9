"""The offboard flight: connect, arm, take off, fly the reference, land, disarm.

`OffboardFlight` is driven by the vehicle's telemetry. Every new ODOMETRY (stamp t) is answered
once by a SET_ACTUATOR_CONTROL_TARGET stamped t: that is the whole lockstep handshake, and in real
time it is simply an event-driven controller. A repeated stamp (the vehicle resending in lockstep)
gets the same target again; an older stamp is stale and ignored: no command is ever computed from
an old state.

The controller's step and preparation are called from the flight loop, in its thread: no
thread hand-off and no event-loop turn a period. Once the answer is sent the loop yields its core
(os.sched_yield) to whoever the answer woke, before the log and the preparation
(`yield_core=False`: not, where the answer woke nobody, as in the in-process harness, whose
vehicle runs in the same thread). Why (and the worker thread this replaced):
docs/decisions/2026-12-04-direct-calls-default.md.

Every period is timed by part with injected CPU clocks: `cpu_ns` (default time.thread_time_ns:
the calling thread's) for the wire (the telemetry's decode into a state, the target's encode and
send) and the log, `process_cpu_ns` (default time.process_time_ns: every thread's) for the whole
period; the controller times its own step's parts and its preparation. StepRecord.cpu holds
them, completed as the period runs (records.PeriodTimes).
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard import lost_motor
from trq_offboard.diagnosis import Diagnosis
from trq_offboard.fused import HealthReport
from trq_offboard.landing import GroundContact
from trq_offboard.link import gnss, wire
from trq_offboard.link.udp import MavlinkUdp
from trq_offboard.records import (
    ActuatorCommand,
    PeriodTimes,
    ReferenceSample,
    SensorSamples,
    StateEstimate,
    StepInfo,
)
from trq_offboard.reference import FlightReference
from trq_wire.mocap import MOCAP_SYSTEM_ID

log = logging.getLogger("trq_offboard")
_sched_yield = getattr(os, "sched_yield", None)      # POSIX; None elsewhere

TOUCHDOWN_ALT_M = 0.05
TAKEOVER_ALTITUDE_M = 0.3         # higher than this, armed: the vehicle is flying
MAX_MODE_REQUESTS = 5
TOUCHDOWN_SPEED_M_S = 0.15
IDLE_STEPS_BEFORE_DISARM = 10
ACK_TIMEOUT_VEHICLE_US = 300_000   # a command's ACK missing this long in vehicle time: resend
# tries of a command (arming, disarming) before giving up, enough for a lossy link (measured:
# docs/decisions/2026-12-02-figures-from-comments.md)
COMMAND_TRIES = 6
# arming temporarily rejected (the vehicle's estimator not ready): try again this often, for at
# most this long, in vehicle time
ARM_RETRY_US = 200_000
ARM_WAIT_US = 10_000_000
# a disarm refused on the ground (the vehicle not yet at rest: a body still turning on its gear
# after a lost motor's spinning landing) is asked again every DISARM_RETRY_US of vehicle time, the
# motors idle, for up to DISARM_WAIT_US (choices: a spin of 30 rad/s stops on the gear within a
# second, docs/decisions/2026-12-05-lost-motor-spin-in-the-loop.md)
DISARM_RETRY_US = 200_000
DISARM_WAIT_US = 5_000_000
# GPS_RAW_INT kept until HOME_POSITION places it (the newest; the filter's history reaches back
# no further than a few fixes)
MAX_UNPLACED_FIXES = 4
LAND_DETECT_S = 0.2                # on the ground and still this long while landing: landed
# in the vehicle's TAKEOFF state the gear still touches until the vehicle climbs: faster than
# PX4's LNDMC_Z_VEL_MAX (the land detector's own bound on vertical movement) is off the ground
LIFTOFF_CLIMB_M_S = 0.25
IDLE = ActuatorCommand((0.0,) * 4, (0.0,) * 4)   # motors at idle, tilts centred


class FlightError(RuntimeError):
    """The flight could not be flown (no vehicle, arming refused, telemetry lost for good)."""


@dataclass
class StepRecord:
    t_s: float
    stamp_us: int
    state: StateEstimate
    ref: ReferenceSample
    cmd: ActuatorCommand
    applied: ActuatorCommand | None
    info: StepInfo | None
    # the period's CPU by part: completed after the record is handed over (prepare, log: at the
    # end of the step's period; period: at the next step's start), so read it late (ControllerLog
    # formats its rows in batches, after their periods have ended)
    cpu: PeriodTimes = field(default_factory=PeriodTimes)


@dataclass
class FlightSummary:
    controller: str
    steps: int = 0
    flight_s: float = 0.0
    rmse_pos_m: float = math.nan
    max_pos_err_m: float = math.nan
    rmse_yaw_deg: float = math.nan
    solve_ms_p50: float = math.nan
    solve_ms_p99: float = math.nan
    fallbacks: int = 0
    landed: bool = False
    disarmed: bool = False
    crashed: bool = False
    took_over: bool = False       # started against a flying vehicle
    ground_by_contact: bool = False   # the landing ended on landing.GroundContact
    offboard: bool = False        # the vehicle granted offboard mode
    errors: list[str] = field(default_factory=list)

    def line(self) -> str:
        """One line of what the controller saw: its errors are its state estimate (what the
        vehicle reported) against its reference over the whole flight, take-off and landing
        included, not the truth (the lab's metrics measure that)."""
        return (f"{self.controller}: {self.flight_s:.1f} s, {self.steps} steps, as seen (estimate "
                f"against reference, landing included): position RMSE "
                f"{self.rmse_pos_m:.3f} m (max {self.max_pos_err_m:.3f} m), yaw RMSE "
                f"{self.rmse_yaw_deg:.2f} deg, solve p50 {self.solve_ms_p50:.1f} ms p99 "
                f"{self.solve_ms_p99:.1f} ms, {self.fallbacks} fallbacks, "
                f"{'took over in flight, ' if self.took_over else ''}"
                f"{'CRASHED, ' if self.crashed else ''}"
                f"{'landed' if self.landed else 'NOT landed'}, "
                f"{'disarmed' if self.disarmed else 'armed'}")


class FlightController(Protocol):
    """What the flight loop uses of a controller (trq_offboard.controller.Controller)."""

    last_prepare_cpu_ns: int      # the CPU of the last `prepare`
    landed: bool                  # set before each step: on the ground, the observers hold

    def reset(self, t_s: float, state: StateEstimate,
              applied: ActuatorCommand | None = None) -> None: ...

    def step(self, t_s: float, state: StateEstimate, applied: ActuatorCommand | None,
             reference: FlightReference) -> tuple[ActuatorCommand, StepInfo | None]: ...

    def prepare(self, reference: FlightReference) -> None: ...

    def solver_line(self) -> str: ...   # what solves the NMPC, for the log's header

    # the raw sensors the controller needs (MAVLink message name: Hz; the fused filter's): the
    # loop asks the vehicle for them at start and, when there are any, hands what arrived to
    # `step` as a fifth argument (records.SensorSamples)
    sensor_streams: dict[str, int]


# the messages `OffboardFlight.on_message` reads, whatever the controller's streams (the raw
# sensors' it reads when asked for: _SENSOR_READS): the link builds no other message, it only
# checks and logs their frames (trq_wire.frames.Unread)
_READS = ("ODOMETRY", "ACTUATOR_OUTPUT_STATUS", "SERVO_OUTPUT_RAW", "ATT_POS_MOCAP",
          "EXTENDED_SYS_STATE", "HEARTBEAT", "COMMAND_ACK", "STATUSTEXT")
_SENSOR_READS = ("HIGHRES_IMU", "GPS_RAW_INT", "HOME_POSITION")
# streams an autopilot sends a companion's link by default (this vehicle's PROTOCOL.md) that
# on_message never reads: turned off once the controller's own are asked for, as a companion
# sets its link's streams, so that no period checks and logs frames nobody reads; and
# SERVO_OUTPUT_RAW once ACTUATOR_OUTPUT_STATUS (the same outputs at full resolution) flows
_UNREAD_DEFAULTS = ("ATTITUDE", "LOCAL_POSITION_NED")


def _msg_id(name: str) -> int:
    return getattr(mavlink, f"MAVLINK_MSG_ID_{name}")


def _time_out(waiter: asyncio.Future) -> None:
    """A wait for the next state is over without one (`_next_odometry`'s timer)."""
    if not waiter.done():
        waiter.set_result(False)


def read_ids(streams, output_status: bool = False) -> frozenset[int]:
    """The ids of the messages on_message reads for a controller's sensor streams; once
    ACTUATOR_OUTPUT_STATUS has been seen (`output_status`) not SERVO_OUTPUT_RAW, which it
    then ignores."""
    names = set(_READS) | {n for n in _SENSOR_READS if n in streams}
    if output_status:
        names.discard("SERVO_OUTPUT_RAW")
    return frozenset(_msg_id(n) for n in names)


def _streams(controller: FlightController) -> dict[str, int]:
    """The controller's sensor_streams (a copy)."""
    return dict(controller.sensor_streams)


class OffboardFlight:
    def __init__(self, link: MavlinkUdp, controller: FlightController,
                 make_reference: Callable[..., FlightReference], *,
                 name: str, tilt_limit_rad: float,
                 record: Callable[[StepRecord], None] | None = None,
                 connect_timeout_s: float = 30.0, telemetry_timeout_s: float = 2.0,
                 telemetry_lost_s: float = 10.0, ack_timeout_s: float = 1.0,
                 yield_core: bool = True, gnss_delay_s: float = 0.0,
                 cpu_ns: Callable[[], int] = time.thread_time_ns,
                 process_cpu_ns: Callable[[], int] = time.process_time_ns) -> None:
        self.link = link
        self.yield_core = yield_core and _sched_yield is not None   # after the answer
        self.cpu_ns = cpu_ns                    # the loop thread's parts (wire, log)
        self.process_cpu_ns = process_cpu_ns    # the whole period: every thread of the process
        self._wire_ns = 0               # the wire's CPU since the last step's start
        self.controller = controller
        self.make_reference = make_reference
        self.name = name
        self.tilt_limit = tilt_limit_rad
        self.record = record
        self.connect_timeout_s = connect_timeout_s
        self.telemetry_timeout_s = telemetry_timeout_s
        self.telemetry_lost_s = telemetry_lost_s
        self.ack_timeout_s = ack_timeout_s
        self.heartbeat = None
        self.vehicle_landed_state = mavlink.MAV_LANDED_STATE_UNDEFINED   # EXTENDED_SYS_STATE's
        self._airborne_seen = False
        self.odometry: wire.Odometry | None = None
        self.applied: ActuatorCommand | None = None
        self._new_odometry = asyncio.Event()
        self._odometry_waiters: list[asyncio.Future] = []   # `_next_odometry`'s, woken by one
        self._heartbeat_seen = asyncio.Event()
        self._acks: dict[int, asyncio.Future] = {}
        self._answered_stamp: int | None = None
        self._last_target = None
        self._have_output_status = False    # prefer ACTUATOR_OUTPUT_STATUS (full resolution)
        self._mode_task: asyncio.Future | None = None
        self.summary = FlightSummary(name)
        self.diagnosis = Diagnosis()        # the motors' estimates, for the ground station
        self._lost_motor = 0                # the motor the controller announced lost
        # the raw sensors the controller needs (its sensor_streams) and those received since
        # its last step
        self.streams: dict[str, int] = _streams(controller)
        # the fused filter's dead reckoning, named after its position source's samples
        self.estimator_report = HealthReport("gnss fix" if "GPS_RAW_INT" in self.streams
                                             else "pose")
        self._accel: list = []
        self._poses: list = []
        self._fixes: list = []          # GNSS fixes in NED (records.PositionFix)
        self.home: tuple[int, int, int] | None = None     # HOME_POSITION: the origin of NED
        self._unplaced: list = []       # GPS_RAW_INT received before the home, to place
        self.forwarded_poses = 0        # motion-capture poses forwarded to the autopilot
        # GPS_RAW_INT is stamped at its arrival (as PX4 stamps it): the fused filter's
        # configured receiver delay (gnss_delay_s) takes it back to its time of validity
        self._gnss_delay_us = round(gnss_delay_s * 1e6)
        self._errors: list[np.ndarray] = []
        self._yaw_errors: list[float] = []
        self._solve_ms: list[float] = []
        link.on_message = self.on_message
        link.wanted = read_ids(self.streams)

    # --- incoming --------------------------------------------------------------------------
    def on_message(self, msg) -> None:
        if msg.get_srcSystem() == MOCAP_SYSTEM_ID:
            self._mocap_pose(msg)
            return
        if msg.get_srcComponent() != wire.VEHICLE_COMPONENT:
            # another component of system 1 (a camera, a gimbal, a second companion that the
            # autopilot routes to this link): its HEARTBEAT is not the vehicle's state
            return
        kind = msg.get_type()
        if kind == "ODOMETRY":
            c0 = self.cpu_ns()
            odo = wire.parse_odometry(msg)
            self._wire_ns += self.cpu_ns() - c0
            if odo is None:
                return
            if self._answered_stamp is not None and odo.stamp_us == self._answered_stamp \
                    and self._last_target is not None:
                self.link.send(self._last_target)      # lockstep resend: same answer again
                return
            if self.odometry is None or odo.stamp_us > self.odometry.stamp_us:
                self.odometry = odo
                self._new_odometry.set()
                for waiter in self._odometry_waiters:
                    if not waiter.done():
                        waiter.set_result(True)
        elif kind in ("ACTUATOR_OUTPUT_STATUS", "SERVO_OUTPUT_RAW"):
            if kind == "SERVO_OUTPUT_RAW" and self._have_output_status:
                return
            applied = wire.parse_actuator_outputs(msg, self.tilt_limit)
            if applied is not None:
                self.applied = applied
                if kind == "ACTUATOR_OUTPUT_STATUS" and not self._have_output_status:
                    self._have_output_status = True
                    self.link.wanted = read_ids(self.streams, output_status=True)
        elif kind == "HIGHRES_IMU" and "HIGHRES_IMU" in self.streams:
            acc = wire.parse_highres_accel(msg)
            if acc is not None:
                self._accel.append(acc)
        elif kind == "ATT_POS_MOCAP" and "ATT_POS_MOCAP" in self.streams:
            pose = wire.parse_mocap(msg)
            if pose is not None:
                self._poses.append(pose)
        elif kind == "GPS_RAW_INT" and "GPS_RAW_INT" in self.streams:
            if self.home is None:       # kept (a few) until the home arrives
                self._unplaced = [*self._unplaced[-(MAX_UNPLACED_FIXES - 1):], msg]
            else:
                fix = gnss.fix_of(msg, self.home, self._gnss_delay_us)
                if fix is not None:
                    self._fixes.append(fix)
        elif kind == "HOME_POSITION" and "HOME_POSITION" in self.streams:
            self.home = gnss.home_of(msg)
            if self.home is not None:
                fixes = [gnss.fix_of(m, self.home, self._gnss_delay_us) for m in self._unplaced]
                self._fixes += [f for f in fixes if f is not None]
                self._unplaced.clear()
        elif kind == "EXTENDED_SYS_STATE":
            # the vehicle's land detector (sil_vehicle/PROTOCOL.md): ON_GROUND ends a landing
            # even when the estimate's height disagrees with the ground's (a GNSS height)
            self.vehicle_landed_state = msg.landed_state
            self._airborne_seen |= msg.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR
        elif kind == "HEARTBEAT":
            self.heartbeat = msg
            self._heartbeat_seen.set()
        elif kind == "COMMAND_ACK":
            fut = self._acks.get(msg.command)
            if fut is not None and not fut.done():
                fut.set_result(msg.result)
        elif kind == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode(errors="replace")
            log.info("vehicle: %s", text)

    def _mocap_pose(self, msg) -> None:
        """A pose from the motion-capture system (trq_wire.mocap): forwarded at once to the
        autopilot as external vision (ODOMETRY, as PX4 takes it), and kept for the fused
        filter when it flies on the pose."""
        if msg.get_type() != "ATT_POS_MOCAP":
            return
        pose = wire.parse_mocap(msg)
        if pose is None or not all(math.isfinite(v) for v in msg.q):
            return
        self.link.send(wire.vision_odometry(msg))
        self.forwarded_poses += 1
        if "ATT_POS_MOCAP" in self.streams:
            self._poses.append(pose)

    async def _next_odometry(self) -> wire.Odometry:
        """The newest state not yet answered; waits for it (FlightError once the telemetry has
        been silent for telemetry_lost_s: the vehicle is gone)."""
        silent_s = 0.0
        while True:
            odo = self.odometry
            if odo is not None and odo.stamp_us != self._answered_stamp:
                return odo
            if silent_s >= self.telemetry_lost_s:
                raise FlightError(f"no new ODOMETRY for {silent_s:g} s: telemetry lost")
            wait_s = min(self.telemetry_timeout_s, self.telemetry_lost_s - silent_s)
            # a future the next ODOMETRY sets (True) or a timer does (False), once a control
            # period: cheaper than asyncio.timeout around Event.wait. A cancellation of the
            # waiting task goes through the await as it is (wait_for could swallow one:
            # CPython gh-86296); the timer never outlives the wait
            loop = asyncio.get_running_loop()
            waiter = loop.create_future()
            timer = loop.call_later(wait_s, _time_out, waiter)
            self._odometry_waiters.append(waiter)
            try:
                arrived = await waiter
            finally:
                timer.cancel()
                self._odometry_waiters.remove(waiter)
            if not arrived:
                silent_s += wait_s
                log.warning("no telemetry for %.1f s: not commanding", silent_s)

    async def _unanswered_state(self, timeout_s: float) -> wire.Odometry | None:
        """The newest state not answered yet, waited for up to `timeout_s` of wall time (None:
        none came, the vehicle silent)."""
        try:
            async with asyncio.timeout(timeout_s):
                return await self._next_odometry()
        except TimeoutError:
            return None

    async def _command(self, msg, command_id: int, retries: int = COMMAND_TRIES,
                       hold: ActuatorCommand | None = None, also: Sequence = ()) -> int:
        """Send a command and wait for its COMMAND_ACK (retries on silence). With `hold` (only
        when the control loop is not running), every new state that arrives meanwhile is
        answered with that command: in lockstep the vehicle's time, and with it a delayed
        link's delivery of the command and of its ACK, moves only on answers (PX4, too, wants
        the setpoint stream flowing around arming and mode changes). With `hold` each try goes
        with a state not answered yet (waited for, up to the ACK's timeout, if every state so
        far is) and leaves before that state's answer: in lockstep the vehicle takes it at that
        state's time, whatever the wall clock does. Sent after the answer, it would race the
        vehicle's next period (taken at one state's time or the next's by which datagram the
        vehicle reads first). `also`: messages sent just before the first try, with it."""
        loop = asyncio.get_running_loop()
        for _ in range(retries):
            fut = loop.create_future()
            self._acks[command_id] = fut
            sent = await self._unanswered_state(self.ack_timeout_s) if hold is not None else None
            for extra in also:
                self.link.send(extra)
            also = ()
            self.link.send(msg)
            if sent is not None:
                self._answer(sent.stamp_us, hold)
            deadline = loop.time() + self.ack_timeout_s
            sent_us = self.odometry.stamp_us if self.odometry is not None else None
            while not fut.done() and loop.time() < deadline:
                if hold is None:
                    await asyncio.wait({fut}, timeout=deadline - loop.time())
                    break
                odo = self.odometry
                if odo is not None and sent_us is not None \
                        and odo.stamp_us - sent_us >= ACK_TIMEOUT_VEHICLE_US:
                    break          # lost (vehicle time: in lockstep it runs on our answers)
                if odo is not None and odo.stamp_us != self._answered_stamp:
                    self._answer(odo.stamp_us, hold)
                self._new_odometry.clear()
                waiter = asyncio.ensure_future(self._new_odometry.wait())
                await asyncio.wait({fut, waiter}, timeout=max(0.0, deadline - loop.time()),
                                   return_when=asyncio.FIRST_COMPLETED)
                waiter.cancel()
            if fut.done():
                return fut.result()
        raise FlightError(f"no COMMAND_ACK for command {command_id} after {retries} tries")

    async def _request_streams(self, hold: bool) -> None:
        """Ask the vehicle for the controller's sensor streams (MAV_CMD_SET_MESSAGE_INTERVAL):
        on the ground each is waited for (its states answered with IDLE meanwhile); taking over
        a flying vehicle, sent without waiting (nothing may hold the control loop up)."""
        for name, rate_hz in self.streams.items():
            msg = wire.message_interval(getattr(mavlink, f"MAVLINK_MSG_ID_{name}"), rate_hz)
            if not hold:
                self.link.send(msg)
                continue
            result = await self._command(msg, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, hold=IDLE)
            if result != mavlink.MAV_RESULT_ACCEPTED:
                log.warning("the vehicle refused %s at %d Hz (MAV_RESULT %s)", name, rate_hz,
                            result)
        if "HOME_POSITION" in self.streams:
            # the origin now, not at the stream's next turn (MAV_CMD_REQUEST_MESSAGE)
            msg = wire.request_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION)
            if hold:
                await self._command(msg, mavlink.MAV_CMD_REQUEST_MESSAGE, hold=IDLE)
            else:
                self.link.send(msg)

    def _streams_off(self) -> list:
        """MAV_CMD_SET_MESSAGE_INTERVAL -1 for each default stream the controller does not read
        (_UNREAD_DEFAULTS; SERVO_OUTPUT_RAW once ACTUATOR_OUTPUT_STATUS has come), sent once and
        never waited for: an autopilot that refuses keeps sending them and the link only checks
        and logs their frames, as it would anyway. Their answers find no command waiting (a
        COMMAND_ACK names only its command), so they go after the stream requests, with the
        arming where there is one (the same state as it, in lockstep)."""
        unread = _UNREAD_DEFAULTS + (("SERVO_OUTPUT_RAW",) if self._have_output_status else ())
        return [wire.stream_off(_msg_id(name)) for name in unread]

    async def _arm(self, also: Sequence = ()) -> bool:
        """Arm; while the vehicle answers MAV_RESULT_TEMPORARILY_REJECTED (an autopilot's
        preflight check: its estimator not aligned yet) try again every ARM_RETRY_US of vehicle
        time, answering its states with IDLE meanwhile, for at most ARM_WAIT_US. Returns whether
        it had to wait; FlightError if arming is refused or never allowed. `also`: messages
        sent once, just before the first try (with its state)."""
        start = self.odometry.stamp_us if self.odometry is not None else 0
        waited = False
        while True:
            # the state this try goes with (the one `_command` sends it with: the newest not
            # answered yet), so that the times below are the vehicle's, whatever the wall clock
            # does (a flight replays bit for bit)
            issued = (await self._next_odometry()).stamp_us
            result = await self._command(wire.arm_command(True),
                                         mavlink.MAV_CMD_COMPONENT_ARM_DISARM, hold=IDLE,
                                         also=also)
            also = ()
            if result == mavlink.MAV_RESULT_ACCEPTED:
                return waited
            if result != mavlink.MAV_RESULT_TEMPORARILY_REJECTED \
                    or issued - start >= ARM_WAIT_US:
                raise FlightError(f"arming refused (MAV_RESULT {result})")
            if not waited:
                log.info("arming not allowed yet (the vehicle's preflight check): retrying")
            waited = True
            end = issued + ARM_RETRY_US
            await self._idle_until(end)

    async def _idle_until(self, end_us: int) -> None:
        """IDLE to every state up to `end_us`; the first state at or after it goes unanswered
        (it is the next attempt's)."""
        while True:
            odo = await self._next_odometry()
            if odo.stamp_us >= end_us:
                return
            self._answer(odo.stamp_us, IDLE)

    def _answer(self, stamp_us: int, cmd: ActuatorCommand) -> None:
        c0 = self.cpu_ns()
        self._last_target = wire.actuator_target(stamp_us, cmd, self.tilt_limit)
        self._answered_stamp = stamp_us
        self.link.send(self._last_target)
        self._wire_ns += self.cpu_ns() - c0

    async def _heartbeats(self) -> None:
        while True:
            self.link.send(wire.heartbeat())
            await asyncio.sleep(1.0)

    # --- the flight ------------------------------------------------------------------------
    async def run(self) -> FlightSummary:
        beat = asyncio.create_task(self._heartbeats())
        try:
            return await self._fly()
        finally:
            beat.cancel()
            if self._mode_task is not None:
                self._mode_task.cancel()

    async def _fly(self) -> FlightSummary:
        try:
            await asyncio.wait_for(self._heartbeat_seen.wait(), self.connect_timeout_s)
        except asyncio.TimeoutError:
            raise FlightError(f"no vehicle heartbeat within {self.connect_timeout_s:g} s on "
                              f"{self.link.connection}") from None
        first = await self._next_odometry()
        # taking over a flying vehicle (a restarted controller, or after the vehicle's failsafe):
        # no take-off and no arming; observer and plan start from the measured state
        airborne = wire.is_armed(self.heartbeat) and \
            first.state.pos_ned_m[2] < wire.HOME_GROUND_DOWN_M - TAKEOVER_ALTITUDE_M
        self.summary.took_over = airborne
        ground_z = wire.HOME_GROUND_DOWN_M if airborne else first.state.pos_ned_m[2]
        await self._request_streams(hold=not airborne)
        quiet = self._streams_off()
        arming = not airborne and not wire.is_armed(self.heartbeat)
        if not arming:
            for msg in quiet:             # no arming to go with
                self.link.send(msg)
        if airborne:
            log.info("taking over a flying vehicle at %.2f m", -first.state.pos_ned_m[2])
        elif arming:
            waited = await self._arm(also=quiet)
            # the plan's clock starts with the first state after arming (which may have
            # taken a few control periods, or retries, of vehicle time on a lossy link)
            first = await self._next_odometry()
            if waited:
                # the vehicle's estimator was not ready at the first state: the ground is
                # where it puts the vehicle now that it is
                ground_z = first.state.pos_ned_m[2]
        t0 = first.stamp_us
        reference = self.make_reference(first.state, airborne)
        self.controller.reset(0.0, first.state)
        answered = 0
        down_since: float | None = None
        contact = GroundContact()
        pending: wire.Odometry | None = first
        prev: StepRecord | None = None       # the last period's record, its period to close
        prev_start = 0
        while True:
            odo = pending if pending is not None else await self._next_odometry()
            pending = None
            start = self.process_cpu_ns()
            if prev is not None:
                prev.cpu.period_ns = start - prev_start
            prev_start = start
            t = (odo.stamp_us - t0) * 1e-6
            ref = reference.sample(t)
            # land detector: on the ground and still, in the landing phase, for LAND_DETECT_S
            # (the plan aims a little below the ground; pushing on the ground longer only
            # winds the observer up and makes the motors thrash), or the plan is over
            # (a motor lost: the controller descends to land whatever the reference's phase)
            if (self._touched_down(odo.state, ground_z) or self._detector_landed()) and (
                    ref.phase == "land"
                                                            or reference.done(t)
                                                            or self._lost_motor):
                down_since = t if down_since is None else down_since
                if reference.done(t) or t - down_since >= LAND_DETECT_S:
                    break
            else:
                down_since = None
            # or the plan presses below a vehicle that no longer moves: the ground, whatever
            # height the estimate gives (trq_offboard/landing.py)
            if contact.update(t, ref.phase, ref.pos_ned_m[2], odo.state.pos_ned_m[2],
                              odo.state.vel_ned_m_s[2]):
                self.summary.ground_by_contact = True
                break
            applied = self.applied
            # on the ground: the vehicle's land detector before the lift-off, the touchdown
            # tests here in a landing (the controller's observers hold: Controller.landed)
            self.controller.landed = (
                self.vehicle_landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
                or (self.vehicle_landed_state == mavlink.MAV_LANDED_STATE_TAKEOFF
                    and -odo.state.vel_ned_m_s[2] < LIFTOFF_CLIMB_M_S)
                or down_since is not None or contact.since_s is not None)
            wire_rx, self._wire_ns = self._wire_ns, 0     # this state's decode
            if self.streams:
                sensors = SensorSamples(odo.stamp_us, tuple(self._accel), tuple(self._poses),
                                        tuple(self._fixes))
                self._accel.clear()
                self._poses.clear()
                self._fixes.clear()
                cmd, info = self.controller.step(t, odo.state, applied, reference, sensors)
            else:
                cmd, info = self.controller.step(t, odo.state, applied, reference)
            self._answer(odo.stamp_us, cmd)
            # the answer is out, hand the core to whoever it woke (in lockstep the vehicle)
            # before the log and the preparation, which are off the latency path
            # (docs/decisions/2026-12-02-flight-loop-direct-calls.md)
            if self.yield_core:
                _sched_yield()
            rec = self._account(t, odo, ref, cmd, applied, info)
            rec.cpu.wire_ns = wire_rx + self._wire_ns
            self._wire_ns = 0
            prev = rec
            answered += 1
            # ask for offboard control once the stream is flowing (PX4 grants it only then;
            # after the vehicle's failsafe it is how control comes back), without ever holding
            # up the control loop for the answer
            if answered == 2:
                self._mode_task = asyncio.ensure_future(self._request_offboard())
            # the preparation phase of the next step (RTI), while the vehicle flies this one
            self.controller.prepare(reference)
            rec.cpu.prepare_ns = self.controller.last_prepare_cpu_ns
            if self.heartbeat is not None and wire.is_crashed(self.heartbeat):
                self.summary.crashed = True
                log.error("the vehicle reports a crash (EMERGENCY)")
                self._finish(t)
                return self.summary
            if reference.done(t) and not reference.land:
                break
        if not (self._touched_down(odo.state, ground_z) or self._detector_landed()
                or self.summary.ground_by_contact):
            # a plan without landing ends in the air: never idle the motors or disarm there
            self._finish(t)
            return self.summary
        self.summary.landed = True
        # idle, then disarm (the vehicle refuses a disarm in flight)
        for _ in range(IDLE_STEPS_BEFORE_DISARM):
            odo = await self._next_odometry()
            self._answer(odo.stamp_us, IDLE)
        result = await self._disarm()
        self.summary.disarmed = result == mavlink.MAV_RESULT_ACCEPTED
        odo = await self._next_odometry()
        self._answer(odo.stamp_us, IDLE)
        self._finish(t)
        return self.summary

    async def _disarm(self) -> int:
        """Disarm on the ground, the motors idle meanwhile; a refusal (MAV_RESULT_DENIED or
        TEMPORARILY_REJECTED: the vehicle not at rest yet) asked again every DISARM_RETRY_US
        of vehicle time up to DISARM_WAIT_US. The last answer's MAV_RESULT."""
        start_us = self.odometry.stamp_us if self.odometry is not None else 0
        while True:
            result = await self._command(wire.arm_command(False),
                                         mavlink.MAV_CMD_COMPONENT_ARM_DISARM, hold=IDLE)
            now_us = self.odometry.stamp_us if self.odometry is not None else start_us
            if result not in (mavlink.MAV_RESULT_DENIED,
                              mavlink.MAV_RESULT_TEMPORARILY_REJECTED) \
                    or now_us - start_us >= DISARM_WAIT_US:
                return result
            end = now_us + DISARM_RETRY_US
            await self._idle_until(end)

    def _detector_landed(self) -> bool:
        """The vehicle's land detector says ON_GROUND after it had said IN_AIR in this flight
        (EXTENDED_SYS_STATE; a vehicle that sends none never ends a landing this way)."""
        return (self._airborne_seen
                and self.vehicle_landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND)

    @staticmethod
    def _touched_down(state: StateEstimate, ground_z: float) -> bool:
        return (abs(state.pos_ned_m[2] - ground_z) < TOUCHDOWN_ALT_M
                and abs(state.vel_ned_m_s[2]) < TOUCHDOWN_SPEED_M_S)

    def _account(self, t, odo, ref, cmd, applied, info) -> StepRecord:
        err = np.subtract(odo.state.pos_ned_m, ref.pos_ned_m)
        self._errors.append(err)
        yaw_err = (odo.state.euler_rad[2] - ref.yaw_rad + math.pi) % (2 * math.pi) - math.pi
        self._yaw_errors.append(math.degrees(yaw_err))
        if info is not None:
            for msg in self.diagnosis.messages(odo.stamp_us, info.effectiveness):
                self.link.send(msg)
            if info.lost_motor and not self._lost_motor:
                # once: what the controller now does (trq_offboard/lost_motor.py)
                self._lost_motor = info.lost_motor
                # (the spinning controller's steps are its own source: spin.py)
                text = lost_motor.status_text(
                    info.lost_motor, "spin" if info.source.value == "spin" else "nmpc")
                log.error(text)
                self.link.send(mavlink.MAVLink_statustext_message(
                    mavlink.MAV_SEVERITY_CRITICAL, text.encode("ascii")))
            if info.estimator is not None:
                for msg in self.estimator_report.messages(info.estimator):
                    self.link.send(msg)
            self._solve_ms.append(info.solve.solve_time_s * 1e3)
            if info.source.value not in ("nmpc", "spin"):      # the spinning one flies
                self.summary.fallbacks += 1
        self.summary.steps += 1
        rec = StepRecord(t, odo.stamp_us, odo.state, ref, cmd, applied, info)
        if self.record:
            c0 = self.cpu_ns()
            self.record(rec)
            rec.cpu.log_ns = self.cpu_ns() - c0
        else:
            rec.cpu.log_ns = 0
        return rec

    async def _request_offboard(self) -> None:
        for _ in range(MAX_MODE_REQUESTS):
            try:
                result = await self._command(wire.set_mode_offboard(),
                                             mavlink.MAV_CMD_DO_SET_MODE, retries=1)
            except FlightError:
                continue
            if result == mavlink.MAV_RESULT_ACCEPTED:
                self.summary.offboard = True
                return
            log.warning("offboard mode refused (MAV_RESULT %s), streaming on", result)
            await asyncio.sleep(0.2)

    async def hand_over(self) -> str:
        """Leaving early (SIGINT, SIGTERM): ask the vehicle to land itself if it flies, disarm
        it if it stands armed on the ground. Returns what was done."""
        hb, odo = self.heartbeat, self.odometry
        if hb is None or not wire.is_armed(hb):
            return "the vehicle is disarmed"
        try:
            flying_z = wire.HOME_GROUND_DOWN_M - TOUCHDOWN_ALT_M
            if odo is not None and odo.state.pos_ned_m[2] < flying_z:
                result = await self._command(wire.set_mode_land(), mavlink.MAV_CMD_DO_SET_MODE,
                                             retries=2)
                return f"asked the vehicle to land (MAV_RESULT {result})"
            result = await self._command(wire.arm_command(False, force=True),
                                         mavlink.MAV_CMD_COMPONENT_ARM_DISARM, retries=2)
            return f"disarmed the vehicle (MAV_RESULT {result})"
        except FlightError as exc:
            return f"could not hand over: {exc}"

    def _finish(self, t_end: float) -> None:
        s = self.summary
        s.flight_s = t_end
        if self._errors:
            e = np.asarray(self._errors)
            norms = np.linalg.norm(e, axis=1)
            s.rmse_pos_m = float(np.sqrt(np.mean(norms ** 2)))
            s.max_pos_err_m = float(norms.max())
            s.rmse_yaw_deg = float(np.sqrt(np.mean(np.square(self._yaw_errors))))
        if self._solve_ms:
            s.solve_ms_p50 = float(np.percentile(self._solve_ms, 50))
            s.solve_ms_p99 = float(np.percentile(self._solve_ms, 99))
