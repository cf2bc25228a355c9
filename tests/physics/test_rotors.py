"""Rotor curves and effectiveness (sil_vehicle.dynamics.rotors, config.Quadratic) against values
computed by hand from the paper's curves and the geometry of params/vehicle/trq.yaml."""

from __future__ import annotations

import math

import pytest

from sil_vehicle.dynamics.rotors import body_wrench, thrust_direction_frd

S = math.sqrt(0.5)        # sin 45 = cos 45: every arm is at 45 deg
L = 0.23                  # arm length, m


def F(z):                 # thrust, N, of eq. (2), by hand
    return max(0.0007 * z * z + 0.0157 * z - 0.1891, 0.0)


def T(z):                 # drag torque, N m
    return max(2e-6 * z * z + 0.0007 * z - 0.008, 0.0)


# --- curves -----------------------------------------------------------------------------------

def test_thrust_curve_hand_values(trq):
    assert trq.thrust_N(100.0) == pytest.approx(8.3809, abs=1e-12)      # 7 + 1.57 - 0.1891
    assert trq.thrust_N(50.0) == pytest.approx(2.3459, abs=1e-12)       # 1.75 + 0.785 - 0.1891
    assert trq.thrust_N(0.0) == 0.0                                     # clamped, not -0.1891
    assert trq.thrust_N(8.6) == 0.0                                     # below the root
    assert trq.thrust_N(8.8) > 0.0
    root = trq.thrust_N.inverse(0.0)
    assert root == pytest.approx(8.6830, abs=1e-4)                      # (-c1 + sqrt(d)) / 2 c2


def test_torque_curve_hand_values(trq):
    assert trq.torque_Nm(100.0) == pytest.approx(0.082, abs=1e-12)      # 0.02 + 0.07 - 0.008
    assert trq.torque_Nm(60.0) == pytest.approx(0.0412, abs=1e-12)
    assert trq.torque_Nm(11.0) == 0.0                                   # root ~ 11.08 %
    assert trq.torque_Nm(11.2) > 0.0
    assert trq.torque_Nm.inverse(0.0) == pytest.approx(11.0779, abs=1e-4)


def test_curve_inverse(trq):
    for f in (0.5, 2.0, 5.14849125, 8.0):
        assert trq.thrust_N(trq.thrust_N.inverse(f)) == pytest.approx(f, rel=1e-12)


# --- geometry ---------------------------------------------------------------------------------

def test_thrust_direction():
    assert thrust_direction_frd((1.0, 0.0, 0.0), 0.0) == (-0.0, 0.0, -1.0)
    # arm along +x tilted by +30 deg: thrust turns towards +y (x cross -z = +y)
    n = thrust_direction_frd((1.0, 0.0, 0.0), math.radians(30))
    assert n == pytest.approx((0.0, 0.5, -math.cos(math.radians(30))), abs=1e-15)
    assert math.isclose(sum(c * c for c in n), 1.0)


# --- effectiveness ------------------------------------------------------------------------------

def test_hover_wrench(trq):
    h = trq.hover_throttle_pct
    fx, fy, fz, mx, my, mz = body_wrench([h] * 4, [0.0] * 4, trq)
    assert fz == pytest.approx(-trq.mass_kg * trq.gravity_m_s2, rel=1e-12)
    assert abs(fx) < 1e-12 and abs(fy) < 1e-12
    assert abs(mx) < 1e-12 and abs(my) < 1e-12 and abs(mz) < 1e-12


def test_one_rotor_tilted(trq):
    z, alpha = 60.0, math.radians(20.0)
    sa, ca = math.sin(alpha), math.cos(alpha)
    f, tau = F(z), T(z)
    w = body_wrench([z, 0.0, 0.0, 0.0], [alpha, 0.3, -0.3, 0.1], trq)   # other rotors stopped
    # rotor 1: arm a = (S, S, 0), at r = L a, ccw (spin +1)
    ax, ay = S, S
    expected = (-ay * sa * f, ax * sa * f, -ca * f,
                 # r x F n = F L (-a_y c, a_x c, s); minus spin tau n
                 f * L * (-ay * ca) - tau * (-ay * sa),
                 f * L * (ax * ca) - tau * (ax * sa),
                 f * L * sa + tau * ca)
    assert w == pytest.approx(expected, abs=1e-12)


def test_spin_directions_give_opposite_yaw(trq):
    z = 70.0
    mz1 = body_wrench([z, 0, 0, 0], [0.0] * 4, trq)[5]      # motor 1 ccw
    mz3 = body_wrench([0, 0, z, 0], [0.0] * 4, trq)[5]      # motor 3 cw
    assert mz1 == pytest.approx(T(z), rel=1e-12)              # ccw rotor yaws the body right
    assert mz3 == pytest.approx(-T(z), rel=1e-12)
    # and a yaw torque only from unequal pairs: 1+2 (ccw) against 3+4 (cw)
    w = body_wrench([z, z, 50.0, 50.0], [0.0] * 4, trq)
    assert w[5] == pytest.approx(2 * T(z) - 2 * T(50.0), rel=1e-12)
    assert abs(w[0]) < 1e-12 and abs(w[1]) < 1e-12


def test_roll_and_pitch_from_differential_thrust(trq):
    # right side (1 front right, 4 rear right) stronger: rolls left (negative Mx, FRD)
    w = body_wrench([70, 50, 50, 70], [0.0] * 4, trq)
    assert w[3] == pytest.approx(-2 * L * S * (F(70) - F(50)), rel=1e-12)
    assert abs(w[4]) < 1e-12
    # front (1, 3) stronger: pitches up (positive My)
    w = body_wrench([70, 50, 70, 50], [0.0] * 4, trq)
    assert w[4] == pytest.approx(2 * L * S * (F(70) - F(50)), rel=1e-12)


def test_tilts_adding_up_to_a_lateral_force(trq):
    # tilts (+a, -a, +a, -a): every rotor's lateral force points +y, the x parts cancel
    z, alpha = 65.0, math.radians(25.0)
    sa, ca = math.sin(alpha), math.cos(alpha)
    w = body_wrench([z] * 4, [alpha, -alpha, alpha, -alpha], trq)
    f, tau = F(z), T(z)
    # the rotor drag torques tilt with the rotors and leave a roll moment 4 S tau sin a
    expected = (0.0, 4 * S * f * sa, -4 * f * ca, 4 * S * tau * sa, 0.0, 0.0)
    assert w == pytest.approx(expected, abs=1e-12)


def test_pure_yaw_tilt_pattern(trq):
    # all four tilted the same way: the lateral forces go round, a pure yaw moment 4 F L sin a
    z, alpha = 65.0, math.radians(-15.0)
    w = body_wrench([z] * 4, [alpha] * 4, trq)
    f = F(z)
    expected = (0.0, 0.0, -4 * f * math.cos(alpha), 0.0, 0.0, 4 * f * L * math.sin(alpha))
    assert w == pytest.approx(expected, abs=1e-12)


def test_quad_has_the_same_effectiveness_untilted(trq, quad):
    u = [55.0, 60.0, 65.0, 70.0]
    assert body_wrench(u, [0.0] * 4, quad) == body_wrench(u, [0.0] * 4, trq)
