"""Offboard controller of the tilt-rotor quadcopter: NMPC + extended state observer + control
allocation, flying a vehicle through MAVLink alone (it never imports sil_vehicle). What both
ends of the wire must compute identically (signing, actuator scaling, log files, the compiled-code
cache) comes from trq_wire.

    config          the controller and vehicle files, loaded and checked (ControllerConfig)
    frames          the rotations, once: Euler angles, quaternions, R (NED from FRD)
    model/          the prediction model in CasADi (PredictionModel: dynamics, b0)
    allocation      body wrench <-> throttles and tilts (the hover trim)
    eso             the extended state observer (the disturbance d)
    rate_observer   the body-rate channels' observer with the autopilot's rate low-pass in its
                    output (rates_lowpass_hz)
    fused           the fused filter (estimator: fused): position and velocity from the pose,
                    the raw IMU and the model with the observer's d
    fused_core, fused_core.c  the fused filter's step in C around the same kernels (what
                    flies where a C compiler is found; fused stays the reference)
    predictor       the delay predictor: the commands sent, the actuators' walk, the state when
                    the command acts, the observer's b0 under the commands in effect
    effectiveness   the motor effectiveness observer and its composition with the model
    observer_period  the observers' regular period (ESO, rate observer, effectiveness) as one
                    compiled call (their own methods stay the reference)
    lost_motor      a whole motor lost: its detector and the failed configuration
    nmpc/           the OCP and its solvers (ocp, base, rti, nlp, factory; hpipm, hpipm_fetch,
                    feedback, cache)
    controller      Controller: the parts composed; step, prepare, the fallback
    spin            the lost-motor controller: a spinning relaxed hover on three rotors (LQR
                    about the body-frame orbit under a position loop), its descent and touchdown
    spin_nmpc       its optional inner loop (`spin.inner: nmpc`): an NMPC on the orbit's model
    reference       the flight's plan (Reference, ConstantReference)
    reference_core, reference_core.c  the plan's grid in C (what Reference.grid runs where a
                    C compiler is found; Reference._pv stays the specification)
    landing         the end of a landing on the ground's contact (GroundContact)
    records         typed records across module boundaries
    loop            the offboard flight over MAVLink (OffboardFlight)
    link/           the MAVLink transport and the wire's arithmetic
    log, diagnosis  controller.csv; the motors' estimates for the ground station
    daemon          trq-offboard: the flight loop with its link, logs and signals
"""
