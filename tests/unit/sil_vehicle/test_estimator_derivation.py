"""The estimator's symbolic equations (sil_vehicle.estimator.derivation) against a numerical
reference: the error-state Jacobians F, G and each measurement's H against central finite
differences of the nominal equations through an error injection written here in NumPy (exact
quaternion exponential and logarithm), the nominal propagation against a NumPy transcription,
and the generated covariance prediction and fusions against their matrix formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.estimator import derivation as d
from sil_vehicle.estimator.codegen import load
from sil_vehicle.frames import quat_to_dcm, quat_to_euler
from sil_vehicle.sensors.noise import perturb_quat

G = 9.80665
EPS = 1e-6


def qmul(a, b):
    return np.array(d.quat_mul(a, b), float)


def qconj(q):
    return np.array((q[0], -q[1], -q[2], -q[3]))


def qlog(q):
    """The rotation vector of a unit quaternion (exact)."""
    q = q if q[0] >= 0 else -q
    n = np.linalg.norm(q[1:])
    return np.zeros(3) if n == 0 else 2 * math.atan2(n, q[0]) * q[1:] / n


def inject(x, dx):
    out = x + np.concatenate((dx[:6], np.zeros(1), dx[6:]))   # all but q add
    out[6:10] = perturb_quat(x[6:10], dx[6:9])
    return out


def diff(xr, x):
    e = np.concatenate((x[:6] - xr[:6], qlog(qmul(qconj(xr[6:10]), x[6:10])), x[10:] - xr[10:]))
    return e


@pytest.fixture(scope="module")
def fns():
    return d.functions(G)


@pytest.fixture(scope="module")
def calls(fns):
    return load(fns)[0]


def random_state(rng):
    x = rng.normal(size=d.NX)
    x[6:10] /= np.linalg.norm(x[6:10])
    x[10:13] *= 0.01
    x[13:16] *= 0.2
    return x


def nominal_np(x, dA, dV, dt, a):
    """The nominal equations (derivation's docstring), with the exact quaternion exponential."""
    q = perturb_quat(x[6:10], dA - x[10:13] * dt)
    v = x[3:6] + np.array(quat_to_dcm(*x[6:10])) @ (dV - x[13:16] * dt) + np.array((0, 0, G)) * dt
    a_gnss, a_baro, bb_ref = a
    return np.concatenate((x[0:3] + (x[3:6] + v) * dt / 2, v, q, x[10:16], a_gnss * x[16:19],
                           bb_ref + a_baro * (x[19:] - bb_ref)))


A_IN = np.array((0.99, 0.97, 1.3))      # (a_gnss, a_baro, bb_ref)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nominal_matches_numpy(fns, seed):
    rng = np.random.default_rng(seed)
    x, dA, dV = random_state(rng), rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1
    got = np.array(fns["nominal"](x, dA, dV, 0.01, A_IN)).ravel()
    np.testing.assert_allclose(got, nominal_np(x, dA, dV, 0.01, A_IN), rtol=0, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_transition_against_finite_differences(fns, seed):
    """F = d diff(f(x), f(inject(x, dx))) / d dx and G (noise on dA, dV), column by column."""
    rng = np.random.default_rng(seed)
    x, dA, dV = random_state(rng), rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1
    dt, a = 0.01, np.array((0.995, 0.98, 0.7))
    F, Gm = (np.array(m) for m in fns["transition"](x, dA, dV, dt, a))
    f0 = nominal_np(x, dA, dV, dt, a)
    F_fd = np.zeros((d.NDX, d.NDX))
    for j in range(d.NDX):
        e = np.zeros(d.NDX)
        e[j] = EPS
        F_fd[:, j] = (diff(f0, nominal_np(inject(x, e), dA, dV, dt, a))
                      - diff(f0, nominal_np(inject(x, -e), dA, dV, dt, a))) / (2 * EPS)
    G_fd = np.zeros((d.NDX, 6))
    for j in range(6):
        n = np.zeros(6)
        n[j] = EPS
        G_fd[:, j] = (diff(f0, nominal_np(x, dA + n[:3], dV + n[3:], dt, a))
                      - diff(f0, nominal_np(x, dA - n[:3], dV - n[3:], dt, a))) / (2 * EPS)
    np.testing.assert_allclose(F, F_fd, rtol=0, atol=1e-7)
    np.testing.assert_allclose(Gm, G_fd, rtol=0, atol=1e-7)


def h_np(name, x, q_ref, m_ned):
    R = np.array(quat_to_dcm(*x[6:10]))
    return {"mocap_pos": x[0:3], "gnss_pos": x[0:3] + x[16:19], "gnss_vel": x[3:6],
            "mocap_att": qlog(qmul(qconj(q_ref), x[6:10])), "baro": np.array((-x[2] + x[19],)),
            "mag": R.T @ m_ned, "ev_yaw": np.array((quat_to_euler(*x[6:10])[2],))}[name]


@pytest.mark.parametrize("name", d.MEASUREMENTS)
def test_measurement_jacobians_against_finite_differences(fns, name):
    rng = np.random.default_rng(7)
    x, m_ned = random_state(rng), np.array((0.2, 0.01, 0.45))
    q_ref = x[6:10]
    h, H = (np.array(m) for m in fns[f"h_{name}"](x, q_ref, m_ned))
    np.testing.assert_allclose(h.ravel(), h_np(name, x, q_ref, m_ned), atol=1e-12)
    H_fd = np.zeros_like(H)
    for j in range(d.NDX):
        e = np.zeros(d.NDX)
        e[j] = EPS
        H_fd[:, j] = (h_np(name, inject(x, e), q_ref, m_ned)
                      - h_np(name, inject(x, -e), q_ref, m_ned)) / (2 * EPS)
    np.testing.assert_allclose(H, H_fd, rtol=0, atol=1e-8)


def spd(rng, n=d.NDX):
    A = rng.normal(size=(n, n)) * 0.1
    return A @ A.T + 0.01 * np.eye(n)


def test_predict_is_the_covariance_formula(calls, fns):
    rng = np.random.default_rng(3)
    x, P = random_state(rng), spd(rng)
    dA, dV, qd = rng.normal(size=3) * 0.05, rng.normal(size=3) * 0.1, rng.uniform(1e-6, 1e-4, d.NQD)
    x1, P1 = (m.copy() for m in calls["predict"](x, P, dA, dV, 0.01, A_IN, qd))
    F, Gm = (np.array(m) for m in fns["transition"](x, dA, dV, 0.01, A_IN))
    Qd = np.diag(np.concatenate((np.zeros(9), np.full(3, qd[4]), np.full(3, qd[5]),
                                 (qd[6], qd[6], qd[7], qd[8]))))
    want = F @ P @ F.T + Gm @ np.diag(np.r_[np.repeat(qd[0], 3), qd[1:4]]) @ Gm.T + Qd
    np.testing.assert_allclose(P1, want, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(P1, P1.T)
    np.testing.assert_allclose(x1.ravel(), nominal_np(x, dA, dV, 0.01, A_IN), atol=1e-10)


@pytest.mark.parametrize("name", d.MEASUREMENTS)
def test_fusion_is_the_joseph_update(calls, fns, name):
    rng = np.random.default_rng(11)
    x, P, m_ned = random_state(rng), spd(rng), np.array((0.2, 0.01, 0.45))
    h, H = (np.array(m) for m in fns[f"h_{name}"](x, x[6:10], m_ned))
    m = h.size
    r = rng.uniform(0.01, 0.1, m)
    if name == "mocap_att":
        z = perturb_quat(x[6:10], np.array((0.01, -0.02, 0.005)))
        y_want = qlog(qmul(qconj(x[6:10]), z))
    elif name == "ev_yaw":
        z = perturb_quat(x[6:10], np.array((0.01, -0.02, 0.005)))
        dyaw = quat_to_euler(*z)[2] - quat_to_euler(*x[6:10])[2]
        y_want = np.array((math.atan2(math.sin(dyaw), math.cos(dyaw)),))
    else:
        z = h.ravel() + rng.normal(size=m) * 0.1
        y_want = z - h.ravel()
    y, s, x1, P1 = (a.copy() for a in calls[f"fuse_{name}"](x, P, z, r, m_ned))
    S = H @ P @ H.T + np.diag(r)
    K = P @ H.T @ np.linalg.inv(S)
    ikh = np.eye(d.NDX) - K @ H
    np.testing.assert_allclose(y.ravel(), y_want, atol=1e-6 if name == "mocap_att" else 1e-12)
    np.testing.assert_allclose(s.ravel(), np.diag(S), rtol=1e-12)
    np.testing.assert_allclose(P1, ikh @ P @ ikh.T + K @ np.diag(r) @ K.T, rtol=1e-9,
                               atol=1e-12)
    x_want = inject(x, K @ y.ravel())
    np.testing.assert_allclose(x1.ravel(), x_want, atol=1e-9)
