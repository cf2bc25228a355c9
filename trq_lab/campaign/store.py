"""The flights flown: one JSON record per flight in DIR/flights/, and flights.csv.

In: a campaign (`spec.Campaign`) and its output directory. Out: the records read back (a torn
file is a flight to fly again) and the rows of flights.csv: a flight's inputs, its metrics, its
envelope columns and its status, one row per flight.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

from trq_params.schema import FLIGHT_METRICS

from trq_lab.campaign.flight import plant_id, severity
from trq_lab.campaign.spec import (FAULT_KEYS, LINK_KEYS, PLANT_KEYS, PLANT_NEUTRAL,
                                   SENSING_DEFAULT, TRAJECTORY_KEYS, WIND_KEYS, Campaign)

def write_json(path: Path, doc: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=str) + "\n")
    os.replace(tmp, path)


def flight_inputs(spec: dict) -> dict:
    """The flat input columns of a flight's row."""
    fault = spec["fault"] or {}
    kind, sev = severity(spec["fault"])
    row = {"id": spec["id"], "controller": spec["controller"],
           "sensing": spec.get("sensing", SENSING_DEFAULT), "fault_kind": kind, "severity": sev}
    for key in FAULT_KEYS:
        row[f"fault_{key}"] = fault.get(key)
    for key in WIND_KEYS:
        row[f"wind_{key}"] = spec["wind"].get(key)
    link = spec.get("link") or {}
    for key in LINK_KEYS:
        row[f"link_{key}"] = link.get(key, 0.0)
    traj = spec["trajectory"]
    row["traj_kind"] = traj.get("kind", "(controller file)")
    for key in TRAJECTORY_KEYS:
        if key != "kind":
            v = traj.get(key)
            row[f"traj_{key}"] = json.dumps(v) if isinstance(v, list) else v
    row.update(seed=spec["seed"], repeat=spec["repeat"])
    if "plant" in spec:
        for key in PLANT_KEYS:
            row[f"plant_{key}"] = spec["plant"].get(key, PLANT_NEUTRAL[key])
        row["controller_model"] = spec.get("controller_model", "nominal")
        row["plant_id"] = plant_id(spec)
    return row


def load_results(out: Path) -> dict[str, dict]:
    results = {}
    for p in sorted((out / "flights").glob("*.json")):
        try:
            doc = json.loads(p.read_text())
        except (OSError, ValueError):
            continue                               # a torn file: the flight is flown again
        results[doc.get("id", p.stem)] = doc
    return results


# a flight's metrics columns: its airframe, then every metric a flight target may bound
METRIC_KEYS = ("vehicle", *FLIGHT_METRICS)


def is_success(record: dict, threshold_m: float) -> bool:
    m = record.get("metrics") or {}
    if record.get("error") or m.get("crashed") is not False:
        return False
    rmse = m.get("rmse_pos_after_fault_m")
    if rmse is None:                      # no fault in this flight: the whole flight counts
        rmse = m.get("rmse_pos_m")
    return rmse is not None and rmse < threshold_m and record.get("status") == "done"


def rows_of(campaign: Campaign, results: dict[str, dict]) -> list[dict]:
    rows = []
    for spec in campaign.flights:
        rec = results.get(spec["id"])
        if rec is None:
            continue
        row = flight_inputs(spec)
        m = rec.get("metrics") or {}
        for key in METRIC_KEYS:
            row[key] = m.get(key)
        env = rec.get("envelope") or {}
        row.update(env_feasible=env.get("feasible"),
                   env_min_margin_pct=env.get("min_throttle_margin_pct"),
                   env_max_throttle_pct=max(env["throttle_pct"]) if env.get("feasible") else None)
        err = rec.get("error")
        row.update(status=rec.get("status"), success=is_success(rec, campaign.success_rmse_m),
                   wall_s=rec.get("wall_s"), sim_s=rec.get("sim_s"),
                   error=err.strip().splitlines()[-1] if err else "")
        rows.append(row)
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    if not rows:
        path.write_text("")
        return
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
