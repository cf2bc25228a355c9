"""MAVLink side of the vehicle: codec (bytes, scalings), parameters, commands. No sockets here:
the daemon owns the transport."""
