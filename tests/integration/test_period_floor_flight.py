"""The replay controller (trq_lab/bench/period_floor.py) flown over both daemons: the real
controller flies a short lockstep flight, then the daemon with the replay of its controller.csv
flies it again, as `trq-bench-floor` does. In lockstep the vehicle is deterministic and the log
carries the commands at full precision, so the replay's vehicle flies the very same flight
(flight.csv identical, row for row) and the replay's log is the recording's but for the loop's
own measurements. Then a replay flown longer than its recording stops at its end."""

from __future__ import annotations

import subprocess  # noqa: F401  (starts processes: this module is of the slow tier)

import numpy as np
import pytest

from trq_lab import metrics
from trq_lab.bench import period_floor as pf
from trq_lab.bench.period import fly_daemons

pytestmark = pytest.mark.slow      # starts both daemons, twice

SECONDS = 2.5


def test_the_replay_flies_the_recorded_flight(tmp_path):
    real = fly_daemons(SECONDS, "trq_nmpc_eso", tmp_path / "real")
    assert real["vehicle_rc"] == 0
    csv = tmp_path / "real" / "controller.csv"
    _, steps = metrics.read_csv(csv)
    assert len(steps["t_s"]) > 100                    # it flew: armed and stepping
    floor = fly_daemons(SECONDS, "trq_nmpc_eso", tmp_path / "floor",
                        controller_cmd=pf.replay_command(csv))
    assert floor["vehicle_rc"] == 0
    assert floor["controller_rc"] == real["controller_rc"]     # both interrupted at the end
    ok, why = pf.same_flight(tmp_path / "real" / "flight.csv", tmp_path / "floor" / "flight.csv")
    assert ok, why
    _, a = metrics.read_csv(tmp_path / "real" / "flight.csv")
    _, b = metrics.read_csv(tmp_path / "floor" / "flight.csv")
    assert len(a["t_us"]) == len(b["t_us"]) > 100
    for name in a:
        if a[name].dtype != object:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    ok, why = pf.replayed_steps(csv, tmp_path / "floor" / "controller.csv")
    assert ok, why
    _, c = metrics.read_csv(tmp_path / "floor" / "controller.csv")
    assert len(c["t_s"]) == len(steps["t_s"])
    # the vehicle climbed under the replayed commands (not a flight on the ground)
    assert float(np.min(b["pos_d_m"] - b["pos_d_m"][0])) < -0.05


def test_a_replay_flown_beyond_its_recording_stops_at_its_end(tmp_path):
    fly_daemons(1.5, "trq_nmpc_eso", tmp_path / "real")
    csv = tmp_path / "real" / "controller.csv"
    n = len(metrics.read_csv(csv)[1]["t_s"])
    floor = fly_daemons(2.5, "trq_nmpc_eso", tmp_path / "floor",
                        controller_cmd=pf.replay_command(csv))
    assert floor["controller_rc"] == 1            # ReplayDiverged: a FlightError, exit 1
    _, c = metrics.read_csv(tmp_path / "floor" / "controller.csv")
    assert len(c["t_s"]) == n


def test_the_benchs_flight_under_a_sensing_profile(tmp_path):
    """trq-bench-nmpc --daemons --sensing: the vehicle carries the profile (its estimator's
    estimate in the log), and the controller flies on it."""
    run = fly_daemons(SECONDS, "trq_nmpc_eso", tmp_path / "mocap", sensing="mocap")
    assert run["vehicle_rc"] == 0
    _, truth = metrics.read_csv(tmp_path / "mocap" / "flight.csv")
    assert "est_pos_n_m" in truth and "mocap_pos_n_m" in truth
    _, steps = metrics.read_csv(tmp_path / "mocap" / "controller.csv")
    assert len(steps["t_s"]) > 50                     # armed once the estimator was ready
