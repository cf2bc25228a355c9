"""The vehicle routes for its companion computer (issue 20), read off the frames it hands its
transports (no sockets): the controller's broadcasts reach the ground station as they came,
what is the vehicle's alone stays, a ground station's own broadcasts never reach the
controller, nothing goes back where it came from, and a signed vehicle forwards no unsigned
frame."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.daemon import VehicleDaemon
from sil_vehicle.sitl import LINKS
from trq_wire.signing import now_10us

KEY = bytes(range(32))
CONTROLLER = ("127.0.0.1", 14540)
GCS = ("127.0.0.1", 14550)


class _Transport:
    def __init__(self) -> None:
        self.sent: list[tuple[bytes, tuple]] = []

    def sendto(self, data, addr) -> None:
        self.sent.append((bytes(data), tuple(addr)))


def vehicle(sim, key=None, allow_unsigned_gcs=False):
    d = VehicleDaemon(sim, None, signing_key=key, allow_unsigned_gcs=allow_unsigned_gcs)
    d.transports = {name: _Transport() for name in LINKS}
    return d


def frame(msg, system, component, key=None):
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        mav.signing.secret_key, mav.signing.sign_outgoing = key, True
        mav.signing.timestamp = now_10us()            # fresh, as the check wants
    return bytes(msg.pack(mav))


def forwarded(d, link):
    """The frames handed to `link`'s transport that the vehicle did not encode itself."""
    # bytes 5 and 6 of a MAVLink 2 frame: its sender (system, component)
    return [data for data, _ in d.transports[link].sent if data[5:7] != b"\x01\x01"]


def heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                             mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                             mavlink.MAV_STATE_ACTIVE, 3)


def test_the_controllers_broadcasts_reach_the_ground_station_as_they_came(sim):
    d = vehicle(sim)
    for msg in (heartbeat(), mavlink.MAVLink_named_value_float_message(1000, b"MOT1_EFF", 0.5),
                mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING,
                                                   b"motor 1 at 50 %")):
        data = frame(msg, 1, 191)
        d.on_datagram("offboard", data, CONTROLLER)
        assert forwarded(d, "gcs")[-1] == data                 # its sender and bytes kept
    assert d.routed["gcs"] == 3 and forwarded(d, "offboard") == []   # never back
    sent_to = {addr for _, addr in d.transports["gcs"].sent}
    assert (d.sim.link("gcs").target.host, d.sim.link("gcs").target.port) in sent_to


def test_what_is_the_vehicles_alone_stays(sim):
    d = vehicle(sim)
    target = mavlink.MAVLink_set_actuator_control_target_message(0, 0, 1, 1, [0.0] * 8)
    arm = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                               1, 0, 0, 0, 0, 0, 0)
    for msg in (target, arm):
        d.on_datagram("offboard", frame(msg, 1, 191), CONTROLLER)
    assert forwarded(d, "gcs") == [] and d.routed["gcs"] == 0


def test_only_what_is_addressed_to_the_controller_goes_to_it(sim):
    d = vehicle(sim)
    d.on_datagram("gcs", frame(heartbeat(), 255, 190), GCS)          # QGC's own heartbeat
    request = mavlink.MAVLink_command_long_message(1, 191, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                                   0, 0, 0, 0, 0, 0, 0)
    to_vehicle = mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE,
                                                      0, 0, 0, 0, 0, 0, 0, 0)
    d.on_datagram("gcs", frame(to_vehicle, 255, 190), GCS)
    assert forwarded(d, "offboard") == []
    data = frame(request, 255, 190)
    d.on_datagram("gcs", data, GCS)
    assert forwarded(d, "offboard") == [data] and d.routed["offboard"] == 1


def test_a_signed_vehicle_forwards_signed_frames_only(sim):
    d = vehicle(sim, key=KEY, allow_unsigned_gcs=True)
    request = mavlink.MAVLink_param_request_list_message(1, 191)     # read-only: accepted
    d.on_datagram("gcs", frame(request, 255, 190), GCS)
    assert forwarded(d, "offboard") == []                          # unsigned: stays here
    signed = frame(request, 255, 190, key=KEY)
    d.on_datagram("gcs", signed, GCS)
    assert forwarded(d, "offboard") == [signed]
    d.on_datagram("offboard", frame(heartbeat(), 1, 191), CONTROLLER)     # refused unsigned
    assert d.routed["gcs"] == 0
    hb = frame(heartbeat(), 1, 191, key=KEY)
    d.on_datagram("offboard", hb, CONTROLLER)
    assert forwarded(d, "gcs")[-1] == hb
