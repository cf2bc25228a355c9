"""MAVLink side of the vehicle. No sockets here: the daemon owns the transport.

    codec     bytes <-> typed messages, and the vehicle's field scalings (degE7, mm, cm/s, cdeg)
    params    the MAVLink parameter protocol over the settings a user changes while flying

Signing and the actuator scalings are trq_wire's (shared with the controller); commands are
answered by sil_vehicle.sitl.
"""
