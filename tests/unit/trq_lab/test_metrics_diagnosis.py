"""The fault's diagnosis time (trq_lab.metrics.diagnosis_time, and diagnosis_s of
metrics.compute) on synthetic logs with hand-computed answers: the last step outside the band
counts, a diagnosis that wanders off again restarts it, only the faulted motors count, a
missing estimate is outside the band, and None without a faulted motor, without an
effectiveness observer (its log all 1 or NaN) or after a crash."""

from __future__ import annotations

import numpy as np
import pytest

from trq_lab import metrics

STEP_US = 20_000                     # 50 Hz control steps
ONSET_US = 1_000_000
T_US = np.arange(0, 3_000_000, STEP_US, dtype=np.int64)      # 3 s, 150 steps


def factors(motor1: float = 0.5) -> np.ndarray:
    """True factors: motor 1 at `motor1` from the onset on, the others healthy."""
    f = np.ones((len(T_US), 4))
    f[T_US >= ONSET_US, 0] = motor1
    return f


def estimate(converged_us: int, value: float = 0.55) -> np.ndarray:
    """The observer's estimate: every motor at 1, motor 1 at `value` from `converged_us` on
    (and a little noise on the healthy motors, as a real observer has)."""
    e = np.ones((len(T_US), 4))
    e[:, 1:] += 0.01 * np.sin(np.arange(len(T_US)))[:, None]
    e[T_US >= converged_us, 0] = value
    return e


def test_the_last_step_outside_the_band():
    # in the band from 1.30 s on: the last step outside is 1.28 s, 0.28 s after the onset
    got = metrics.diagnosis_time(T_US, estimate(1_300_000), factors(), ONSET_US)
    assert got == pytest.approx(0.28, abs=1e-12)


def test_a_diagnosis_that_wanders_off_again_does_not_count():
    eff = estimate(1_300_000)
    eff[(T_US >= 1_800_000) & (T_US < 2_000_000), 0] = 0.75      # 0.25 off: outside again
    got = metrics.diagnosis_time(T_US, eff, factors(), ONSET_US)
    assert got == pytest.approx(0.98, abs=1e-12)                  # 1.98 s, the last outside


def test_the_band_edge_is_inside():
    # an estimate exactly `band` off is inside (a difference exact in binary: 0.125)
    eff = estimate(1_300_000, value=0.625)
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US, band=0.125) == \
        pytest.approx(0.28, abs=1e-12)
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US, band=0.124) == \
        pytest.approx((T_US[-1] - ONSET_US) * 1e-6)              # never: the last step


def test_already_right_at_the_onset_is_zero():
    eff = estimate(0, value=0.5)                # (as if the estimate had known it all along)
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US) == 0.0


def test_only_the_faulted_motors_count():
    eff = estimate(1_300_000)
    eff[T_US >= 2_500_000, 2] = 0.7            # a healthy motor's estimate 0.3 off late on
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US) == pytest.approx(0.28)


def test_two_faulted_motors_the_later_diagnosis():
    f = factors()
    f[T_US >= ONSET_US, 3] = 0.8
    eff = estimate(1_300_000)
    eff[:, 3] = 1.0
    eff[T_US >= 1_500_000, 3] = 0.8                # motor 4 diagnosed later, at 1.50 s
    assert metrics.diagnosis_time(T_US, eff, f, ONSET_US) == pytest.approx(0.48, abs=1e-12)


def test_a_missing_estimate_is_outside_the_band():
    eff = estimate(1_300_000)
    eff[T_US == 1_700_000, 0] = np.nan
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US) == pytest.approx(0.7,
                                                                                   abs=1e-12)


def test_before_the_onset_does_not_count():
    eff = estimate(1_300_000)
    eff[T_US < 500_000, 0] = 0.2                   # wrong before the fault: not the diagnosis
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US) == pytest.approx(0.28)


@pytest.mark.parametrize("fill", [1.0, np.nan])
def test_no_effectiveness_observer_is_none(fill):
    eff = np.ones((len(T_US), 4))
    eff[::7] = fill                # exactly 1 everywhere, or NaN where a step had no solve
    assert metrics.diagnosis_time(T_US, eff, factors(), ONSET_US) is None


def test_no_faulted_motor_is_none():
    assert metrics.diagnosis_time(T_US, estimate(1_300_000), factors(1.0), ONSET_US) is None


def test_no_step_after_the_onset_is_none():
    assert metrics.diagnosis_time(T_US, estimate(1_300_000), factors(), 10_000_000) is None


# --- through metrics.compute: the logs' columns, the true factor at the controller's stamps


def logs(converged_us: int = 1_300_000):
    """Truth at 100 Hz (the factor steps at a truth row between two controller steps) and the
    controller's steps at 50 Hz, on the reference."""
    t_truth = np.arange(0, 3_000_000, STEP_US // 2, dtype=float)
    n = len(t_truth)
    truth = {"t_us": t_truth, "pos_n_m": np.zeros(n), "pos_e_m": np.zeros(n),
             "pos_d_m": np.full(n, -1.0), "yaw_rad": np.zeros(n), "crashed": np.zeros(n)}
    for i in range(1, 5):
        truth[f"motor{i}_factor"] = np.ones(n)
    truth["motor1_factor"][t_truth >= ONSET_US + STEP_US // 2] = 0.5
    m = len(T_US)
    steps = {"stamp_us": T_US.astype(float), "ref_pos_n_m": np.zeros(m),
             "ref_pos_e_m": np.zeros(m), "ref_pos_d_m": np.full(m, -1.0),
             "ref_yaw_rad": np.zeros(m), "phase": np.array(["hover"] * m, dtype=object),
             "solve_ms": np.full(m, 5.0)}
    eff = estimate(converged_us)
    for i in range(1, 5):
        steps[f"eff_motor{i}"] = eff[:, i - 1]
    return truth, steps


def test_compute_reads_the_logs():
    truth, steps = logs()
    onset = ONSET_US + STEP_US // 2            # the fault between two controller steps
    m = metrics.compute("trq_nmpc_eso", "trq", truth, steps, onset)
    assert m.diagnosis_s == pytest.approx((1_280_000 - onset) * 1e-6, abs=1e-12)
    assert m.as_dict()["diagnosis_s"] == m.diagnosis_s


def test_compute_crashed_is_none():
    truth, steps = logs()
    truth["crashed"][truth["t_us"] >= 2_000_000] = 1.0
    m = metrics.compute("trq_nmpc_eso", "trq", truth, steps, ONSET_US)
    assert m.crashed and m.diagnosis_s is None


def test_compute_without_a_fault_or_the_columns_is_none():
    truth, steps = logs()
    assert metrics.compute("c", "trq", truth, steps, None).diagnosis_s is None
    for i in range(1, 5):
        del steps[f"eff_motor{i}"]
    assert metrics.compute("c", "trq", truth, steps, ONSET_US).diagnosis_s is None


def test_compute_leaves_out_the_landing():
    truth, steps = logs()
    steps["phase"][T_US >= 2_700_000] = "land"                 # the landing from 2.7 s
    truth["landed"] = np.zeros(len(truth["t_us"]))
    truth["landed"][truth["t_us"] >= 2_900_000] = 1.0          # touchdown at 2.9 s
    steps["eff_motor1"][T_US >= 2_800_000] = 0.1               # the ground's reaction
    m = metrics.compute("trq_nmpc_eso", "trq", truth, steps, ONSET_US)
    assert m.diagnosis_s == pytest.approx(0.28, abs=1e-12)
    steps["phase"][:] = "hover"                                # no landing: it counts
    m = metrics.compute("trq_nmpc_eso", "trq", truth, steps, ONSET_US)
    assert m.diagnosis_s == pytest.approx((2_880_000 - ONSET_US) * 1e-6, abs=1e-12)
    truth["landed"][:] = 0.0                                   # and airborne, to the end
    m = metrics.compute("trq_nmpc_eso", "trq", truth, steps, ONSET_US)
    assert m.diagnosis_s == pytest.approx((T_US[-1] - ONSET_US) * 1e-6, abs=1e-12)
