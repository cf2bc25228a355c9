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

from trq_params.schema import FLIGHT_METRICS, OUTAGE_METRICS

from trq_lab.campaign.flight import plant_id, severity
from trq_lab.campaign.spec import (FAULT_KEYS, LINK_KEYS, OUTAGE_KEYS, PLANT_KEYS, PLANT_NEUTRAL,
                                   SENSING_DEFAULT, TRAJECTORY_KEYS, WIND_KEYS, Campaign,
                                   outage_label)

def write_json(path: Path, doc: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=str) + "\n")
    os.replace(tmp, path)


def flight_inputs(spec: dict, outage: bool | None = None) -> dict:
    """The flat input columns of a flight's row; the outage's (`outage` its label, `none`
    without one, then its keys) with `outage` true, or by default when the flight has one (a
    campaign with the axis gives them to every row: `rows_of`)."""
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
    if outage or (outage is None and "outage" in spec):
        out = spec.get("outage") or {}
        row["outage"] = outage_label(spec.get("outage"))
        for key in OUTAGE_KEYS:
            row[f"outage_{key}"] = out.get(key)
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


# a flight's metrics columns: its airframe, then every metric a flight target may bound (the
# outage's only in a campaign with the axis: `metric_keys`)
METRIC_KEYS = ("vehicle", *FLIGHT_METRICS)


def has_outage(campaign: Campaign) -> bool:
    """Whether a campaign has the outage axis: a flight with an outage."""
    return campaign.outages != ("none",)


def metric_keys(campaign: Campaign) -> tuple[str, ...]:
    """The metric columns of a campaign's rows: METRIC_KEYS, the outage's only with the axis."""
    return METRIC_KEYS if has_outage(campaign) else tuple(
        k for k in METRIC_KEYS if k not in OUTAGE_METRICS)


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
    outage, keys = has_outage(campaign), metric_keys(campaign)
    for spec in campaign.flights:
        rec = results.get(spec["id"])
        if rec is None:
            continue
        row = flight_inputs(spec, outage)
        m = rec.get("metrics") or {}
        for key in keys:
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
