"""The daemon's flight log under a sensing profile (sil_vehicle.daemon.VehicleDaemon): the
position source's columns and the profile in the header; under truth the header as before."""

from __future__ import annotations

from sil_vehicle.config import sensing_profile
from sil_vehicle.daemon import VehicleDaemon
from sil_vehicle.sitl import ESTIMATE_LOG_COLUMNS, LOG_COLUMNS
from trq_wire.logfile import read_header


def header(path):
    with open(path) as f:
        return read_header(f)


def test_truth_keeps_the_header(sim, tmp_path):
    d = VehicleDaemon(sim, tmp_path)
    d.close()
    meta, columns = header(tmp_path / "flight.csv")
    assert columns == list(LOG_COLUMNS) and "sensing" not in meta


def test_a_position_source_adds_its_columns(sim, tmp_path):
    d = VehicleDaemon(sim.with_changes(sensing=sensing_profile("rtk", 1000, "t")), tmp_path)
    for _ in range(200):
        d.sitl.step()
    d.flight_log(d.sitl.log_row())
    d.close()
    meta, columns = header(tmp_path / "flight.csv")
    assert meta["sensing"].endswith("rtk.yaml")
    assert columns == list(LOG_COLUMNS) + ["gnss_t_us", "gnss_pos_n_m", "gnss_pos_e_m",
                                           "gnss_pos_d_m"] + list(ESTIMATE_LOG_COLUMNS)
    rows = (tmp_path / "flight.csv").read_text().splitlines()
    last = dict(zip(columns, rows[-1].split(",")))
    assert len(last) == len(columns) and last["gnss_t_us"] == "0"   # the fix of t = 0 (110 ms)
    assert last["est_aligned"] in ("0", "1") and float(last["est_pos_d_m"]) == float(
        last["est_pos_d_m"])                                        # the estimate, a number
