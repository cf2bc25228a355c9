"""A closed-loop flight under a sensing profile, in one process (trq_lab.harness): the sensors
sample every tick of a real flight, the position source lands in flight.csv, and the controller
flies on what the vehicle reports, its estimator's estimate (ODOMETRY with covariances): the
vehicle refuses arming until the estimator is ready and the controller retries, the flight is
flown, and the estimate stays near the truth throughout (judged against truth)."""

from __future__ import annotations

import numpy as np
import pytest

from trq_lab import harness
from trq_lab.metrics import read_csv
from trq_offboard.config import load_controller

from sil_vehicle.sitl import ESTIMATE_LOG_COLUMNS, LOG_COLUMNS

pytestmark = pytest.mark.slow

REFERENCE = {"kind": "hover", "altitude_m": 1.0, "climb_speed_m_s": 0.8, "hold_s": 0.5,
             "duration_s": 1.5, "ramp_s": 0.5}


def test_a_mocap_flight_flies_on_the_estimate_and_logs_the_pose(tmp_path):
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso", REFERENCE, tmp_path))
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing="mocap")
    res = harness.fly_inprocess(cfg, sim, out_dir=tmp_path / "mocap", timeout_s=12.0)
    assert res.status in ("done", "not landed"), res.summary
    _, mocap = read_csv(res.flight_csv)
    assert list(mocap)[len(LOG_COLUMNS):] == ["mocap_t_us", "mocap_pos_n_m", "mocap_pos_e_m",
                                              "mocap_pos_d_m"] + list(ESTIMATE_LOG_COLUMNS)
    assert mocap["pos_d_m"].min() < -0.5        # it flew
    armed = mocap["armed"] > 0.5
    # armed only once the estimator was ready (the vehicle's preflight check)
    assert np.all(mocap["est_aligned"][armed] == 1) and np.all(
        mocap["est_position_valid"][armed] == 1)
    # each row's pose: the latest sample, 10 ms old or more, near the truth of its time
    t, ts = mocap["t_us"], mocap["mocap_t_us"]
    late = np.isfinite(ts)
    assert np.all(t[late] - ts[late] >= 10_000) and np.all(t[late] - ts[late] <= 40_000)
    at = np.searchsorted(t, ts[late])
    ok = (at < len(t)) & (t[np.minimum(at, len(t) - 1)] == ts[late])
    assert ok.sum() > 0.9 * late.sum()
    for a in "ned":
        err = mocap[f"mocap_pos_{a}_m"][late][ok] - mocap[f"pos_{a}_m"][at[ok]]
        assert np.max(np.abs(err)) < 0.005        # 0.5 mm noise: ten sigma
    # the estimate the controller flew on, against the truth, while armed: within three times
    # the vision noise the filter is told (EKF2_EVP_NOISE 0.01 m in the mocap profile; its
    # largest error is the take-off's transient, docs/decisions/2026-12-05-ekf2-defaults.md)
    for a in "ned":
        err = mocap[f"est_pos_{a}_m"][armed] - mocap[f"pos_{a}_m"][armed]
        assert np.max(np.abs(err)) < 0.03, a


def test_the_motion_capture_lost_in_flight_the_vehicle_descends_on_its_estimate(tmp_path):
    """A sensor fault in a closed-loop flight: the motion capture off for good at 1.5 s. The
    estimator dead-reckons for its no-aid timeout, then the vehicle takes over (position lost:
    AUTO.LAND on its estimate), lands and disarms without a crash; flight.csv says when."""
    from sil_vehicle.faultscript import parse_event
    from sil_vehicle.sitl import NAV_FAILURES
    hover = dict(REFERENCE, duration_s=30.0)
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso", hover, tmp_path))
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing="mocap")
    lost = parse_event({"at_s": 1.5, "sensor": "mocap", "failure": "off"})
    res = harness.fly_inprocess(cfg, sim, (lost,), out_dir=tmp_path / "lost", timeout_s=25.0)
    _, log = read_csv(res.flight_csv)
    t = log["t_us"] * 1e-6
    assert not log["crashed"].any()
    failed = log["nav_failure"] == NAV_FAILURES["position"]
    assert failed.any()
    first = t[failed][0]
    timeout_s = 5.0                                    # the estimator's no-aid timeout
    assert 1.5 + timeout_s <= first <= 1.5 + timeout_s + 0.2
    assert np.all(log["sensor_fault_mask"][t > 1.6] == 1 << 6)     # FAILURE_UNIT_SENSOR_VIO
    # it came down and disarmed on its own, level all the way
    assert log["armed"][-1] == 0 and log["landed"][-1] == 1
    assert np.max(np.abs(log["roll_rad"][failed])) < 0.3
