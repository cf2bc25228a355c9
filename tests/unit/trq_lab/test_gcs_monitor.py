"""trq-monitor and the ground-station client keep the vehicle's messages apart from those of the
other components routed through it (the offboard controller, 1/191): the controller's HEARTBEAT
must not read as the vehicle's state, and its MOTn_EFF estimates and STATUSTEXTs are shown with
their sender."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from trq_lab.gcs.client import MavClient
from trq_lab.gcs.monitor import Monitor


def _frames(system: int, component: int, *msgs) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    return b"".join(m.pack(mav) for m in msgs)


def _decode(data: bytes) -> list:
    rx = mavlink.MAVLink(None)
    return rx.parse_buffer(data) or []


def _feed(client: MavClient, data: bytes) -> None:
    client._receive = lambda timeout_s: _decode(data)        # one read of these bytes
    client.poll(0.0)


def _vehicle_heartbeat(armed: bool):
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
        mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0, 0, mavlink.MAV_STATE_ACTIVE, 3)


def _controller_heartbeat():
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
        mavlink.MAV_STATE_ACTIVE, 3)


def test_companion_heartbeat_is_not_the_vehicles():
    with MavClient("udpout:127.0.0.1:9") as client:
        _feed(client, _frames(1, 1, _vehicle_heartbeat(armed=True)))
        _feed(client, _frames(1, 191, _controller_heartbeat()))
        assert client.last["HEARTBEAT"].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert client.others[(1, 191)]["HEARTBEAT"].type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER


def test_monitor_shows_the_controllers_estimates_and_warning():
    with MavClient("udpout:127.0.0.1:9") as client:
        mon = Monitor(client, 45.0, "udpout:127.0.0.1:9")
        _feed(client, _frames(1, 1, _vehicle_heartbeat(armed=True)))
        named = [mavlink.MAVLink_named_value_float_message(1000 * i, f"MOT{n}_EFF".encode(), v)
                 for i, (n, v) in enumerate([(2, 1.0), (1, 0.52), (4, 0.98), (3, 1.0)])]
        _feed(client, _frames(1, 191, _controller_heartbeat(), *named,
                              mavlink.MAVLink_statustext_message(
                                  mavlink.MAV_SEVERITY_WARNING, b"motor 1 at 52 %")))
        text = mon.render()
        assert "ARMED" in text                          # the vehicle's heartbeat, not 191's
        line = next(ln for ln in text.splitlines() if ln.startswith("component"))
        assert "1/191" in line and "heartbeat" in line
        assert line.index("MOT1_EFF 0.52") < line.index("MOT2_EFF 1.00") \
            < line.index("MOT3_EFF 1.00") < line.index("MOT4_EFF 0.98")
        assert "WARNING  [1/191] motor 1 at 52 %" in text


def test_monitor_without_a_controller_says_so():
    with MavClient("udpout:127.0.0.1:9") as client:
        mon = Monitor(client, 45.0, "udpout:127.0.0.1:9")
        _feed(client, _frames(1, 1, _vehicle_heartbeat(armed=False)))
        assert "component   (no offboard controller heard)" in mon.render()


def test_the_health_line_names_each_present_sensor_ok_or_failing():
    from pymavlink.dialects.v20 import common as mavlink

    from trq_lab.gcs.monitor import health_line

    gps, xy = mavlink.MAV_SYS_STATUS_SENSOR_GPS, mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    gyro = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    st = mavlink.MAVLink_sys_status_message(gps | xy | gyro, gps | xy | gyro, xy | gyro,
                                            0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert health_line(st) == "gyro ok, gps FAILING, position ok"
