"""Allan deviation of an IMU at rest, and the vehicle's IMU model run at rest.

    t_us, gyro, accel = static_recording(imu_params, duration_s=3600, seed=7)
    fit = allan_fit(gyro, rate_hz)          # per axis: N, B, K and the curve they come from

The terms read off the overlapping Allan deviation sigma(tau) (IEEE Std 952, Annex C; the
same reading as Kalibr's and imu_utils' notes):

    white noise (angle / velocity random walk)   sigma^2 = N^2 / tau     N: the line at 1 s
    bias instability (flicker)                   sigma   = 0.664 B       B: the minimum / 0.664
    bias random walk (rate / accel random walk)  sigma^2 = K^2 tau / 3   K: the line at 3 s

N and K come from a weighted least-squares fit of sigma^2 = N^2 / tau + C + K^2 tau / 3 over every
tau (weights: each point's own confidence, the number of independent clusters, so the long taus
count for what they are worth), not from the raw curve at 1 s and 3 s, where the other terms
still add; B is the curve's minimum / 0.664 as the standard reads it. The vehicle's IMU model
(sil_vehicle.sensors.imu) has white noise and a bias random walk and no flicker term: its
"bias instability" is the flat minimum the two make, sqrt(2 N K / sqrt(3)) / 0.664
(`model_bias_instability`), and that is what a recording from a profile must give back.

`static_recording` is that model at rest (no rotation, specific force (0, 0, -g), motors off),
one physics tick per sample: the model's own `sil_vehicle.sensors.imu.noise_block` over blocks of
standard normals (the same stream as a draw per tick), truth added and the full scales applied as
`imu.step` does: an hour at 1 kHz in seconds. The vibration lines are the rotors' and their
amplitude scales with each rotor's thrust fraction (zero with the motors stopped: the vehicle's
thrust curve is clamped at zero there), so at rest the model is bias plus white noise; the
vibration is read from a flight's spectra instead (trq_lab.reallogs.calibrate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sil_vehicle.sensors import imu
from sil_vehicle.sensors.imu import ImuParams
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2

__all__ = ["AllanFit", "allan_fit", "model_bias_instability", "static_recording",
           "relative_sigma"]

_BLOCK = 100_000        # samples per NumPy block of the static recording (memory, not results)
BIAS_INSTABILITY_FACTOR = 0.664     # sqrt(2 ln 2 / pi): IEEE Std 952's flicker floor factor


def static_recording(p: ImuParams, duration_s: float, seed: int) -> tuple[np.ndarray, np.ndarray,
                                                                            np.ndarray]:
    """(t_us (n,), gyro (n, 3) rad/s, accel (n, 3) m/s^2) of the IMU model at rest, level, one
    physics tick per sample (`p` at its own rate: ticks_per_sample 1; a ValueError otherwise)."""
    if p.ticks_per_sample != 1:
        raise ValueError(f"static_recording: the IMU at {p.rate_hz} Hz over a physics rate of "
                         f"{p.physics_rate_hz} Hz; load the profile at the IMU's rate")
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * p.rate_hz))
    state = imu.initial(p, rng)         # the turn-on biases
    gyro, accel = np.empty((n, 3)), np.empty((n, 3))
    rest = np.array((0.0, 0.0, 0.0, 0.0, 0.0, -STANDARD_GRAVITY_M_S2))
    for s in range(0, n, _BLOCK):
        k = min(_BLOCK, n - s)
        # bias plus white noise per tick, the model's own arithmetic (imu.noise_block); the
        # rotors stopped: no vibration lines (their amplitude scales with thrust, zero at rest)
        adds, bias = imu.noise_block(p, state, rng.standard_normal((k, imu.NOISE)))
        g = rest[:3] + (adds[:, :3] + 0.0)
        a = rest[3:] + (adds[:, 3:] + 0.0)
        gyro[s:s + k] = np.clip(g, -p.gyro_full_scale_rad_s, p.gyro_full_scale_rad_s)
        accel[s:s + k] = np.clip(a, -p.accel_full_scale_m_s2, p.accel_full_scale_m_s2)
        state = imu.ImuState(bias[-1, :3].copy(), bias[-1, 3:].copy())
    t_us = (np.arange(1, n + 1, dtype=np.int64) * p.period_us)
    return t_us, gyro, accel


def model_bias_instability(n_density: float, k_rw: float) -> float:
    """The flat minimum of sqrt(N^2 / tau + K^2 tau / 3), divided by 0.664."""
    return math.sqrt(2.0 * n_density * k_rw / math.sqrt(3.0)) / BIAS_INSTABILITY_FACTOR


def relative_sigma(duration_s: float, tau_s: float) -> float:
    """One Allan deviation point's relative standard error, 1 / sqrt(2 (T / tau - 1)) (IEEE Std
    952, Annex C: the clusters of length tau in a record of length T)."""
    return 1.0 / math.sqrt(max(2.0 * (duration_s / tau_s - 1.0), 1e-9))


@dataclass(frozen=True)
class AllanFit:
    taus_s: np.ndarray              # (m,)
    adev: np.ndarray                # (m, 3) per axis
    n_density: np.ndarray           # (3,) N, units/sqrt(Hz)
    bias_instability: np.ndarray    # (3,) B
    tau_min_s: np.ndarray           # (3,) where the minimum is
    k_random_walk: np.ndarray       # (3,) K, units sqrt(Hz)/s
    duration_s: float

    def mean(self, name: str) -> float:
        """The axes' root mean square (the profile's figure is one per sensor)."""
        v = getattr(self, name)
        return float(np.sqrt(np.mean(v * v)))


def _fit_axis(taus: np.ndarray, adev: np.ndarray, duration_s: float) -> tuple[float, float]:
    """N and K from sigma^2 = N^2 / tau + C + K^2 tau / 3, weighted by each point's confidence,
    the terms kept non-negative (a term fitted negative is dropped and the rest refitted)."""
    var = adev ** 2
    sig = np.array([relative_sigma(duration_s, t) for t in taus]) * 2 * var    # of sigma^2
    basis = np.column_stack((1.0 / taus, np.ones_like(taus), taus / 3.0))
    active = [0, 1, 2]
    while True:
        a = basis[:, active] / sig[:, None]
        coef, *_ = np.linalg.lstsq(a, var / sig, rcond=None)
        if (coef >= 0).all() or len(active) == 1:
            break
        active.pop(int(np.argmin(coef)))
    full = dict(zip(active, np.maximum(coef, 0.0)))
    return math.sqrt(full.get(0, 0.0)), math.sqrt(full.get(2, 0.0))


def allan_fit(data: np.ndarray, rate_hz: float) -> AllanFit:
    """The overlapping Allan deviation of each column of `data` (n, 3), a rate or a specific
    force sampled at `rate_hz`, and its N, B, K."""
    import allantools  # a well-kept Allan deviation library (pyproject: dependencies)

    n = len(data)
    duration = n / rate_hz
    # octave-spaced taus up to a ninth of the record (at least nine clusters: IEEE's advice)
    taus = np.unique(np.round(np.logspace(0, math.log10(n / 9), 40)).astype(int)) / rate_hz
    out = []
    for i in range(data.shape[1]):
        t, ad, _, _ = allantools.oadev(np.ascontiguousarray(data[:, i]), rate=rate_hz,
                                       data_type="freq", taus=taus)
        out.append((np.asarray(t), np.asarray(ad)))
    taus = out[0][0]
    adev = np.column_stack([o[1][:len(taus)] for o in out])
    ns, ks, bs, tm = [], [], [], []
    for i in range(adev.shape[1]):
        nn, kk = _fit_axis(taus, adev[:, i], duration)
        j = int(np.argmin(adev[:, i]))
        ns.append(nn)
        ks.append(kk)
        bs.append(adev[j, i] / BIAS_INSTABILITY_FACTOR)
        tm.append(taus[j])
    return AllanFit(taus, adev, np.array(ns), np.array(bs), np.array(tm), np.array(ks), duration)
