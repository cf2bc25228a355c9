"""The magnetometer: the earth's field, fixed in NED, seen in body FRD, plus a bias and noise.

Model (k the sample index, dt = 1 / rate_hz, w.[k] independent standard normals, per axis):

    m_ned    = F (cos I cos D, cos I sin D, sin I)          F field, D declination, I inclination
    mag[k]   = R(q[k])^T m_ned + b[k] + sigma w_m[k],       sigma = noise density * sqrt(rate)
    b[k+1]   = b[k] + rw sqrt(dt) w_b[k],                   b[0] ~ N(0, turn_on^2)

(PX4's gazebo magnetometer plugin has the same parts, its bias as a Gauss-Markov process.)

The sums are in plain floats (NumPy's per-call cost outweighs the arithmetic on 3-vectors; the
same operations in the same order, so the same readings bit for bit); the rotation stays
NumPy's product.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sil_vehicle.sensors.noise import random_walk_std, rotate_to_body, white_std
from sil_vehicle.sensors.truth import Truth

__all__ = ["MagParams", "MagState", "MagReading", "NOISE", "initial", "draw", "step"]

NOISE = 6       # w_m, w_b (3 each)


@dataclass(frozen=True)
class MagParams:
    rate_hz: int
    field_gauss: float
    declination_rad: float
    inclination_rad: float
    noise_density_gauss_rthz: float
    bias_random_walk_gauss_s_rthz: float
    turn_on_bias_gauss: float

    # derived once
    period_us: int = field(init=False)
    field_ned_gauss: np.ndarray = field(init=False, compare=False)     # (3,)
    white_gauss: float = field(init=False)
    bias_step_gauss: float = field(init=False)

    def __post_init__(self) -> None:
        ci = math.cos(self.inclination_rad)
        m = self.field_gauss * np.array((ci * math.cos(self.declination_rad),
                                         ci * math.sin(self.declination_rad),
                                         math.sin(self.inclination_rad)))
        m.flags.writeable = False
        for name, value in (
                ("period_us", 1_000_000 // self.rate_hz), ("field_ned_gauss", m),
                ("white_gauss", white_std(self.noise_density_gauss_rthz, self.rate_hz)),
                ("bias_step_gauss",
                 random_walk_std(self.bias_random_walk_gauss_s_rthz, 1.0 / self.rate_hz))):
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class MagState:
    bias_frd_gauss: np.ndarray      # (3,)


@dataclass(frozen=True)
class MagReading:
    t_us: int
    field_frd_gauss: np.ndarray     # (3,)

    @property
    def arrival_us(self) -> int:
        return self.t_us


def initial(params: MagParams, rng: np.random.Generator) -> MagState:
    return MagState(params.turn_on_bias_gauss * rng.standard_normal(3))


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def step(p: MagParams, s: MagState, truth: Truth, w: np.ndarray) -> tuple[MagState, MagReading]:
    r0, r1, r2 = rotate_to_body(truth.quat, p.field_ned_gauss).tolist()
    b0, b1, b2 = s.bias_frd_gauss.tolist()
    w0, w1, w2, w3, w4, w5 = w.tolist()
    sw, sb = p.white_gauss, p.bias_step_gauss
    m = np.array((r0 + b0 + sw * w0, r1 + b1 + sw * w1, r2 + b2 + sw * w2))
    return (MagState(np.array((b0 + sb * w3, b1 + sb * w4, b2 + sb * w5))),
            MagReading(truth.t_us, m))
