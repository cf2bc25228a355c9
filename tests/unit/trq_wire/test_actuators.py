"""Actuator scaling on the wire (trq_wire.actuators), shared by the vehicle's codec and the
controller's link: hand-computed values both directions, round trips, and out-of-range, NaN
and malformed input (sil_vehicle/PROTOCOL.md's mapping)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trq_wire import actuators as act

LIMIT = math.radians(30.0)


def test_tilt_half_range():
    assert act.tilt_half_range(math.radians(-20), math.radians(30)) == math.radians(30)
    assert act.tilt_half_range(math.radians(-35), math.radians(30)) == math.radians(35)
    assert act.tilt_half_range(0.0, 0.0) == 0.0                 # a fixed-rotor vehicle


# --- normalised ------------------------------------------------------------------------------

def test_to_normalised_hand_computed():
    got = act.to_normalised((0.0, 10.0, 55.0, 100.0), (-LIMIT, -LIMIT / 2, 0.0, LIMIT / 3),
                            LIMIT)
    assert got == pytest.approx([0.0, 0.1, 0.55, 1.0, -1.0, -0.5, 0.0, 1 / 3], abs=1e-15)
    assert act.to_normalised((50.0,), (), LIMIT) == [0.5]        # any number of actuators


def test_to_normalised_does_not_clip():
    assert act.to_normalised((-5.0, 130.0), (2 * LIMIT,), LIMIT) == \
        pytest.approx([-0.05, 1.3, 2.0])


def test_from_normalised_hand_computed():
    thr, tilt = act.from_normalised([0.0, 0.25, 0.5, 1.0, -1.0, -0.5, 0.25, 1.0] + [9.0] * 24,
                                    LIMIT)
    assert thr == (0.0, 25.0, 50.0, 100.0)                      # exact: 100 x a power of two
    assert tilt == pytest.approx((-LIMIT, -LIMIT / 2, LIMIT / 4, LIMIT), abs=1e-15)


@given(st.lists(st.floats(0.0, 100.0), min_size=4, max_size=4),
       st.lists(st.floats(-LIMIT, LIMIT), min_size=4, max_size=4))
def test_normalised_round_trip(thr, tilt):
    back_thr, back_tilt = act.from_normalised(act.to_normalised(thr, tilt, LIMIT), LIMIT)
    assert back_thr == pytest.approx(thr, rel=1e-15, abs=1e-13)
    assert back_tilt == pytest.approx(tilt, rel=1e-15, abs=1e-15)


def test_clip_controls():
    got = act.clip_controls([-0.05, 1.3, 0.5, 1.0000001, -2.0, 1.5, 0.0, -1e9])
    assert got == [0.0, 1.0, 0.5, 1.0, -1.0, 1.0, 0.0, -1.0]
    assert act.clip_controls([0.0, 1.0, 0.3, 0.7, -1.0, 1.0, -0.3, 0.3]) == \
        [0.0, 1.0, 0.3, 0.7, -1.0, 1.0, -0.3, 0.3]               # in range: untouched


@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=8, max_size=8))
def test_clip_controls_is_min_of_max_to_the_bit(values):
    """Each value as min(max(v, lo), hi) gives it (a NaN and a -0.0 as they come through)."""
    want = [min(max(v, 0.0), 1.0) for v in values[:4]] + \
        [min(max(v, -1.0), 1.0) for v in values[4:]]
    assert [repr(v) for v in act.clip_controls(values)] == [repr(v) for v in want]
    edges = [-0.0, math.nan, -math.inf, math.inf, -0.0, math.nan, -math.inf, math.inf]
    want = [min(max(v, 0.0), 1.0) for v in edges[:4]] + [min(max(v, -1.0), 1.0) for v in edges[4:]]
    assert [repr(v) for v in act.clip_controls(edges)] == [repr(v) for v in want]


def test_controls_in_range_accepts_the_edges():
    assert act.controls_in_range([0.0, 1.0, 0.5, 0.5, -1.0, 1.0, 0.0, 0.2])


@pytest.mark.parametrize("bad_index, bad_value", [
    (0, math.nan), (3, math.inf), (5, -math.inf), (7, math.nan),
    (1, 1.01), (2, -0.01), (4, 1.5), (6, -1.0001),
])
def test_controls_in_range_rejects_one_bad_value(bad_index, bad_value):
    controls = [0.5] * 4 + [0.2] * 4
    controls[bad_index] = bad_value
    assert not act.controls_in_range(controls)


@pytest.mark.parametrize("n", [0, 4, 7, 9, 16])
def test_controls_in_range_needs_eight_values(n):
    assert not act.controls_in_range([0.5] * n)


# --- PWM -------------------------------------------------------------------------------------

@pytest.mark.parametrize("pct, pwm", [(0, 1000), (100, 2000), (50, 1500), (76.82, 1768),
                                      (-5, 1000), (150, 2000), (0.04, 1000), (0.05, 1000),
                                      (0.06, 1001)])
def test_throttle_to_pwm(pct, pwm):
    assert act.throttle_to_pwm(pct) == pwm


@pytest.mark.parametrize("tilt, pwm", [(0.0, 1500), (LIMIT, 2000), (-LIMIT, 1000),
                                       (LIMIT / 2, 1750), (2 * LIMIT, 2000), (-3 * LIMIT, 1000)])
def test_tilt_to_pwm(tilt, pwm):
    assert act.tilt_to_pwm(tilt, LIMIT) == pwm


def test_pwm_to_physical_hand_computed():
    assert act.pwm_to_throttle(1768) == pytest.approx(76.8)
    assert act.pwm_to_throttle(1000) == 0.0 and act.pwm_to_throttle(2000) == 100.0
    assert act.pwm_to_tilt(1750, LIMIT) == pytest.approx(LIMIT / 2)
    assert act.pwm_to_tilt(1000, LIMIT) == -LIMIT and act.pwm_to_tilt(1500, LIMIT) == 0.0
    # out-of-range PWM is converted, not clipped: the receiver decides what to make of it
    assert act.pwm_to_throttle(900) == -10.0 and act.pwm_to_tilt(2500, LIMIT) == 2 * LIMIT


def test_pwm_round_trips():
    for pwm in range(1000, 2001):
        assert act.throttle_to_pwm(act.pwm_to_throttle(pwm)) == pwm
        assert act.tilt_to_pwm(act.pwm_to_tilt(pwm, LIMIT), LIMIT) == pwm


def test_to_pwm_and_from_pwm():
    pwm = act.to_pwm((0.0, 50.0, 100.0, 10.0), (0.0, LIMIT, -LIMIT, LIMIT / 2), LIMIT)
    assert pwm == [1000, 1500, 2000, 1100, 1500, 2000, 1000, 1750]
    thr, tilt = act.from_pwm(pwm, LIMIT)
    assert thr == (0.0, 50.0, 100.0, 10.0)
    assert tilt == pytest.approx((0.0, LIMIT, -LIMIT, LIMIT / 2), abs=1e-15)
    assert act.from_pwm([1000, 1250, 1775, 2000, 1000, 1250, 1500, 2000] + [0] * 8, LIMIT) == \
        ((0.0, 25.0, 77.5, 100.0), pytest.approx((-LIMIT, -LIMIT / 2, 0.0, LIMIT)))
