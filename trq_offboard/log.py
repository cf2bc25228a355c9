"""The controller's flight log: one CSV row per control step (estimated state, reference,
observer estimate, command, applied outputs, solve time and status), flushed about once a
second, plus a .tlog of the MAVLink traffic of the offboard link."""

from __future__ import annotations

import math
import struct
import time
from pathlib import Path

from trq_offboard.loop import StepRecord

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
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "w", encoding="ascii", newline="\n")
        for key, value in meta.items():
            self._f.write(f"# {key}: {value}\n")
        self._f.write(",".join(COLUMNS) + "\n")
        self._n, self._every = 0, flush_every

    def __call__(self, r: StepRecord) -> None:
        s, ref, info = r.state, r.ref, r.info
        nan4 = (math.nan,) * 4
        applied = r.applied
        row = ([r.t_s, r.stamp_us, *s.pos_ned_m, *s.vel_ned_m_s, *s.euler_rad, *s.rates_frd_rad_s,
                *ref.pos_ned_m, *ref.vel_ned_m_s, ref.yaw_rad, ref.phase]
               + list(info.disturbance if info else (math.nan,) * 6)
               + [*r.cmd.throttle_pct, *r.cmd.tilt_rad]
               + list(applied.throttle_pct if applied else nan4)
               + list(applied.tilt_rad if applied else nan4)
               + ([info.solve.solve_time_s * 1e3, info.solve.iterations, info.solve.status.value,
                   info.source.value, info.output_error, info.solve.cost] if info else
                  [math.nan, 0, "none", "none", math.nan, math.nan])
               + list(info.effectiveness if info else nan4))
        self._f.write(",".join(v if isinstance(v, str) else repr(float(v)) if isinstance(v, float)
                               else str(v) for v in row) + "\n")
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()


class Tlog:
    """pymavlink .tlog: 8-byte big-endian UNIX time (us), then the frame."""

    def __init__(self, path: Path, flush_every: int = 500) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        self._n, self._every = 0, flush_every

    def __call__(self, frame: bytes) -> None:
        self._f.write(struct.pack(">Q", time.time_ns() // 1000) + frame)
        self._n += 1
        if self._n % self._every == 0:
            self._f.flush()

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()
