"""Motion capture: the pose only (NED position, attitude quaternion) at `rate_hz`, arriving
`latency_ticks` physics ticks after its time of validity, with white noise and dropouts.

Model (k the sample index, w.[k] independent standard normals, u[k] uniform on [0, 1)):

    pos[k]   = p[k] + sigma_p w_p[k]
    q[k]     = q_true[k] * exp(sigma_a w_a[k] / 2)        (a small body-frame rotation)
    dropped  = u[k] < dropout_probability  or  t[k] in a scripted window [start, end)

A dropped sample produces no reading (the estimator sees a gap, as with a lost marker set); the
noise is drawn for it all the same, so a dropout never shifts the random stream.

The arithmetic is in plain floats where NumPy's per-call cost outweighs it (the same operations
in the same order: the same readings bit for bit); `draw` fills one array in the stream's order
(six normals, then the uniform).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sil_vehicle.sensors import delay
from sil_vehicle.sensors.noise import perturb_quat
from sil_vehicle.sensors.truth import Truth

__all__ = ["MocapParams", "MocapState", "MocapReading", "NOISE", "initial", "draw", "sample",
           "release", "dropped"]

NOISE = 7       # w_p, w_a (3 each), then u (uniform)


@dataclass(frozen=True)
class MocapParams:
    rate_hz: int
    latency_ticks: int
    dt_us: int
    position_noise_m: float
    attitude_noise_rad: float
    dropout_probability: float
    dropout_windows_us: tuple[tuple[int, int], ...] = ()    # [start, end)

    @property
    def period_us(self) -> int:
        return 1_000_000 // self.rate_hz

    @property
    def latency_us(self) -> int:
        return self.latency_ticks * self.dt_us

    @property
    def capacity(self) -> int:
        return delay.capacity(self.latency_ticks, self.period_us // self.dt_us)


@dataclass(frozen=True)
class MocapState:
    pending: tuple["MocapReading", ...] = ()


@dataclass(frozen=True)
class MocapReading:
    t_us: int
    arrival_us: int
    pos_ned_m: np.ndarray           # (3,)
    quat_wxyz: np.ndarray           # (4,)
    # the variances the pose reports, when its message carries them (VISION_POSITION_ESTIMATE's
    # covariance; None: none): the estimator floors them by EKF2_EVP_NOISE / EKF2_EVA_NOISE
    pos_var_m2: float | None = None
    att_var_rad2: float | None = None


def initial(params: MocapParams, rng: np.random.Generator) -> MocapState:
    return MocapState()


def draw(rng: np.random.Generator) -> np.ndarray:
    w = np.empty(NOISE)
    rng.standard_normal(out=w[:6])
    w[6] = rng.random()
    return w


def dropped(p: MocapParams, t_us: int, u: float) -> bool:
    if u < p.dropout_probability:
        return True
    for a, b in p.dropout_windows_us:
        if a <= t_us < b:
            return True
    return False


def sample(p: MocapParams, s: MocapState, truth: Truth, w: np.ndarray) -> MocapState:
    t_us = truth.t_us
    if dropped(p, t_us, float(w[6])):
        return s
    sigma = p.position_noise_m
    n, e, d = truth.pos
    w0, w1, w2 = w[0:3].tolist()
    reading = MocapReading(t_us, t_us + p.latency_us,
                           np.array((n + sigma * w0, e + sigma * w1, d + sigma * w2)),
                           perturb_quat(truth.quat, p.attitude_noise_rad * w[3:6]))
    return MocapState(delay.push(s.pending, reading, p.capacity))


def release(s: MocapState, t_us: int) -> tuple[MocapState, tuple[MocapReading, ...]]:
    pending, out = delay.release(s.pending, t_us)
    return MocapState(pending), out
