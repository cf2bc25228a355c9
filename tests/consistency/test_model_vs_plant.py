"""The controller's CasADi model against the truth plant with its extras off (zero wind, no lags):
accelerations agree to ~1e-9 relative at random states and inputs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sil_vehicle.config import load_vehicle
from sil_vehicle.dynamics.rigid_body import derivative
from sil_vehicle.dynamics.rotors import body_wrench
from sil_vehicle.frames import euler_to_quat, quat_to_euler
from trq_offboard.config import load_vehicle_model
from trq_offboard.model import PredictionModel

VEH = Path(__file__).resolve().parents[2] / "params" / "vehicle"


@pytest.mark.parametrize("airframe", ["trq", "quad"])
def test_wrench_and_accelerations_match_plant(airframe):
    vp = load_vehicle(VEH / f"{airframe}.yaml")
    model = PredictionModel(load_vehicle_model(VEH / f"{airframe}.yaml"))
    rng = np.random.default_rng(7)
    for _ in range(25):
        roll, pitch = rng.uniform(-0.6, 0.6, 2)
        yaw = rng.uniform(-math.pi, math.pi)
        pos, vel, rates = rng.normal(0, 3, 3), rng.normal(0, 3, 3), rng.normal(0, 2, 3)
        zeta = rng.uniform(12.0, 100.0, 4)          # above the torque curve's root (11.1 %)
        alpha = rng.uniform(vp.tilt_min_rad, vp.tilt_max_rad, 4) if not vp.tilt_locked \
            else np.zeros(4)
        u = np.concatenate([alpha, zeta]) if not vp.tilt_locked else zeta
        w_plant = np.array(body_wrench(zeta, alpha, vp))
        w_model = np.asarray(model.wrench(u)).ravel()
        np.testing.assert_allclose(w_model, w_plant, rtol=1e-12, atol=1e-12)

        q = euler_to_quat(roll, pitch, yaw)
        x13 = (*pos, *vel, *q, *rates)
        dx = np.array(derivative(x13, w_plant, (0.0, 0.0, 0.0), vp.mass_kg, vp.inertia_kg_m2,
                                 vp.gravity_m_s2, vp.drag_N_s2_m2))
        x12 = np.array([*pos, *vel, roll, pitch, yaw, *rates])
        f = np.asarray(model.f(x12, u, np.zeros(6))).ravel()
        np.testing.assert_allclose(f[0:3], dx[0:3], rtol=1e-12)
        np.testing.assert_allclose(f[3:6], dx[3:6], rtol=1e-9, atol=1e-9 * np.abs(dx[3:6]).max())
        np.testing.assert_allclose(f[9:12], dx[10:13], rtol=1e-9,
                                   atol=1e-9 * np.abs(dx[10:13]).max())
        # Euler rates: differentiate the plant's quaternion motion through its own conversion
        eps = 1e-6
        qp = np.array(q) + eps * dx[6:10]
        qm = np.array(q) - eps * dx[6:10]
        e_p = np.array(quat_to_euler(*(qp / np.linalg.norm(qp))))
        e_m = np.array(quat_to_euler(*(qm / np.linalg.norm(qm))))
        d_eta = (e_p - e_m + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_allclose(f[6:9], d_eta / (2 * eps), rtol=1e-7, atol=1e-8)


def test_disturbance_enters_as_documented():
    model = PredictionModel(load_vehicle_model(VEH / "trq.yaml"))
    x = np.zeros(12)
    x[6:9] = (0.2, -0.1, 0.5)
    u = np.array([0.1, -0.1, 0.05, 0.0, 70, 75, 80, 72.0])
    d = np.array([0.3, -0.2, 0.1, 2.0, -1.0, 0.5])
    f0 = np.asarray(model.f(x, u, np.zeros(6))).ravel()
    f1 = np.asarray(model.f(x, u, d)).ravel()
    np.testing.assert_allclose(f1 - f0, np.concatenate([np.zeros(3), d[0:3], np.zeros(3),
                                                        d[3:6]]), atol=1e-12)


def test_rk4_matches_plant_integration_without_extras():
    """One 0.05 s step of the model's RK4 against 50 plant RK4 ticks of 1 ms, fixed wrench."""
    from sil_vehicle.dynamics.rigid_body import rk4_step
    vp = load_vehicle(VEH / "trq.yaml")
    model = PredictionModel(load_vehicle_model(VEH / "trq.yaml"))
    F = model.discrete(0.05, 10)
    u = np.array([0.05, -0.02, 0.1, -0.1, 78, 76, 77, 79.0])
    alpha, zeta = u[0:4], u[4:8]
    x13 = (0.0, 0.0, -2.0, 0.5, -0.3, 0.1, *euler_to_quat(0.1, -0.05, 0.3), 0.2, -0.1, 0.3)
    wrench = body_wrench(zeta, alpha, vp)
    xs = x13
    for _ in range(50):
        xs = rk4_step(xs, 0.001, wrench, (0.0, 0.0, 0.0), vp.mass_kg, vp.inertia_kg_m2,
                      vp.gravity_m_s2, vp.drag_N_s2_m2)
    x12 = np.array([*x13[0:6], 0.1, -0.05, 0.3, *x13[10:13]])
    xm = np.asarray(F(x12, u, np.zeros(6))).ravel()
    np.testing.assert_allclose(xm[0:6], xs[0:6], atol=1e-8)
    np.testing.assert_allclose(xm[6:9], quat_to_euler(*xs[6:10]), atol=1e-8)
    np.testing.assert_allclose(xm[9:12], xs[10:13], atol=1e-8)
