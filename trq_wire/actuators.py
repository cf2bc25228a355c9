"""Actuator scaling on the wire: throttles (percent) and tilts (rad) to and from the normalised
values of SET_ACTUATOR_CONTROL_TARGET and ACTUATOR_OUTPUT_STATUS, and the PWM microseconds of
SERVO_OUTPUT_RAW (sil_vehicle/PROTOCOL.md).

Normalised: throttle 0..1 (percent / 100), tilt -1..1 of the servo half-range
(`tilt_half_range`). PWM: motors 1000 + 10 x throttle percent (1000 stopped, 2000 full), tilt
servos 1500 + 500 x tilt / half-range. A group-0 control vector holds eight values: throttles
of motors 1..4, then tilts of servos 1..4.

Which side clips and which side refuses is each daemon's decision: the controller clips before
it sends (`clip_controls`), the vehicle refuses a whole target that is not `controls_in_range`.
The functions here never clip unless they say so, and never raise on a value; NaN goes through.
"""

from __future__ import annotations

import math
from typing import Iterable, Sequence

__all__ = ["PWM_MIN_US", "PWM_MAX_US", "PWM_MID_US", "tilt_half_range", "to_normalised",
           "from_normalised", "clip_controls", "controls_in_range", "throttle_to_pwm",
           "tilt_to_pwm", "pwm_to_throttle", "pwm_to_tilt", "to_pwm", "from_pwm"]

PWM_MIN_US, PWM_MAX_US, PWM_MID_US = 1000, 2000, 1500
N_MOTORS = 4     # controls[0..3] throttles, controls[4..7] tilts


def tilt_half_range(tilt_min_rad: float, tilt_max_rad: float) -> float:
    """The angle a normalised tilt of 1 stands for (PROTOCOL.md: max(|min|, max))."""
    return max(abs(tilt_min_rad), abs(tilt_max_rad))


# --- normalised (SET_ACTUATOR_CONTROL_TARGET, ACTUATOR_OUTPUT_STATUS) ------------------------

def to_normalised(throttle_pct: Iterable[float], tilt_rad: Iterable[float],
                  limit_rad: float) -> list[float]:
    """Throttles / 100, then tilts / half-range, unclipped."""
    return [v / 100.0 for v in throttle_pct] + [a / limit_rad for a in tilt_rad]


def from_normalised(values: Sequence[float], limit_rad: float
                    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(throttles in percent, tilts in rad) of values[0..3] and values[4..7]."""
    return (tuple(100.0 * v for v in values[:N_MOTORS]),
            tuple(limit_rad * v for v in values[N_MOTORS:2 * N_MOTORS]))


def clip_controls(values: Sequence[float]) -> list[float]:
    """Throttles (values[0..3]) clipped to 0..1, tilts (the rest) to -1..1."""
    # min(max(v, lo), hi)'s results, a NaN and a -0.0 passed through as they pass it, without
    # its two calls a value (the controller's answer every period)
    return ([0.0 if v < 0.0 else 1.0 if v > 1.0 else v for v in values[:N_MOTORS]]
            + [-1.0 if v < -1.0 else 1.0 if v > 1.0 else v for v in values[N_MOTORS:]])


def controls_in_range(values: Sequence[float]) -> bool:
    """Eight finite values, throttles within 0..1 and tilts within -1..1."""
    if len(values) != 2 * N_MOTORS or not all(math.isfinite(v) for v in values):
        return False
    return all(0.0 <= v <= 1.0 for v in values[:N_MOTORS]) and \
        all(-1.0 <= v <= 1.0 for v in values[N_MOTORS:])


# --- PWM (SERVO_OUTPUT_RAW) ------------------------------------------------------------------

def throttle_to_pwm(throttle_pct: float) -> int:
    """1000 + 10 x throttle percent, the throttle clipped to 0..100 first."""
    return int(round(PWM_MIN_US + 10.0 * min(max(throttle_pct, 0.0), 100.0)))


def tilt_to_pwm(tilt_rad: float, limit_rad: float) -> int:
    """1500 + 500 x tilt / half-range, the ratio clipped to -1..1 first."""
    norm = min(max(tilt_rad / limit_rad, -1.0), 1.0)
    return int(round(PWM_MID_US + 500.0 * norm))


def pwm_to_throttle(pwm_us: int) -> float:
    return (pwm_us - PWM_MIN_US) / 10.0


def pwm_to_tilt(pwm_us: int, limit_rad: float) -> float:
    return (pwm_us - PWM_MID_US) / 500.0 * limit_rad


def to_pwm(throttle_pct: Iterable[float], tilt_rad: Iterable[float],
           limit_rad: float) -> list[int]:
    """PWM of the motors, then of the tilt servos."""
    return ([throttle_to_pwm(v) for v in throttle_pct]
            + [tilt_to_pwm(a, limit_rad) for a in tilt_rad])


def from_pwm(pwm_us: Sequence[int], limit_rad: float
             ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(throttles in percent, tilts in rad) of pwm_us[0..3] and pwm_us[4..7]."""
    return (tuple(pwm_to_throttle(p) for p in pwm_us[:N_MOTORS]),
            tuple(pwm_to_tilt(p, limit_rad) for p in pwm_us[N_MOTORS:2 * N_MOTORS]))
