"""The controller's flight log: one CSV row per control step (estimated state, reference,
observer estimate, command, applied outputs, solve time and status), flushed about once a
second. The file format (header, row formatting, flushing) and the .tlog of the offboard link's
MAVLink traffic are trq_wire.logfile's, shared with the vehicle's flight.csv."""

from __future__ import annotations

import math
from pathlib import Path

from trq_offboard.loop import StepRecord
from trq_wire.logfile import CsvLog

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
    + [f"eff_motor{i}" for i in range(1, 5)])


class ControllerLog:
    def __init__(self, path: Path, meta: dict[str, object], flush_every: int = 50) -> None:
        self._log = CsvLog(path, COLUMNS, meta, flush_every=flush_every)
        self.path = self._log.path

    def __call__(self, r: StepRecord) -> None:
        s, ref, info = r.state, r.ref, r.info
        nan4 = (math.nan,) * 4
        applied = r.applied
        self._log([r.t_s, r.stamp_us, *s.pos_ned_m, *s.vel_ned_m_s, *s.euler_rad,
                   *s.rates_frd_rad_s, *ref.pos_ned_m, *ref.vel_ned_m_s, ref.yaw_rad, ref.phase]
                  + list(info.disturbance if info else (math.nan,) * 6)
                  + [*r.cmd.throttle_pct, *r.cmd.tilt_rad]
                  + list(applied.throttle_pct if applied else nan4)
                  + list(applied.tilt_rad if applied else nan4)
                  + ([info.solve.solve_time_s * 1e3, info.solve.iterations,
                      info.solve.status.value, info.source.value, info.output_error,
                      info.solve.cost] if info else
                     [math.nan, 0, "none", "none", math.nan, math.nan])
                  + list(info.effectiveness if info else nan4))

    def close(self) -> None:
        self._log.close()
