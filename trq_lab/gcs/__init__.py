"""What a ground station does, from the command line, over the vehicle's ground-station port.

    client    MavClient: blocking, every wait with a timeout (NoAnswer names what was expected)
    inject    trq-inject-fault: motor and servo faults, wind, fault scripts; waits for the answer
    monitor   trq-monitor: a live terminal view of attitude, position, actuators and faults
Nothing here is used by the daemons; these are clients of the wire contract (PROTOCOL.md).
"""
