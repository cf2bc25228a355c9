"""lost_motor_axes by cell: per motor, failure time and wind, the issue's one-motor targets and
the figures that say why a cell misses them (cells.md beside this script). Reads the campaign's
flights.csv (trq-campaign lost_motor_axes --out OUT). Standard library only.

    python cells.py OUT/flights.csv DEST_DIR
"""

from __future__ import annotations

import csv
import statistics
import sys
from pathlib import Path

# issue 40, one motor lost: no crash, touchdown at no more than 2 m/s and never above 3.8 m/s,
# within 2 m of where the motor failed (lost_motor_axes.yaml's flight_targets)
TOUCHDOWN_M_S, TOUCHDOWN_NEVER_M_S, DRIFT_M = 2.0, 3.8, 2.0


def _num(v: str):
    return None if v in ("", None) else float(v)


def _med_worst(vals, nd=2, worst=max):
    vals = [v for v in vals if v is not None]
    if not vals:
        return "-"
    return f"{statistics.median(vals):.{nd}f} / {worst(vals):.{nd}f}"


def _met(r) -> bool:
    v, d = _num(r["touchdown_speed_m_s"]), _num(r["drift_after_fault_m"])
    return (r["crashed"] == "False" and r["status"] == "done" and v is not None
            and v <= TOUCHDOWN_M_S and v <= TOUCHDOWN_NEVER_M_S and d is not None and d <= DRIFT_M)


def main(flights_csv: Path, dest: Path) -> None:
    rows = list(csv.DictReader(open(flights_csv, newline="")))
    cells: dict = {}
    for r in rows:
        key = (int(r["fault_motor"]), float(r["fault_at_s"]), float(r["wind_speed_m_s"]))
        cells.setdefault(key, []).append(r)
    lines = [
        "# lost_motor_axes by cell (cells.py)", "",
        f"Per motor, failure time and wind, {len(rows)} flights, trq_nmpc_eso_lost. Targets (issue "
        f"40, one motor lost): no crash, touchdown <= {TOUCHDOWN_M_S} m/s (never above "
        f"{TOUCHDOWN_NEVER_M_S}), drift from the point of failure <= {DRIFT_M} m. Figures: median "
        "/ worst of the cell's seeds.", "",
        "| motor | fault at s | wind m/s | flights | crashed | targets met | touchdown m/s | "
        "drift m | detection s | max thrust tilt deg | touchdown tilt deg | missed by |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for key in sorted(cells):
        rs = cells[key]

        def col(name):
            return [_num(r[name]) for r in rs]
        misses = []
        for r in rs:
            v, d = _num(r["touchdown_speed_m_s"]), _num(r["drift_after_fault_m"])
            why = []
            if r["crashed"] != "False":
                why.append("crash")
            if v is None:
                why.append("no touchdown")
            elif v > TOUCHDOWN_M_S:
                why.append(f"touchdown {v:.2f}")
            if d is not None and d > DRIFT_M:
                why.append(f"drift {d:.2f}")
            if why:
                misses.append(f"r{r['repeat']}: " + ", ".join(why))
        lines.append(
            f"| {key[0]} | {key[1]:g} | {key[2]:g} | {len(rs)} | "
            f"{sum(r['crashed'] != 'False' for r in rs)} | {sum(_met(r) for r in rs)} of {len(rs)} | "
            f"{_med_worst(col('touchdown_speed_m_s'))} | {_med_worst(col('drift_after_fault_m'))} | "
            f"{_med_worst(col('detection_s'))} | "
            f"{_med_worst(col('max_thrust_tilt_after_fault_deg'), 1)} | "
            f"{_med_worst(col('touchdown_tilt_deg'), 1)} | {'; '.join(misses) or '-'} |")
    lines += ["", "Pooled:", "",
              "| by | value | flights | crashed | targets met | touchdown m/s | drift m | "
              "max thrust tilt deg |", "|---|---|---|---|---|---|---|---|"]
    for name, idx in (("motor", 0), ("fault at s", 1), ("wind m/s", 2)):
        groups: dict = {}
        for key, rs in cells.items():
            groups.setdefault(key[idx], []).extend(rs)
        for val in sorted(groups):
            rs = groups[val]

            def col(n):
                return [_num(r[n]) for r in rs]
            lines.append(
                f"| {name} | {val:g} | {len(rs)} | {sum(r['crashed'] != 'False' for r in rs)} | "
                f"{sum(_met(r) for r in rs)} of {len(rs)} | "
                f"{_med_worst(col('touchdown_speed_m_s'))} | "
                f"{_med_worst(col('drift_after_fault_m'))} | "
                f"{_med_worst(col('max_thrust_tilt_after_fault_deg'), 1)} |")
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "cells.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
