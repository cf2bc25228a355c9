"""CasADi prediction model of the tilt-rotor (and fixed-rotor) quadcopter.

Contract: `PredictionModel(vehicle)` builds, once, symbolic functions of
    x (12) = [p_ned (m), v_ned (m/s), roll, pitch, yaw (rad, ZYX), p, q, r (rad/s, body FRD)]
    u      = TRQ: [alpha_1..4 (rad), zeta_1..4 (throttle %)]  (paper order, rotors PX4 quad X)
             quad (tilt locked): [zeta_1..4 (%)]
    d (6)  = [acceleration NED (m/s^2), angular acceleration body FRD (rad/s^2)]
and their fixed-step RK4 discretisation. No I/O, clock or randomness.
"""

from trq_offboard.model.dynamics import PredictionModel, euler_rate_matrix, rotation_ned_frd

__all__ = ["PredictionModel", "euler_rate_matrix", "rotation_ned_frd"]
