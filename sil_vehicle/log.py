"""Flight logs: the truth-state CSV (with a metadata header) and the MAVLink .tlog.

Both are flushed about once a second (every `flush_every` rows / messages), so that a killed
process leaves files readable up to the last flush; `close()` flushes the rest.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Iterable


class FlightLog:
    """CSV: '# key: value' header lines, a column-name line, then one row per log tick.
    Floats are written with repr(), so identical runs give identical bytes."""

    def __init__(self, path: Path, columns: Iterable[str], meta: dict[str, object],
                 flush_every: int = 100) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "w", encoding="ascii", newline="\n")
        for key, value in meta.items():
            self._f.write(f"# {key}: {value}\n")
        self._f.write(",".join(columns) + "\n")
        self._f.flush()
        self._n = 0
        self._every = max(1, flush_every)

    def __call__(self, row: tuple) -> None:
        self._f.write(",".join(map(repr, row)) + "\n")
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


class Tlog:
    """pymavlink's telemetry log: each message as an 8-byte big-endian UNIX time in
    microseconds followed by the raw MAVLink frame (readable by mavlogdump.py)."""

    def __init__(self, path: Path, flush_every: int = 500) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._n = 0
        self._every = flush_every

    def write(self, unix_us: int, frame: bytes) -> None:
        self._f.write(struct.pack(">Q", unix_us) + frame)
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


def read_flight_log(path: Path) -> tuple[dict[str, str], list[str], "object"]:
    """(metadata, columns, rows as a NumPy array) of a flight log."""
    import numpy as np

    meta: dict[str, str] = {}
    with open(path, encoding="ascii") as f:
        line = f.readline()
        while line.startswith("#"):
            key, _, value = line[2:].rstrip("\n").partition(": ")
            meta[key] = value
            line = f.readline()
        columns = line.rstrip("\n").split(",")
        data = np.loadtxt(f, delimiter=",", ndmin=2)
    return meta, columns, data
