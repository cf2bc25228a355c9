"""The lost-motor controller's pieces (trq_offboard/spin.py): its trim against the envelope's, its
parameters, its landing reference, its command's shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trq_offboard.config import load_vehicle_model
from trq_offboard.records import ReferenceSample, StateEstimate
from trq_offboard.spin import (SpinController, equilibrium, landing_reference,
                               load_spin_config, spin_sense)
from trq_params.loader import ConfigError

from conftest import PARAMS, TRQ_YAML

CONTROLLER = PARAMS / "controller" / "trq_nmpc_eso.yaml"


@pytest.fixture(scope="module")
def controller():
    cfg = load_spin_config(CONTROLLER)
    return SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)


def test_trim_is_the_envelopes_relaxed_hover():
    """Motor 1 dead at 20 rad/s: the envelope record's figures (docs/decisions/
    2026-12-05-lost-motor-envelope.md: 91.1 % on each live rotor, tilts 0.7 / -22.2 / 23.9 deg,
    the axis 23.1 deg from body up, margin 0.099), and the torque balance M = w^2 n x J n."""
    vm = load_vehicle_model(TRQ_YAML)
    t = equilibrium(vm, 1, 20.0)
    assert t.throttle_pct[0] == 0.0 and t.tilt_rad[0] == 0.0
    assert t.throttle_pct[1:] == pytest.approx((91.12,) * 3, abs=0.02)
    assert np.degrees(t.tilt_rad[1:]) == pytest.approx((0.65, -22.23, 23.85), abs=0.05)
    n = np.asarray(t.axis_frd)
    assert math.degrees(math.acos(-n[2])) == pytest.approx(23.1, abs=0.05)
    assert t.margin == pytest.approx(0.0986, abs=5e-4)


def test_no_trim_below_the_slowest_hover_or_on_a_locked_airframe():
    vm = load_vehicle_model(TRQ_YAML)
    with pytest.raises(ValueError, match="no relaxed hover"):
        equilibrium(vm, 1, 10.0)                    # the envelope: hover from 14.39 rad/s up
    with pytest.raises(ValueError, match="expected 1..4"):
        equilibrium(vm, 0, 20.0)
    with pytest.raises(ValueError, match="tilts locked"):
        equilibrium(load_vehicle_model(PARAMS / "vehicle" / "quad.yaml"), 1, 20.0)


def test_missing_section_names_the_file(tmp_path):
    text = (PARAMS / "controller" / "nmpc.yaml").read_text()
    f = tmp_path / "c.yaml"
    f.write_text(text.replace("vehicle: ../vehicle/", f"vehicle: {PARAMS}/vehicle/"))
    with pytest.raises(ConfigError, match="spin: missing"):
        load_spin_config(f)


def test_on_the_orbit_the_command_is_the_trim(controller):
    """On the orbit, the axis where it is asked for, the rates w n, the actuators at the trim:
    the command is the trim (the LQR's deviation is zero), the dead motor off."""
    t = controller.trim
    n = np.asarray(t.axis_frd)
    # an attitude that turns n onto world up: roll and pitch from n (ZYX, yaw 0)
    pitch = math.asin(n[0])             # R^T up = n with up = (0, 0, -1): n = (sp, -sr cp, -cr cp)
    roll = math.atan2(-n[1], -n[2])
    est = StateEstimate((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (roll, pitch, 0.0),
                        tuple(t.spin_rad_s * n))
    controller.reset(est)
    cmd = controller.step(est, ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0))
    assert cmd.throttle_pct[0] == 0.0 and cmd.tilt_rad[0] == 0.0
    assert cmd.throttle_pct == pytest.approx(t.throttle_pct, abs=0.05)
    assert cmd.tilt_rad == pytest.approx(t.tilt_rad, abs=1e-3)
    assert controller.info.axis_error_rad < 1e-6


def test_the_position_integral_starts_where_it_is_told(controller):
    """reset's integral_m_s2 (the wind the observer learnt before the switch, negated) is the
    position loop's integral's start, bounded by max_integral_m_s2; none: zero."""
    lim = controller.config.position.max_integral_m_s2
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, -5.0), integral_m_s2=(0.95, -0.2, 0.0))
    assert controller._integral == pytest.approx([0.95, -0.2, 0.0])
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, -5.0), integral_m_s2=(9.0, -9.0, 0.0))
    assert controller._integral == pytest.approx([lim, -lim, 0.0])
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, -5.0))
    assert not np.any(controller._integral)


def test_landing_reference_holds_then_descends_then_slows():
    from trq_offboard.spin import SpinLanding
    la = SpinLanding(hold_s=2.0, descent_speed_m_s=1.0, final_height_m=1.0, final_speed_m_s=0.5,
                     contact_height_m=0.05, contact_speed_m_s=0.05,
                     final_spin_rate_rad_s=30.0)
    start = (1.0, 2.0, -5.0)
    assert landing_reference(1.0, start, la).pos_ned_m == start
    assert landing_reference(1.0, start, la).phase == "hold"
    r = landing_reference(4.0, start, la)              # 2 s of descent at 1 m/s
    assert r.pos_ned_m == pytest.approx((1.0, 2.0, -3.0)) and r.vel_ned_m_s[2] == 1.0
    r = landing_reference(7.0, start, la)              # 4 m in 4 s, then 1 s at 0.5 m/s
    assert r.pos_ned_m[2] == pytest.approx(-0.5) and r.vel_ned_m_s[2] == 0.5
    assert landing_reference(60.0, start, la).pos_ned_m[2] == 0.0


def test_touchdown_cuts_the_motors(controller):
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, 0.0))
    est = StateEstimate((0.0, 0.0, -0.01), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cmd = controller.step(est, ReferenceSample((0.0, 0.0, 0.0), (0.0, 0.0, 0.4), 0.0, "land"))
    assert cmd.throttle_pct == (0.0,) * 4 and controller.info.landed
    # still in the air while holding: never cut
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, 0.0))
    controller.step(est, ReferenceSample((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, "hold"))
    assert not controller.info.landed


def test_expm_and_riccati_against_their_definitions():
    """The numpy matrix exponential against exp of a diagonalisable matrix, and the Riccati
    solution satisfying its equation with a stable closed loop (the LQR's pieces)."""
    from trq_offboard.spin import _dare, _expm
    rng = np.random.default_rng(0)
    v = rng.normal(size=(5, 5))
    lam = np.array([-3.0, -0.5, 0.0, 0.7, 2.0])
    m = v @ np.diag(lam) @ np.linalg.inv(v)
    assert np.allclose(_expm(m), v @ np.diag(np.exp(lam)) @ np.linalg.inv(v), rtol=1e-9,
                       atol=1e-9)
    a = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.0, 0.0, 1.02]])   # unstable, controllable
    b = np.array([[0.0], [0.0], [0.1]])
    q, r = np.eye(3), np.array([[0.5]])
    p = _dare(a, b, q, r)
    k = np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    assert np.allclose(a.T @ p @ a - a.T @ p @ b @ k + q, p, atol=1e-8)
    assert np.max(np.abs(np.linalg.eigvals(a - b @ k))) < 1.0


def test_the_delay_is_carried_in_the_gain():
    cfg = load_spin_config(CONTROLLER)
    c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1, delay_s=0.015)
    assert c.delay_steps == 2 and c.gain.shape == (6, 11 + 12)
    with pytest.raises(ValueError, match="delay_s"):
        SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1, delay_s=-0.01)


def test_the_spin_turns_the_way_the_live_rotors_push():
    """Motor 1 or 2 (ccw) lost: the cw rotors 3 and 4 push the body -z, omega = +w n (n up);
    motor 3 or 4 (cw) lost: the other way."""
    cfg = load_spin_config(CONTROLLER)
    vm = load_vehicle_model(cfg.vehicle_file)
    assert SpinController(cfg, vm, 1).direction == 1
    assert SpinController(cfg, vm, 4).direction == -1
    assert SpinController(cfg, vm, 4, direction=1).direction == 1


def test_the_sense_at_the_switch_is_the_yaws_not_the_tumbles():
    """lost_motor_axes' worst flight (motor 3 at 8 s, calm; the record
    2026-12-05-lost-motor-axes.md): at the detection the body rolls and pitches towards the dead
    rotor at (-1.27, -3.78) rad/s and yaws at -0.22. The whole rate's projection on motor 3's
    axis is negative (-0.46 rad/s: the tumble's), the yaw's positive: the sense is the yaw's
    (+1: omega = +w n turns the body -z, as r < 0 does)."""
    axis = equilibrium(load_vehicle_model(TRQ_YAML), 3, 20.0).axis_frd
    rates = (-1.27, -3.78, -0.22)
    assert float(np.dot(rates, axis)) < -0.3
    assert spin_sense(rates, axis) == 1
    assert spin_sense((-1.27, -3.78, 0.22), axis) == -1
    assert spin_sense((0.0, 0.0, 0.0), axis) == 1


def test_a_non_finite_estimate_gives_the_trim(controller):
    controller.reset(None, hold_pos_ned_m=(0.0, 0.0, -5.0))
    est = StateEstimate((0.0, 0.0, math.nan), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    cmd = controller.step(est, ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0))
    assert controller.info.fallback
    assert cmd.throttle_pct == controller.trim.throttle_pct
    assert all(math.isfinite(a) for a in cmd.tilt_rad)
