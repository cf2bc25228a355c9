"""Discrete-time noise of the sensor models: continuous-time figures (the datasheets' and the
simulators' densities) turned into per-sample standard deviations, and the small rotations the
attitude noise needs. Pure functions; the standard normal samples arrive as arguments.

    white_std(density, rate_hz)           sigma_d = density * sqrt(rate)
    random_walk_std(rw, dt_s)             sigma_b = rw * sqrt(dt)
    markov_coefficients(sigma, tau, dt)   x[k+1] = a x[k] + b w[k], a = exp(-dt / tau),
                                          b = sigma * sqrt(1 - a^2) (exact: the stationary
                                          std is sigma at any dt)
"""

from __future__ import annotations

import math

import numpy as np

from sil_vehicle.frames import quat_to_dcm

__all__ = ["white_std", "random_walk_std", "markov_coefficients", "rotate_to_body",
           "perturb_quat"]


def white_std(density: float, rate_hz: float) -> float:
    """Per-sample std of white noise of one-sided density `density` (unit/sqrt(Hz)) sampled at
    `rate_hz`: sigma = density / sqrt(dt) = density * sqrt(rate), the usual discretisation of
    a continuous white noise of that density held over one sample (Kalibr's IMU noise model;
    PX4's gazebo IMU plugin)."""
    return density * math.sqrt(rate_hz)


def random_walk_std(rw: float, dt_s: float) -> float:
    """Per-sample std of the increment of a random walk of density `rw` (unit/s/sqrt(Hz))."""
    return rw * math.sqrt(dt_s)


def markov_coefficients(sigma: float, tau_s: float, dt_s: float) -> tuple[float, float]:
    """(a, b) of a first-order Gauss-Markov process of stationary std `sigma` and correlation
    time `tau_s`, discretised exactly at step `dt_s`."""
    a = math.exp(-dt_s / tau_s)
    return a, sigma * math.sqrt(max(0.0, 1.0 - a * a))


def rotate_to_body(quat_wxyz: np.ndarray, v_ned: np.ndarray) -> np.ndarray:
    """A world NED vector seen in body FRD: R(q)^T v (R from sil_vehicle.frames)."""
    return np.array(quat_to_dcm(*quat_wxyz)).T @ v_ned


def perturb_quat(quat_wxyz, angle_frd_rad: np.ndarray) -> np.ndarray:
    """q * exp(angle / 2): the attitude turned by the small body-frame rotation vector
    `angle_frd_rad` (the attitude error of a pose sensor), normalised. The norms are
    np.linalg.norm's own computation (sqrt of the vector's dot with itself), spelled out to
    spare its overhead; the rest in plain floats."""
    a = np.asarray(angle_frd_rad, dtype=float)
    theta = math.sqrt(a.dot(a))
    if theta == 0.0:
        return np.array(quat_wxyz, dtype=float)
    s = math.sin(theta / 2) / theta
    ax, ay, az = a.tolist()
    dw, dx, dy, dz = math.cos(theta / 2), s * ax, s * ay, s * az
    w, x, y, z = quat_wxyz
    q = np.array((w * dw - x * dx - y * dy - z * dz, w * dx + x * dw + y * dz - z * dy,
                  w * dy - x * dz + y * dw + z * dx, w * dz + x * dy - y * dx + z * dw))
    return q / math.sqrt(q.dot(q))
