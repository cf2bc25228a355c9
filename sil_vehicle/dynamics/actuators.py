"""Actuator dynamics over one physics tick: a first-order lag with a rate limit, then limits.

The lag is discretised exactly (y += (1 - exp(-dt/T)) (u - y)); the rate limit caps the change per
tick. A time constant of zero passes the target through (still rate limited).
"""

from __future__ import annotations

import math


def lag_factor(time_constant_s: float, dt_s: float) -> float:
    return 1.0 if time_constant_s <= 0.0 else 1.0 - math.exp(-dt_s / time_constant_s)


def first_order_step(value: float, target: float, factor: float, max_change: float,
                     lo: float, hi: float) -> float:
    delta = factor * (target - value)
    if delta > max_change:
        delta = max_change
    elif delta < -max_change:
        delta = -max_change
    value += delta
    return lo if value < lo else hi if value > hi else value
