"""The controller's side of the wire. Nothing here knows about the simulator; see
sil_vehicle/PROTOCOL.md for the contract.

    wire      MAVLink messages in and out: ODOMETRY into a state, the actuator target, commands
    gnss      GPS_RAW_INT into a position fix in NED around HOME_POSITION's origin
    endpoint  what every transport shares: the trusted peer, signing, counters, `send`
    udp       the UDP endpoint (`udpin:`, `udpout:`), the hot frames through trq_wire.frames
    stream    the byte-stream endpoint: a serial line or TCP (trq_wire.stream, trq_wire.framing)

Signing, the actuator scalings and the frames are trq_wire's (shared with the vehicle).
"""
