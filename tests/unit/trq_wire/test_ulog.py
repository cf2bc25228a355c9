"""trq_wire.ulog: a CSV log's rows as PX4's ULog, read back by pyulog as a PX4 log is, and
written on the ground as the same CSV bytes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trq_wire.logfile import CsvLog
from trq_wire.ulog import MAGIC, UlogLog, to_csv

COLUMNS = ["t_s", "stamp_us", "x", "phase", "count", "y"]
KINDS = "fifsif"
META = {"controller": "trq_nmpc_eso", "frames": "world NED, body FRD", "solver": "rti x, y"}


def _rows(n: int, rng) -> list[list]:
    """Rows with every kind of value a log holds: negative zero, nan, infinities, tiny and huge
    floats, an integer column that is nan in some rows, strings that first appear late."""
    specials = [0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 1.7976931348623157e308,
                0.1, 1e16, 1e-5, 123456789.123]
    phases = ["takeoff", "hold", "circle", "land", "landed"]
    rows = []
    for k in range(n):
        rows.append([0.01 * k, 1_000_000 + 10_000 * k, float(rng.choice(specials))
                     if k % 3 else float(rng.normal() * 10.0 ** int(rng.integers(-6, 6))),
                     phases[min(k // max(1, n // 5), 4)],
                     math.nan if k % 7 == 0 else int(rng.integers(0, 60)),
                     float(np.float64(rng.uniform(-1, 1)))])
    return rows


def _both(tmp_path, rows):
    csv = CsvLog(tmp_path / "a.csv", COLUMNS, META)
    ulg = UlogLog(tmp_path / "a.ulg", COLUMNS, KINDS, META, timestamp="stamp_us",
                  name="trq_test", flush_every=7)
    for row in rows:
        csv(list(row))
        ulg(list(row))
    csv.close()
    ulg.close()
    return tmp_path / "a.csv", tmp_path / "a.ulg"


def test_the_ground_csv_is_the_flight_csv_byte_for_byte(tmp_path):
    rows = _rows(400, np.random.default_rng(3))
    csv, ulg = _both(tmp_path, rows)
    flight = csv.read_bytes()
    assert to_csv(ulg, tmp_path / "ground.csv").read_bytes() == flight
    assert to_csv(ulg) == csv and csv.read_bytes() == flight          # beside it by default
    assert ulg.read_bytes()[:len(MAGIC)] == MAGIC


def test_pyulog_reads_it_as_a_px4_log(tmp_path):
    """What PX4's tools see (pyulog's ULog: Flight Review, ulog2csv): one topic, its timestamp
    the stamp column, a double per column, the system's name."""
    from pyulog import ULog

    rows = _rows(50, np.random.default_rng(4))
    _, ulg = _both(tmp_path, rows)
    log = ULog(str(ulg))
    assert [d.name for d in log.data_list] == ["trq_test"]
    data = log.data_list[0].data
    assert data["timestamp"].tolist() == [r[1] for r in rows]
    assert np.array_equal(data["y"], [r[5] for r in rows])
    assert log.msg_info_dict["sys_name"] == "trq-ftc"
    assert log.msg_info_dict["trq_meta:solver"] == "rti x, y"


def test_a_file_cut_short_reads_back_to_its_last_whole_row(tmp_path):
    """A killed daemon leaves a partial last message: the rows before it come back, the same
    as the CSV's first rows."""
    rows = _rows(30, np.random.default_rng(5))
    csv, ulg = _both(tmp_path, rows)
    data = ulg.read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:-30])           # into the last row's message (61 bytes)
    lines = to_csv(cut, tmp_path / "cut.csv").read_text().splitlines()
    want = csv.read_text().splitlines()
    assert lines == want[:-1]


def test_bad_definitions_are_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="kinds 'ff'"):
        UlogLog(tmp_path / "b.ulg", COLUMNS, "ff", META, timestamp="stamp_us")
    with pytest.raises(ValueError, match="kinds"):
        UlogLog(tmp_path / "b.ulg", COLUMNS, "fifsiq", META, timestamp="stamp_us")
    with pytest.raises(ValueError, match="'a b'"):
        UlogLog(tmp_path / "b.ulg", ["a b"], "f", META, timestamp="a b")
    with pytest.raises(ValueError, match="timestamp column 'phase'"):
        UlogLog(tmp_path / "b.ulg", COLUMNS, KINDS, META, timestamp="phase")
    with pytest.raises(ValueError, match="'timestamp'"):
        UlogLog(tmp_path / "b.ulg", ["timestamp"], "i", META, timestamp="timestamp")
    with pytest.raises(ValueError, match="meta key 'solver name'"):
        UlogLog(tmp_path / "b.ulg", COLUMNS, KINDS, {"solver name": 1}, timestamp="stamp_us")
    assert not (tmp_path / "b.ulg").exists()             # refused before anything is written


def test_other_files_are_refused_by_name(tmp_path):
    csv, _ = _both(tmp_path, _rows(3, np.random.default_rng(6)))
    with pytest.raises(ValueError, match=r"a\.csv: not a ULog file"):
        to_csv(csv)
    # a ULog, but not one of ours (no kinds): a PX4 log handed to the wrong command
    other = tmp_path / "px4.ulg"
    other.write_bytes(MAGIC + bytes((1,)) + bytes(8))
    with pytest.raises(ValueError, match=r"px4\.ulg: not a log of trq_wire\.ulog"):
        to_csv(other)


def test_the_tail_follows_a_log_being_written(tmp_path):
    """LogTail (a flight's progress read from another process): None before the first row, the
    newest whole row after each flush, never a row cut in half, strings as their indices."""
    from trq_wire.ulog import LogTail

    rows = _rows(40, np.random.default_rng(7))
    path = tmp_path / "live.ulg"
    log = UlogLog(path, COLUMNS, KINDS, META, timestamp="stamp_us", flush_every=1)
    tail = LogTail(path)
    assert tail.last() is None
    for k, row in enumerate(rows):
        log(list(row))
        got = tail.last()
        assert got["stamp_us"] == row[1] and got["t_s"] == row[0], k
    whole = path.read_bytes()
    log.close()
    half = tmp_path / "half.ulg"
    half.write_bytes(whole[:-20])                # the last row half written
    assert LogTail(half).last()["stamp_us"] == rows[-2][1]
    assert LogTail(tmp_path / "none.ulg").last() is None
