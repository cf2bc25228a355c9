"""SIL vehicle: the truth plant of a tilt-rotor (or fixed-rotor) quadcopter behind a MAVLink 2
interface that behaves like a PX4 SITL autopilot. See PROTOCOL.md for the wire contract.

Layers (each importing only the ones above it):
    frames              every frame and unit conversion
    impair              a seeded bad link (loss, delay, jitter, duplication, reordering)
    sensors/            simulated sensors (IMU, barometer, magnetometer, GNSS, motion capture):
                        pure seeded models and the sensing profiles that configure them
    estimator/          the autopilot's estimator: an error-state Kalman filter on EKF2's
                        delayed horizon with an output predictor (pure; run by sitl under a
                        sensing profile; its equations and per-sample step compiled and cached)
    config              frozen parameter records from params/*.yaml (trq_params.loader)
                        (the gear's contact record from dynamics.contact, which imports
                        nothing of this package)
    dynamics/           pure physics (rotors, actuators, environment, ground contact, rigid
                        body; tick.c)
    faults              actuator faults as data (effectiveness, time-varying, off, stuck)
    faultscript         timed fault and wind events from a fault script (params/faults/)
    vehicle             the plant, one physics tick at a time (no I/O, injected RNG)
    compiled            the tick in C (dynamics/tick.c), built once and loaded; bit-identical
    failsafe            the autopilot's own hold-and-land controller when the offboard link is lost
    land_detector       the autopilot's land detector (PX4-shaped), EXTENDED_SYS_STATE's landed_state
    mavlink/            codec (bytes <-> messages, field scalings) and the parameter protocol
    sitl                the autopilot without sockets: telemetry due, commands, parameters,
                        actuator targets, failsafe, the sensing profile's sensors sampled each
                        tick; driven by messages, answers with messages
    clock               real-time pacing (lockstep needs none)
    daemon              the only loop: wires clock, `Sitl` and links (UDP, serial, TCP), logs

What the controller must compute identically (signing, actuator scaling, the log files, the
compiled-code cache) is trq_wire's, imported here and by trq_offboard.
"""
