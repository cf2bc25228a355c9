"""The companion's ground contact at the end of a landing (trq_offboard/landing.py)."""

from __future__ import annotations

import pytest

from trq_offboard.landing import BELOW_MARGIN_M, HOLD_S, Z_VEL_MAX_M_S, GroundContact

STEP_S = 0.01


def feed(contact, samples, t0=0.0):
    """(phase, ref_down, est_down, est_vel_down) every STEP_S; the times it said ground."""
    said = []
    for k, (phase, ref, est, vel) in enumerate(samples):
        t = t0 + k * STEP_S
        if contact.update(t, phase, ref, est, vel):
            said.append(t)
    return said


def test_the_plan_pressing_below_a_still_vehicle_is_the_ground_after_the_hold():
    n = int(HOLD_S / STEP_S) + 5
    said = feed(GroundContact(), [("landed", 0.2, -0.7, 0.05)] * n)
    assert said and said[0] == pytest.approx(HOLD_S, abs=STEP_S)


@pytest.mark.parametrize("sample, why", [
    (("hold", 0.2, -0.7, 0.0), "not landing"),
    (("land", -0.7 + 0.5 * BELOW_MARGIN_M, -0.7, 0.0), "the plan at the estimate"),
    (("land", 0.2, -0.7, 0.3), "descending"),
    (("land", 0.2, -0.7, -0.3), "climbing"),
])
def test_no_ground_while_the_plan_does_not_press_or_the_vehicle_moves(sample, why):
    assert not feed(GroundContact(), [sample] * int(3 * HOLD_S / STEP_S)), why


def test_a_bounce_restarts_the_count_a_small_one_does_not():
    half = int(0.6 * HOLD_S / STEP_S)
    still, small, big = ("land", 0.2, -0.5, 0.0), ("land", 0.2, -0.5, 1.5 * Z_VEL_MAX_M_S), \
        ("land", 0.2, -0.5, 3.0 * Z_VEL_MAX_M_S)
    c = GroundContact()
    assert not feed(c, [still] * half + [big] + [still] * half)
    c = GroundContact()
    said = feed(c, [still] * half + [small] + [still] * half)
    assert said and said[0] == pytest.approx(HOLD_S, abs=STEP_S)
    # a count only starts on a still vehicle
    c = GroundContact()
    assert not feed(c, [small] * (2 * half))
