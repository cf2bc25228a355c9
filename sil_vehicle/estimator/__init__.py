"""The autopilot's state estimator: an error-state Kalman filter with EKF2's architecture (PX4
EKF2: a delayed fusion horizon and an output predictor), a pure module: no I/O, no clock, no
random numbers; time as integer microseconds.

    derivation  the filter's equations in CasADi SX: nominal propagation, error-state F and G,
                each measurement's h and H, built once into casadi.Function objects
    codegen     those functions generated as C, compiled once into a cached library, called
                through ctypes (CasADi's interpreter without a compiler)
"""
