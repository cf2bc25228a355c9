"""A CSV log's rows written as PX4 writes its own flight log: ULog (PX4's binary log format,
docs.px4.io "ULog File Format"), one topic whose fields are the log's columns, and its
conversion to the CSV log on the ground.

Why: formatting a row of some sixty floats as text (repr) costs the controller more than
several of its observers a period; packing it costs a struct (issue 39, item 5). PX4 logs
binary on board for the same reason and converts on the ground (pyulog's ulog2csv, Flight
Review, PlotJuggler), which read this file as they read a PX4 log.

    log = UlogLog(path, columns, kinds, meta, timestamp="stamp_us")   # header and definitions
    log(row)                          # one data message a row; strings become enum indices
    log.close()
    to_csv(path)                      # the CSV log trq_wire.logfile.CsvLog would have written
    tail = LogTail(path); tail.last()  # the newest whole row of a log being written (progress)

The file: the ULog header (version 1, the first row's timestamp unknown: 0), the flag bits,
one format `trq_<name>` (uint64_t timestamp, then a double per column), information messages
(`sys_name`; `trq_kinds`: a letter a column, f a float, i an integer, s a string; `trq_meta:<key>`
the CSV header's lines, in order), one subscription, then a data message a row. A string
column's values are written as indices, each string's index announced by an information
message `trq_enum:<column>:<index>` before the first row that uses it (ULog allows information
messages among the data), so that a file cut short by a killed process reads back to its last
whole message.

`to_csv` reads the file with pyulog (a declared dependency: the reference reader of the
format) and writes the rows as CsvLog writes them (trq_wire.logfile.format_row): a float with
repr, an integer column with str (nan where the row had none), a string as it was. The same
bytes as the CSV log written during the flight, for rows whose values have their column's type.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from trq_wire.logfile import CsvLog, FlushedFile

__all__ = ["UlogLog", "LogTail", "to_csv", "KINDS", "MAGIC"]

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
KINDS = "fis"                  # float, integer (or nan), string
_HEADER = struct.Struct("<HB")                 # a message's size (after this header) and type
_FLAGS = struct.Struct("<8B8B3Q")             # compat, incompat flags, appended offsets
MSG_ID = 0
_DATA, _FORMAT = ord("D"), ord("F")            # a data and a format message's type


def _data_layout(n_columns: int) -> str:
    """A data message's payload: the topic's id, its timestamp, a double per column."""
    return f"HQ{n_columns}d"


def _message(kind: str, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise ValueError(f"a ULog message holds at most 65535 bytes, not {len(payload)}")
    return _HEADER.pack(len(payload), ord(kind)) + payload


def _info(key: str, value: str) -> bytes:
    """An information message: the string `value` under `key` (no spaces, ULog's `char[n] key`)."""
    data = value.encode("utf-8")
    type_key = f"char[{len(data)}] {key}".encode("ascii")
    return _message("I", bytes((len(type_key),)) + type_key + data)


def _field_name(name: str, what: str = "column") -> str:
    if not name or not all(c.isalnum() or c == "_" for c in name) or name == "timestamp":
        raise ValueError(f"{what} {name!r}: a ULog name is letters, digits and '_' "
                         "(and not 'timestamp', the topic's own)")
    return name


class UlogLog(FlushedFile):
    """A CSV log's rows as one ULog topic (the module docstring): the definitions at once, a
    data message per call, flushed every `flush_every` rows and at close."""

    def __init__(self, path: Path, columns: Sequence[str], kinds: str,
                 meta: Mapping[str, object], *, timestamp: str, name: str = "trq_log",
                 sys_name: str = "trq-ftc", flush_every: int = 100) -> None:
        columns = [_field_name(c) for c in columns]
        if len(kinds) != len(columns) or set(kinds) - set(KINDS):
            raise ValueError(f"kinds {kinds!r}: one of {KINDS!r} for each of the "
                             f"{len(columns)} columns")
        if timestamp not in columns or kinds[columns.index(timestamp)] == "s":
            raise ValueError(f"timestamp column {timestamp!r}: a numeric column of the log")
        self._time = columns.index(timestamp)
        self._strings = [i for i, k in enumerate(kinds) if k == "s"]
        self._columns = columns
        self._enums: list[dict[str, int]] = [{} for _ in columns]
        self._row = struct.Struct("<HB" + _data_layout(len(columns)))    # with its header
        self._size = self._row.size - _HEADER.size
        out = [MAGIC, bytes((VERSION,)), struct.pack("<Q", 0),
               _message("B", _FLAGS.pack(*([0] * 16), 0, 0, 0)),
               _message("F", (f"{name}:uint64_t timestamp;"
                              + "".join(f"double {c};" for c in columns)).encode("ascii")),
               _info("sys_name", sys_name), _info("trq_kinds", kinds)]
        for key, value in meta.items():
            out.append(_info(f"trq_meta:{_field_name(str(key), 'meta key')}", str(value)))
        out.append(_message("A", struct.pack("<BH", 0, MSG_ID) + name.encode("ascii")))
        super().__init__(path, "wb", flush_every)       # every definition checked first
        self._f.write(b"".join(out))
        self._f.flush()

    def _index(self, i: int, value: str) -> int:
        enum = self._enums[i]
        k = enum.get(value)
        if k is None:
            k = enum[value] = len(enum)
            self._f.write(_info(f"trq_enum:{self._columns[i]}:{k}", value))
        return k

    def __call__(self, row: list) -> None:
        """One row (a list in the columns' order; its string columns are replaced in place by
        their indices)."""
        for i in self._strings:
            row[i] = self._index(i, row[i])
        self._put(self._row.pack(self._size, _DATA, MSG_ID, int(row[self._time]), *row))


def _int_or_nan(v: float):
    return int(v) if math.isfinite(v) else v


def to_csv(path: Path, csv_path: Path | None = None) -> Path:
    """Write the CSV log of a ULog file written by UlogLog (beside it, .csv, unless
    `csv_path`); returns its path. A file that is not one, or has no rows' topic, raises
    ValueError naming it."""
    from pyulog import ULog

    path = Path(path)
    with open(path, "rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise ValueError(f"{path}: not a ULog file (no ULog header)")
    ulog = ULog(str(path))
    info = ulog.msg_info_dict
    kinds = info.get("trq_kinds")
    fmt = [m for m in ulog.message_formats.values()
           if m.fields and m.fields[0][2] == "timestamp"]
    if kinds is None or len(fmt) != 1:
        raise ValueError(f"{path}: not a log of trq_wire.ulog (no trq_kinds or no single topic)")
    columns = [field for _, _, field in fmt[0].fields[1:]]
    if len(columns) != len(kinds):
        raise ValueError(f"{path}: {len(columns)} fields but {len(kinds)} kinds")
    meta = {key.split(":", 1)[1]: value for key, value in info.items()
            if key.startswith("trq_meta:")}
    data = [d for d in ulog.data_list if d.name == fmt[0].name]
    rows = len(data[0].data["timestamp"]) if data else 0
    cols: list[Iterable] = []
    for c, kind in zip(columns, kinds):
        values = data[0].data[c].tolist() if data else []
        if kind == "i":
            values = [_int_or_nan(v) for v in values]
        elif kind == "s":
            names = {int(key.rsplit(":", 1)[1]): value for key, value in info.items()
                     if key.startswith(f"trq_enum:{c}:")}
            missing = {int(v) for v in values} - names.keys()
            if missing:
                raise ValueError(f"{path}: column {c}: indices {sorted(missing)} have no "
                                 f"trq_enum:{c}:<index> information message")
            values = [names[int(v)] for v in values]
        cols.append(values)
    out = Path(csv_path) if csv_path is not None else path.with_suffix(".csv")
    part = out.with_name(out.name + ".part")      # renamed into place whole
    log = CsvLog(part, columns, meta, flush_every=max(1, rows))
    try:
        for row in zip(*cols):
            log(row)
    finally:
        log.close()
    part.replace(out)
    return out


class LogTail:
    """The newest whole row of a UlogLog file while it is written (a flight's progress, read
    from another process): each `last()` reads on from where the previous call stopped, whole
    messages only, and returns {column: value} of the newest data message so far (strings as
    their indices), or None before the first."""

    _START = len(MAGIC) + 9                        # the header: magic, version, timestamp

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._offset = self._START
        self._columns: list[str] | None = None
        self._row: struct.Struct | None = None
        self._last: dict[str, float] | None = None

    def last(self) -> dict[str, float] | None:
        try:
            with open(self.path, "rb") as f:
                f.seek(self._offset)
                data = f.read()
        except OSError:
            return self._last
        i, n = 0, len(data)
        newest = None                                  # only the newest row is unpacked
        while i + _HEADER.size <= n:
            size, kind = _HEADER.unpack_from(data, i)
            end = i + _HEADER.size + size
            if end > n:
                break                                  # a message still being written
            body = data[i + _HEADER.size:end]
            if kind == _FORMAT and self._columns is None:
                fields = body.decode("ascii").split(":", 1)[1].strip(";").split(";")
                self._columns = [f.split(" ", 1)[1] for f in fields[1:]]
                self._row = struct.Struct("<" + _data_layout(len(self._columns)))
            elif kind == _DATA and self._row is not None and size == self._row.size:
                newest = body
            i = end
        self._offset += i
        if newest is not None:
            self._last = dict(zip(self._columns, self._row.unpack(newest)[2:]))
        return self._last
