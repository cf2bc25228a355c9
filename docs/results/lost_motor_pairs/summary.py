"""The two-motor flights of run.sh, summarised: flights.csv (one row a flight) and summary.md (per
scenario and controller: the plant's crash, the touchdown's speed and tilt, the detection; the
issue's two-motor target judged beside the plant's crash). Standard library only.

    python summary.py OUT_DIR DEST_DIR
"""

from __future__ import annotations

import csv
import json
import statistics
import sys
from pathlib import Path

TARGET_M_S = 5.7          # issue 40: an upright descent, touchdown at no more than 5.7 m/s
UPRIGHT_DEG = 90.0        # upright: the thrust axis never past horizontal after the fault
CRASH_M_S = 2.5           # the plant's impact crash (params/sim/default.yaml, docs/simulator.md)
COLS = ("scenario", "seed", "controller", "crashed", "touchdown_speed_m_s", "touchdown_tilt_deg",
        "max_thrust_tilt_after_fault_deg", "drift_after_fault_m", "descent_rate_m_s",
        "detection_s", "flight_s", "target_met", "flight_csv_sha")


def _f(v, nd=2):
    return "-" if v is None else f"{v:.{nd}f}"


def main(out: Path, dest: Path) -> None:
    rows = []
    for mfile in sorted(out.glob("*/s*/metrics.json")):
        scenario, seed = mfile.parent.parent.name, int(mfile.parent.name[1:])
        for run in json.loads(mfile.read_text())["runs"]:
            v, tilt = run.get("touchdown_speed_m_s"), run.get("max_thrust_tilt_after_fault_deg")
            met = (v is not None and v <= TARGET_M_S and tilt is not None
                   and tilt < UPRIGHT_DEG)
            rows.append({"scenario": scenario, "seed": seed, **{k: run.get(k) for k in COLS[2:]
                                                                   if k != "target_met"},
                         "target_met": met})
    rows.sort(key=lambda r: (r["scenario"], r["controller"], r["seed"]))
    dest.mkdir(parents=True, exist_ok=True)
    with open(dest / "flights.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, COLS)
        w.writeheader()
        w.writerows(rows)
    lines = ["# Two motors lost, on seeds (run.sh; summary.py)", "",
             f"Target (issue 40): an upright descent (the thrust axis never past {UPRIGHT_DEG:.0f}"
             f" deg after the fault) and touchdown at no more than {TARGET_M_S} m/s. Beside it "
             f"the plant's crash (an impact above {CRASH_M_S} m/s, a tip-over, a tumble): the "
             "plant is not redefined.", "",
             "| scenario | controller | flights | plant crash | target met | touchdown m/s "
             "median (range) | touchdown tilt deg median (max) | max thrust tilt deg median "
             "(max) | detection s median (range) |",
             "|---|---|---|---|---|---|---|---|---|"]
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["scenario"], r["controller"]), []).append(r)
    for (scenario, ctl), rs in groups.items():
        def col(key):
            return [r[key] for r in rs if r[key] is not None]
        v, tt, mt, det = (col("touchdown_speed_m_s"), col("touchdown_tilt_deg"),
                          col("max_thrust_tilt_after_fault_deg"), col("detection_s"))
        lines.append(
            f"| {scenario} | {ctl} | {len(rs)} | {sum(bool(r['crashed']) for r in rs)} | "
            f"{sum(r['target_met'] for r in rs)} of {len(rs)} | "
            + (f"{_f(statistics.median(v))} ({_f(min(v))}-{_f(max(v))}) | " if v else
               "- (no touchdown: a tumble) | ")
            + (f"{_f(statistics.median(tt), 1)} ({_f(max(tt), 1)}) | " if tt else "- | ")
            + (f"{_f(statistics.median(mt), 0)} ({_f(max(mt), 0)}) | " if mt else "- | ")
            + (f"{_f(statistics.median(det))} ({_f(min(det))}-{_f(max(det))}) |" if det else
               "- |"))
    (dest / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
