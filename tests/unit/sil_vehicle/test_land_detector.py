"""The land detector (sil_vehicle.land_detector): its states in the order PX4's takes them."""

from __future__ import annotations

from sil_vehicle.land_detector import (GROUND_CONTACT_S, IN_AIR, LANDED_S, LANDING, ON_GROUND,
                                       TAKEOFF, TAKEOFF_S, LandDetector)

STILL = (0.0, 0.0, 0.0)


def feed(d, t0, t1, armed, vel, thrust, rates=STILL, dt=0.02):
    states = []
    t = t0
    while t < t1 - 1e-9:
        states.append(d.update(t, armed, vel, rates, thrust))
        t += dt
    return states


def test_disarmed_is_on_the_ground():
    d = LandDetector()
    assert feed(d, 0.0, 1.0, False, (0.0, 0.0, -2.0), 1.5) == [ON_GROUND] * 50


def test_take_off_flight_landing_and_landed():
    d = LandDetector()
    assert set(feed(d, 0.0, 0.5, True, STILL, 0.1)) == {ON_GROUND}     # armed, idling
    assert feed(d, 0.5, 0.52, True, STILL, 1.2) == [TAKEOFF]            # thrust above hover
    assert set(feed(d, 0.52, 0.5 + TAKEOFF_S - 0.05, True, (0, 0, -1.0), 1.1)) == {TAKEOFF}
    assert feed(d, 2.0, 5.0, True, (1.0, 0.0, 0.0), 1.0)[-1] == IN_AIR
    # descending slowly on less than hover thrust: ground contact, then landing
    assert feed(d, 5.0, 5.5, True, (0.0, 0.0, 0.1), 0.8)[-1] == LANDING
    # idle on the ground, still: maybe landed, then landed after LANDED_S
    states = feed(d, 5.5, 5.5 + GROUND_CONTACT_S + LANDED_S + 0.1, True, STILL, 0.05)
    assert states[-1] == ON_GROUND and states[0] == LANDING
    assert d.landed


def test_hovering_is_not_landing_and_turning_is_not_landed():
    d = LandDetector()
    feed(d, 0.0, 0.1, True, STILL, 1.2)
    assert feed(d, 0.1, 3.0, True, STILL, 1.0)[-1] == IN_AIR            # hover thrust
    assert feed(d, 3.0, 6.0, True, STILL, 0.05, rates=(0.0, 0.0, 1.0))[-1] == LANDING
