"""A bounded delay line: readings held until their arrival time, released in order. Pure
functions on an immutable tuple (the state of a delayed sensor carries it).

A reading is pushed when it is measured (its `t_us`, the time of validity) and released at its
`arrival_us` = t_us + delay. The capacity is fixed when the profile is loaded (the delay is at
most DELAY_BUFFER_MS, so at most delay / period + 1 readings are ever in flight); overflowing it
is a bug, not a condition to handle.
"""

from __future__ import annotations

from typing import Any

__all__ = ["capacity", "push", "release"]


def capacity(delay_ticks: int, period_ticks: int) -> int:
    """The most readings in flight for a delay and a sample period, both in physics ticks."""
    return delay_ticks // period_ticks + 1


def push(line: tuple[Any, ...], reading: Any, cap: int) -> tuple[Any, ...]:
    if len(line) >= cap:
        raise RuntimeError(f"delay line full ({cap} readings): the delay outgrew its buffer")
    return line + (reading,)


def release(line: tuple[Any, ...], t_us: int) -> tuple[tuple[Any, ...], tuple[Any, ...]]:
    """(what stays, what arrives by `t_us`), both in measurement order."""
    n = 0
    while n < len(line) and line[n].arrival_us <= t_us:
        n += 1
    return line[n:], line[:n]
