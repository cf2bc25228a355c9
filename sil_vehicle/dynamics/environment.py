"""Wind: a steady mean plus Dryden turbulence, and the airframe drag it causes.

Turbulence is the first-order (Gauss-Markov) form of the Dryden model on each NED axis: the
exact discretisation of a filter with correlation length L traversed at airspeed V,
    g_{k+1} = a g_k + sigma sqrt(1 - a^2) w_k,   a = exp(-V dt / L),
which keeps the Dryden variance sigma^2 and correlation time L / V. The white-noise samples w_k
are arguments, so the function is pure; the caller draws them from its seeded generator.
"""

from __future__ import annotations

import math
from typing import Sequence


def gust_coefficients(sigma_m_s: float, length_m: float, airspeed_m_s: float,
                      dt_s: float) -> tuple[float, float]:
    """(a, b) of g_{k+1} = a g_k + b w_k; the airspeed is floored at 1 m/s (near hover)."""
    a = math.exp(-max(airspeed_m_s, 1.0) * dt_s / length_m)
    return a, sigma_m_s * math.sqrt(1.0 - a * a)


def gust_step(gust_ned: Sequence[float], noise: Sequence[float], a: float,
              b: float) -> tuple[float, float, float]:
    return (a * gust_ned[0] + b * noise[0], a * gust_ned[1] + b * noise[1],
            a * gust_ned[2] + b * noise[2])


def drag_force_ned(vel_ned: Sequence[float], wind_ned: Sequence[float],
                   k: float) -> tuple[float, float, float]:
    """F = -k |v_rel| v_rel with v_rel the velocity relative to the air."""
    rx, ry, rz = vel_ned[0] - wind_ned[0], vel_ned[1] - wind_ned[1], vel_ned[2] - wind_ned[2]
    s = -k * math.sqrt(rx * rx + ry * ry + rz * rz)
    return s * rx, s * ry, s * rz
