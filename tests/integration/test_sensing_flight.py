"""A closed-loop flight under a sensing profile, in one process (trq_lab.harness): the sensors
sample every tick of a real flight and the position source lands in flight.csv, while the
flight itself (the controller still reads the state stream) is the flight under `truth`, bit
for bit: the sensors draw from their own generator and send nothing on the offboard link."""

from __future__ import annotations

import numpy as np
import pytest

from trq_lab import harness
from trq_lab.metrics import read_csv
from trq_offboard.config import load_controller

from sil_vehicle.sitl import LOG_COLUMNS

pytestmark = pytest.mark.slow

REFERENCE = {"kind": "hover", "altitude_m": 1.0, "climb_speed_m_s": 0.8, "hold_s": 0.5,
             "duration_s": 1.5, "ramp_s": 0.5}


def test_a_mocap_flight_logs_the_pose_and_flies_as_under_truth(tmp_path):
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso", REFERENCE, tmp_path))
    logs = {}
    for sensing in ("truth", "mocap"):
        sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing=sensing)
        res = harness.fly_inprocess(cfg, sim, out_dir=tmp_path / sensing, timeout_s=8.0)
        assert res.status in ("done", "not landed", "timeout"), res.summary
        logs[sensing] = read_csv(res.flight_csv)
    (meta_t, truth), (meta_m, mocap) = logs["truth"], logs["mocap"]
    assert list(truth) == list(LOG_COLUMNS) and "sensing" not in meta_t
    assert list(mocap)[len(LOG_COLUMNS):] == ["mocap_t_us", "mocap_pos_n_m", "mocap_pos_e_m",
                                              "mocap_pos_d_m"]
    for c in LOG_COLUMNS:                       # the same flight, bit for bit
        assert np.array_equal(truth[c], mocap[c]), c
    assert truth["pos_d_m"].min() < -0.5        # it flew
    # each row's pose: the latest sample, 10 ms old or more, near the truth of its time
    t, ts = mocap["t_us"], mocap["mocap_t_us"]
    assert np.all(t - ts >= 10_000) and np.all(t - ts <= 40_000)
    at = np.searchsorted(t, ts)
    ok = (at < len(t)) & (t[np.minimum(at, len(t) - 1)] == ts)
    assert ok.sum() > 0.9 * len(t)
    for a in "ned":
        err = mocap[f"mocap_pos_{a}_m"][ok] - mocap[f"pos_{a}_m"][at[ok]]
        assert np.max(np.abs(err)) < 0.005        # 0.5 mm noise: ten sigma
