"""The motion capture wired as on a rig (sim `mocap_wiring: companion`, trq_wire.mocap): the
simulated mocap PC streams ATT_POS_MOCAP from its own system to the companion, the companion
forwards each pose to the autopilot as external vision (ODOMETRY, estimator_type MOCAP), and
the autopilot's estimator flies on the forwarded copies, which arrive a control period or less
after the pose reached the companion. One short in-process flight, deterministic."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from trq_lab import harness
from trq_lab.metrics import read_csv
from trq_offboard.config import load_controller

pytestmark = pytest.mark.slow

REFERENCE = {"kind": "hover", "altitude_m": 1.0, "climb_speed_m_s": 0.8, "hold_s": 0.5,
             "duration_s": 1.5, "ramp_s": 0.5}


def fly(cfg, tmp_path, name):
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing="mocap")
    sim = dataclasses.replace(sim, mocap_wiring="companion")
    return harness.fly_inprocess(cfg, sim, out_dir=tmp_path / name, timeout_s=12.0)


def test_a_flight_on_the_forwarded_pose(tmp_path):
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso", REFERENCE, tmp_path))
    res = fly(cfg, tmp_path, "a")
    assert res.status in ("done", "not landed"), res.summary
    _, log = read_csv(res.flight_csv)
    assert log["pos_d_m"].min() < -0.5                    # it flew, armed on the estimate
    armed = log["armed"] > 0.5
    assert np.all(log["est_position_valid"][armed] == 1)
    for a in "ned":
        # the filter trusts the forwarded pose to EKF2_EVP_NOISE (0.01 m, as a motion-capture
        # user sets it) and integrates the vibrating IMU between poses: within three of those
        err = log[f"est_pos_{a}_m"][armed] - log[f"pos_{a}_m"][armed]
        assert np.max(np.abs(err)) < 0.03, a
    # lockstep stays deterministic: the same flight again, the same log
    again = fly(cfg, tmp_path, "b")
    assert harness.fingerprint(res.flight_csv) == harness.fingerprint(again.flight_csv)


def test_over_udp_the_daemons_carry_the_mocap_pcs_pose_and_its_forward(tmp_path, daemons):
    """Both daemons over UDP in lockstep: the vehicle daemon hosts the mocap PC (system 200 on
    the offboard port), trq-offboard forwards each pose, the vehicle's estimator flies on the
    forwards: the hover is flown, landed and disarmed, on an estimate within a centimetre."""
    from pathlib import Path

    import yaml
    from test_offboard_daemon import HOVER, assert_landed_summary, fly_all, logs, start_flight

    import trq_params

    src = Path(trq_params.resolve("sim", "default"))
    sim = yaml.safe_load(src.read_text())
    sim["vehicle"] = str((src.parent / sim["vehicle"]).resolve())
    sim["mocap_wiring"] = "companion"
    sim_file = tmp_path / "companion.yaml"
    sim_file.write_text(yaml.safe_dump(sim))
    flight = start_flight(daemons, tmp_path / "udp", "trq_nmpc_eso", HOVER, "--mode",
                          "lockstep", "--sim", str(sim_file), "--sensing", "mocap")
    fly_all([flight], 180.0)
    assert_landed_summary(flight)
    truth, _ = logs(flight)
    armed = truth["armed"] > 0.5
    assert truth["pos_d_m"].min() < -0.5
    for a in "ned":
        assert np.max(np.abs(truth[f"est_pos_{a}_m"][armed] - truth[f"pos_{a}_m"][armed])) < 0.03   # as above: three of EKF2_EVP_NOISE
