"""A bad link, on purpose: seeded loss, delay, jitter, duplication and reordering of the
messages of one link, in simulated time, so that an impaired flight is as deterministic as a
clean one (`links.<name>.impair` in the sim YAML).

The vehicle applies it to both directions of the link: its telemetry is held back or dropped
before it is sent, and what it receives is dropped or applied late. Because the vehicle itself
decides, the lockstep never waits for an answer to a message it dropped.
"""

from __future__ import annotations

import heapq
import zlib
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
    """One direction of one link: `offer(now_us, item, kind)` then `due(now_us)`.

    Each kind of message (its MAVLink type) draws from its own random stream, derived from the
    link's seed and the kind's name: what happens to the actuator targets depends only on the
    targets, not on how many heartbeats or command replies the wall clock slipped in between
    (a controller's 1 Hz heartbeat is timed by its wall clock, even in lockstep). That keeps an
    impaired lockstep flight reproducible bit for bit."""

    def __init__(self, params: ImpairParams, seed: np.random.SeedSequence) -> None:
        self.p = params
        self._seed = seed
        self._rngs: dict[str, np.random.Generator] = {}
        self._queue: list[tuple[int, int, Any]] = []
        self._n = 0
        self.lost = 0
        self.duplicated = 0
        self.reordered = 0

    def _rng(self, kind: str) -> np.random.Generator:
        rng = self._rngs.get(kind)
        if rng is None:
            seq = np.random.SeedSequence(self._seed.entropy, spawn_key=(
                *self._seed.spawn_key, zlib.crc32(kind.encode("utf-8"))))
            rng = self._rngs[kind] = np.random.default_rng(seq)
        return rng

    def offer(self, now_us: int, item: Any, kind: str = "") -> bool:
        """Queue an item for delivery; False if it is lost."""
        p = self.p
        u = self._rng(kind).random(4)       # always four draws: the stream stays aligned
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
