"""Flight metrics of a scenario run, from the two logs: the vehicle's truth (flight.csv) and the
controller's steps (controller.csv). Pure functions of arrays, so they can be tested on synthetic
logs with known answers.

Errors are truth minus reference at the controller's steps (the stamps of both logs are the
vehicle's microseconds). A run's metrics cover the flight from the first step to touchdown or to
the crash, whichever comes first:

    rmse_pos_m, max_pos_err_m      norm of the 3-D position error
    rmse_pos_after_fault_m         the same from the fault onset on
    rmse_vert_after_fault_m        its vertical part (down axis; the horizontal part is
                                   sqrt(after^2 - vert^2)): after a motor loss the vehicle hovers
                                   near full thrust, so height lost in the transient is slow to
                                   win back and this part usually dominates
    max_sink_after_fault_m         the largest height below the reference after the onset (0 if
                                   it never was below)
    rmse_yaw_deg, max_yaw_err_deg  yaw error, wrapped to +-180 deg
    recovery_s                     from the onset to the last time the position error exceeded
                                   the recovery threshold (0 if it never did; None if crashed)
    diagnosis_s                    from the onset to the last time the controller's estimated
                                   effectiveness of a faulted motor (eff_motorN) was more than
                                   DIAGNOSIS_BAND from the true one (motorN_factor): see
                                   `diagnosis_time`; over the steps before the landing (None
                                   without a faulted motor, without an effectiveness observer,
                                   or if crashed)
    solve_ms_p50, solve_ms_p99     controller solve time per step
    touchdown_speed_m_s            the vehicle's last touchdown: its down speed just before the
    touchdown_tilt_deg             gear touched and its tilt from vertical then (flight.csv's
                                   columns; None without a touchdown or from an older log)
    max_pos_err_outage_m           with a sensor outage (a campaign's `outage` axis): the
                                   largest position error from the outage's start to
                                   OUTAGE_SETTLE_S after its end (None without an outage, or
                                   with no step in that window)
    est_jump_touchdown_m           the vehicle's estimator across its touchdowns: the largest
                                   change of its position error (estimate minus truth) from
                                   TOUCHDOWN_JUMP_PRE_S before a touchdown to TOUCHDOWN_JUMP_POST_S
                                   after it (`touchdown_estimate_jump`; None under `truth`, or
                                   without a touchdown)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from trq_wire.logfile import read_header

GROUND_DOWN_M = 0.0
# how close the controller's estimated effectiveness of a faulted motor must come to the true
# factor for the fault to count as diagnosed (issue 33: MOT1_EFF within 0.1 of the true value)
DIAGNOSIS_BAND = 0.1
# how long after a sensor outage ends its window still counts: while the sensor is off the
# estimate drifts and the controller takes the vehicle away with it, unseen; when the sensor
# returns, the estimator jumps back to it and the controller flies the vehicle back, and that
# return (its overshoot included) is part of what the outage cost. One second is a few of the
# position loop's time constants, and short enough that the flight's own tracking error (the
# fault's transient, max_pos_err_m) does not stand in for the outage's
OUTAGE_SETTLE_S = 1.0
# the window of est_jump_touchdown_m around each touchdown (issue 39: no estimator position jump
# above 0.1 m across a landing). Before: the error half a second ahead of the contact is the
# estimate as it flew, before the gear's impulse reaches the IMU (a choice: a few filter time
# constants of the vision's fusion, short against the landing's descent). After: two seconds
# hold the impulse, the clipping and what the filter makes of them (a choice); a campaign's log
# ends when the controller's landing is done, so usually sooner
TOUCHDOWN_JUMP_PRE_S = 0.5
TOUCHDOWN_JUMP_POST_S = 2.0


@dataclass(frozen=True)
class RunMetrics:
    controller: str
    vehicle: str
    crashed: bool
    flight_s: float
    rmse_pos_m: float
    max_pos_err_m: float
    rmse_pos_after_fault_m: float | None
    rmse_vert_after_fault_m: float | None
    max_sink_after_fault_m: float | None
    rmse_yaw_deg: float
    max_yaw_err_deg: float
    recovery_s: float | None
    solve_ms_p50: float
    solve_ms_p99: float
    # the vehicle's estimator against the truth, over the controlled flight (None under the
    # `truth` sensing profile, whose flight.csv has no estimate)
    est_rmse_pos_m: float | None = None
    est_rmse_att_deg: float | None = None
    diagnosis_s: float | None = None
    max_pos_err_outage_m: float | None = None
    # a whole motor lost (issue 40): the lost-motor block below (`lost_motor_metrics`); the
    # touchdown's (`touchdown`): after a fault the first after its onset, else the last
    max_thrust_tilt_after_fault_deg: float | None = None
    drift_after_fault_m: float | None = None
    descent_rate_m_s: float | None = None
    touchdown_speed_m_s: float | None = None
    touchdown_tilt_deg: float | None = None
    detection_s: float | None = None
    est_jump_touchdown_m: float | None = None

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def read_csv(path: Path) -> tuple[dict[str, str], dict[str, np.ndarray]]:
    """(metadata, columns) of a log with '# key: value' header lines. Text columns stay text."""
    with open(path, encoding="ascii") as f:
        meta, names = read_header(f)
        rows = [r.rstrip("\n").split(",") for r in f if r.strip()]
    cols: dict[str, np.ndarray] = {}
    for i, name in enumerate(names):
        raw = [r[i] for r in rows if len(r) == len(names)]
        try:
            cols[name] = np.array(raw, dtype=float)
        except ValueError:
            cols[name] = np.array(raw, dtype=object)
    return meta, cols


def wrap_deg(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class Samples:
    """The samples the metrics are taken over: each controller step whose stamp is a truth row,
    before a crash and before the landed phase."""
    t_us: np.ndarray            # the steps' stamps
    rows: np.ndarray            # their truth rows
    keep: np.ndarray            # which steps (bool, over all of `steps`)
    pos: np.ndarray             # (n, 3) the vehicle's true position, NED
    ref: np.ndarray             # (n, 3) the reference (down clamped at the ground)
    crash_us: int | None


def samples(truth: dict[str, np.ndarray], steps: dict[str, np.ndarray]) -> Samples:
    """The vehicle's truth against the reference at every kept control step."""
    t_truth = truth["t_us"].astype(np.int64)
    crashed_rows = np.flatnonzero(truth["crashed"] > 0.5)
    crash_us = int(t_truth[crashed_rows[0]]) if len(crashed_rows) else None
    stamps = steps["stamp_us"].astype(np.int64)
    index = {int(t): i for i, t in enumerate(t_truth)}
    keep = np.array([int(s) in index for s in stamps], dtype=bool)
    if crash_us is not None:
        keep &= stamps < crash_us
    phase = steps.get("phase")
    if phase is not None:
        keep &= np.array([p != "landed" for p in phase], dtype=bool)
    rows = np.array([index[int(s)] for s in stamps[keep]], dtype=np.int64)
    pos = np.column_stack([truth[f"pos_{a}_m"][rows] for a in "ned"])
    ref = np.column_stack([steps[f"ref_pos_{a}_m"][keep] for a in "ned"])
    # the landing reference aims a little below the ground so that the vehicle settles: the
    # ground (home, down = 0) is where it can get to
    ref[:, 2] = np.minimum(ref[:, 2], GROUND_DOWN_M)
    return Samples(stamps[keep], rows, keep, pos, ref, crash_us)


def diagnosis_time(t_us: np.ndarray, eff: np.ndarray, true_factor: np.ndarray,
                   fault_onset_us: int, band: float = DIAGNOSIS_BAND) -> float | None:
    """Seconds from the fault onset to the diagnosis of the faulted motor(s), defined like
    recovery_s: the last step from the onset on at which the estimate of a faulted motor was
    outside `band` of the true factor (or not finite), so a diagnosis that wanders off again
    does not count until it is back for good; 0 if it never was outside; the time of the last
    step if it is outside at the end.

    t_us (n,) the controller's steps; eff (n, 4) the controller's estimated effectiveness at
    them (eff_motor1..4); true_factor (n, 4) the true factors at the same stamps. A motor is
    faulted when its true factor differs from 1 at a step from the onset on. None when no motor
    is faulted, when no step is at or after the onset, or when the controller has no
    effectiveness observer: its log then holds exactly 1 (StepInfo's default) or NaN (a step
    without a solve) for every motor at every step."""
    t_us = np.asarray(t_us, dtype=np.int64)
    eff = np.asarray(eff, dtype=float)
    true_factor = np.asarray(true_factor, dtype=float)
    sel = t_us >= fault_onset_us
    finite = eff[np.isfinite(eff)]
    if not sel.any() or np.all(finite == 1.0):
        return None
    faulted = np.flatnonzero(np.any(true_factor[sel] != 1.0, axis=0))
    if len(faulted) == 0:
        return None
    e, f = eff[:, faulted], true_factor[:, faulted]
    outside = np.any(~np.isfinite(e) | (np.abs(e - f) > band), axis=1)
    over = np.flatnonzero(sel & outside)
    return 0.0 if len(over) == 0 else float((t_us[over[-1]] - fault_onset_us) * 1e-6)


def outage_error(t_us: np.ndarray, err: np.ndarray, outage_us: tuple[int, int] | None,
                 settle_s: float = OUTAGE_SETTLE_S) -> float | None:
    """The largest position error `err` (m, at the steps' stamps `t_us`) from an outage's start
    to `settle_s` after its end, both included: outage_us is (start, end) in vehicle
    microseconds. None without an outage or without a step in the window (a crash before it)."""
    if outage_us is None:
        return None
    start_us, end_us = outage_us
    sel = (t_us >= start_us) & (t_us <= end_us + int(round(settle_s * 1e6)))
    return float(err[sel].max()) if sel.any() else None


def compute(controller: str, vehicle: str, truth: dict[str, np.ndarray],
            steps: dict[str, np.ndarray], fault_onset_us: int | None,
            recovery_threshold_m: float = 0.1, *,
            outage_us: tuple[int, int] | None = None) -> RunMetrics:
    """Metrics of one run; `truth` and `steps` as read by read_csv; `outage_us`, a sensor
    outage's (start, end) in vehicle microseconds, for max_pos_err_outage_m."""
    sm = samples(truth, steps)
    t_us, crash_us = sm.t_us, sm.crash_us
    stamps = steps["stamp_us"].astype(np.int64)
    err = np.linalg.norm(sm.pos - sm.ref, axis=1)
    down_err = sm.pos[:, 2] - sm.ref[:, 2]            # > 0: below the reference
    yaw_err = wrap_deg(np.degrees(truth["yaw_rad"][sm.rows] - steps["ref_yaw_rad"][sm.keep]))

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan

    after = vert = sink = None
    recovery = None
    if fault_onset_us is not None:
        sel = t_us >= fault_onset_us
        after, vert = rms(err[sel]), rms(down_err[sel])       # nan when no step is after
        sink = float(max(0.0, down_err[sel].max())) if sel.any() else math.nan
        if crash_us is None and sel.any():
            over = np.flatnonzero(sel & (err > recovery_threshold_m))
            recovery = 0.0 if len(over) == 0 else float((t_us[over[-1]] - fault_onset_us) * 1e-6)
    solve = steps["solve_ms"][np.isfinite(steps["solve_ms"])]
    flight_end = crash_us if crash_us is not None else (int(stamps[-1]) if len(stamps) else 0)
    est_pos = est_att = None
    if "est_pos_n_m" in truth and len(stamps):
        rows = (truth["t_us"] >= stamps[0]) & (truth["t_us"] <= flight_end)
        d_pos = np.stack([truth[f"est_pos_{a}_m"][rows] - truth[f"pos_{a}_m"][rows]
                          for a in "ned"], axis=1)
        d_att = np.stack([wrap_deg(np.degrees(truth[f"est_{a}_rad"][rows]
                                              - truth[f"{a}_rad"][rows]))
                          for a in ("roll", "pitch", "yaw")], axis=1)
        est_pos = rms(np.linalg.norm(d_pos, axis=1))
        est_att = rms(np.linalg.norm(d_att, axis=1))
    return RunMetrics(
        controller=controller, vehicle=vehicle, crashed=crash_us is not None,
        flight_s=float((flight_end - (int(stamps[0]) if len(stamps) else 0)) * 1e-6),
        rmse_pos_m=rms(err), max_pos_err_m=float(err.max()) if len(err) else math.nan,
        rmse_pos_after_fault_m=after, rmse_vert_after_fault_m=vert,
        max_sink_after_fault_m=sink, rmse_yaw_deg=rms(yaw_err),
        max_yaw_err_deg=float(np.abs(yaw_err).max()) if len(yaw_err) else math.nan,
        recovery_s=recovery,
        solve_ms_p50=float(np.percentile(solve, 50)) if len(solve) else math.nan,
        solve_ms_p99=float(np.percentile(solve, 99)) if len(solve) else math.nan,
        est_rmse_pos_m=est_pos, est_rmse_att_deg=est_att,
        diagnosis_s=_diagnosis(sm, truth, steps, fault_onset_us),
        max_pos_err_outage_m=outage_error(t_us, err, outage_us),
        est_jump_touchdown_m=touchdown_estimate_jump(truth),
        **_with_last_touchdown(lost_motor_metrics(truth, steps, fault_onset_us), truth))


def _with_last_touchdown(out: dict, truth: dict[str, np.ndarray]) -> dict:
    """A flight with no fault (or none touched down after it): its last touchdown, as the plant
    recorded it (`touchdown_speed_m_s`, `touchdown_tilt_deg` of flight.csv)."""
    if out.get("touchdown_speed_m_s") is None:
        out["touchdown_speed_m_s"] = _last_finite(truth, "touchdown_speed_m_s")
        out["touchdown_tilt_deg"] = _last_finite(truth, "touchdown_tilt_deg")
    return out


def _last_finite(truth: dict[str, np.ndarray], column: str) -> float | None:
    """The log's last finite value of `column` (None: no such column, or never set)."""
    values = truth.get(column)
    if values is None:
        return None
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if len(finite) else None


def _diagnosis(sm: Samples, truth: dict[str, np.ndarray], steps: dict[str, np.ndarray],
               fault_onset_us: int | None) -> float | None:
    """diagnosis_s over the kept steps before the landing (None if crashed, without a fault or
    without the columns): the true factors interpolated at the controller's stamps. The
    touchdown puts the ground's reaction into the observer's disturbance, which the
    effectiveness observer reads as a motor's deficit: from the reference's landing phase on
    ("land"; the vehicle's `landed` too) the estimate says nothing of the diagnosis."""
    if (fault_onset_us is None or sm.crash_us is not None or "eff_motor1" not in steps
            or "motor1_factor" not in truth):
        return None
    airborne = np.ones(len(sm.rows), dtype=bool)
    if "landed" in truth:
        airborne &= truth["landed"][sm.rows] < 0.5
    if "phase" in steps:
        phase = steps["phase"][sm.keep]
        landing = np.flatnonzero(phase == "land")
        if len(landing):
            airborne[landing[0]:] = False
    t_us = sm.t_us[airborne]
    t_truth = truth["t_us"].astype(np.int64)
    true_factor = np.column_stack([np.interp(t_us, t_truth, truth[f"motor{i}_factor"])
                                   for i in range(1, 5)])
    eff = np.column_stack([steps[f"eff_motor{i}"][sm.keep][airborne] for i in range(1, 5)])
    return diagnosis_time(t_us, eff, true_factor, fault_onset_us)


def true_disturbance(truth: dict[str, np.ndarray], vehicle_params) -> np.ndarray:
    """The disturbance the observer should see, per truth row (n x 6): what the real outputs,
    wind and faults do minus what the nominal model predicts from the commands, as NED
    acceleration (m/s^2) and body angular acceleration (rad/s^2). Uses the simulator's own
    pure dynamics (tools may import it; the controller never does)."""
    from sil_vehicle.dynamics.environment import drag_force_ned
    from sil_vehicle.dynamics.rotors import body_wrench
    from sil_vehicle.frames import quat_to_dcm

    vp = vehicle_params
    n = len(truth["t_us"])
    out = np.zeros((n, 6))
    ixx, iyy, izz = vp.inertia_kg_m2
    for k in range(n):
        q = [truth[f"q{a}"][k] for a in "wxyz"]
        rot = np.array(quat_to_dcm(*q))
        vel = [truth[f"vel_{a}_m_s"][k] for a in "ned"]
        wind = [truth[f"wind_{a}_m_s"][k] for a in "ned"]
        out_thr = [truth[f"out_throttle{i}_pct"][k] for i in range(1, 5)]
        out_tilt = [truth[f"out_tilt{i}_rad"][k] for i in range(1, 5)]
        armed = truth["armed"][k] > 0.5
        # what the commands would give on the nominal vehicle (disarmed: motors stopped)
        cmd_thr = [max(truth[f"cmd_throttle{i}_pct"][k], vp.idle_pct) if armed else 0.0
                   for i in range(1, 5)]
        cmd_tilt = [0.0 if (vp.tilt_locked or not armed) else truth[f"cmd_tilt{i}_rad"][k]
                    for i in range(1, 5)]
        real = np.array(body_wrench(out_thr, out_tilt, vp))
        nominal = np.array(body_wrench(cmd_thr, cmd_tilt, vp))
        drag_real = np.array(drag_force_ned(vel, wind, vp.drag_N_s2_m2))
        drag_nominal = np.array(drag_force_ned(vel, (0.0, 0.0, 0.0), vp.drag_N_s2_m2))
        out[k, 0:3] = (rot @ (real[0:3] - nominal[0:3]) + drag_real - drag_nominal) / vp.mass_kg
        dm = real[3:6] - nominal[3:6]
        out[k, 3:6] = (dm[0] / ixx, dm[1] / iyy, dm[2] / izz)
    return out


# --------------------------------------------------------------------------------------------
# a whole motor lost (issue 40): from the fault's onset to the first ground contact
# --------------------------------------------------------------------------------------------
# the vehicle touches the ground when its truth position is this close to it (m, down): the
# landing gear's height above the reference point is 0 in the plant (a choice of the metric)
CONTACT_DOWN_M = -0.02


def thrust_tilt_deg(truth: dict[str, np.ndarray]) -> np.ndarray:
    """The angle (deg) between the body's thrust axis (-z FRD) and the world's up, per truth
    row, from the attitude quaternion (qw, qx, qy, qz): acos(1 - 2 (qx^2 + qy^2)); yaw-free."""
    c = 1.0 - 2.0 * (truth["qx"] ** 2 + truth["qy"] ** 2)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def touchdown(truth: dict[str, np.ndarray], after_us: int) -> int | None:
    """The truth row of the first touchdown from `after_us` on: where the plant's own record of
    its touchdowns (flight.csv's `touchdown_speed_m_s`, docs/simulator.md) shows a new one; in
    a log without that record, the vehicle within CONTACT_DOWN_M of the ground or the plant's
    `landed` flag set. None if it never touches (a crash in the air, a tumble, is no touchdown:
    the log ends soon after it). THE definition of the touchdown for touchdown_speed_m_s and
    touchdown_tilt_deg (one function, so that there is one)."""
    t = truth["t_us"].astype(np.int64)
    if "touchdown_speed_m_s" in truth:
        hit = [i for i in touchdown_rows(truth) if t[i] >= after_us]
        return hit[0] if hit else None
    on = truth["pos_d_m"] >= GROUND_DOWN_M + CONTACT_DOWN_M
    if "landed" in truth:
        on |= truth["landed"] > 0.5
    hit = np.flatnonzero((t >= after_us) & on)
    return int(hit[0]) if len(hit) else None


def touchdown_rows(truth: dict[str, np.ndarray]) -> list[int]:
    """Every touchdown's truth row in the plant's own record (sil_vehicle.vehicle,
    docs/simulator.md): a row where a new touchdown's speed appears in flight.csv's
    `touchdown_speed_m_s`. Empty without that column (an older log) or without a touchdown."""
    sp = truth.get("touchdown_speed_m_s")
    if sp is None:
        return []
    prev = np.concatenate(([np.nan], sp[:-1]))
    return [int(i) for i in np.flatnonzero(np.isfinite(sp) & ~(sp == prev))]


def touchdown_estimate_jump(truth: dict[str, np.ndarray], pre_s: float = TOUCHDOWN_JUMP_PRE_S,
                            post_s: float = TOUCHDOWN_JUMP_POST_S) -> float | None:
    """How far the vehicle's position estimate jumps across its touchdowns (m): for each
    touchdown (`touchdown_rows`), the estimate's error e = est_pos - pos (NED) at the last row
    at or before pre_s ahead of the contact is the reference, and the jump is the largest
    |e - e_ref| (3-D) over the rows from there to post_s after the contact (or the log's end);
    the largest over all touchdowns (a bounce is two). A slow drift of the estimate counts as
    much as a step, since both put the vehicle's idea of where it stands off by that much. Rows
    without a finite estimate are left out (the reference is the last finite one). None under
    `truth` (no est_pos_* columns), without a touchdown, or without a finite estimate ahead of
    any."""
    if "est_pos_n_m" not in truth:
        return None
    t = truth["t_us"].astype(np.int64)
    err = np.stack([truth[f"est_pos_{a}_m"] - truth[f"pos_{a}_m"] for a in "ned"], axis=1)
    finite = np.all(np.isfinite(err), axis=1)
    jumps = []
    for i in touchdown_rows(truth):
        before = np.flatnonzero(finite & (t <= t[i] - int(round(pre_s * 1e6))))
        if not len(before):                  # no estimate ahead of this contact to start from
            continue
        i0 = int(before[-1])
        win = finite & (t >= t[i0]) & (t <= t[i] + int(round(post_s * 1e6)))
        jumps.append(float(np.linalg.norm(err[win] - err[i0], axis=1).max()))
    return max(jumps) if jumps else None


def lost_motor_metrics(truth: dict[str, np.ndarray], steps: dict[str, np.ndarray],
                       fault_onset_us: int | None) -> dict:
    """The lost-motor metrics of a run (all None without a fault), from the fault's onset to the
    first ground contact (`touchdown`; the log's end without one):

        max_thrust_tilt_after_fault_deg  the largest tilt of the thrust axis from the vertical
        drift_after_fault_m              the largest horizontal distance from where the vehicle
                                         was at the onset
        descent_rate_m_s                 height lost over the time taken, onset to contact
        touchdown_speed_m_s              the vertical speed (down, m/s) at the contact (the
                                         last truth row before it)
        touchdown_tilt_deg               the thrust axis' tilt at the contact
        detection_s                      from the onset to the first controller step that flies
                                         a motor as lost (controller.csv's lost_motor; None if
                                         it never does or has no such column)
    """
    keys = ("max_thrust_tilt_after_fault_deg", "drift_after_fault_m", "descent_rate_m_s",
            "touchdown_speed_m_s", "touchdown_tilt_deg", "detection_s")
    out = dict.fromkeys(keys)
    if fault_onset_us is None or "qx" not in truth:
        return out
    t = truth["t_us"].astype(np.int64)
    after = np.flatnonzero(t >= fault_onset_us)
    if not len(after):
        return out
    i0 = int(after[0])
    i1 = touchdown(truth, fault_onset_us)
    end = i1 if i1 is not None else len(t) - 1
    tilt = thrust_tilt_deg(truth)
    win = slice(i0, end + 1)
    out["max_thrust_tilt_after_fault_deg"] = float(tilt[win].max())
    dn = truth["pos_n_m"][win] - truth["pos_n_m"][i0]
    de = truth["pos_e_m"][win] - truth["pos_e_m"][i0]
    out["drift_after_fault_m"] = float(np.hypot(dn, de).max())
    if i1 is not None:
        dur = (t[i1] - t[i0]) * 1e-6
        drop = truth["pos_d_m"][i1] - truth["pos_d_m"][i0]
        out["descent_rate_m_s"] = float(drop / dur) if dur > 0 else None
        if "touchdown_speed_m_s" in truth:          # as the plant recorded it at the contact
            out["touchdown_speed_m_s"] = float(truth["touchdown_speed_m_s"][i1])
            out["touchdown_tilt_deg"] = float(truth["touchdown_tilt_deg"][i1])
        else:
            # an older log: the speed it arrived at, the last row above the ground (the
            # contact's own row may already carry the ground's reaction)
            out["touchdown_speed_m_s"] = float(truth["vel_d_m_s"][max(i1 - 1, i0)])
            out["touchdown_tilt_deg"] = float(tilt[i1])
    if "lost_motor" in steps:
        lost = np.flatnonzero((steps["stamp_us"] >= fault_onset_us) & (steps["lost_motor"] > 0))
        if len(lost):
            out["detection_s"] = float((steps["stamp_us"][lost[0]] - fault_onset_us) * 1e-6)
    return out
