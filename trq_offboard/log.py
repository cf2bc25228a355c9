"""The controller's flight log: one row per control step (estimated state, reference,
observer estimate, command, applied outputs, solve time and status, the period's CPU time by
part), flushed about once a second. Two forms of the same rows: controller.csv, formatted in
flight (trq_wire.logfile's format, shared with the vehicle's flight.csv), or controller.ulg,
the rows packed as PX4's ULog (trq_wire.ulog: what the daemon writes by default, as PX4 logs
on board; `trq_wire.ulog.to_csv` writes the same CSV bytes from it on the ground). The .tlog
of the offboard link's MAVLink traffic is trq_wire.logfile's.

Rows are kept as the loop's records and formatted in batches of `batch` (off the control step:
a call only appends, one call in `batch` writes the batch), every record but the newest, whose
period (StepRecord.cpu) is complete only at the next step's start; `close()` writes the rest.

CPU columns (ms, records.StepTimes and records.PeriodTimes; nan when not measured), each part in
the thread that ran it: cpu_observer_ms, cpu_effectiveness_ms, cpu_predictor_ms,
cpu_feedback_ms (the step's parts), cpu_prepare_ms (the preparation after the command),
cpu_wire_ms (the state's decode, the target's encode and send), cpu_log_ms (this log's share),
cpu_period_ms (the whole period, every thread of the process: the parts, the event loop, the
transport's frame parse).

The state columns (pos_*, vel_*) are the state the controller flew on: the vehicle's estimate,
or the fused filter's position and velocity (estimator kind fused), whose health follows in
est_test_ratio (the last pose's innovation test ratio), est_pos_var_m2 (the position's variance),
est_dead_reckoning (1 without a pose for the filter's dropout_s), est_rejected (the poses its
gate has rejected so far), est_resets (its position resets after a dropout so far) and
est_accel_rejected (the periods whose accelerometer mean its gate rejected); nan without the
filter. lost_motor: the motor the controller flies as lost (trq_offboard/lost_motor.py; two
motors i < j: 10 i + j), 0 while none is."""

from __future__ import annotations

import math
from pathlib import Path

from trq_offboard.loop import FlightController, StepRecord
from trq_wire.logfile import CsvLog
from trq_wire.ulog import UlogLog

CPU_PARTS = ("observer", "effectiveness", "predictor", "feedback", "prepare", "wire", "log",
             "period")
COLUMNS = (
    ["t_s", "stamp_us"] + [f"pos_{a}_m" for a in "ned"] + [f"vel_{a}_m_s" for a in "ned"]
    + ["roll_rad", "pitch_rad", "yaw_rad"] + [f"rate_{a}_rad_s" for a in "pqr"]
    + [f"ref_pos_{a}_m" for a in "ned"] + [f"ref_vel_{a}_m_s" for a in "ned"]
    + ["ref_yaw_rad", "phase"]
    + [f"d_acc_{a}_m_s2" for a in "ned"] + [f"d_ang_{a}_rad_s2" for a in "pqr"]
    + [f"cmd_throttle{i}_pct" for i in range(1, 5)] + [f"cmd_tilt{i}_rad" for i in range(1, 5)]
    + [f"applied_throttle{i}_pct" for i in range(1, 5)]
    + [f"applied_tilt{i}_rad" for i in range(1, 5)]
    + ["solve_ms", "iterations", "status", "source", "output_error", "cost"]
    + [f"eff_motor{i}" for i in range(1, 5)]
    + [f"cpu_{part}_ms" for part in CPU_PARTS]
    + ["est_test_ratio", "est_pos_var_m2", "est_dead_reckoning", "est_rejected", "est_resets",
       "est_accel_rejected"]
    + ["lost_motor"])
# each column's type in the ULog form (trq_wire.ulog: f float, i integer or nan, s string)
_INTEGERS = {"stamp_us", "iterations", "est_dead_reckoning", "est_rejected", "est_resets",
             "est_accel_rejected", "lost_motor"}
_STRINGS = {"phase", "status", "source"}
KINDS = "".join("i" if c in _INTEGERS else "s" if c in _STRINGS else "f" for c in COLUMNS)


def _ms(ns: int) -> float:
    return ns * 1e-6 if ns >= 0 else math.nan


def solver_header(controller: FlightController) -> dict:
    """The header's `solver` line: what solved the NMPC (Controller.solver_line)."""
    return {"solver": controller.solver_line()}


class ControllerLog:
    def __init__(self, path: Path, meta: dict[str, object], flush_every: int = 50,
                 batch: int = 50) -> None:
        """`path`: controller.csv, or a .ulg path for the ULog form (trq_wire.ulog: the rows
        packed, not formatted; `trq_wire.ulog.to_csv` writes the same CSV from it)."""
        if Path(path).suffix == ".ulg":
            self._log = UlogLog(path, COLUMNS, KINDS, meta, timestamp="stamp_us",
                                name="trq_controller", sys_name="trq-offboard",
                                flush_every=flush_every)
        else:
            self._log = CsvLog(path, COLUMNS, meta, flush_every=flush_every)
        self.path = self._log.path
        self._batch = max(1, batch)
        self._rows: list[StepRecord] = []

    def __call__(self, r: StepRecord) -> None:
        rows = self._rows
        rows.append(r)
        if len(rows) > self._batch:
            for old in rows[:-1]:
                self._write(old)
            del rows[:-1]

    def _write(self, r: StepRecord) -> None:
        s, ref, info, c = r.state, r.ref, r.info, r.cpu
        nan4 = (math.nan,) * 4
        applied = r.applied
        est = info.estimator if info else None
        pos, vel = (est.pos_ned_m, est.vel_ned_m_s) if est else (s.pos_ned_m, s.vel_ned_m_s)
        self._log([r.t_s, r.stamp_us, *pos, *vel, *s.euler_rad,
                   *s.rates_frd_rad_s, *ref.pos_ned_m, *ref.vel_ned_m_s, ref.yaw_rad, ref.phase]
                  + list(info.disturbance if info else (math.nan,) * 6)
                  + [*r.cmd.throttle_pct, *r.cmd.tilt_rad]
                  + list(applied.throttle_pct if applied else nan4)
                  + list(applied.tilt_rad if applied else nan4)
                  + ([info.solve.solve_time_s * 1e3, info.solve.iterations,
                      info.solve.status.value, info.source.value, info.output_error,
                      info.solve.cost] if info else
                     [math.nan, 0, "none", "none", math.nan, math.nan])
                  + list(info.effectiveness if info else nan4)
                  + ([info.cpu.observer_ns * 1e-6, info.cpu.effectiveness_ns * 1e-6,
                      info.cpu.predictor_ns * 1e-6, info.cpu.feedback_ns * 1e-6] if info
                     else list(nan4))
                  + [_ms(c.prepare_ns), _ms(c.wire_ns), _ms(c.log_ns), _ms(c.period_ns)]
                  + ([est.test_ratio, est.pos_var_m2, int(est.dead_reckoning), est.rejected,
                      est.resets, est.accel_rejected] if est else [math.nan] * 6)
                  + [info.lost_motor if info else 0])

    def close(self) -> None:
        for r in self._rows:
            self._write(r)
        self._rows.clear()
        self._log.close()
