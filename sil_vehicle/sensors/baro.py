"""The barometer: static pressure at the vehicle's altitude, with white noise and a slow drift.

Model (k the sample index, dt = 1 / rate_hz, w.[k] independent standard normals):

    h[k]     = home_alt_m - down[k] + d[k] + noise_m w_h[k]     (altitude AMSL the sensor sees)
    d[k+1]   = a d[k] + b w_d[k],  a = exp(-dt / tau), b = drift_sigma sqrt(1 - a^2),
               d[0] ~ N(0, drift_sigma^2)                       (a first-order Gauss-Markov drift)
    p[k]     = p0 (1 - L h[k] / T0)^(g M / (R L))                (ISA troposphere)

The reading carries the pressure (Pa), the pressure altitude h (m AMSL) and the ISA temperature
at h (degC). `home_alt_m` comes from the simulation settings (the suite passes it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sil_vehicle.sensors.noise import markov_coefficients
from sil_vehicle.sensors.truth import Truth

__all__ = ["BaroParams", "BaroState", "BaroReading", "NOISE", "initial", "draw", "step",
           "isa_pressure_pa", "isa_temperature_degc"]

NOISE = 2
P0_PA = 101_325.0          # ISA sea-level pressure
T0_K = 288.15              # ISA sea-level temperature
LAPSE_K_M = 0.0065         # ISA troposphere lapse rate
EXPONENT = 5.255877        # g M / (R L) of the ISA troposphere


def isa_pressure_pa(alt_m: float) -> float:
    return P0_PA * (1.0 - LAPSE_K_M * alt_m / T0_K) ** EXPONENT


def isa_temperature_degc(alt_m: float) -> float:
    return T0_K - LAPSE_K_M * alt_m - 273.15


@dataclass(frozen=True)
class BaroParams:
    rate_hz: int
    noise_m: float
    drift_sigma_m: float
    drift_tau_s: float
    home_alt_m: float = 0.0

    @property
    def period_us(self) -> int:
        return 1_000_000 // self.rate_hz

    @property
    def drift_ab(self) -> tuple[float, float]:
        return markov_coefficients(self.drift_sigma_m, self.drift_tau_s, 1.0 / self.rate_hz)


@dataclass(frozen=True)
class BaroState:
    drift_m: float


@dataclass(frozen=True)
class BaroReading:
    t_us: int
    pressure_pa: float
    pressure_alt_m: float          # AMSL
    temperature_degc: float

    @property
    def arrival_us(self) -> int:
        return self.t_us


def initial(params: BaroParams, rng: np.random.Generator) -> BaroState:
    """The drift starts from its stationary distribution."""
    return BaroState(params.drift_sigma_m * float(rng.standard_normal()))


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def step(p: BaroParams, s: BaroState, truth: Truth,
         w: np.ndarray) -> tuple[BaroState, BaroReading]:
    h = p.home_alt_m - truth.pos[2] + s.drift_m + p.noise_m * float(w[0])
    a, b = p.drift_ab
    return (BaroState(a * s.drift_m + b * float(w[1])),
            BaroReading(truth.t_us, isa_pressure_pa(h), h, isa_temperature_degc(h)))
