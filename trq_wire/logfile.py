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
from typing import Callable, Iterable, TextIO

__all__ = ["CsvLog", "Tlog", "VehicleTimeline", "FlushedFile", "format_row", "read_header",
           "read_csv_log"]


def format_row(row: Iterable[object]) -> str:
    """One CSV line (without its newline)."""
    # exact types first (a list, not a generator: both cheaper per value); a float subclass
    # (NumPy's float64) as the float it is
    return ",".join([v if type(v) is str else repr(v) if type(v) is float
                     else repr(float(v)) if isinstance(v, float)
                     else v if isinstance(v, str) else str(v) for v in row])


class FlushedFile:
    """A log file being written (its folder made), flushed every `flush_every` records
    (`_put`) so that a killed process leaves it readable up to the last flush, and at close."""

    def __init__(self, path: Path, mode: str, flush_every: int, **open_args) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, mode, **open_args)
        self._n = 0
        self._every = max(1, flush_every)

    def _put(self, data) -> None:
        self._f.write(data)
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


class CsvLog(FlushedFile):
    """A CSV log being written: the header at once, then a row per call."""

    def __init__(self, path: Path, columns: Iterable[str], meta: dict[str, object],
                 flush_every: int = 100) -> None:
        super().__init__(path, "w", flush_every, encoding="ascii", newline="\n")
        for key, value in meta.items():
            self._f.write(f"# {key}: {value}\n")
        self._f.write(",".join(columns) + "\n")
        self._f.flush()

    def __call__(self, row: Iterable[object]) -> None:
        self._put(format_row(row) + "\n")


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


_pack_stamp = struct.Struct(">Q").pack


class Tlog(FlushedFile):
    """pymavlink's telemetry log: each message as an 8-byte big-endian UNIX time in
    microseconds followed by the raw MAVLink frame (readable by mavlogdump.py)."""

    def __init__(self, path: Path, flush_every: int = 500,
                 clock: Callable[[], int] = lambda: time.time_ns() // 1000) -> None:
        super().__init__(path, "wb", flush_every)
        self._clock = clock

    def write(self, unix_us: int, frame: bytes) -> None:
        """A frame with the UNIX time (us) it was sent or received."""
        self._put(_pack_stamp(unix_us) + frame)

    def __call__(self, frame: bytes) -> None:
        """A frame stamped with the log's clock now (the wall clock unless given another)."""
        self._put(_pack_stamp(self._clock()) + frame)       # `write`'s, a call less a frame


MAGIC_V2 = 0xFD
ODOMETRY_ID = 331
_ODOMETRY_LOW = ODOMETRY_ID & 0xFF
VEHICLE = (1, 1)              # the autopilot: system 1, component 1 (PROTOCOL.md)
RESTART_US = 1_000_000        # the vehicle's time going back further than this: it restarted


class VehicleTimeline:
    """The controller's .tlog clock: the vehicle's own time, anchored at the wall.

    `heard(frame)` reads the time_usec of each ODOMETRY the autopilot sends; `now_us()` is the
    wall time at which the first was heard plus the vehicle time since then. In lockstep this
    is the flight's own timeline (as the vehicle's vehicle.tlog is, PROTOCOL.md), however long
    the run took; in real time it is the vehicle's clock, the wall clock of a vehicle running
    at real time, and a real autopilot's boot clock: the controller's log lines up with the
    vehicle's either way. Before the first ODOMETRY, the wall clock. A vehicle that restarts
    (its time back by more than RESTART_US) is anchored again. Non-decreasing otherwise."""

    def __init__(self, wall_us: Callable[[], int] = lambda: time.time_ns() // 1000) -> None:
        self._wall_us = wall_us
        self._offset: int | None = None
        self._latest = 0

    def heard(self, frame: bytes) -> None:
        # the message id's low byte first: most frames are not ODOMETRY
        if len(frame) < 12 or frame[7] != _ODOMETRY_LOW \
                or frame[7] | frame[8] << 8 | frame[9] << 16 != ODOMETRY_ID \
                or frame[0] != MAGIC_V2 or (frame[5], frame[6]) != VEHICLE:
            return
        # time_usec leads ODOMETRY's payload; MAVLink 2 drops trailing zero bytes
        stamp = struct.unpack_from("<Q", frame[10:10 + min(frame[1], 8)].ljust(8, b"\0"))[0]
        if self._offset is None or stamp < self._latest - RESTART_US:
            self._offset, self._latest = self._wall_us() - stamp, stamp
        self._latest = max(self._latest, stamp)

    def now_us(self) -> int:
        if self._offset is None:
            return self._wall_us()
        return self._offset + self._latest
