"""Flight metrics (trq_lab.metrics) on synthetic logs with hand-computed answers: RMSE and
maximum of the position error, the error after the fault onset, yaw wrapping, recovery time,
truncation at a crash, the landed rows and the landing reference below ground, solve-time
percentiles; read_csv against the two real log writers; the true disturbance of the observer
figure against hand arithmetic. The outage metric: max_pos_err_outage_m is the largest position
error from the outage's start to OUTAGE_SETTLE_S after its end, both ends included; an error
before the start, or after the settle, does not count; None without an outage, or when the
flight crashed before the window; the other metrics do not move with it."""

from __future__ import annotations

import math

import numpy as np
import pytest


from trq_lab import metrics

STEP_US = 20_000            # 50 Hz control steps
N_STEPS = 100               # 2 s of flight


def synthetic(n_steps: int = N_STEPS):
    """Truth at 100 Hz (twice the step rate, so that the stamp -> row lookup matters) and
    controller steps at 50 Hz, hovering at 1 m with yaw 0 exactly on the reference."""
    t_truth = np.arange(0, n_steps * STEP_US, STEP_US // 2, dtype=float)
    n = len(t_truth)
    truth = {"t_us": t_truth, "pos_n_m": np.zeros(n), "pos_e_m": np.zeros(n),
             "pos_d_m": np.full(n, -1.0), "yaw_rad": np.zeros(n), "crashed": np.zeros(n)}
    stamps = np.arange(0, n_steps * STEP_US, STEP_US, dtype=float)
    m = len(stamps)
    steps = {"stamp_us": stamps, "ref_pos_n_m": np.zeros(m), "ref_pos_e_m": np.zeros(m),
             "ref_pos_d_m": np.full(m, -1.0), "ref_yaw_rad": np.zeros(m),
             "phase": np.array(["hover"] * m, dtype=object), "solve_ms": np.full(m, 5.0)}
    return truth, steps


def at(truth, t_us: float) -> np.ndarray:
    """Truth rows at or after t_us."""
    return truth["t_us"] >= t_us


def compute(truth, steps, onset=None, threshold=0.1):
    return metrics.compute("trq_nmpc_eso", "trq", truth, steps, onset, threshold)


def test_on_the_reference_everything_is_zero():
    m = compute(*synthetic(), onset=None)
    assert m.rmse_pos_m == 0.0 and m.max_pos_err_m == 0.0
    assert m.rmse_yaw_deg == 0.0 and m.max_yaw_err_deg == 0.0
    assert m.crashed is False and m.recovery_s is None and m.rmse_pos_after_fault_m is None
    assert m.rmse_vert_after_fault_m is None and m.max_sink_after_fault_m is None
    assert m.flight_s == pytest.approx((N_STEPS - 1) * STEP_US * 1e-6)
    assert (m.controller, m.vehicle) == ("trq_nmpc_eso", "trq")


def test_constant_north_offset():
    truth, steps = synthetic()
    truth["pos_n_m"] += 0.1
    m = compute(truth, steps)
    assert m.rmse_pos_m == pytest.approx(0.1, abs=1e-12)
    assert m.max_pos_err_m == pytest.approx(0.1, abs=1e-12)


def test_offset_after_the_fault_only():
    truth, steps = synthetic()
    onset = 1_000_000                                   # step 50 of 100
    truth["pos_e_m"][at(truth, onset)] = 0.3
    truth["pos_d_m"][at(truth, onset)] = -1.4           # and 0.4 m high: |e| = 0.5
    m = compute(truth, steps, onset=onset)
    assert m.rmse_pos_after_fault_m == pytest.approx(0.5, abs=1e-12)
    assert m.rmse_vert_after_fault_m == pytest.approx(0.4, abs=1e-12)   # its vertical part
    assert m.max_sink_after_fault_m == 0.0                # high, not low: no sink
    # half of the steps at 0.5 m, half at 0: sqrt(0.25 / 2)
    assert m.rmse_pos_m == pytest.approx(math.sqrt(0.125), abs=1e-12)
    assert m.max_pos_err_m == pytest.approx(0.5, abs=1e-12)
    # never back under the threshold: the last excursion is the last step
    assert m.recovery_s == pytest.approx(((N_STEPS - 1) * STEP_US - onset) * 1e-6)


def test_vertical_part_and_sink_after_the_fault():
    truth, steps = synthetic()
    onset = 1_000_000
    after = at(truth, onset)
    t = truth["t_us"]
    truth["pos_n_m"][after] = 0.3
    # the down error ramps from 0 to 0.5 m below the reference over the steps after the onset
    ramp = (t - onset) / (t.max() - onset)
    truth["pos_d_m"][after] += 0.5 * ramp[after]
    truth["pos_d_m"][~after] -= 1.0                     # 1 m high before: not a sink, not after
    m = compute(truth, steps, onset=onset)
    down = 0.5 * ramp[np.isin(t, steps["stamp_us"]) & after]
    assert m.rmse_vert_after_fault_m == pytest.approx(math.sqrt(np.mean(down ** 2)), abs=1e-12)
    assert m.max_sink_after_fault_m == pytest.approx(down.max(), abs=1e-12)
    assert m.rmse_pos_after_fault_m ** 2 == pytest.approx(0.09 + m.rmse_vert_after_fault_m ** 2,
                                                          abs=1e-12)


def test_offset_before_the_fault_does_not_count_after():
    truth, steps = synthetic()
    onset = 1_000_000
    truth["pos_n_m"][~at(truth, onset)] = 2.0
    m = compute(truth, steps, onset=onset)
    assert m.rmse_pos_after_fault_m == 0.0
    assert m.recovery_s == 0.0                          # no excursion after the onset
    assert m.rmse_pos_m == pytest.approx(math.sqrt(2.0), abs=1e-12)   # sqrt(4 / 2)


def test_yaw_error_wraps():
    assert metrics.wrap_deg(np.array([350.0, -350.0, 180.0, 10.0, 725.0])) == \
        pytest.approx([-10.0, 10.0, -180.0, 10.0, 5.0])
    truth, steps = synthetic()
    truth["yaw_rad"][:] = math.radians(350.0)
    m = compute(truth, steps)
    assert m.rmse_yaw_deg == pytest.approx(10.0)
    assert m.max_yaw_err_deg == pytest.approx(10.0)
    # reference at +170, truth at -170: 20 deg apart, not 340
    truth["yaw_rad"][:] = math.radians(-170.0)
    steps["ref_yaw_rad"][:] = math.radians(170.0)
    assert compute(truth, steps).max_yaw_err_deg == pytest.approx(20.0)


def test_recovery_is_the_last_excursion_after_onset():
    truth, steps = synthetic()
    onset = 600_000
    t = truth["t_us"]
    truth["pos_n_m"][(t >= 100_000) & (t < 300_000)] = 1.0     # before the onset: ignored
    truth["pos_n_m"][(t >= 700_000) & (t <= 900_000)] = 0.5    # excursion ...
    truth["pos_n_m"][(t > 900_000) & (t <= 1_500_000)] = 0.05  # ... under the threshold ...
    truth["pos_n_m"][t == 1_200_000] = 0.15                    # ... one more excursion
    m = compute(truth, steps, onset=onset, threshold=0.1)
    assert m.recovery_s == pytest.approx(0.6)                  # 1.2 s - 0.6 s
    assert m.crashed is False
    # a larger threshold: only the first excursion counts
    m = compute(truth, steps, onset=onset, threshold=0.2)
    assert m.recovery_s == pytest.approx(0.3)                  # 0.9 s - 0.6 s
    # an excursion exactly at the threshold is not one
    m = compute(truth, steps, onset=onset, threshold=0.5)
    assert m.recovery_s == 0.0


def test_crash_truncates():
    truth, steps = synthetic()
    onset = 500_000
    crash = 1_200_000
    t = truth["t_us"]
    truth["pos_n_m"][(t >= onset) & (t < crash)] = 0.2
    truth["crashed"][t >= crash] = 1.0
    truth["pos_d_m"][t >= crash] = 0.0
    truth["pos_n_m"][t >= crash] = 30.0                 # after the crash: must not count
    truth["yaw_rad"][t >= crash] = 2.0
    m = compute(truth, steps, onset=onset)
    assert m.crashed is True
    assert m.recovery_s is None
    assert m.flight_s == pytest.approx(1.2)
    # steps 0..59 count: 25 at 0, 35 at 0.2 m
    assert m.rmse_pos_m == pytest.approx(math.sqrt(35 * 0.04 / 60))
    assert m.max_pos_err_m == pytest.approx(0.2)
    assert m.rmse_pos_after_fault_m == pytest.approx(0.2)
    assert m.max_yaw_err_deg == 0.0
    d = m.as_dict()
    assert d["crashed"] is True and d["recovery_s"] is None


def test_landed_rows_are_excluded():
    truth, steps = synthetic()
    steps["phase"][80:] = "landed"
    truth["pos_n_m"][at(truth, 80 * STEP_US)] = 5.0     # e.g. resting beside the pad
    steps["phase"][:10] = "takeoff"                     # other phases count
    truth["pos_e_m"][~at(truth, 10 * STEP_US)] = 0.1
    m = compute(truth, steps)
    assert m.max_pos_err_m == pytest.approx(0.1)
    assert m.rmse_pos_m == pytest.approx(math.sqrt(10 * 0.01 / 80))


def test_landing_reference_below_ground_is_clamped():
    truth, steps = synthetic()
    steps["ref_pos_d_m"][50:] = np.linspace(0.05, 0.5, 50)    # aims below the ground
    truth["pos_d_m"][at(truth, 50 * STEP_US)] = 0.0           # sitting on the ground
    m = compute(truth, steps)
    assert m.max_pos_err_m == 0.0
    # and above ground the reference is taken as it is
    truth, steps = synthetic()
    steps["ref_pos_d_m"][:] = -0.5
    truth["pos_d_m"][:] = -0.3
    assert compute(truth, steps).max_pos_err_m == pytest.approx(0.2)


def test_steps_without_truth_rows_are_skipped():
    truth, steps = synthetic()
    steps["stamp_us"][10] += 1                          # a stamp the vehicle never logged
    truth["pos_n_m"][truth["t_us"] == 10 * STEP_US + 1] = 0.0
    steps["ref_pos_n_m"][10] = 99.0                     # would dominate if it were used
    assert compute(truth, steps).max_pos_err_m == 0.0


def test_solve_percentiles():
    truth, steps = synthetic()
    steps["solve_ms"] = np.arange(1.0, N_STEPS + 1.0)   # 1 .. 100 ms
    steps["solve_ms"][0] = math.nan                     # a step without a solve
    m = compute(truth, steps)
    values = np.arange(2.0, N_STEPS + 1.0)              # 2 .. 100 (99 values)
    assert m.solve_ms_p50 == pytest.approx(51.0)
    assert m.solve_ms_p99 == pytest.approx(np.percentile(values, 99))
    assert m.solve_ms_p99 == pytest.approx(2.0 + 0.99 * 98.0)   # linear interpolation
    steps["solve_ms"][:] = math.nan
    m = compute(truth, steps)
    assert math.isnan(m.solve_ms_p50)
    assert m.as_dict()["solve_ms_p50"] is None


# --- read_csv against the writers -------------------------------------------------------------

def test_read_csv_round_trips_the_vehicle_log(tmp_path):
    from trq_wire.logfile import CsvLog as FlightLog
    from sil_vehicle.sitl import LOG_COLUMNS

    path = tmp_path / "flight.csv"
    log = FlightLog(path, LOG_COLUMNS, {"vehicle_file": "/x/trq.yaml", "seed": 3})
    rows = [tuple([10_000 * (k + 1)] + [0.1 * k + j * 1e-3 for j in range(len(LOG_COLUMNS) - 1)])
            for k in range(3)]
    for r in rows:
        log(r)
    log.close()
    meta, cols = metrics.read_csv(path)
    assert meta == {"vehicle_file": "/x/trq.yaml", "seed": "3"}
    assert list(cols) == list(LOG_COLUMNS)
    assert cols["t_us"].tolist() == [10_000, 20_000, 30_000]
    for j, name in enumerate(LOG_COLUMNS):
        assert cols[name].dtype == float
        assert cols[name].tolist() == [r[j] for r in rows]      # repr round-trips exactly


def test_read_csv_round_trips_the_controller_log(tmp_path):
    from trq_offboard.log import COLUMNS, ControllerLog
    from trq_offboard.loop import StepRecord
    from trq_offboard.records import (ActuatorCommand, CommandSource, ReferenceSample,
                                      SolveInfo, SolveStatus, StateEstimate, StepInfo)

    path = tmp_path / "controller.csv"
    log = ControllerLog(path, {"controller": "trq_nmpc_eso"})
    state = StateEstimate((0.1, 0.2, -1.0), (0.0, 0.0, 0.0), (0.01, 0.02, 0.03), (0.0, 0.0, 0.0))
    cmd = ActuatorCommand((60.0, 61.0, 62.0, 63.0), (0.0, 0.1, -0.1, 0.0))
    info = StepInfo(CommandSource.NMPC, SolveInfo(SolveStatus.OK, 2, 0.0042, 1.5),
                    (0.1, 0.2, 0.3, 0.4, 0.5, 0.6), 0.01, 0, 0, 0)
    log(StepRecord(0.02, 20_000, state, ReferenceSample((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), 0.0,
                                                        "takeoff"), cmd, None, None))
    log(StepRecord(0.04, 40_000, state, ReferenceSample((0.0, 0.0, -1.0), (0.0, 0.0, 0.0), 0.0,
                                                        "hover"), cmd, cmd, info))
    log.close()
    meta, cols = metrics.read_csv(path)
    assert meta == {"controller": "trq_nmpc_eso"}
    assert list(cols) == list(COLUMNS)
    assert cols["phase"].dtype == object and cols["phase"].tolist() == ["takeoff", "hover"]
    assert cols["status"].dtype == object and cols["status"].tolist() == ["none", "ok"]
    assert cols["source"].tolist() == ["none", "nmpc"]
    assert cols["stamp_us"].dtype == float and cols["stamp_us"].tolist() == [20_000, 40_000]
    assert math.isnan(cols["solve_ms"][0]) and cols["solve_ms"][1] == pytest.approx(4.2)
    assert cols["d_acc_e_m_s2"][1] == 0.2 and cols["cmd_throttle4_pct"].tolist() == [63.0, 63.0]
    assert math.isnan(cols["applied_tilt2_rad"][0]) and cols["applied_tilt2_rad"][1] == 0.1


# --- true disturbance -------------------------------------------------------------------------

def truth_row(vp, *, cmd=(60.0,) * 4, out=None, vel=(1.0, 0.0, 0.0), wind=(0.0, 0.0, 0.0),
              q=(1.0, 0.0, 0.0, 0.0)):
    out = cmd if out is None else out
    row = {"t_us": [0.0], "armed": [1.0]}
    row.update({f"q{a}": [v] for a, v in zip("wxyz", q)})
    row.update({f"vel_{a}_m_s": [v] for a, v in zip("ned", vel)})
    row.update({f"wind_{a}_m_s": [v] for a, v in zip("ned", wind)})
    for i in range(4):
        row[f"cmd_throttle{i + 1}_pct"] = [cmd[i]]
        row[f"out_throttle{i + 1}_pct"] = [out[i]]
        row[f"cmd_tilt{i + 1}_rad"] = [0.0]
        row[f"out_tilt{i + 1}_rad"] = [0.0]
    return {k: np.array(v, dtype=float) for k, v in row.items()}


def test_true_disturbance_is_zero_when_disarmed(trq):
    row = truth_row(trq, cmd=(0.0,) * 4, out=(0.0,) * 4, vel=(0.0, 0.0, 0.0))
    row["armed"] = np.array([0.0])
    assert np.all(metrics.true_disturbance(row, trq) == 0.0)


def test_true_disturbance_is_zero_without_wind_and_faults(trq):
    d = metrics.true_disturbance(truth_row(trq, vel=(2.0, -1.0, 0.5)), trq)
    assert d.shape == (1, 6)
    assert np.abs(d).max() < 1e-12
    # a command below idle is raised to idle, as the vehicle does: still no disturbance
    d = metrics.true_disturbance(truth_row(trq, cmd=(5.0,) * 4, out=(trq.idle_pct,) * 4), trq)
    assert np.abs(d).max() < 1e-12


def test_true_disturbance_of_the_wind(trq):
    k, m = 0.03125, 2.1                                 # trq.yaml: drag and mass
    assert (trq.drag_N_s2_m2, trq.mass_kg) == (k, m)
    d = metrics.true_disturbance(truth_row(trq, vel=(1.0, 0.0, 0.0), wind=(0.0, 2.0, 0.0)), trq)
    # relative to the air (1, -2, 0), |.| = sqrt 5; without wind (1, 0, 0), |.| = 1
    drag_wind = -k * math.sqrt(5.0) * np.array([1.0, -2.0, 0.0])
    drag_calm = -k * 1.0 * np.array([1.0, 0.0, 0.0])
    assert d[0, :3] == pytest.approx((drag_wind - drag_calm) / m, abs=1e-12)
    assert d[0, 3:] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)


def test_true_disturbance_of_half_a_motor(trq):
    d = metrics.true_disturbance(truth_row(trq, vel=(0.0, 0.0, 0.0), cmd=(60.0,) * 4,
                                           out=(30.0, 60.0, 60.0, 60.0)), trq)
    # eq. (2): thrust 0.0007 z^2 + 0.0157 z - 0.1891 N, torque 2e-6 z^2 + 0.0007 z - 0.008 N m
    df = (0.0007 * 900 + 0.0157 * 30 - 0.1891) - (0.0007 * 3600 + 0.0157 * 60 - 0.1891)
    dtau = (2e-6 * 900 + 0.0007 * 30 - 0.008) - (2e-6 * 3600 + 0.0007 * 60 - 0.008)
    assert df == pytest.approx(0.9119 - 3.2729)
    # motor 1 front right: at 0.23 m along azimuth 45 deg, thrust along -z body, ccw
    px = py = 0.23 * math.sqrt(0.5)
    # level: body = NED, so the lost thrust pushes down (+z)
    assert d[0, :3] == pytest.approx([0.0, 0.0, -df / 2.1], abs=1e-12)
    # r x (0, 0, -f) = (-py f, px f, 0); the ccw drag torque spin * tau about +z
    assert d[0, 3] == pytest.approx(-py * df / 0.01241)     # roll: right side drops
    assert d[0, 4] == pytest.approx(px * df / 0.01241)      # pitch: nose drops
    assert d[0, 5] == pytest.approx(dtau / 0.02365)         # yaw: less right-yaw torque
    assert d[0, 3] > 0 and d[0, 4] < 0 and d[0, 5] < 0


def test_true_disturbance_rotates_the_force_into_ned(trq):
    # rolled 90 deg right: body y points down, body z (where the lost thrust pushes) west
    half = math.sqrt(0.5)
    d = metrics.true_disturbance(truth_row(trq, vel=(0.0, 0.0, 0.0), q=(half, half, 0.0, 0.0),
                                           out=(30.0, 60.0, 60.0, 60.0)), trq)
    df = (0.0007 * 900 + 0.0157 * 30) - (0.0007 * 3600 + 0.0157 * 60)
    assert d[0, :3] == pytest.approx([0.0, df / 2.1, 0.0], abs=1e-9)


# --- the outage metric ----------------------------------------------------------------------------

OUTAGE_STEPS = 300          # 6 s of flight
START_US, END_US = 2_000_000, 3_000_000          # the outage: off at 2 s, ok again at 3 s
SETTLE_US = int(metrics.OUTAGE_SETTLE_S * 1e6)


def compute_outage(truth, steps, outage_us=(START_US, END_US)):
    return metrics.compute("trq_nmpc_eso_fused", "trq", truth, steps, None, 0.1,
                           outage_us=outage_us)


def offset_at(truth, t_us: int, north_m: float) -> None:
    """The vehicle north of the reference by north_m at the truth row stamped t_us."""
    truth["pos_n_m"][truth["t_us"] == t_us] = north_m


def test_without_an_outage_there_is_no_figure():
    truth, steps = synthetic(OUTAGE_STEPS)
    offset_at(truth, START_US, 0.2)
    assert compute_outage(truth, steps, outage_us=None).max_pos_err_outage_m is None
    assert metrics.compute("c", "trq", truth, steps, None).max_pos_err_outage_m is None


def test_the_largest_error_in_the_window():
    truth, steps = synthetic(OUTAGE_STEPS)
    offset_at(truth, START_US + 400_000, 0.03)     # drifting, unseen, in the outage
    offset_at(truth, END_US + 200_000, 0.04)       # flown back after the sensor returned
    m = compute_outage(truth, steps)
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
    truth, steps = synthetic(OUTAGE_STEPS)
    offset_at(truth, t_us, 0.5)
    offset_at(truth, START_US + STEP_US, 0.01)     # the window's own largest error otherwise
    m = compute_outage(truth, steps)
    assert m.max_pos_err_outage_m == pytest.approx(0.5 if counts else 0.01, abs=1e-12)
    assert m.max_pos_err_m == pytest.approx(0.5, abs=1e-12)     # the whole flight's, as ever


def test_a_crash_before_the_window_leaves_it_empty():
    truth, steps = synthetic(OUTAGE_STEPS)
    truth["crashed"][truth["t_us"] >= START_US - 500_000] = 1.0
    m = compute_outage(truth, steps)
    assert m.crashed is True and m.max_pos_err_outage_m is None


def test_a_crash_in_the_window_counts_the_steps_before_it():
    truth, steps = synthetic(OUTAGE_STEPS)
    offset_at(truth, START_US + 100_000, 0.07)
    truth["crashed"][truth["t_us"] >= START_US + 300_000] = 1.0
    m = compute_outage(truth, steps)
    assert m.crashed is True and m.max_pos_err_outage_m == pytest.approx(0.07, abs=1e-12)


def test_outage_error_alone():
    t_us = np.array([0, 1_000_000, 2_000_000, 3_000_000], dtype=np.int64)
    err = np.array([9.0, 0.1, 0.3, 9.0])
    assert metrics.outage_error(t_us, err, (1_000_000, 1_500_000), settle_s=0.5) == 0.3
    assert metrics.outage_error(t_us, err, (1_000_000, 1_500_000), settle_s=0.0) == 0.1
    assert metrics.outage_error(t_us, err, (1_200_000, 1_500_000), settle_s=0.0) is None
    assert metrics.outage_error(t_us, err, None) is None


def test_touchdown_is_the_logs_last_one():
    truth, steps = synthetic()
    assert compute(truth, steps).touchdown_speed_m_s is None          # an older log: no column
    n = len(truth["t_us"])
    speed = np.full(n, np.nan)
    tilt = np.full(n, np.nan)
    speed[n // 2:], tilt[n // 2:] = 0.4, 3.0                           # a touchdown mid-log
    truth |= {"touchdown_speed_m_s": speed, "touchdown_tilt_deg": tilt}
    m = compute(truth, steps)
    assert (m.touchdown_speed_m_s, m.touchdown_tilt_deg) == (0.4, 3.0)
    assert compute(truth | {"touchdown_speed_m_s": np.full(n, np.nan)},
                   steps).touchdown_speed_m_s is None                  # never touched down
