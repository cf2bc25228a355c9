"""The outage metric of trq_lab.metrics on synthetic logs with hand-computed answers:
max_pos_err_outage_m is the largest position error from the outage's start to OUTAGE_SETTLE_S
after its end, both ends included; an error before the start, or after the settle, does not
count; None without an outage, or when the flight crashed before the window; the other metrics
do not move with it."""

from __future__ import annotations

import numpy as np
import pytest

from trq_lab import metrics

STEP_US = 20_000            # 50 Hz control steps
N_STEPS = 300               # 6 s of flight
START_US, END_US = 2_000_000, 3_000_000          # the outage: off at 2 s, ok again at 3 s
SETTLE_US = int(metrics.OUTAGE_SETTLE_S * 1e6)


def synthetic():
    """Truth at 100 Hz and steps at 50 Hz, hovering at 1 m exactly on the reference."""
    t_truth = np.arange(0, N_STEPS * STEP_US, STEP_US // 2, dtype=float)
    n = len(t_truth)
    truth = {"t_us": t_truth, "pos_n_m": np.zeros(n), "pos_e_m": np.zeros(n),
             "pos_d_m": np.full(n, -1.0), "yaw_rad": np.zeros(n), "crashed": np.zeros(n)}
    stamps = np.arange(0, N_STEPS * STEP_US, STEP_US, dtype=float)
    m = len(stamps)
    steps = {"stamp_us": stamps, "ref_pos_n_m": np.zeros(m), "ref_pos_e_m": np.zeros(m),
             "ref_pos_d_m": np.full(m, -1.0), "ref_yaw_rad": np.zeros(m),
             "phase": np.array(["hover"] * m, dtype=object), "solve_ms": np.full(m, 5.0)}
    return truth, steps


def compute(truth, steps, outage_us=(START_US, END_US)):
    return metrics.compute("trq_nmpc_eso_fused", "trq", truth, steps, None, 0.1,
                           outage_us=outage_us)


def offset_at(truth, t_us: int, north_m: float) -> None:
    """The vehicle north of the reference by north_m at the truth row stamped t_us."""
    truth["pos_n_m"][truth["t_us"] == t_us] = north_m


def test_without_an_outage_there_is_no_figure():
    truth, steps = synthetic()
    offset_at(truth, START_US, 0.2)
    assert compute(truth, steps, outage_us=None).max_pos_err_outage_m is None
    assert metrics.compute("c", "trq", truth, steps, None).max_pos_err_outage_m is None


def test_the_largest_error_in_the_window():
    truth, steps = synthetic()
    offset_at(truth, START_US + 400_000, 0.03)     # drifting, unseen, in the outage
    offset_at(truth, END_US + 200_000, 0.04)       # flown back after the sensor returned
    m = compute(truth, steps)
    assert m.max_pos_err_outage_m == pytest.approx(0.04, abs=1e-12)
    assert m.max_pos_err_m == pytest.approx(0.04, abs=1e-12)
    assert m.as_dict()["max_pos_err_outage_m"] == pytest.approx(0.04, abs=1e-12)


@pytest.mark.parametrize("t_us, counts", [
    (START_US - STEP_US, False),                   # the step before the start
    (START_US, True),                              # the start, included
    (END_US, True),
    (END_US + SETTLE_US, True),                    # the end of the settle, included
    (END_US + SETTLE_US + STEP_US, False),         # the step after it
])
def test_the_window_runs_from_the_start_to_the_settle_after_the_end(t_us, counts):
    truth, steps = synthetic()
    offset_at(truth, t_us, 0.5)
    offset_at(truth, START_US + STEP_US, 0.01)     # the window's own largest error otherwise
    m = compute(truth, steps)
    assert m.max_pos_err_outage_m == pytest.approx(0.5 if counts else 0.01, abs=1e-12)
    assert m.max_pos_err_m == pytest.approx(0.5, abs=1e-12)     # the whole flight's, as ever


def test_a_crash_before_the_window_leaves_it_empty():
    truth, steps = synthetic()
    truth["crashed"][truth["t_us"] >= START_US - 500_000] = 1.0
    m = compute(truth, steps)
    assert m.crashed is True and m.max_pos_err_outage_m is None


def test_a_crash_in_the_window_counts_the_steps_before_it():
    truth, steps = synthetic()
    offset_at(truth, START_US + 100_000, 0.07)
    truth["crashed"][truth["t_us"] >= START_US + 300_000] = 1.0
    m = compute(truth, steps)
    assert m.crashed is True and m.max_pos_err_outage_m == pytest.approx(0.07, abs=1e-12)


def test_outage_error_alone():
    t_us = np.array([0, 1_000_000, 2_000_000, 3_000_000], dtype=np.int64)
    err = np.array([9.0, 0.1, 0.3, 9.0])
    assert metrics.outage_error(t_us, err, (1_000_000, 1_500_000), settle_s=0.5) == 0.3
    assert metrics.outage_error(t_us, err, (1_000_000, 1_500_000), settle_s=0.0) == 0.1
    assert metrics.outage_error(t_us, err, (1_200_000, 1_500_000), settle_s=0.0) is None
    assert metrics.outage_error(t_us, err, None) is None
