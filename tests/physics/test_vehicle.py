"""Invariants of the composed truth plant (sil_vehicle.vehicle.Vehicle): hover at trim, free fall,
drag and wind, ground contact and crashes, actuator lag and rate limits, motor faults."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from sil_vehicle.dynamics.actuators import first_order_step, lag_factor
from sil_vehicle.faults import MotorFault
from sil_vehicle.frames import euler_to_quat, tilt_from_vertical
from sil_vehicle.vehicle import ActuatorCommand, Vehicle

G = 9.80665


def make(sim, **vehicle_changes):
    if vehicle_changes:
        sim = sim.with_changes(vehicle=dataclasses.replace(sim.vehicle, **vehicle_changes))
    return Vehicle(sim, np.random.default_rng(0))


def place(v, down_m=-5.0, vel=(0.0, 0.0, 0.0), q=None, motor_pct=None, tilt_rad=None):
    """Put the vehicle somewhere in the air (down_m < 0), optionally with actuators spun up."""
    x = list(v.state.x)
    x[2] = down_m
    x[3:6] = vel
    if q is not None:
        x[6:10] = q
    changes = {"x": tuple(x), "landed": down_m >= 0.0}
    if motor_pct is not None:
        changes["motor_pct"] = tuple(motor_pct)
    if tilt_rad is not None:
        changes["tilt_rad"] = tuple(tilt_rad)
    v.state = dataclasses.replace(v.state, **changes)


def run(v, ticks):
    states = []
    for _ in range(ticks):
        states.append(v.step())
    return states


@pytest.mark.parametrize("airframe", ["trq", "quad"])
def test_hover_at_trim_holds_altitude(sim, quad, airframe):
    s = sim if airframe == "trq" else sim.with_changes(vehicle=quad)
    v = Vehicle(s, np.random.default_rng(0))
    trim = s.vehicle.hover_throttle_pct
    v.armed = True
    v.command = ActuatorCommand((trim,) * 4)
    place(v, -5.0, motor_pct=(trim,) * 4)
    states = run(v, 2000)                                            # 2 s
    end = states[-1]
    assert abs(end.x[2] + 5.0) < 1e-9 and abs(end.x[5]) < 1e-9
    assert tilt_from_vertical(*end.x[6:10]) < 1e-9 and max(map(abs, end.x[10:13])) < 1e-9
    assert not end.landed and not end.crashed


def test_more_than_trim_climbs_less_descends(sim):
    trim = sim.vehicle.hover_throttle_pct
    for delta, sign in ((+3.0, -1), (-3.0, +1)):
        v = make(sim)
        v.armed = True
        v.command = ActuatorCommand((trim + delta,) * 4)
        place(v, -20.0, motor_pct=(trim,) * 4)
        end = run(v, 500)[-1]
        assert sign * end.x[5] > 0.1                               # down velocity's sign


def test_free_fall_gives_g(sim):
    v = make(sim, drag_N_s2_m2=0.0)
    place(v, -100.0)                                               # disarmed: motors off
    end = run(v, 1000)[-1]                                         # 1 s
    assert end.t_us == 1_000_000
    assert end.x[5] == pytest.approx(G * 1.0, rel=1e-9)
    assert end.x[2] == pytest.approx(-100.0 + 0.5 * G, rel=1e-9)
    assert end.motor_pct == (0.0,) * 4


def test_terminal_velocity_with_drag(sim):
    v = make(sim)
    vt = math.sqrt(2.1 * G / 0.03125)
    place(v, -2000.0)
    end = run(v, 15_000)[-1]                                       # tanh(15 g / vt) ~ 1 - 4e-5
    assert end.x[5] == pytest.approx(vt, rel=1e-4)
    assert end.x[5] == pytest.approx(vt * math.tanh(G * 15.0 / vt), rel=1e-8)


def test_wind_pushes_a_vehicle_at_rest(sim):
    v = make(sim, drag_N_s2_m2=0.03125)
    v.set_wind(8.0, 180.0, False, 1.0, 50.0)                       # from the south: blows north
    place(v, -100.0)
    s1 = v.step()
    assert s1.wind_ned_m_s == pytest.approx((8.0, 0.0, 0.0), abs=1e-12)
    # 2 N on 2.1 kg at rest (0.03125 x 8^2): over one 1 ms tick, on average, a hair less since
    # the air-relative speed drops; exactly, m dv/dt = k (w - v)^2: v = w - 1 / (1/w + k t / m)
    assert 2.1 * s1.x[3] / 0.001 == pytest.approx(2.0, rel=2e-4)
    # (to 1e-6: the vehicle also starts falling, which adds a little to the air-relative speed)
    assert s1.x[3] == pytest.approx(8.0 - 1.0 / (1.0 / 8.0 + 0.03125 * 0.001 / 2.1), rel=1e-6)
    assert s1.x[4] == pytest.approx(0.0, abs=1e-15)


def test_gusts_are_seeded(sim):
    def winds(seed):
        s = sim.with_changes(gusts_enabled=True, wind_speed_m_s=5.0)
        v = Vehicle(s, np.random.default_rng(seed))
        place(v, -500.0)
        return [st.wind_ned_m_s for st in run(v, 300)]
    a, b, c = winds(1), winds(1), winds(2)
    assert a == b and a != c
    assert a[-1] != a[0]


def test_idle_on_the_ground_stays_put(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((0.0,) * 4)                        # raised to idle (10 %)
    states = run(v, 1000)
    assert states[-1].motor_pct == pytest.approx((10.0,) * 4, abs=1e-6)
    assert all(abs(s.x[2]) < 1e-4 and abs(s.x[5]) < 1e-3 and s.landed for s in states)
    assert max(map(abs, states[-1].x[0:2])) < 1e-9
    # and at 60 %: 4 x 3.27 N < m g, still on the ground (the gear a little less compressed)
    v.command = ActuatorCommand((60.0,) * 4)
    assert all(abs(s.x[2]) < 1e-3 and s.on_ground and not s.crashed for s in run(v, 1000))


def test_gentle_landing_never_goes_below_ground(sim):
    v = make(sim)
    place(v, -0.2)                                                 # 1.98 m/s at touch-down
    states = run(v, 800)
    assert all(s.x[2] <= 0.01 for s in states)                     # the gear's compression
    assert states[-1].landed and not states[-1].crashed and abs(states[-1].x[2]) < 1e-4
    assert abs(states[-1].x[5]) < 1e-3


def test_take_off_from_the_ground(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((90.0,) * 4)
    states = run(v, 1000)
    assert not states[-1].landed and states[-1].x[2] < -0.5


def test_drop_from_5m_crashes(sim):
    v = make(sim)
    place(v, -5.0)
    states = run(v, 1500)                                          # no exception
    end = states[-1]
    assert end.crashed and end.crash_reason.startswith("ground impact at 9.")
    # with quadratic drag, v^2 = vt^2 (1 - exp(-2 g h / vt^2)) at the ground: 9.55 m/s (9.90
    # without drag), reached at t = vt / g acosh(exp(g h / vt^2))
    vt2 = 2.1 * G / 0.03125
    speed = float(re.search(r"at ([0-9.]+) m/s", end.crash_reason).group(1))
    assert speed == pytest.approx(math.sqrt(vt2 * (1 - math.exp(-2 * G * 5.0 / vt2))), abs=0.02)
    first = next(i for i, s in enumerate(states) if s.crashed)
    t_impact = math.sqrt(vt2) / G * math.acosh(math.exp(G * 5.0 / vt2))
    assert first + 1 == pytest.approx(1000 * t_impact, abs=1.5)                # tick of impact
    # crashed: arming is refused and motors stay stopped even if armed underneath
    assert v.set_armed(True) == "crashed"
    v.armed = True
    v.command = ActuatorCommand((90.0,) * 4)
    assert run(v, 100)[-1].motor_pct == (0.0,) * 4


def test_attitude_past_limit_crashes(sim):
    v = make(sim)
    place(v, -50.0, q=euler_to_quat(math.radians(100.0), 0.0, 0.0))
    s = v.step()
    assert s.crashed and "attitude" in s.crash_reason


# --- actuators ----------------------------------------------------------------------------------

def test_first_order_step_pure():
    f = lag_factor(0.03, 0.001)
    assert f == pytest.approx(1 - math.exp(-1 / 30))
    y = 0.0
    for _ in range(30):
        y = first_order_step(y, 1.0, f, 10.0, 0.0, 100.0)
    assert y == pytest.approx(1 - math.exp(-1), rel=1e-12)          # 63.2 % at one time constant
    assert lag_factor(0.0, 0.001) == 1.0
    assert first_order_step(0.0, 50.0, 1.0, 2.0, 0.0, 100.0) == 2.0  # rate limited
    assert first_order_step(99.0, 150.0, 1.0, 100.0, 0.0, 100.0) == 100.0   # clamped


def test_motor_lag_63_percent_in_one_time_constant(sim):
    v = make(sim)
    v.armed = True
    v.state = dataclasses.replace(v.state, motor_pct=(10.0,) * 4)
    v.command = ActuatorCommand((30.0,) * 4)                        # a 20 % step, not rate limited
    tc_ticks = round(sim.vehicle.motor_time_constant_s / 0.001)     # 30
    states = run(v, tc_ticks + 1)
    expected = 10.0 + 20.0 * (1 - math.exp(-1))
    assert states[tc_ticks - 1].motor_pct[0] == pytest.approx(expected, rel=1e-9)
    assert states[tc_ticks - 2].motor_pct[0] < expected < states[tc_ticks].motor_pct[0]


def test_servo_lag_63_percent_in_one_time_constant(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((10.0,) * 4, (0.1, -0.1, 0.05, 0.0))
    tc_ticks = round(sim.vehicle.servo_time_constant_s / 0.001)     # 40
    states = run(v, tc_ticks)
    assert states[-1].tilt_rad == pytest.approx(
        tuple(a * (1 - math.exp(-1)) for a in (0.1, -0.1, 0.05, 0.0)), rel=1e-9, abs=1e-15)


def test_servo_rate_limit(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((10.0,) * 4, (0.5, -0.5, 0.5, -0.5))
    max_step = math.radians(300.0) * 0.001
    states = run(v, 400)
    tilts = np.array([s.tilt_rad for s in states])
    steps = np.abs(np.diff(np.vstack([np.zeros(4), tilts]), axis=0))
    assert steps.max() <= max_step * (1 + 1e-12)
    assert steps[0] == pytest.approx([max_step] * 4, rel=1e-12)     # the limit is reached
    assert tilts[-1] == pytest.approx([0.5, -0.5, 0.5, -0.5], abs=1e-3)
    assert np.all(np.abs(tilts) <= math.radians(30.0) + 1e-15)


def test_servo_limits_and_disarmed_centring(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((10.0,) * 4, (1.0, -1.0, 1.0, -1.0))   # past 30 deg
    run(v, 500)
    r30 = math.radians(30)
    assert v.state.tilt_rad == pytest.approx((r30, -r30, r30, -r30), rel=1e-12)
    v.armed = False
    run(v, 500)
    assert v.state.tilt_rad == pytest.approx((0.0,) * 4, abs=1e-4)


def test_motor_rate_limit(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((100.0,) * 4)
    states = run(v, 50)
    motor = [0.0] + [s.motor_pct[0] for s in states]
    assert max(np.diff(motor)) == pytest.approx(1500.0 * 0.001, rel=1e-12)


def test_quad_ignores_tilt_commands(sim, quad):
    v = Vehicle(sim.with_changes(vehicle=quad), np.random.default_rng(0))
    v.armed = True
    v.command = ActuatorCommand((50.0,) * 4, (0.5,) * 4)
    assert run(v, 200)[-1].tilt_rad == (0.0,) * 4


# --- faults -----------------------------------------------------------------------------------

def test_fault_factor_formula():
    paper = MotorFault(0.8, 0.2, 0.01, 0.0)
    assert paper.factor(0.0) == 0.8
    assert paper.factor(math.pi / 2 / 0.01) == pytest.approx(0.6)
    assert paper.factor(3 * math.pi / 2 / 0.01) == pytest.approx(1.0)
    assert MotorFault(0.9, 0.3, 1.0, 0.0).factor(3 * math.pi / 2) == 1.0    # 1.2 clamped
    assert MotorFault(0.1, 0.3, 1.0, 0.0).factor(math.pi / 2) == 0.0        # -0.2 clamped
    assert MotorFault(0.8, 0.2, 0.01, 0.0, off=True).factor(0.0) == 0.0
    assert MotorFault(0.7).factor(123.0) == 0.7
    for t in (0.3, 1.7, 4.2):
        assert MotorFault(0.7, 0.2, 2.0, 0.5).factor(t) == pytest.approx(
            0.7 - 0.2 * math.sin(2.0 * t + 0.5), rel=1e-15)


def test_time_varying_fault_in_the_plant(sim):
    # instant motors: what a motor produces is exactly command x (a - b sin(w t + phi)), t the
    # time at the start of the tick
    v = make(sim, motor_time_constant_s=0.0, motor_rate_limit_pct_s=1e6)
    v.faults = v.faults.with_motor(1, effectiveness=0.7, amplitude=0.2, omega_rad_s=2.0,
                                   phase_rad=0.5)
    v.faults = v.faults.with_motor(3, effectiveness=0.5)
    v.armed = True
    v.command = ActuatorCommand((50.0,) * 4)
    for _ in range(1500):
        t_s = v.state.t_us * 1e-6
        s = v.step()
        assert s.motor_pct[1] == pytest.approx(50.0 * (0.7 - 0.2 * math.sin(2.0 * t_s + 0.5)),
                                               rel=1e-12)
    assert s.motor_pct[0] == 50.0 and s.motor_pct[3] == 25.0


def test_motor_off_stops_it(sim):
    v = make(sim)
    v.armed = True
    v.command = ActuatorCommand((60.0,) * 4)
    run(v, 300)
    v.faults = v.faults.with_motor(0, off=True)
    end = run(v, 500)[-1]
    assert end.motor_pct[0] < 0.01 and end.motor_pct[1] == pytest.approx(60.0)
    v.faults = v.faults.with_motor(0, off=False)
    assert run(v, 500)[-1].motor_pct[0] == pytest.approx(60.0)


def test_state_is_plain_floats_with_gusts(sim):
    # the plant runs on Python floats (fast, and repr() in the flight log is a plain number);
    # NumPy scalars from the gust generator must not leak into the state
    s = sim.with_changes(gusts_enabled=True, wind_speed_m_s=5.0)
    v = Vehicle(s, np.random.default_rng(3))
    v.armed = True
    v.command = ActuatorCommand((90.0,) * 4)
    end = run(v, 300)[-1]
    assert not end.landed
    for value in end.x + end.wind_ned_m_s + end.motor_pct + end.tilt_rad:
        assert type(value) is float, type(value)
