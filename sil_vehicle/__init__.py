"""SIL vehicle: the truth plant of a tilt-rotor (or fixed-rotor) quadcopter behind a MAVLink 2
interface that behaves like a PX4 SITL autopilot. See PROTOCOL.md for the wire contract.

Layers (each importing only the ones above it):
    config              frozen parameter records from params/*.yaml (trq_params.loader)
    frames              every frame and unit conversion
    dynamics/           pure physics (rotors, actuators, environment, rigid body)
    faults, vehicle     the plant, one physics tick at a time (no I/O, injected RNG)
    clock               lockstep and real-time pacing
    mavlink/            codec (bytes <-> messages), parameters, commands, telemetry
    daemon              the only loop: wires clock, vehicle and links

What the controller must compute identically (signing, actuator scaling, the log files, the
compiled-code cache) is trq_wire's, imported here and by trq_offboard; `log` and
`mavlink.signing` only re-export it for older callers.
"""
