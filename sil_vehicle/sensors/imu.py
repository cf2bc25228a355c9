"""The IMU: a 3-axis gyro and a 3-axis accelerometer in body FRD, sampled at `rate_hz`.

Model (per axis, k the sample index, dt = 1 / rate_hz, w.[k] independent standard normals):

    gyro[k]  = omega[k] + bg[k] + sigma_g w_g[k] + vib_g z^2 w_vg[k]
    accel[k] = f[k]     + ba[k] + sigma_a w_a[k] + vib_a z^2 w_va[k]
    bg[k+1]  = bg[k] + rw_g sqrt(dt) w_bg[k],     bg[0] ~ N(0, turn_on_g^2)
    ba[k+1]  = ba[k] + rw_a sqrt(dt) w_ba[k],     ba[0] ~ N(0, turn_on_a^2)

with omega the body rates, f the specific force (a - g in body axes, so a level vehicle at rest
reads (0, 0, -g)), sigma = noise density * sqrt(rate_hz) (white noise over the band up to the
Nyquist frequency), rw the bias random walk density, and z the mean motor output as a fraction
of full (0..1): the rotors' vibration, taken as proportional to the mean rotor speed squared,
with rotor speed proportional to throttle; vib_g, vib_a are its std at full throttle. This is the
Kalibr / PX4 (gazebo imu plugin) continuous-time model with the bias as a pure random walk.

`initial` draws the turn-on biases once from the injected generator; `step` is a pure function
of (params, state, truth, noise) returning the next state and the reading.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sil_vehicle.sensors.noise import random_walk_std, white_std
from sil_vehicle.sensors.truth import Truth

__all__ = ["ImuParams", "ImuState", "ImuReading", "NOISE", "initial", "draw", "step"]

NOISE = 18      # standard normals per sample: w_g, w_a, w_vg, w_va, w_bg, w_ba (3 each)


@dataclass(frozen=True)
class ImuParams:
    rate_hz: int
    gyro_noise_density_rad_s_rthz: float
    gyro_bias_random_walk_rad_s2_rthz: float
    gyro_turn_on_bias_rad_s: float
    gyro_vibration_rad_s: float
    accel_noise_density_m_s2_rthz: float
    accel_bias_random_walk_m_s3_rthz: float
    accel_turn_on_bias_m_s2: float
    accel_vibration_m_s2: float

    # derived once (per-sample standard deviations)
    period_us: int = field(init=False)
    gyro_white_rad_s: float = field(init=False)
    accel_white_m_s2: float = field(init=False)
    gyro_bias_step_rad_s: float = field(init=False)
    accel_bias_step_m_s2: float = field(init=False)

    def __post_init__(self) -> None:
        dt = 1.0 / self.rate_hz
        for name, value in (
                ("period_us", 1_000_000 // self.rate_hz),
                ("gyro_white_rad_s", white_std(self.gyro_noise_density_rad_s_rthz, self.rate_hz)),
                ("accel_white_m_s2", white_std(self.accel_noise_density_m_s2_rthz, self.rate_hz)),
                ("gyro_bias_step_rad_s",
                 random_walk_std(self.gyro_bias_random_walk_rad_s2_rthz, dt)),
                ("accel_bias_step_m_s2",
                 random_walk_std(self.accel_bias_random_walk_m_s3_rthz, dt))):
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class ImuState:
    gyro_bias_frd_rad_s: np.ndarray     # (3,)
    accel_bias_frd_m_s2: np.ndarray     # (3,)


@dataclass(frozen=True)
class ImuReading:
    t_us: int                           # time of validity (no delay: also its arrival)
    gyro_frd_rad_s: np.ndarray          # (3,)
    accel_frd_m_s2: np.ndarray          # (3,) specific force

    @property
    def arrival_us(self) -> int:
        return self.t_us


def initial(params: ImuParams, rng: np.random.Generator) -> ImuState:
    """The turn-on biases, drawn once."""
    w = rng.standard_normal(6)
    return ImuState(params.gyro_turn_on_bias_rad_s * w[:3], params.accel_turn_on_bias_m_s2 * w[3:])


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def step(p: ImuParams, s: ImuState, truth: Truth, w: np.ndarray) -> tuple[ImuState, ImuReading]:
    n = truth.motor_pct.size
    z = float(truth.motor_pct.sum()) / (100.0 * n) if n else 0.0
    z2 = z * z
    gyro = (truth.rates_frd_rad_s + s.gyro_bias_frd_rad_s + p.gyro_white_rad_s * w[0:3]
            + p.gyro_vibration_rad_s * z2 * w[6:9])
    accel = (truth.specific_force_frd_m_s2 + s.accel_bias_frd_m_s2 + p.accel_white_m_s2 * w[3:6]
             + p.accel_vibration_m_s2 * z2 * w[9:12])
    nxt = ImuState(s.gyro_bias_frd_rad_s + p.gyro_bias_step_rad_s * w[12:15],
                   s.accel_bias_frd_m_s2 + p.accel_bias_step_m_s2 * w[15:18])
    return nxt, ImuReading(truth.t_us, gyro, accel)
