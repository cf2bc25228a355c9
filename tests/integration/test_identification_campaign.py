"""Identification-error campaigns flown (trq-campaign with a plant axis):

- identification_smoke (the full campaign's first three plants, the three controllers) on two
  workers: every flight records its plant and its faulted trim, the report separates the
  envelope from the controller (classes, rank correlations, the paired comparison, the targets
  and why they are missed) with its figures, metrics.json feeds the README's campaigns row;
- any flight flies again alone from the spec in its JSON, to the same result;
- the plant reaches the simulated vehicle only, unless the campaign asks for the controller's
  model to be the plant too (then the controller's log names the perturbed airframe).

About two minutes on two cores.
"""

from __future__ import annotations

import csv
import json
import subprocess

import pytest
from conftest import PARAMS, ROOT, cli

from trq_lab.campaign.flight import run_flight
from trq_lab.campaign.spec import load_campaign

pytestmark = pytest.mark.slow      # flies: the full run only

pytest.importorskip("distributed")

IDENT_SMOKE = PARAMS / "campaigns" / "identification_smoke.yaml"


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    out = tmp_path_factory.mktemp("ident") / "identification_smoke"
    r = subprocess.run([*cli("trq-campaign"), str(IDENT_SMOKE), "--out", str(out),
                        "--workers", "2"], cwd=ROOT, capture_output=True, text=True,
                       timeout=900)
    return r, out


def _records(out):
    return {p.stem: json.loads(p.read_text()) for p in (out / "flights").glob("*.json")}


def test_every_flight_records_its_plant_and_its_trim(flown):
    r, out = flown
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    recs = _records(out)
    assert len(recs) == 9 and all(rec["error"] is None for rec in recs.values())
    by_plant: dict[str, dict] = {}
    for rec in recs.values():
        spec, env = rec["spec"], rec["envelope"]
        assert set(spec["plant"]) == {"mass_scale", "inertia_scale", "thrust_scale",
                                      "torque_scale", "motor_lag_scale", "servo_lag_scale"}
        assert env["motor_factors"] == [0.5, 1.0, 1.0, 1.0]
        if spec["controller"] == "quad_nmpc":
            assert env["feasible"] is False               # half a motor: no yaw balance
            assert env["min_throttle_margin_pct"] is None
        else:
            key = json.dumps(spec["plant"], sort_keys=True)
            by_plant.setdefault(key, []).append(env)
            if env["feasible"]:
                assert 0.0 <= env["min_throttle_margin_pct"] <= min(   # both rounded to 0.01
                    100.0 - z for z in env["throttle_pct"]) + 1e-9
    # both tilt-rotor controllers fly the same plant: the same trim
    assert len(by_plant) == 3 and all(len(v) == 2 and v[0] == v[1] for v in by_plant.values())
    with open(out / "flights.csv") as f:
        rows = list(csv.DictReader(f))
    for key in ("plant_mass_scale", "plant_thrust_scale", "plant_id", "controller_model",
                "env_feasible", "env_min_margin_pct"):
        assert key in rows[0], key
    assert len({r["plant_id"] for r in rows}) == 3


def test_the_report_separates_the_envelope_from_the_controller(flown):
    r, out = flown
    assert r.returncode == 0, r.stderr[-3000:]
    text = (out / "report.md").read_text()
    for heading in ("## Plants: the envelope and the flights",
                    "## Which parameters explain the misses",
                    "## `trq_nmpc_eso` against the others on the same plants",
                    "## Targets", "### Where the misses come from"):
        assert heading in text, heading
    assert "| mass_scale |" in text and "| trim margin |" in text
    assert "Among the " in text and "does better than `trq_nmpc` on" in text
    assert "## `trq_nmpc_eso`\n" not in text             # one cell: no wind x fault tables
    for name in ("margin.png", "rmse_dist.png", "params.png"):
        assert f"({name})" in text
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["campaign"] == "identification_smoke" and doc["flights"] == 9
    assert doc["plants"] == 3 and set(doc["controllers"]) == {"trq_nmpc_eso", "trq_nmpc",
                                                              "quad_nmpc"}
    envelope = doc["controllers"]["quad_nmpc"]["envelope"]
    assert envelope["no trim"] == 3
    assert isinstance(doc["failures"], list)
    assert doc["target_paired"]["trq_nmpc"]["pairs"] == 3
    # what the report says of each target agrees with metrics.json
    assert ("**Missed:**" in text) == bool(doc["failures"])
    from trq_lab.reporting import results
    row = results.campaigns_table([out / "metrics.json"])
    assert "`identification_smoke`" in row and "9 (3 plants)" in row


def test_a_flight_flies_again_alone_from_its_record(flown):
    _, out = flown
    recs = _records(out)
    rec = next(r for r in recs.values() if r["spec"]["controller"] == "trq_nmpc_eso")
    again = run_flight(rec["spec"])
    assert again["error"] is None and again["status"] == rec["status"]
    assert again["envelope"] == rec["envelope"]
    timing = ("solve_ms_p50", "solve_ms_p99")
    assert {k: v for k, v in again["metrics"].items() if k not in timing} == \
        {k: v for k, v in rec["metrics"].items() if k not in timing}


HOVER = """\
name: hover_plants
description: short hovers of a heavier, slower plant; the controller's model nominal or the plant
seed: 1
controllers: [trq_nmpc_eso]
success_rmse_m: 0.1
recovery_threshold_m: 0.1
timeout_s: 30
controller_model: [nominal, plant]
grid:
  fault: {motor: 1, effectiveness: 0.6, at_s: 1.5}
  trajectory: {kind: hover, altitude_m: 0.6, climb_speed_m_s: 1.0, hold_s: 0.3, duration_s: 0.6,
               ramp_s: 0.2}
  plant: [{}, {mass_scale: 1.1, motor_lag_scale: 1.5}]
"""


def test_the_plant_reaches_the_vehicle_and_the_model_only_when_asked(tmp_path):
    from trq_lab import metrics

    path = tmp_path / "hover_plants.yaml"
    path.write_text(HOVER)
    plan = load_campaign(path)
    assert len(plan.flights) == 4
    logs = tmp_path / "logs"
    truth, model_file, vehicle_file, recs = {}, {}, {}, {}
    for spec in plan.flights:
        rec = run_flight(spec, str(logs))
        assert rec["error"] is None and rec["status"] == "done", rec
        key = (json.dumps(spec["plant"]), spec.get("controller_model", "nominal"))
        meta, _ = metrics.read_csv(logs / spec["id"] / "flight.csv")
        cmeta, _ = metrics.read_csv(logs / spec["id"] / "controller.csv")
        vehicle_file[key], model_file[key] = meta["vehicle_file"], cmeta["vehicle_file"]
        truth[key] = [ln for ln in open(logs / spec["id"] / "flight.csv")
                      if not ln.startswith("#")]
        recs[key] = rec
    nominal = str((PARAMS / "vehicle" / "trq.yaml").resolve())
    heavy = json.dumps({"mass_scale": 1.1, "motor_lag_scale": 1.5})
    for (plant, model), vfile in vehicle_file.items():
        assert vfile.endswith("/plant/trq.yaml")             # the simulated airframe: the plant's
        assert model_file[(plant, model)] == (nominal if model == "nominal" else vfile)
    # the neutral plant with its own model is the nominal flight; the heavy plant is another
    assert truth[("{}", "nominal")] == truth[("{}", "plant")]
    assert truth[(heavy, "nominal")] != truth[("{}", "nominal")]
    assert truth[(heavy, "plant")] != truth[(heavy, "nominal")]
    assert recs[(heavy, "nominal")]["envelope"] == recs[(heavy, "plant")]["envelope"]
    assert (recs[(heavy, "nominal")]["envelope"]["min_throttle_margin_pct"]
            < recs[("{}", "nominal")]["envelope"]["min_throttle_margin_pct"])
