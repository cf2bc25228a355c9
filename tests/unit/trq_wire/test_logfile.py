"""The log files both daemons write (trq_wire.logfile): the CSV header and rows of flight.csv
and controller.csv, their reader, and the .tlog record format."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from trq_wire.logfile import CsvLog, Tlog, format_row, read_csv_log


def test_format_row_hand_written():
    assert format_row([1, 0.1, -2.5e-300, "ok", 3]) == "1,0.1,-2.5e-300,ok,3"
    assert format_row([math.nan, math.inf, True]) == "nan,inf,True"
    assert format_row([np.float64(0.1), np.int64(7)]) == "0.1,7"   # no 'np.float64(...)'
    assert format_row([]) == ""


def test_csv_log_bytes(tmp_path):
    path = tmp_path / "sub" / "flight.csv"                     # the folder is made
    log = CsvLog(path, ["t_us", "x_m", "phase"], {"seed": 5, "vehicle": "trq"})
    log((10_000, 0.1, "hover"))
    log([20_000, 1 / 3, "land"])
    log.close()
    log.close()                                                # twice is harmless
    assert path.read_text(encoding="ascii") == (
        "# seed: 5\n# vehicle: trq\nt_us,x_m,phase\n"
        "10000,0.1,hover\n20000,0.3333333333333333,land\n")


def test_header_is_on_disk_before_any_row(tmp_path):
    path = tmp_path / "c.csv"
    log = CsvLog(path, ["a"], {"k": "v"}, flush_every=1000)
    assert path.read_text() == "# k: v\na\n"
    log((1,))
    log.close()


def test_rows_flushed_every_n(tmp_path):
    path = tmp_path / "c.csv"
    log = CsvLog(path, ["a"], {}, flush_every=2)
    log((1,))
    assert path.read_text() == "a\n"
    log((2,))
    assert path.read_text() == "a\n1\n2\n"
    log.close()


def test_floats_read_back_exactly(tmp_path):
    path = tmp_path / "f.csv"
    values = [0.1, 1 / 3, -1e-320, 2.0 ** 60, math.pi, math.nan]
    log = CsvLog(path, [f"c{i}" for i in range(len(values))], {"file": "/x/y.yaml", "n": 2})
    log(values)
    log(values)
    log.close()
    meta, columns, data = read_csv_log(path)
    assert meta == {"file": "/x/y.yaml", "n": "2"}
    assert columns == ["c0", "c1", "c2", "c3", "c4", "c5"]
    assert data.shape == (2, 6)
    assert list(data[1, :5]) == values[:5] and math.isnan(data[1, 5])


def test_reader_keeps_a_colon_in_a_value(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("# connect: udpin:127.0.0.1:14540\na\n1\n")
    meta, columns, data = read_csv_log(path)
    assert meta == {"connect": "udpin:127.0.0.1:14540"} and data.tolist() == [[1.0]]


def test_reader_of_a_header_only_log(tmp_path):
    path = tmp_path / "f.csv"
    CsvLog(path, ["a", "b"], {"seed": 1}).close()
    with pytest.warns(UserWarning):                    # numpy: the file has no data rows
        meta, columns, data = read_csv_log(path)
    assert columns == ["a", "b"] and data.size == 0


def test_tlog_records(tmp_path):
    path = tmp_path / "t" / "link.tlog"
    tlog = Tlog(path)
    tlog.write(0x0102030405060708, b"\xfd\x01")
    tlog(b"\xfe")
    tlog.close()
    data = path.read_bytes()
    assert data[:10] == bytes([1, 2, 3, 4, 5, 6, 7, 8, 0xFD, 0x01])
    (stamp_us,) = struct.unpack(">Q", data[10:18])
    assert stamp_us > 1_600_000_000 * 10**6 and data[18:] == b"\xfe"    # UNIX time, us
