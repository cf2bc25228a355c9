"""The log files of both daemons: the CSV log (flight.csv of the vehicle, controller.csv of the
controller) and pymavlink's .tlog of a link's MAVLink traffic.

CSV: '# key: value' header lines (the run's metadata), a column-name line, then one row per
tick. A string is written as it is, a float with repr() (so identical runs give identical
bytes, and a float reads back exactly), anything else (integers) with str(). Both files are
flushed every `flush_every` rows / messages, so that a killed process leaves them readable up
to the last flush; `close()` flushes the rest.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path
from typing import Iterable, TextIO

__all__ = ["CsvLog", "Tlog", "format_row", "read_header", "read_csv_log"]


def format_row(row: Iterable[object]) -> str:
    """One CSV line (without its newline)."""
    return ",".join(v if isinstance(v, str) else repr(float(v)) if isinstance(v, float)
                    else str(v) for v in row)


class CsvLog:
    """A CSV log being written: the header at once, then a row per call."""

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

    def __call__(self, row: Iterable[object]) -> None:
        self._f.write(format_row(row) + "\n")
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


def read_header(f: TextIO) -> tuple[dict[str, str], list[str]]:
    """(metadata, column names) from an open CSV log: its '# key: value' lines and the line of
    names after them; `f` is left at the first row."""
    meta: dict[str, str] = {}
    line = f.readline()
    while line.startswith("#"):
        key, _, value = line[2:].rstrip("\n").partition(": ")
        meta[key] = value
        line = f.readline()
    return meta, line.rstrip("\n").split(",")


def read_csv_log(path: Path) -> tuple[dict[str, str], list[str], "object"]:
    """(metadata, columns, rows as a NumPy array of floats) of a CSV log with numeric rows."""
    import numpy as np

    with open(path, encoding="ascii") as f:
        meta, columns = read_header(f)
        data = np.loadtxt(f, delimiter=",", ndmin=2)
    return meta, columns, data


class Tlog:
    """pymavlink's telemetry log: each message as an 8-byte big-endian UNIX time in
    microseconds followed by the raw MAVLink frame (readable by mavlogdump.py)."""

    def __init__(self, path: Path, flush_every: int = 500) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._n = 0
        self._every = max(1, flush_every)

    def write(self, unix_us: int, frame: bytes) -> None:
        """A frame with the UNIX time (us) it was sent or received."""
        self._f.write(struct.pack(">Q", unix_us) + frame)
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def __call__(self, frame: bytes) -> None:
        """A frame stamped with the wall clock now."""
        self.write(time.time_ns() // 1000, frame)

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()
