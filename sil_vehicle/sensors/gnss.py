"""GNSS: NED position and velocity at `rate_hz`, arriving `delay_ticks` physics ticks after their
time of validity, with a slowly wandering position error and the receiver's accuracy fields.

Model (k the sample index, dt = 1 / rate_hz, w.[k] independent standard normals, per axis; h for
north and east, v for down):

    e[k+1]   = a e[k] + b w_e[k],  a = exp(-dt / tau), b = sigma_m sqrt(1 - a^2),
               e[0] ~ N(0, sigma_m^2)                     (first-order Gauss-Markov, exact)
    pos[k]   = p[k] + e[k] + sigma_w w_p[k]
    vel[k]   = v[k] + sigma_vel w_v[k]

eph_m / epv_m report the 1-sigma position error the model makes, sqrt(sigma_m^2 + sigma_w^2)
horizontally and vertically; the fix type and the satellites are the profile's, fixed. Latitude
and longitude are the codec's business (it converts NED around home).

Delay: `sample` pushes the reading into the state's delay line (arrival = t + delay), `release`
returns the readings whose arrival time has come. Both are pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sil_vehicle.sensors import delay
from sil_vehicle.sensors.noise import markov_coefficients
from sil_vehicle.sensors.truth import Truth

__all__ = ["GnssParams", "GnssState", "GnssReading", "NOISE", "initial", "draw", "sample",
           "release"]

NOISE = 9       # w_p, w_v, w_e (3 each)


@dataclass(frozen=True)
class GnssParams:
    rate_hz: int
    delay_ticks: int
    dt_us: int                      # the physics tick
    fix_type: int                   # MAVLink GPS_FIX_TYPE
    satellites: int
    position_white_h_m: float
    position_white_v_m: float
    position_markov_h_m: float
    position_markov_v_m: float
    position_markov_tau_s: float
    velocity_white_h_m_s: float
    velocity_white_v_m_s: float

    @property
    def period_us(self) -> int:
        return 1_000_000 // self.rate_hz

    @property
    def delay_us(self) -> int:
        return self.delay_ticks * self.dt_us

    @property
    def capacity(self) -> int:
        return delay.capacity(self.delay_ticks, self.period_us // self.dt_us)

    @property
    def markov_sigma_m(self) -> np.ndarray:
        h, v = self.position_markov_h_m, self.position_markov_v_m
        return np.array((h, h, v))

    @property
    def markov_ab(self) -> tuple[float, np.ndarray]:
        a, _ = markov_coefficients(1.0, self.position_markov_tau_s, 1.0 / self.rate_hz)
        return a, self.markov_sigma_m * math.sqrt(max(0.0, 1.0 - a * a))

    @property
    def eph_m(self) -> float:
        return math.hypot(self.position_markov_h_m, self.position_white_h_m)

    @property
    def epv_m(self) -> float:
        return math.hypot(self.position_markov_v_m, self.position_white_v_m)


@dataclass(frozen=True)
class GnssState:
    error_ned_m: np.ndarray                     # (3,) the Gauss-Markov position error
    pending: tuple["GnssReading", ...] = ()     # the delay line


@dataclass(frozen=True)
class GnssReading:
    t_us: int                       # time of validity
    arrival_us: int                 # when the receiver reports it
    pos_ned_m: np.ndarray           # (3,)
    vel_ned_m_s: np.ndarray         # (3,)
    fix_type: int
    satellites: int
    eph_m: float
    epv_m: float
    speed_accuracy_m_s: float


def initial(params: GnssParams, rng: np.random.Generator) -> GnssState:
    """The position error starts from its stationary distribution."""
    return GnssState(params.markov_sigma_m * rng.standard_normal(3))


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def sample(p: GnssParams, s: GnssState, truth: Truth, w: np.ndarray) -> GnssState:
    hv = np.array((p.position_white_h_m, p.position_white_h_m, p.position_white_v_m))
    vv = np.array((p.velocity_white_h_m_s, p.velocity_white_h_m_s, p.velocity_white_v_m_s))
    reading = GnssReading(truth.t_us, truth.t_us + p.delay_us,
                          truth.pos_ned_m + s.error_ned_m + hv * w[0:3],
                          truth.vel_ned_m_s + vv * w[3:6], p.fix_type, p.satellites, p.eph_m,
                          p.epv_m, p.velocity_white_h_m_s)
    a, b = p.markov_ab
    return GnssState(a * s.error_ned_m + b * w[6:9], delay.push(s.pending, reading, p.capacity))


def release(s: GnssState, t_us: int) -> tuple[GnssState, tuple[GnssReading, ...]]:
    pending, out = delay.release(s.pending, t_us)
    return GnssState(s.error_ned_m, pending), out
