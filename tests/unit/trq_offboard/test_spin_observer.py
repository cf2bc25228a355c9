"""The lost-motor controller fed the observer's estimate (trq_offboard/spin.py,
`observer_lowpass_s`), flown in a closed loop of the spinning body: a force and a torque its
model does not have are cancelled with the estimate, and leave the position and the spin rate off
without it."""

from __future__ import annotations

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from trq_offboard.config import load_vehicle_model
from trq_offboard.records import ReferenceSample, StateEstimate
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.spin_nmpc import geometry, live_wrench

from conftest import PARAMS

CONTROLLER = PARAMS / "controller" / "trq_nmpc_eso.yaml"
HOLD = ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0)


def _euler(r: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles of a body FRD -> world NED rotation."""
    return (math.atan2(r[2, 1], r[2, 2]), -math.asin(max(-1.0, min(1.0, r[2, 0]))),
            math.atan2(r[1, 0], r[0, 0]))


def _exp(w: np.ndarray) -> np.ndarray:
    a = float(np.linalg.norm(w))
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if a < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(a) / a * k + (1.0 - math.cos(a)) / a ** 2 * k @ k


def _fly(c: SpinController, observe: bool, force_ned_n, torque_frd_nm,
         seconds: float = 2.0) -> tuple[float, float]:
    """The spinning body (the live rotors' wrench through first-order lags, the world force
    `force_ned_n` and the body torque `torque_frd_nm` added, the dead rotor giving nothing) from
    the orbit at the hold point, c commanding it every period from the true state; with
    `observe` the controller is handed the disturbance as its observer would estimate it (the
    nominal model flying the dead rotor at idle). Returns, over the last half second, the mean
    distance from the hold point (m) and the mean error of the spin rate (rad/s, signed)."""
    vm = c.vehicle
    live = c._live
    zs, al = ca.SX.sym("z", 3), ca.SX.sym("a", 3)
    f, m = live_wrench(vm, ca.DM(geometry(vm, live)), [zs[k] for k in range(3)],
                       [al[k] for k in range(3)])
    wrench = ca.Function("w", [zs, al], [f, m])
    force, torque = np.asarray(force_ned_n, float), np.asarray(torque_frd_nm, float)
    j = np.asarray(vm.inertia_kg_m2)
    n = np.asarray(c.trim.axis_frd)
    # the body with its axis n on world up (-z NED), spinning about it
    up = np.array([0.0, 0.0, -1.0])
    v = np.cross(n, up)
    r = _exp(v / np.linalg.norm(v) * math.acos(float(n @ up))) if np.linalg.norm(v) > 0 \
        else np.eye(3)
    om = c.direction * c.trim.spin_rad_s * n
    p, v = np.asarray(HOLD.pos_ned_m, float), np.zeros(3)
    g = np.array([0.0, 0.0, vm.gravity_m_s2])
    y = np.array([c.trim.throttle_pct[i] / 100.0 for i in live] + [c.trim.tilt_rad[i] for i in live])
    tau = np.array([vm.motor_time_constant_s] * 3 + [vm.servo_time_constant_s] * 3)
    c.reset(None, hold_pos_ned_m=HOLD.pos_ned_m)
    d_obs = np.concatenate([np.zeros(3), (torque - c._idle_torque) / j])
    h = 0.001
    ticks = int(round(c.config.dt_s / h))
    errors = []
    for k in range(int(round(seconds / c.config.dt_s))):
        est = StateEstimate(tuple(p), tuple(v), _euler(r), tuple(om))
        d_obs[0:3] = (force - r @ c._idle_force) / vm.mass_kg
        cmd = c.step(est, HOLD, d_obs if observe else None)
        u = np.array([cmd.throttle_pct[i] / 100.0 for i in live] + [cmd.tilt_rad[i] for i in live])
        for _ in range(ticks):
            fb, mb = (np.array(w).ravel() for w in wrench(100.0 * y[0:3], y[3:6]))
            v = v + h * ((r @ fb + force) / vm.mass_kg + g)
            p = p + h * v
            om = om + h * (mb + torque - np.cross(om, j * om)) / j
            r = r @ _exp(om * h)
            y = y + (1.0 - np.exp(-h / tau)) * (u - y)
        if k * c.config.dt_s >= seconds - 0.5:
            errors.append((float(np.linalg.norm(p - HOLD.pos_ned_m)),
                           float(om @ n) * c.direction - c.trim.spin_rad_s))
    return np.mean(errors, axis=0)


@pytest.fixture(scope="module", params=["lqr", "nmpc"])
def pair(request):
    """The spinning controller, motor 1 dead, without and with the observer's estimate."""
    cfg = dataclasses.replace(load_spin_config(CONTROLLER), inner=request.param,
                              observer_lowpass_s=0.05)
    vm = load_vehicle_model(cfg.vehicle_file)
    return SpinController(dataclasses.replace(cfg, observer_lowpass_s=None), vm, 1), \
        SpinController(cfg, vm, 1)


@pytest.mark.slow
def test_a_steady_force_is_cancelled(pair):
    """2 N from the north (about what an 8 m/s wind's drag gives), from the switch on: the
    position loop's integral alone still leaves the body tens of centimetres downwind after 3 s;
    with the estimate (its low-pass starting from none) a few centimetres."""
    without, with_it = pair
    force, torque = (2.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    off = _fly(without, False, force, torque, seconds=3.0)[0]
    on = _fly(with_it, True, force, torque, seconds=3.0)[0]
    assert off > 0.3
    assert on < 0.2 * off


@pytest.mark.slow
def test_a_torque_about_the_axis_is_cancelled(pair):
    """0.01 N m along the primary axis (a reaction torque the rotor curves get wrong): without
    the estimate the spin settles off the rate it settles at undisturbed (the LQR has no
    integral); with it, on that rate."""
    without, with_it = pair
    torque = 0.01 * np.asarray(without.trim.axis_frd)
    calm = _fly(without, False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))[1]
    off = _fly(without, False, (0.0, 0.0, 0.0), torque)[1] - calm
    on = _fly(with_it, True, (0.0, 0.0, 0.0), torque)[1] - calm
    assert abs(off) > 0.01
    assert abs(on) < 0.05 * abs(off)


def test_the_estimate_is_not_taken_while_the_observer_settles(pair):
    """For observer_settle_s after the switch the observer still carries the lost motor's
    deficit (the record: about 100 rad/s^2): fed that, the controller commands what it does
    without the estimate; from the next period on, the estimate moves its command."""
    without, with_it = pair
    n = np.asarray(with_it.trim.axis_frd)
    est = StateEstimate(HOLD.pos_ned_m, (0.0, 0.0, 0.0),
                        (math.atan2(-n[1], -n[2]), math.asin(n[0]), 0.0),
                        tuple(with_it.direction * with_it.trim.spin_rad_s * n))
    deficit = np.array([0.0, 0.0, 3.4, 100.0, -100.0, 0.0])
    without.reset(est)
    with_it.reset(est)
    settle = int(round(with_it.config.observer_settle_s / with_it.config.dt_s))
    for k in range(settle + 1):
        a = without.step(est, HOLD)
        b = with_it.step(est, HOLD, deficit)
        if k < settle:
            assert a == b
    assert a != b
