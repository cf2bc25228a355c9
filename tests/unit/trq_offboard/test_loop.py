"""The offboard flight loop (trq_offboard/loop.py) without sockets or an NMPC: a fake link records
what the loop sends, a fake controller returns a fixed command, a fake reference says when the
plan is over, and the test plays the vehicle by calling `flight.on_message` with pymavlink
messages from a coroutine (the lockstep handshake of sil_vehicle/PROTOCOL.md)."""

from __future__ import annotations

import dataclasses
import asyncio
import math

import pytest
from conftest import Ticks
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.link.udp import Connection
from trq_offboard.loop import COMMAND_TRIES, IDLE_STEPS_BEFORE_DISARM, FlightError, OffboardFlight
from trq_offboard.records import (
    ActuatorCommand,
    CommandSource,
    ReferenceSample,
    SolveInfo,
    SolveStatus,
    StepInfo,
)

LIMIT = math.radians(30.0)
CMD = ActuatorCommand((60.0, 61.0, 62.0, 63.0), (0.1, -0.1, 0.05, 0.0))
WAIT_S = 2.0                      # deadline of every wait for the loop (normally milliseconds)
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM


class FakeLink:
    def __init__(self) -> None:
        self.connection = Connection("udpin", "127.0.0.1", 14540)
        self.on_message = None
        self.sent: list = []

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def of_type(self, kind: str) -> list:
        return [m for m in self.sent if m.get_type() == kind]

    def targets(self, stamp: int | None = None) -> list:
        return [m for m in self.of_type("SET_ACTUATOR_CONTROL_TARGET")
                if stamp is None or m.time_usec == stamp]

    def commands(self, param1: float | None = None) -> list:
        return [m for m in self.of_type("COMMAND_LONG")
                if m.command == ARM and (param1 is None or m.param1 == param1)]


class FakeController:
    """A loop.FlightController whose preparation does nothing (and costs nothing)."""

    def __init__(self) -> None:
        self.steps: list[tuple[float, object]] = []
        self.resets: list[float] = []
        self.last_prepare_cpu_ns = 0

    def reset(self, t_s, state, applied=None) -> None:
        self.resets.append(t_s)

    def step(self, t_s, state, applied, reference):
        self.steps.append((t_s, state))
        info = StepInfo(CommandSource.NMPC, SolveInfo(SolveStatus.OK, 1, 1e-3, 0.0),
                        (0.0,) * 6, 0.0, 0, 0, 0)
        return CMD, info

    def prepare(self, reference) -> None:
        pass

    sensor_streams: dict[str, int] = {}

    def solver_line(self) -> str:
        return "fake"


class FakeReference:
    def __init__(self, done_at_s: float, land: bool = True) -> None:
        self.done_at_s = done_at_s
        self.land = land

    def sample(self, t_s):
        return ReferenceSample((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), 0.0, "hold")

    def done(self, t_s) -> bool:
        return t_s >= self.done_at_s


_VEHICLE = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)


def from_vehicle(msg, component: int = 1):
    """The message as the controller receives it: packed by the vehicle's autopilot (1/1, or
    another component of system 1) and parsed, so that its header names its sender."""
    tx = _VEHICLE if component == 1 else mavlink.MAVLink(None, srcSystem=1,
                                                         srcComponent=component)
    rx = mavlink.MAVLink(None)
    return rx.parse_buffer(msg.pack(tx))[0]


def heartbeat(armed: bool = False, component: int = 1):
    mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
        mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return from_vehicle(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR,
                                                          mavlink.MAV_AUTOPILOT_GENERIC, mode, 0,
                                                          mavlink.MAV_STATE_STANDBY, 3),
                        component)


def odometry(stamp_us: int, down_m: float = 0.0):
    nan21 = [math.nan] * 21
    return from_vehicle(mavlink.MAVLink_odometry_message(
        stamp_us, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_LOCAL_NED, 0.0, 0.0, down_m,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, nan21, nan21, 0, 0, 100))


def ack(result: int):
    return from_vehicle(mavlink.MAVLink_command_ack_message(ARM, result))


def make_flight(reference: FakeReference | None = None, link: FakeLink | None = None,
                ctl: FakeController | None = None, **kw):
    link, ctl = link or FakeLink(), ctl or FakeController()
    ref = reference or FakeReference(done_at_s=1e9)
    kw.setdefault("connect_timeout_s", 1.0)
    kw.setdefault("ack_timeout_s", 0.5)
    flight = OffboardFlight(link, ctl, lambda state, airborne=False: ref, name="fake",
                            tilt_limit_rad=LIMIT, **kw)
    assert link.on_message == flight.on_message     # the loop takes over the link's callback
    return flight, link, ctl


async def until(predicate, what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not predicate():
        assert loop.time() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.002)


async def cancelled(task) -> None:
    """Cancel the flight's task and see it end cancelled."""
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def settle() -> None:
    """Give the loop time to do whatever it would do."""
    await asyncio.sleep(0.05)


async def take_off(flight, link) -> None:
    """Heartbeat, first ODOMETRY (stamp 0), arm accepted, stamp 0 answered."""
    flight.on_message(heartbeat())
    flight.on_message(odometry(0))
    await until(lambda: link.commands(1.0), "the ARM command")
    flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
    await until(lambda: link.targets(0), "the target of stamp 0")


def test_arms_then_answers_each_stamp_once_and_lands():
    async def scenario():
        flight, link, ctl = make_flight(FakeReference(done_at_s=0.02))
        task = asyncio.create_task(flight.run())
        flight.on_message(heartbeat())
        await settle()
        assert not link.commands(), "armed before any state was known"
        flight.on_message(odometry(0))
        await until(lambda: link.commands(1.0), "the ARM command")
        arm = link.commands(1.0)[0]
        assert (arm.target_system, arm.target_component) == (1, 1)
        await settle()
        # while the ARM waits for its ACK the stamps are answered with idle only (in lockstep
        # the vehicle's time, and a delayed link's delivery of the ACK, move on answers)
        assert [list(m.controls) for m in link.targets()] == [[0.0] * 8], \
            "commanded before the vehicle accepted to arm"
        assert not ctl.steps
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        await settle()

        # one new stamp, one target with that stamp, computed from that state; the plan's clock
        # starts with the first state after arming
        flight.on_message(odometry(10_000, down_m=-0.5))
        await until(lambda: link.targets(10_000), "the target of stamp 10000")
        await settle()
        assert len(link.targets(10_000)) == 1 and len(link.targets()) == 2
        assert [t for t, _ in ctl.steps] == pytest.approx([0.0])
        assert ctl.steps[-1][1].pos_ned_m[2] == pytest.approx(-0.5)
        first = link.targets(10_000)[0]
        assert list(first.controls) == pytest.approx(
            [0.60, 0.61, 0.62, 0.63] + [v / LIMIT for v in CMD.tilt_rad])

        # lockstep resend of the same stamp: the same answer again, nothing recomputed
        flight.on_message(odometry(10_000, down_m=-0.5))
        await settle()
        again = link.targets(10_000)
        assert len(again) == 2 and list(again[1].controls) == list(first.controls)
        assert len(ctl.steps) == 1

        # an older stamp is stale: no command from an old state
        flight.on_message(odometry(5_000, down_m=-0.4))
        await settle()
        assert not link.targets(5_000) and len(ctl.steps) == 1

        flight.on_message(odometry(20_000, down_m=-0.3))
        await until(lambda: link.targets(20_000), "the target of stamp 20000")
        assert len(ctl.steps) == 2

        # the plan is over (t >= 0.02 s) and the vehicle is on the ground: idle, then disarm
        stamp = 30_000
        stamp = await answer_until_disarm(flight, link, stamp)
        assert len(ctl.steps) == 2, "a command was computed after touchdown"
        idle = [m for m in link.targets() if m.time_usec >= 30_000]
        # the idle steps, then the state the disarm goes with, answered right after it
        assert len(idle) == IDLE_STEPS_BEFORE_DISARM + 1
        assert all(list(m.controls) == [0.0] * 8 for m in idle)
        disarm = link.commands(0.0)[0]
        after = link.sent[link.sent.index(disarm) + 1]
        assert after is idle[-1] and after.time_usec == stamp - 10_000
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        flight.on_message(odometry(stamp, down_m=0.0))
        summary = await asyncio.wait_for(task, WAIT_S)
        assert summary.landed and summary.disarmed
        assert summary.steps == 2 and summary.controller == "fake"
        assert "landed" in summary.line() and "disarmed" in summary.line()
        assert list(link.targets(stamp)[0].controls) == [0.0] * 8
        # every stamp was answered by targets with that stamp only, never two different ones
        by_stamp: dict[int, set] = {}
        for m in link.targets():
            by_stamp.setdefault(m.time_usec, set()).add(tuple(m.controls))
        assert all(len(v) == 1 for v in by_stamp.values())
        assert link.of_type("HEARTBEAT"), "the controller sends its own heartbeat"

    asyncio.run(scenario())


def test_already_armed_vehicle_is_not_armed_again():
    async def scenario():
        flight, link, ctl = make_flight()
        task = asyncio.create_task(flight.run())
        flight.on_message(heartbeat(armed=True))
        flight.on_message(odometry(0))
        await until(lambda: link.targets(0), "the target of stamp 0")
        assert not link.commands()
        await cancelled(task)

    asyncio.run(scenario())


def test_another_components_heartbeat_is_not_the_vehicles():
    async def scenario():
        flight, link, _ = make_flight(connect_timeout_s=0.2)
        # an armed heartbeat from a camera (1/100) routed to the controller by the autopilot
        flight.on_message(heartbeat(armed=True, component=100))
        flight.on_message(odometry(0))
        with pytest.raises(FlightError, match=r"heartbeat"):
            await flight.run()
        assert not link.targets()
        flight.on_message(heartbeat(armed=False))              # the autopilot's own
        assert flight.heartbeat is not None and flight.heartbeat.get_srcComponent() == 1

    asyncio.run(scenario())


def test_no_heartbeat_is_a_flight_error_naming_the_connection():
    async def scenario():
        flight, link, _ = make_flight(connect_timeout_s=0.1)
        flight.on_message(odometry(0))            # telemetry alone is not a vehicle
        with pytest.raises(FlightError, match=r"heartbeat.*0\.1 s.*udpin:127\.0\.0\.1:14540"):
            await asyncio.wait_for(flight.run(), WAIT_S)
        assert not link.commands() and not link.targets()

    asyncio.run(scenario())


def test_arming_denied_is_a_flight_error():
    async def scenario():
        flight, link, ctl = make_flight()
        task = asyncio.create_task(flight.run())
        flight.on_message(heartbeat())
        flight.on_message(odometry(0))
        await until(lambda: link.commands(1.0), "the ARM command")
        flight.on_message(ack(mavlink.MAV_RESULT_DENIED))
        with pytest.raises(FlightError, match="arming refused"):
            await asyncio.wait_for(task, WAIT_S)
        assert not ctl.steps        # stamps answered with idle only while the ARM waited
        assert all(list(m.controls) == [0.0] * 8 for m in link.targets())

    asyncio.run(scenario())


def test_unanswered_arm_command_is_retried_then_a_flight_error():
    async def scenario():
        flight, link, _ = make_flight(ack_timeout_s=0.05)
        task = asyncio.create_task(flight.run())
        flight.on_message(heartbeat())
        flight.on_message(odometry(0))
        with pytest.raises(FlightError, match=f"no COMMAND_ACK.*after {COMMAND_TRIES} tries"):
            await asyncio.wait_for(task, WAIT_S)
        assert len(link.commands(1.0)) == COMMAND_TRIES

    asyncio.run(scenario())


def test_telemetry_lost_for_good_is_a_flight_error():
    async def scenario():
        flight, link, _ = make_flight(telemetry_timeout_s=0.05, telemetry_lost_s=0.2)
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        # the vehicle stops talking: the loop must give up, not wait forever
        with pytest.raises(FlightError, match="telemetry lost"):
            await asyncio.wait_for(task, WAIT_S)

    asyncio.run(scenario())


def test_a_wait_for_the_next_state_wakes_every_waiter_and_leaves_nothing_behind():
    """One ODOMETRY wakes each task waiting for a new state; a cancelled wait raises
    CancelledError through (never swallowed) and leaves no waiter and no live timer."""
    async def scenario():
        flight, _, _ = make_flight(telemetry_timeout_s=5.0, telemetry_lost_s=10.0)
        loop = asyncio.get_running_loop()
        waits = [asyncio.create_task(flight._next_odometry()) for _ in range(2)]
        await asyncio.sleep(0)
        assert len(flight._odometry_waiters) == 2
        flight.on_message(odometry(1_000))
        got = await asyncio.wait_for(asyncio.gather(*waits), WAIT_S)
        assert [o.stamp_us for o in got] == [1_000, 1_000]
        assert flight._odometry_waiters == []
        flight._answered_stamp = 1_000                  # answered: the next call waits again
        timers_before = len(loop._scheduled)
        wait = asyncio.create_task(flight._next_odometry())
        await asyncio.sleep(0)
        assert len(flight._odometry_waiters) == 1
        wait.cancel()
        with pytest.raises(asyncio.CancelledError):
            await wait
        assert flight._odometry_waiters == []
        assert all(h.cancelled() for h in loop._scheduled[timers_before:])

    asyncio.run(scenario())


def test_plan_without_landing_never_idles_the_motors_in_the_air():
    async def scenario():
        flight, link, ctl = make_flight(FakeReference(done_at_s=0.01, land=False))
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        for stamp in (10_000, 20_000):
            flight.on_message(odometry(stamp, down_m=-1.0))       # hovering 1 m up
            await until(lambda: link.targets(stamp), f"the target of stamp {stamp}")
        summary = await asyncio.wait_for(task, WAIT_S)
        assert not summary.landed and not summary.disarmed
        # idle only for stamp 0, on the ground, while the ARM waited for its ACK
        assert all(list(m.controls) != [0.0] * 8 for m in link.targets() if m.time_usec > 0)
        assert not link.commands(0.0), "disarm commanded in flight"

    asyncio.run(scenario())


class LandingReference(FakeReference):
    """Landing from the start and never done: only the land detector can end the flight."""

    def sample(self, t_s):
        return ReferenceSample((0.0, 0.0, 0.2), (0.0, 0.0, 0.1), 0.0, "land")


def test_land_detector_ends_the_landing_once_down_and_still():
    from trq_offboard.loop import LAND_DETECT_S

    async def scenario():
        flight, link, ctl = make_flight(LandingReference(done_at_s=1e9))
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        stamp = 10_000
        # in the air, then one touch and a bounce: the detector restarts
        for down in (-0.5, -0.2, 0.0, -0.2):
            flight.on_message(odometry(stamp, down_m=down))
            await until(lambda: link.targets(stamp), f"the target of stamp {stamp}")
            stamp += 10_000
        steps_before = len(ctl.steps)
        first_down = stamp
        stamp = await answer_until_disarm(
            flight, link, stamp, check=lambda s: s - first_down <= 2e6 * LAND_DETECT_S,
            why="the detector did not fire")
        # commanded while down for LAND_DETECT_S (0.01 s stamps), then idle only
        down_steps = len(ctl.steps) - steps_before
        assert down_steps == pytest.approx(LAND_DETECT_S / 0.01, abs=1)
        idle = [m for m in link.targets() if m.time_usec > first_down + 1e6 * LAND_DETECT_S]
        assert idle and all(list(m.controls) == [0.0] * 8 for m in idle)
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        flight.on_message(odometry(stamp, down_m=0.0))
        summary = await asyncio.wait_for(task, WAIT_S)
        assert summary.landed and summary.disarmed

    asyncio.run(scenario())


def test_a_landing_on_a_height_the_estimate_gets_wrong_ends_on_the_ground():
    """Under GNSS the estimate can say 0.7 m up while the vehicle stands on its gear: the
    touchdown test never fires, and no land detector reports ON_GROUND; the plan pressing 0.9 m
    below a vehicle that does not move ends the landing (trq_offboard/landing.py), idles the
    motors and disarms."""
    from trq_offboard.landing import HOLD_S
    from trq_offboard.loop import IDLE_STEPS_BEFORE_DISARM

    async def scenario():
        flight, link, ctl = make_flight(LandingReference(done_at_s=1e9))
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        first = 10_000
        stamp = await answer_until_disarm(
            flight, link, first, down_m=lambda s: -0.7,
            check=lambda s: s - first <= 1e6 * HOLD_S + 10_000 * (IDLE_STEPS_BEFORE_DISARM + 3),
            why="the contact did not fire")
        assert stamp - first >= 1e6 * HOLD_S
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        flight.on_message(odometry(stamp, down_m=-0.7))
        summary = await asyncio.wait_for(task, WAIT_S)
        assert summary.landed and summary.disarmed and summary.ground_by_contact

    asyncio.run(scenario())


def test_a_lost_arm_is_resent_after_vehicle_time_not_wall_time():
    """In lockstep, answering stamps while ARM waits lets vehicle time run as fast as the
    exchange goes: a lost ARM (a lossy link) must be resent after ACK_TIMEOUT_VEHICLE_US of
    vehicle time (it waited a wall-clock second: 30 s of flight time went by)."""
    from trq_offboard.loop import ACK_TIMEOUT_VEHICLE_US

    async def scenario():
        flight, link, ctl = make_flight(ack_timeout_s=30.0)
        task = asyncio.create_task(flight.run())
        flight.on_message(heartbeat())
        flight.on_message(odometry(0))
        await until(lambda: link.commands(1.0), "the ARM command")
        stamp = 10_000
        while stamp < ACK_TIMEOUT_VEHICLE_US:
            flight.on_message(odometry(stamp))
            await until(lambda: link.targets(stamp), f"the idle answer to {stamp}")
            assert len(link.commands(1.0)) == 1, f"resent early, at {stamp}"
            stamp += 10_000
        flight.on_message(odometry(stamp))
        await until(lambda: len(link.commands(1.0)) == 2, "the ARM resent")
        assert not ctl.steps and all(list(m.controls) == [0.0] * 8 for m in link.targets())
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    asyncio.run(scenario())


def test_each_period_is_timed_by_part():
    records = []

    async def scenario():
        flight, link, ctl = make_flight(record=records.append, cpu_ns=Ticks(),
                                        process_cpu_ns=Ticks())
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        for k in (1, 2, 3):
            flight.on_message(odometry(10_000 * k, down_m=-0.5))
            await until(lambda: link.targets(10_000 * k), f"the target of stamp {10_000 * k}")
            await settle()
        await cancelled(task)
        return ctl

    ctl = asyncio.run(scenario())
    assert [r.stamp_us for r in records] == [10_000, 20_000, 30_000] and len(ctl.steps) == 3
    for r in records:
        assert r.cpu.prepare_ns == 0                     # FakeController's costs nothing
        assert r.cpu.wire_ns >= 2000 and r.cpu.log_ns == 1000   # decode, encode; one log call
    # a period is closed by the next step's start; the last one is still open
    assert all(r.cpu.period_ns > 0 for r in records[:-1]) and records[-1].cpu.period_ns == -1


class PreparingController(FakeController):
    """A controller with a preparation phase that can fail."""

    def __init__(self, fail_at: int | None = None) -> None:
        super().__init__()
        self.events: list[str] = []
        self.fail_at = fail_at
        self.prepares = 0
        self.last_prepare_cpu_ns = 0

    def step(self, t_s, state, applied, reference):
        self.events.append(f"step {t_s:.2f}")
        return super().step(t_s, state, applied, reference)

    def prepare(self, reference) -> None:
        self.prepares += 1
        self.last_prepare_cpu_ns = 7_000 * self.prepares
        self.events.append("prepare")
        if self.prepares == self.fail_at:
            raise ArithmeticError("preparation failed")


def make_preparing_flight(ctl: PreparingController, **kw):
    link = FakeLink()
    flight = OffboardFlight(link, ctl, lambda state, airborne=False: FakeReference(1e9),
                            name="fake", tilt_limit_rad=LIMIT, connect_timeout_s=1.0,
                            ack_timeout_s=0.5, **kw)
    return flight, link


@pytest.mark.parametrize("fail_at", [None, 2])
def test_the_loop_answers_then_prepares_in_its_thread(fail_at):
    """Called from the flight loop: each step's answer is sent before its
    preparation runs, the next step after it, each period's record gets its own preparation's
    CPU, and a failed preparation ends the flight before any step from it."""
    import threading

    records: list = []
    loop_thread = threading.get_ident()
    threads: set = set()

    async def scenario():
        ctl = PreparingController(fail_at=fail_at)
        sent_before_prepare = []
        prepare = ctl.prepare

        def watched(reference):
            threads.add(threading.get_ident())
            sent_before_prepare.append(bool(link.targets(10_000 * (ctl.prepares + 1))))
            prepare(reference)
        ctl.prepare = watched
        flight, link = make_preparing_flight(ctl, record=records.append)
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        for k in (1, 2, 3):
            flight.on_message(odometry(10_000 * k, down_m=-0.5))
            if fail_at is not None and k > fail_at:
                with pytest.raises(ArithmeticError, match="preparation failed"):
                    await asyncio.wait_for(task, WAIT_S)
                assert not link.targets(10_000 * k)      # nothing from the failed preparation
                return ctl, sent_before_prepare
            await until(lambda: link.targets(10_000 * k), f"the target of stamp {10_000 * k}")
        await settle()
        await cancelled(task)
        return ctl, sent_before_prepare

    ctl, sent_before_prepare = asyncio.run(scenario())
    assert threads == {loop_thread}                       # in the loop's thread
    assert all(sent_before_prepare) and sent_before_prepare
    if fail_at is None:
        assert ctl.events[:6] == ["step 0.00", "prepare", "step 0.01", "prepare", "step 0.02",
                                  "prepare"]
        assert [r.cpu.prepare_ns for r in records[:3]] == [7_000, 14_000, 21_000]
    else:
        assert ctl.events == ["step 0.00", "prepare", "step 0.01", "prepare"]


def test_gnss_fixes_wait_for_the_home_and_then_come_in_ned():
    """With GPS_RAW_INT and HOME_POSITION among the controller's streams: a fix before the home
    is kept, placed in NED once HOME_POSITION arrives, and a 2D fix is no position."""
    from sil_vehicle.mavlink import codec
    from sil_vehicle.sensors.gnss import GnssReading

    home = (51.5246, -0.134, 30.0)
    flight, _, ctl = make_flight()
    flight.streams = {"HIGHRES_IMU": 125, "GPS_RAW_INT": 10, "HOME_POSITION": 1}
    # GPS_RAW_INT stamped at its arrival, 110 ms after validity: the configured delay undoes it
    flight._gnss_delay_us = 110_000

    def fix(t_us, pos, fix_type=6):
        r = GnssReading(t_us, t_us + 110_000, pos, (0.0, 0.0, 0.0), fix_type, 24, 0.01, 0.01,
                        0.05)
        return from_vehicle(codec.gnss_raw_int(r, home))

    flight.on_message(fix(100_000, (1.0, 2.0, -3.0)))
    assert flight.home is None and not flight._fixes
    flight.on_message(from_vehicle(codec.home_position(home, 200_000)))
    flight.on_message(fix(200_000, (1.5, 2.0, -3.0)))
    flight.on_message(fix(300_000, (9.0, 9.0, -9.0), fix_type=mavlink.GPS_FIX_TYPE_2D_FIX))
    assert [f.t_us for f in flight._fixes] == [100_000, 200_000]
    assert flight._fixes[1].pos_ned_m == pytest.approx((1.5, 2.0, -3.0), abs=0.006)


async def answer_until_disarm(flight, link, stamp: int, *, down_m=lambda s: 0.0, check=None,
                              why: str = "") -> int:
    """States every 10 ms from `stamp` (at down_m(stamp)), each answered, until the flight asks
    for the disarm; `check(stamp)` must hold after each. Returns the next stamp."""
    while not link.commands(0.0):
        flight.on_message(odometry(stamp, down_m=down_m(stamp)))
        await until(lambda: link.targets(stamp) or link.commands(0.0), f"answer to {stamp}")
        stamp += 10_000
        assert check is None or check(stamp), why
    return stamp


def never_done_flight(ctl):
    """A FakeLink and an OffboardFlight of `ctl` on a reference in phase "hold" that is never
    done (a lost motor's landing ends the flight, not the plan)."""
    link = FakeLink()
    ref = FakeReference(done_at_s=1e9)
    return link, OffboardFlight(link, ctl, lambda state, airborne=False: ref, name="fake",
                                tilt_limit_rad=LIMIT, connect_timeout_s=1.0, ack_timeout_s=0.5)


class LostMotorController(FakeController):
    """Declares motor 1 lost from its second step on (StepInfo.lost_motor)."""

    def step(self, t_s, state, applied, reference):
        cmd, info = super().step(t_s, state, applied, reference)
        return cmd, dataclasses.replace(info, lost_motor=1 if len(self.steps) > 1 else 0)


def test_a_lost_motor_is_announced_once_and_its_touchdown_lands():
    """The controller's lost motor: one STATUSTEXT CRITICAL naming it and what is done; the
    touchdown then ends the flight (idle, disarm) though the reference is still holding."""
    from trq_offboard.loop import LAND_DETECT_S

    async def scenario():
        link, flight = never_done_flight(LostMotorController())
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        stamp = 10_000
        for down in (-1.0, -0.6, -0.3):
            flight.on_message(odometry(stamp, down_m=down))
            await until(lambda: link.targets(stamp), f"the target of stamp {stamp}")
            stamp += 10_000
        texts = [m.text for m in link.of_type("STATUSTEXT")]
        assert texts == ["motor 1 lost: yaw given up, descending to land"]
        assert link.of_type("STATUSTEXT")[0].severity == mavlink.MAV_SEVERITY_CRITICAL
        first_down = stamp
        stamp = await answer_until_disarm(
            flight, link, stamp, check=lambda s: s - first_down <= 2e6 * LAND_DETECT_S,
            why="the touchdown did not land")
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        flight.on_message(odometry(stamp, down_m=0.0))
        summary = await asyncio.wait_for(task, WAIT_S)
        assert summary.landed and summary.disarmed
        assert len(link.of_type("STATUSTEXT")) == 1

    asyncio.run(scenario())


def test_a_refused_disarm_is_asked_again_while_the_vehicle_comes_to_rest():
    """After a lost motor's landing the body may still turn on its gear: the vehicle refuses the
    disarm (DENIED); the loop answers idle and asks again after DISARM_RETRY_US of vehicle
    time, and the flight ends disarmed."""
    from trq_offboard.loop import DISARM_RETRY_US

    async def scenario():
        link, flight = never_done_flight(LostMotorController())
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        stamp = 10_000
        stamp = await answer_until_disarm(
            flight, link, stamp, down_m=lambda s: -1.0 if s < 30_000 else 0.0,
            check=lambda s: s < 2_000_000, why="no disarm")
        flight.on_message(ack(mavlink.MAV_RESULT_DENIED))
        refused_at = stamp
        while len(link.commands(0.0)) < 2:
            flight.on_message(odometry(stamp, down_m=0.0))
            await until(lambda: link.targets(stamp) or len(link.commands(0.0)) > 1,
                        f"answer to {stamp}")
            stamp += 10_000
            assert stamp - refused_at <= 2 * DISARM_RETRY_US, "the disarm was not asked again"
        assert stamp - refused_at >= DISARM_RETRY_US - 10_000
        assert all(list(m.controls) == [0.0] * 8 for m in link.targets()[-5:])   # idle
        flight.on_message(ack(mavlink.MAV_RESULT_ACCEPTED))
        flight.on_message(odometry(stamp, down_m=0.0))
        summary = await asyncio.wait_for(task, WAIT_S)
        assert summary.landed and summary.disarmed

    asyncio.run(scenario())


class SpinningController(LostMotorController):
    """Declares motor 1 lost and flies it with the spinning controller (source spin)."""

    def step(self, t_s, state, applied, reference):
        cmd, info = super().step(t_s, state, applied, reference)
        return cmd, dataclasses.replace(
            info, source=CommandSource.SPIN if info.lost_motor else info.source)


def test_a_spinning_response_is_announced_as_such():
    async def scenario():
        link, flight = never_done_flight(SpinningController())
        task = asyncio.create_task(flight.run())
        await take_off(flight, link)
        for stamp in (10_000, 20_000, 30_000):
            flight.on_message(odometry(stamp, down_m=-1.0))
            await until(lambda: link.targets(stamp), f"the target of stamp {stamp}")
        assert [m.text for m in link.of_type("STATUSTEXT")] == \
            ["motor 1 lost: spinning, holding position, landing"]
        assert flight.summary.fallbacks == 0          # the spinning steps are no fallback
        task.cancel()

    asyncio.run(scenario())


def test_the_link_builds_every_message_the_loop_reads_and_no_other():
    """The link is told the ids the loop reads (loop.read_ids): every message type named in
    on_message is among them (with the raw sensors' streams asked for), HIGHRES_IMU only when
    asked for, and SERVO_OUTPUT_RAW no more once ACTUATOR_OUTPUT_STATUS has come (the loop
    ignores it from then on)."""
    import inspect
    import re

    from trq_offboard.loop import read_ids

    named = set(re.findall(r'"([A-Z_]+)"', inspect.getsource(OffboardFlight.on_message)))
    named = {n for n in named if hasattr(mavlink, f"MAVLINK_MSG_ID_{n}")}
    assert {"ODOMETRY", "HIGHRES_IMU", "STATUSTEXT"} <= named
    every = read_ids({"HIGHRES_IMU": 125, "ATT_POS_MOCAP": 50, "GPS_RAW_INT": 10,
                      "HOME_POSITION": 1})
    for n in named:
        assert getattr(mavlink, f"MAVLINK_MSG_ID_{n}") in every, n
    flight, link, _ = make_flight()
    assert link.wanted == read_ids({})
    assert mavlink.MAVLINK_MSG_ID_HIGHRES_IMU not in link.wanted
    assert mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW in link.wanted
    flight.on_message(from_vehicle(mavlink.MAVLink_actuator_output_status_message(
        1, 8, [0.5] * 8 + [0.0] * 24)))
    assert flight.applied is not None
    assert mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW not in link.wanted
    assert mavlink.MAVLINK_MSG_ID_ODOMETRY in link.wanted


class LockstepVehicle(FakeLink):
    """A vehicle in lockstep behind the fake link: it takes each command at its current stamp
    and acknowledges it at once, and steps one period on the answer to its stamp. What it sends
    reaches the controller in order, all in the loop's next turn (`apart` False) or one message
    every 5 ms (`apart` True), so that an ACK and the next state come together or apart. It notes
    each command that left while the newest state the controller had was already answered: in
    lockstep such a command races the vehicle's step (PROTOCOL.md)."""

    def __init__(self, apart: bool) -> None:
        super().__init__()
        self.t_us, self.apart = 0, apart
        self.taken: list[tuple[int, float, int]] = []     # (command, param1, stamp)
        self.off: list[tuple[int, int]] = []   # streams turned off (interval -1): (id, stamp)
        self.late: list[int] = []          # commands sent after their state's answer
        self.newest = None                 # the newest state delivered to the controller
        self.answered: set[int] = set()
        self._outbox: list = []

    def deliver(self, msg) -> None:
        if msg.get_type() == "ODOMETRY":
            self.newest = msg.time_usec
        self.on_message(msg)

    def _out(self, msg) -> None:
        self._outbox.append(msg)
        if len(self._outbox) == 1:
            asyncio.get_running_loop().call_soon(self._pump)

    def _pump(self) -> None:
        while self._outbox:
            self.deliver(self._outbox.pop(0))
            if self.apart and self._outbox:      # the controller's loop turns in between
                asyncio.get_running_loop().call_later(0.005, self._pump)
                return

    def send(self, msg) -> bool:
        super().send(msg)
        if msg.get_type() == "COMMAND_LONG":
            if self.newest in self.answered:
                self.late.append(msg.command)
            if msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and msg.param2 == -1:
                self.off.append((int(msg.param1), self.t_us))
            else:
                self.taken.append((msg.command, msg.param1, self.t_us))
            self._out(from_vehicle(mavlink.MAVLink_command_ack_message(
                msg.command, mavlink.MAV_RESULT_ACCEPTED)))
        elif msg.get_type() == "SET_ACTUATOR_CONTROL_TARGET":
            self.answered.add(msg.time_usec)
            if msg.time_usec == self.t_us:
                self.t_us += 10_000
                self._out(odometry(self.t_us))
        return True


class SensorsController(FakeController):
    """A FakeController handed the sensor samples of its streams (and dropping them)."""

    def step(self, t_s, state, applied, reference, sensors=None):
        return super().step(t_s, state, applied, reference)


@pytest.mark.parametrize("apart", [False, True])
def test_commands_on_hold_leave_before_their_states_answer(apart):
    """Two stream requests and the arming: every command leaves while the newest state is not
    answered yet, before its answer, so that in lockstep the vehicle takes it at that state's
    stamp whatever the wall clock does; the same stamps whether each ACK and the next state
    reach the controller together or apart."""
    async def scenario():
        flight, link, _ = make_flight(link=LockstepVehicle(apart), ctl=SensorsController())
        flight.streams = {"HIGHRES_IMU": 125, "ATT_POS_MOCAP": 100}
        task = asyncio.create_task(flight.run())
        link.deliver(heartbeat())
        link.deliver(odometry(0))
        await until(lambda: link.commands(1.0) and link.t_us >= 30_000, "the arming")
        await cancelled(task)
        return link

    link = asyncio.run(scenario())
    interval = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
    on_hold = (interval, ARM)             # the flight's own request for OFFBOARD is not held
    assert [c for c in link.late if c in on_hold] == [], \
        "a command on hold left after the answer to its state"
    assert [t for t in link.taken if t[0] in on_hold] == [
        (interval, float(mavlink.MAVLINK_MSG_ID_HIGHRES_IMU), 0),
        (interval, float(mavlink.MAVLINK_MSG_ID_ATT_POS_MOCAP), 10_000),
        (ARM, 1.0, 20_000)]


@pytest.mark.parametrize("output_status", [False, True])
def test_streams_nobody_reads_are_turned_off_without_holding_the_flight(output_status):
    """After its own streams, the flight turns off the vehicle's default streams it never
    reads (ATTITUDE, LOCAL_POSITION_NED), and SERVO_OUTPUT_RAW only where ACTUATOR_OUTPUT_STATUS
    (the same outputs) flows: once, with the arming's state, none of them waited for (the
    arming goes with the same state as without them) and none racing the vehicle's step."""
    async def scenario():
        flight, link, _ = make_flight(link=LockstepVehicle(False), ctl=SensorsController())
        flight.streams = {"HIGHRES_IMU": 125}
        task = asyncio.create_task(flight.run())
        link.deliver(heartbeat())
        if output_status:
            link.deliver(from_vehicle(mavlink.MAVLink_actuator_output_status_message(
                0, 8, [0.0] * 32)))
        link.deliver(odometry(0))
        await until(lambda: link.commands(1.0) and link.t_us >= 20_000, "the arming")
        await cancelled(task)
        return link

    link = asyncio.run(scenario())
    off = [mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED]
    if output_status:
        off.append(mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW)
    assert link.off == [(i, 10_000) for i in off]
    assert [t for t in link.taken if t[0] == ARM] == [(ARM, 1.0, 10_000)]
    assert link.late == []
