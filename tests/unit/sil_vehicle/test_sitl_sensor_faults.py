"""Sensor faults in the vehicle (sil_vehicle.sitl.Sitl): MAV_CMD_INJECT_FAILURE's sensor units
reach the readings the estimator and the telemetry see, and a lost estimate is met as an
autopilot meets it: no position, the vehicle descends on its own (AUTO.LAND) and says so; no
attitude, it terminates the flight and says so; the flight log records both."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import sensing_profile
from sil_vehicle.faultscript import InjectAction, Event
from sil_vehicle.mavlink.codec import Codec
from sil_vehicle.sensors.mocap import MocapReading
from sil_vehicle.sitl import (IMU_TIMEOUT_US, MODE_AUTO_LAND, MODE_OFFBOARD, NAV_FAILURES,
                              Sitl)
from sil_vehicle.vehicle import ActuatorCommand

_CLIENT = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
VIO, GYRO, GPS = (mavlink.FAILURE_UNIT_SENSOR_VIO, mavlink.FAILURE_UNIT_SENSOR_GYRO,
                  mavlink.FAILURE_UNIT_SENSOR_GPS)


def command(cmd, *p):
    p = tuple(p) + (0.0,) * (7 - len(p))
    msg = mavlink.MAVLink_command_long_message(1, 1, cmd, 0, *p)
    (back,) = Codec().decode(bytes(msg.pack(_CLIENT)))
    return back


def inject(s, unit, kind, instance=1, p4=float("nan")):
    out = s.handle("gcs", command(mavlink.MAV_CMD_INJECT_FAILURE, unit, kind, instance, p4))
    (ack,) = [o.msg for o in out if o.msg.get_type() == "COMMAND_ACK"]
    return ack.result, [o.msg.text for o in out if o.msg.get_type() == "STATUSTEXT"]


def vehicle(sim, profile="mocap", rows=None) -> Sitl:
    p = sensing_profile(profile, 1000, "test")
    # the motion capture wired to the autopilot: no companion here to forward it
    return Sitl(sim.with_changes(sensing=p, clock_mode="realtime", mocap_wiring="autopilot"),
                log_sink=rows.append if rows is not None else None)


def airborne(s: Sitl) -> None:
    """Armed once the estimator allows it, then hovering a little above the ground on a held
    command near hover (the companion's stream stands in: no offboard-loss failsafe)."""
    for _ in range(5000):
        if s.estimator_ready():
            break
        s.step()
    s.handle("gcs", command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    assert s.vehicle.armed
    hover = s.sim.vehicle.hover_throttle_pct
    s.vehicle.command = ActuatorCommand((hover + 3.0,) * 4, (0.0,) * 4)
    s._last_target_us = 10**12
    for _ in range(1500):
        s.step()
    assert not s.state.landed and s.mode == MODE_OFFBOARD


def texts(out):
    return [o.msg.text for o in out if o.msg.get_type() == "STATUSTEXT"]


def run(s: Sitl, ticks: int) -> list[str]:
    said = []
    for _ in range(ticks):
        said += texts(s.step())
    return said


def test_mocap_off_stops_its_readings_and_ok_brings_them_back(sim):
    s = vehicle(sim)
    run(s, 200)
    result, said = inject(s, VIO, mavlink.FAILURE_TYPE_OFF)
    assert result == mavlink.MAV_RESULT_ACCEPTED
    assert "sensor faults: mocap off" in said
    seen = []
    for _ in range(300):
        s.step()
        seen += [r for r in s.readings if isinstance(r, MocapReading)]
    assert not seen
    assert inject(s, VIO, mavlink.FAILURE_TYPE_OK)[0] == mavlink.MAV_RESULT_ACCEPTED
    for _ in range(300):
        s.step()
        seen += [r for r in s.readings if isinstance(r, MocapReading)]
    assert seen


def test_a_sensor_the_profile_lacks_is_denied_but_ok_on_it_accepted(sim):
    s = vehicle(sim, "mocap")
    assert inject(s, GPS, mavlink.FAILURE_TYPE_OFF)[0] == mavlink.MAV_RESULT_DENIED
    assert inject(s, GPS, mavlink.FAILURE_TYPE_OK)[0] == mavlink.MAV_RESULT_ACCEPTED
    assert inject(s, VIO, mavlink.FAILURE_TYPE_OFF, 2)[0] == mavlink.MAV_RESULT_DENIED
    assert inject(s, VIO, mavlink.FAILURE_TYPE_SLOW)[0] == mavlink.MAV_RESULT_UNSUPPORTED
    assert not s.sensor_faults.active


def test_losing_the_position_source_in_flight_descends_and_says_so(sim):
    rows = []
    s = vehicle(sim, rows=rows)
    airborne(s)
    inject(s, VIO, mavlink.FAILURE_TYPE_OFF)
    said = run(s, s.estimator.params.no_aid_timeout_us // 1000 + 300)
    assert s.mode == MODE_AUTO_LAND and s.nav_failure == "position"
    assert "position estimate lost: failsafe, descending" in said
    assert s.vehicle.armed and s.lander.active
    # the offboard mode is refused while there is no position
    out = s.handle("gcs", command(mavlink.MAV_CMD_DO_SET_MODE, 1.0, 6.0))
    (ack,) = [o.msg for o in out if o.msg.get_type() == "COMMAND_ACK"]
    assert ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    col = s.log_columns.index
    last = rows[-1]
    assert last[col("nav_failure")] == NAV_FAILURES["position"]
    assert last[col("sensor_fault_mask")] == 1 << VIO
    assert last[col("est_position_valid")] == 0


def test_a_silent_imu_in_flight_terminates_and_says_so(sim):
    rows = []
    s = vehicle(sim, rows=rows)
    airborne(s)
    inject(s, GYRO, mavlink.FAILURE_TYPE_OFF)
    said = run(s, IMU_TIMEOUT_US // 1000 + 20)
    assert not s.vehicle.armed and s.nav_failure == "attitude"
    assert any(t == "no attitude (IMU silent): flight termination" for t in said)
    assert rows[-1][s.log_columns.index("nav_failure")] == NAV_FAILURES["attitude"]


def test_a_script_plays_sensor_faults(sim):
    s = vehicle(sim)
    s.schedule([Event(100_000, (InjectAction(VIO, mavlink.FAILURE_TYPE_WRONG, 1, 0.25),),
                      "mocap wrong by 0.25")])
    said = run(s, 200)
    assert any("script: mocap wrong by 0.25" in t for t in said)
    assert s.sensor_faults.describe() == "mocap wrong by 0.25"


def test_truth_has_no_sensor_to_fail_and_no_navigation_failsafe(sim):
    s = Sitl(sim.with_changes(clock_mode="realtime"))
    assert s.sensor_faults is None
    assert inject(s, VIO, mavlink.FAILURE_TYPE_OFF)[0] == mavlink.MAV_RESULT_DENIED
    assert inject(s, VIO, mavlink.FAILURE_TYPE_OK)[0] == mavlink.MAV_RESULT_ACCEPTED
