"""Pacing of simulated time against the wall clock.

Simulated time is the vehicle's integer microsecond count; it never comes from here. In lockstep
the vehicle advances only when the controller has answered, so no clock is involved at all. In
real time, `RealTimePacer` says how far the simulation should have got, with a speed-up factor.
The monotonic time source is injected so that tests can drive it.
"""

from __future__ import annotations

import time
from typing import Callable


class RealTimePacer:
    def __init__(self, speed_up: float = 1.0,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        if speed_up <= 0:
            raise ValueError(f"speed_up must be > 0, got {speed_up}")
        self.speed_up = speed_up
        self._now = monotonic
        self._wall0 = 0.0
        self._sim0_us = 0

    def start(self, sim_us: int) -> None:
        self._wall0 = self._now()
        self._sim0_us = sim_us

    def due_us(self) -> int:
        """Simulated time (us) that should have been reached by now."""
        return self._sim0_us + int((self._now() - self._wall0) * self.speed_up * 1e6)

    def wait_s(self, sim_us: int) -> float:
        """Wall seconds until `sim_us` is due (<= 0 if it already is)."""
        return self._wall0 + (sim_us - self._sim0_us) * 1e-6 / self.speed_up - self._now()

    def factor(self, sim_us: int) -> float:
        """Achieved real-time factor since start."""
        wall = self._now() - self._wall0
        return (sim_us - self._sim0_us) * 1e-6 / wall if wall > 0 else 0.0

