"""The controller's side of the wire: MAVLink messages in and out (wire), and the UDP endpoint
(udp), with signing and the actuator scalings from trq_wire. Nothing here knows about the
simulator; see sil_vehicle/PROTOCOL.md for the contract."""
