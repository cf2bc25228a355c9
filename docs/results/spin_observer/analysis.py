"""Paired comparison of a spin_observer campaign's flights (docs/decisions/2026-12-06-spin-observer.md):
per metric, each controller's median and worst, and its ratio to the first controller's flight
with the same draw (plant, motor, failure time, wind, seed); then the flights that crash or miss a
one-motor target, with their plant. With --margins, each draw's relaxed-hover margin at 20 rad/s
on its plant (the lost-motor controller's trim, spin.equilibrium, on the perturbed airframe).

    python docs/results/spin_observer/analysis.py docs/results/spin_observer/gusts.csv
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np

METRICS = ("drift_after_fault_m", "touchdown_speed_m_s", "max_thrust_tilt_after_fault_deg",
           "touchdown_tilt_deg")
PLANT = ("mass_scale", "inertia_scale", "thrust_scale", "torque_scale", "motor_lag_scale",
         "servo_lag_scale")


def _num(row: dict, key: str) -> float:
    try:
        return float(row[key])
    except (KeyError, ValueError):
        return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("flights", type=Path)
    ap.add_argument("--margins", action="store_true")
    a = ap.parse_args()
    rows = list(csv.DictReader(a.flights.open()))
    ctrls = list(dict.fromkeys(r["controller"] for r in rows))
    by: dict[tuple, dict] = {}
    for r in rows:
        key = (r.get("plant_id", ""), r["fault_motor"], r["fault_at_s"], r["wind_speed_m_s"],
               r["wind_direction_deg"], r["seed"])
        by.setdefault(key, {})[r["controller"]] = r
    keys = [k for k in by if all(c in by[k] for c in ctrls)]
    print(f"{len(keys)} draws, controllers: {', '.join(ctrls)}")
    for m in METRICS:
        print(m)
        base = np.array([_num(by[k][ctrls[0]], m) for k in keys])
        for c in ctrls:
            v = np.array([_num(by[k][c], m) for k in keys])
            ok = np.isfinite(v) & np.isfinite(base)
            print(f"  {Path(c).stem:40s} median {np.nanmedian(v):.3f} worst {np.nanmax(v):.3f}"
                  f" | paired ratio median {np.median(v[ok] / base[ok]):.3f},"
                  f" lower on {int(np.sum(v[ok] < base[ok]))} of {int(ok.sum())}")
    print("crashed, or touchdown above 2 m/s, or drift above 2 m:")
    for k in keys:
        for c in ctrls:
            r = by[k][c]
            if (r["crashed"] == "True" or _num(r, "touchdown_speed_m_s") > 2.0
                    or _num(r, "drift_after_fault_m") > 2.0):
                plant = " ".join(f"{p} {r['plant_' + p]}" for p in PLANT if r.get("plant_" + p))
                print(f"  {Path(c).stem} draw {k}: crashed {r['crashed']}, touchdown "
                      f"{_num(r, 'touchdown_speed_m_s'):.2f} m/s, drift "
                      f"{_num(r, 'drift_after_fault_m'):.2f} m; {plant}")
    if a.margins:
        from trq_lab.overlays import write_vehicle_overlay
        from trq_offboard.config import load_vehicle_model
        from trq_offboard.spin import equilibrium
        airframe = Path(__file__).resolve().parents[3] / "params" / "vehicle" / "trq.yaml"
        out = []
        for k in keys:
            r = by[k][ctrls[0]]
            plant = {p: float(r["plant_" + p]) for p in PLANT if r.get("plant_" + p)}
            with tempfile.TemporaryDirectory() as d:
                vm = load_vehicle_model(write_vehicle_overlay(airframe, plant, Path(d)))
            try:
                margin = equilibrium(vm, int(r["fault_motor"]), 20.0).margin
            except ValueError:
                margin = float("nan")
            out.append((margin, k, _num(r, "touchdown_speed_m_s")))
        print("the draws' margins at 20 rad/s, least first (margin, draw, the first "
              "controller's touchdown m/s):")
        for margin, k, td in sorted(out)[:8]:
            print(f"  {margin:.3f} {k} {td:.2f}")


if __name__ == "__main__":
    main()
