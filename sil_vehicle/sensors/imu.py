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

The IMU samples every physics tick, so its step is split for speed, the arithmetic unchanged
(the same floating-point operations in the same order, so the same readings bit for bit):
`noise_block` turns the standard normals of K samples (one (K, 18) draw, the same stream as K
draws of 18) into what each sample adds, with NumPy over the whole block: the bias it sees (the
random walk, a sequential `np.add.accumulate`), its scaled white noise and its vibration
normals; `measure` then makes one reading from the tick's truth in plain floats (NumPy costs
more per call than the arithmetic on 3-vectors), and the reading keeps them as floats (`gyro`,
`accel`; the arrays `gyro_frd_rad_s`, `accel_frd_m_s2` are built when read). `step` is the two
for one sample; the sensor suite calls them per block and per tick.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from sil_vehicle.sensors.noise import random_walk_std, white_std
from sil_vehicle.sensors.truth import Truth

__all__ = ["ImuParams", "ImuState", "ImuReading", "NOISE", "initial", "draw", "step",
           "noise_block", "measure", "mean_throttle"]

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
    integration_rate_hz: int = 200      # HIGHRES_IMU's interval (PX4's IMU_INTEG_RATE)

    # derived once (per-sample standard deviations)
    period_us: int = field(init=False)
    samples_per_interval: int = field(init=False)     # the integration interval, in samples
    gyro_white_rad_s: float = field(init=False)
    accel_white_m_s2: float = field(init=False)
    gyro_bias_step_rad_s: float = field(init=False)
    accel_bias_step_m_s2: float = field(init=False)

    def __post_init__(self) -> None:
        dt = 1.0 / self.rate_hz
        for name, value in (
                ("period_us", 1_000_000 // self.rate_hz),
                ("samples_per_interval", max(1, round(self.rate_hz / self.integration_rate_hz))),
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
    """One IMU sample. Its vectors are held as the floats the model computes (a reading is
    built every physics tick, and a consumer at that rate wants floats); the arrays are built on
    access."""
    t_us: int                           # time of validity (no delay: also its arrival)
    gyro: Sequence[float]               # (3,) body FRD rates, rad/s
    accel: Sequence[float]              # (3,) specific force, body FRD, m/s^2
    # the sample's interval (us; 0: the IMU's nominal period) and which axes clipped in it
    # (the names the IMU's integrating model fills; the estimator reads them)
    dt_us: int = 0
    accel_clipped: tuple[bool, bool, bool] = (False, False, False)
    gyro_clipped: tuple[bool, bool, bool] = (False, False, False)

    @property
    def arrival_us(self) -> int:
        return self.t_us

    @property
    def gyro_frd_rad_s(self) -> np.ndarray:     # (3,), a new array per access
        return np.array(self.gyro, dtype=float)

    @property
    def accel_frd_m_s2(self) -> np.ndarray:     # (3,), a new array per access
        return np.array(self.accel, dtype=float)


def initial(params: ImuParams, rng: np.random.Generator) -> ImuState:
    """The turn-on biases, drawn once."""
    w = rng.standard_normal(6)
    return ImuState(params.gyro_turn_on_bias_rad_s * w[:3], params.accel_turn_on_bias_m_s2 * w[3:])


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def noise_block(p: ImuParams, s: ImuState,
                w: np.ndarray) -> tuple[list[list[float]], ImuState]:
    """What each of K samples adds, from their standard normals `w` (K, NOISE) and the state
    before the first: per sample the list [bg (3), ba (3), sigma_g w_g (3), sigma_a w_a (3),
    w_vg (3), w_va (3)]; and the state after the K-th."""
    k = len(w)
    steps = np.empty((k + 1, 6))
    steps[0, :3], steps[0, 3:] = s.gyro_bias_frd_rad_s, s.accel_bias_frd_m_s2
    steps[1:, :3] = p.gyro_bias_step_rad_s * w[:, 12:15]
    steps[1:, 3:] = p.accel_bias_step_m_s2 * w[:, 15:18]
    bias = np.add.accumulate(steps, axis=0)         # b[j] = b[j-1] + step_j, in order
    rows = np.concatenate((bias[:k], p.gyro_white_rad_s * w[:, 0:3],
                           p.accel_white_m_s2 * w[:, 3:6], w[:, 6:12]), axis=1)
    return rows.tolist(), ImuState(bias[k, :3].copy(), bias[k, 3:].copy())


def mean_throttle(motor_pct) -> float:
    """The mean motor output as a fraction of full: the sum in NumPy's order (for fewer than 8
    motors its reduction adds to 0.0 each in turn; from 8 on it is NumPy's own)."""
    n = len(motor_pct)
    if n == 4:                      # the quad-tilt-rotor's, every tick: the loop below unrolled
        m0, m1, m2, m3 = motor_pct
        return float(0.0 + m0 + m1 + m2 + m3) / 400.0
    if n >= 8:
        return float(np.add.reduce(np.asarray(motor_pct, float))) / (100.0 * n)
    total = 0.0
    for m in motor_pct:
        total += m
    return float(total) / (100.0 * n) if n else 0.0


def measure(p: ImuParams, truth: Truth, row: list[float]) -> ImuReading:
    """The reading at `truth` from one sample's row of `noise_block`."""
    bg0, bg1, bg2, ba0, ba1, ba2, ng0, ng1, ng2, na0, na1, na2, vg0, vg1, vg2, va0, va1, va2 = row
    r0, r1, r2 = truth.rates
    f0, f1, f2 = truth.force
    z = mean_throttle(truth.motors)
    z2 = z * z
    cg, ca = p.gyro_vibration_rad_s * z2, p.accel_vibration_m_s2 * z2
    return ImuReading(truth.t_us,
                      (r0 + bg0 + ng0 + cg * vg0, r1 + bg1 + ng1 + cg * vg1,
                       r2 + bg2 + ng2 + cg * vg2),
                      (f0 + ba0 + na0 + ca * va0, f1 + ba1 + na1 + ca * va1,
                       f2 + ba2 + na2 + ca * va2))


def step(p: ImuParams, s: ImuState, truth: Truth, w: np.ndarray) -> tuple[ImuState, ImuReading]:
    rows, nxt = noise_block(p, s, np.asarray(w, float).reshape(1, NOISE))
    return nxt, measure(p, truth, rows[0])
