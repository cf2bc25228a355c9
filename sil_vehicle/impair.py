"""A bad link, on purpose: seeded loss, delay, jitter, duplication and reordering of the
messages of one link, in simulated time, so that an impaired flight is as deterministic as a
clean one (`links.<name>.impair` in the sim YAML).

The vehicle applies it to both directions of the link: its telemetry is held back or dropped
before it is sent, and what it receives is dropped or applied late. Because the vehicle itself
decides, the lockstep never waits for an answer to a message it dropped.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class ImpairParams:
    loss: float = 0.0           # probability that a message is lost
    delay_ms: float = 0.0       # fixed one-way delay
    jitter_ms: float = 0.0      # extra delay, uniform in [0, jitter]
    duplicate: float = 0.0      # probability that a message is delivered twice
    reorder: float = 0.0        # probability that a message is held back one extra delay + 10 ms

    @property
    def active(self) -> bool:
        return any((self.loss, self.delay_ms, self.jitter_ms, self.duplicate, self.reorder))


class Impairment:
    """One direction of one link: `offer(now_us, item)` then `due(now_us)`."""

    def __init__(self, params: ImpairParams, rng: np.random.Generator) -> None:
        self.p = params
        self._rng = rng
        self._queue: list[tuple[int, int, Any]] = []
        self._n = 0
        self.lost = 0
        self.duplicated = 0
        self.reordered = 0

    def offer(self, now_us: int, item: Any) -> bool:
        """Queue an item for delivery; False if it is lost."""
        p = self.p
        u = self._rng.random(4)             # always four draws: the stream stays aligned
        if u[0] < p.loss:
            self.lost += 1
            return False
        delay = p.delay_ms + p.jitter_ms * u[1]
        if u[2] < p.reorder:
            delay += p.delay_ms + 10.0
            self.reordered += 1
        self._push(now_us + int(round(delay * 1000.0)), item)
        if u[3] < p.duplicate:
            self.duplicated += 1
            self._push(now_us + int(round(delay * 1000.0)), item)
        return True

    def _push(self, at_us: int, item: Any) -> None:
        heapq.heappush(self._queue, (at_us, self._n, item))
        self._n += 1

    def due(self, now_us: int) -> list[Any]:
        out = []
        while self._queue and self._queue[0][0] <= now_us:
            out.append(heapq.heappop(self._queue)[2])
        return out
