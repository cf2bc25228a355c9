"""MAVLink side of the vehicle: codec (bytes, scalings), parameters, commands. No sockets here:
the daemon owns the transport. Signing and the actuator scalings are trq_wire's (shared with the
controller)."""
