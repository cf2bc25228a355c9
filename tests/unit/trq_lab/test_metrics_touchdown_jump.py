"""The estimator's jump across a touchdown (trq_lab.metrics.touchdown_estimate_jump, issue 39's
touchdown target) on synthetic logs with known answers, and a campaign flight measured again from
its kept logs (trq_lab.campaign.flight.rescore)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import trq_params
from trq_lab import metrics
from trq_lab.campaign.flight import rescore


def _log(step_m=(0.0, 0.0, 0.0), at_s=5.05):
    """100 Hz, 0 to 6 s: descending at 0.5 m/s onto the ground at 5 s (the plant's touchdown
    record from then), the estimate 3 mm north of the truth throughout, and from at_s on off by
    step_m more."""
    t_us = np.arange(0, 6_000_001, 10_000, dtype=np.int64)
    t = t_us * 1e-6
    down = np.minimum(-2.5 + 0.5 * t, 0.0)
    zero = np.zeros_like(t)
    speed = np.where(t >= 5.0, 0.5, np.nan)
    truth = {"t_us": t_us, "pos_n_m": zero.copy(), "pos_e_m": zero.copy(), "pos_d_m": down,
             "touchdown_speed_m_s": speed, "touchdown_tilt_deg": np.where(t >= 5.0, 1.0, np.nan)}
    for a, s in zip("ned", step_m):
        truth[f"est_pos_{a}_m"] = truth[f"pos_{a}_m"] + (0.003 if a == "n" else 0.0) \
            + np.where(t >= at_s, s, 0.0)
    return truth


def test_a_steady_estimate_does_not_jump_and_a_step_at_the_contact_does():
    assert metrics.touchdown_estimate_jump(_log()) == pytest.approx(0.0, abs=1e-12)
    assert metrics.touchdown_estimate_jump(_log((0.0, 0.3, 0.4))) == pytest.approx(0.5)


def test_the_window_ends_post_s_after_the_contact_and_starts_pre_s_before_it():
    late = _log((0.2, 0.0, 0.0), at_s=5.5)
    assert metrics.touchdown_estimate_jump(late) == pytest.approx(0.2)
    assert metrics.touchdown_estimate_jump(late, post_s=0.4) == pytest.approx(0.0, abs=1e-12)
    early = _log((0.2, 0.0, 0.0), at_s=4.7)      # inside the half second before the contact
    assert metrics.touchdown_estimate_jump(early) == pytest.approx(0.2)
    assert metrics.touchdown_estimate_jump(early, pre_s=0.2) == pytest.approx(0.0, abs=1e-12)


def test_a_bounce_is_two_touchdowns_and_the_larger_jump_counts():
    truth = _log((0.0, 0.0, 0.1), at_s=5.6)
    sp = truth["touchdown_speed_m_s"]
    sp[truth["t_us"] >= 5_500_000] = 0.2          # a second contact at 5.5 s
    assert metrics.touchdown_rows(truth) == [500, 550]
    assert metrics.touchdown_estimate_jump(truth, post_s=0.2) == pytest.approx(0.1)


def test_no_estimate_no_touchdown_or_lost_estimate_rows():
    truth = _log()
    assert metrics.touchdown_estimate_jump(
        {k: v for k, v in truth.items() if not k.startswith("est_")}) is None
    truth["touchdown_speed_m_s"] = np.full_like(truth["pos_d_m"], np.nan)
    assert metrics.touchdown_estimate_jump(truth) is None
    truth = _log((0.0, 0.0, 0.05))
    truth["est_pos_d_m"][520:530] = np.nan          # rows without an estimate are left out
    assert metrics.touchdown_estimate_jump(truth) == pytest.approx(0.05)


def _write(path, meta, cols):
    names = list(cols)
    with open(path, "w", encoding="ascii") as f:
        for k, v in meta.items():
            f.write(f"# {k}: {v}\n")
        f.write(",".join(names) + "\n")
        for i in range(len(cols[names[0]])):
            f.write(",".join(str(cols[n][i]) for n in names) + "\n")


def test_rescore_measures_a_flight_again_from_its_kept_logs(tmp_path):
    truth = _log((0.0, 0.0, 0.05))
    n = len(truth["t_us"])
    truth.update({"crashed": np.zeros(n)})
    for a in ("roll", "pitch", "yaw"):
        truth[f"{a}_rad"] = truth[f"est_{a}_rad"] = np.zeros(n)
    steps = {"stamp_us": truth["t_us"], "ref_pos_n_m": np.zeros(n), "ref_pos_e_m": np.zeros(n),
             "ref_pos_d_m": truth["pos_d_m"], "ref_yaw_rad": np.zeros(n),
             "phase": ["land"] * n, "solve_ms": np.full(n, 1.0)}
    spec = {"id": "f1", "controller": "trq_nmpc_eso", "fault": None, "recovery_threshold_m": 0.1}
    logs = tmp_path / "logs"
    (logs / "f1").mkdir(parents=True)
    _write(logs / "f1" / "flight.csv",
           {"vehicle_file": trq_params.resolve("vehicle", "trq")}, truth)
    _write(logs / "f1" / "controller.csv", {}, steps)
    old = {"id": "f1", "spec": spec, "status": "done", "metrics": {"rmse_pos_m": 9.0},
           "wall_s": 1.0}
    new = rescore(old, logs)
    assert new["metrics"]["est_jump_touchdown_m"] == pytest.approx(0.05)
    assert new["metrics"]["rmse_pos_m"] == pytest.approx(0.0)
    assert new["wall_s"] == 1.0 and old["metrics"] == {"rmse_pos_m": 9.0}
    json.dumps(new)                                   # a record as the store writes it
    failed = {**old, "metrics": None}
    assert rescore(failed, logs) is failed
    assert rescore({**old, "spec": {**spec, "id": "gone"}}, logs)["metrics"] == old["metrics"]
