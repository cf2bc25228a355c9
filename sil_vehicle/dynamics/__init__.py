"""Pure physics of the truth plant: no I/O, clock or randomness (noise arrives as arguments).

rotors       rotor thrust and drag torque, tilt geometry, the body wrench (effectiveness)
actuators    motor lag and servo slew and limits, one physics tick
environment  wind: steady plus Dryden gusts driven by given white-noise samples
contact      the ground: spring-damper normal force and anchored Coulomb friction at the
             landing gear's points (added to the wrench inside every RK4 stage)
rigid_body   6-DoF Newton-Euler equations and their fixed-step RK4 integration
tick.c       the whole tick (vehicle.Vehicle._tick_python) in C, the same arithmetic in the same
             order (bit-identical); built and loaded by sil_vehicle.compiled
"""
