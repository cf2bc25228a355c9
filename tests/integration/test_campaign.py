"""Fault campaigns on Dask (trq-campaign) and the in-process flight they are made of
(trq_lab.harness).

- the smoke campaign runs on a LocalCluster of 2 workers and writes flights.csv, report.md and
  the heat maps; deleting one result and running again flies that flight only;
- a flight that cannot be flown (an invalid reference) is recorded with its error, skipped on a
  rerun (not lost, not retried) unless --retry-failed; --max-flights stops early and the rest
  follows on the next run;
- a bad campaign file is refused with its file name and the key;
- a flight with a sensor outage has the sensor off for the outage's window and nowhere else, is
  the flight without it until the outage starts, and has the outage's metric;
- the in-process flight (Sitl + OffboardFlight over an in-memory MAVLink link) gives the same
  flight as the two daemons over UDP in lockstep: bit-identical truth log, the same metrics.

About 80 s on two cores.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from conftest import PARAMS, ROOT, cli

from trq_lab.campaign.flight import run_flight
from trq_lab.campaign.spec import load_campaign
from trq_offboard.nmpc import hpipm
from trq_lab.campaign.store import flight_inputs
from trq_lab.reporting.campaign import summarise, wind_label

pytestmark = pytest.mark.slow      # starts daemons or flies: the full run only

pytest.importorskip("distributed")

ENV = dict(os.environ)
SMOKE = PARAMS / "campaigns" / "smoke.yaml"


def run_campaign(*args: str, timeout: float = 180.0) -> subprocess.CompletedProcess:
    return subprocess.run([*cli("trq-campaign"), *map(str, args)],
                          cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout)


def flight_files(out: Path) -> dict[str, float]:
    return {p.stem: p.stat().st_mtime_ns for p in (out / "flights").glob("*.json")}


# --- the smoke campaign on 2 workers, and resuming it ------------------------------------------

@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign") / "smoke"
    r = run_campaign(SMOKE, "--out", out, "--workers", "2")
    return r, out


def test_smoke_campaign_runs_on_two_workers(smoke):
    r, out = smoke
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "2 worker(s)" in r.stderr
    assert "flights/hour" in r.stdout
    assert "8/8 flights, 0 failed" in r.stderr           # the progress bar's last line
    plan = load_campaign(SMOKE)
    assert len(plan.flights) == 8
    assert set(flight_files(out)) == {f["id"] for f in plan.flights}


def test_smoke_campaign_csv_has_inputs_and_scenario_metrics(smoke):
    import csv

    _, out = smoke
    with open(out / "flights.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 8
    for key in ("id", "controller", "fault_motor", "fault_effectiveness", "fault_at_s",
                "severity", "wind_speed_m_s", "wind_direction_deg", "traj_kind", "seed",
                "crashed", "flight_s", "rmse_pos_m", "max_pos_err_m", "rmse_pos_after_fault_m",
                "rmse_yaw_deg", "max_yaw_err_deg", "recovery_s", "solve_ms_p50", "solve_ms_p99",
                "status", "success"):
        assert key in rows[0], key
    assert {r["controller"] for r in rows} == {"trq_nmpc_eso", "quad_nmpc"}
    for r in rows:
        # the fixed-rotor quadcopter cannot balance the fault's yaw torque: with the 60 % fault
        # it may land tilted and tip over on its gear (a crash, the flight still recorded whole)
        faulted_quad = r["controller"] == "quad_nmpc" and float(r["fault_effectiveness"]) < 1.0
        if faulted_quad:
            assert r["status"] in ("done", "crashed"), r
        else:
            assert r["status"] == "done" and r["crashed"] == "False", r
        assert 0.0 < float(r["rmse_pos_m"]) < 2.0
        assert float(r["flight_s"]) > 2.0                     # past the onset at 1.5 s
    eso = [r for r in rows if r["controller"] == "trq_nmpc_eso"]
    assert all(r["success"] == "True" for r in eso)          # the observer copes with 40 %
    # every controller in a cell flies with the same seed (same noise and gusts)
    cells = {}
    for r in rows:
        cells.setdefault((r["fault_effectiveness"], r["wind_speed_m_s"]), set()).add(r["seed"])
    assert all(len(s) == 1 for s in cells.values())


def test_smoke_campaign_report_and_heat_maps(smoke):
    _, out = smoke
    text = (out / "report.md").read_text()
    assert "# Campaign `smoke`" in text
    assert "8 of 8 flights flown" in text and "flights/hour" in text
    # which QP library flew them (another flies other last bits): this environment's
    assert f"the NMPC's QPs solved by {hpipm.library_label()}" in text
    assert json.loads((out / "last_run.json").read_text())["qp_library"] == hpipm.library_label()
    assert "## `trq_nmpc_eso`" in text and "## `quad_nmpc`" in text
    assert "Where each controller stops coping" in text
    for name in ("success.png", "rmse.png"):
        assert f"({name})" in text
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def test_resume_flies_only_the_missing_flight(smoke):
    r0, out = smoke
    assert r0.returncode == 0
    before = flight_files(out)
    victim = sorted(before)[3]
    was = json.loads((out / "flights" / f"{victim}.json").read_text())["status"]
    (out / "flights" / f"{victim}.json").unlink()
    r = run_campaign(SMOKE, "--out", out, "--workers", "1", "--no-figures")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "8 flights, 7 already done, 1 to fly" in r.stderr
    assert json.loads((out / "last_run.json").read_text())["flown"] == 1
    after = flight_files(out)
    assert set(after) == set(before)
    assert [k for k in before if after[k] != before[k]] == [victim]   # nothing else flown again
    # flown again to the same end (a faulted quad may tip over on its gear: "crashed")
    assert json.loads((out / "flights" / f"{victim}.json").read_text())["status"] == was
    assert was in ("done", "crashed")
    # and with everything done, nothing is flown at all (no cluster is even started)
    r = run_campaign(SMOKE, "--out", out, "--no-figures")
    assert r.returncode == 0 and "8 already done, 0 to fly" in r.stderr
    assert flight_files(out) == after
    # which leaves the last run that flew, and the report's throughput from it, as they were
    assert json.loads((out / "last_run.json").read_text())["flown"] == 1
    assert "flights/hour" in (out / "report.md").read_text()


# --- failures, limits and bad files -----------------------------------------------------------

BAD_REFERENCE = """\
name: bad_reference
description: a reference whose ramps are longer than half its manoeuvre (the loader refuses it)
seed: 1
controllers: [trq_nmpc_eso]
success_rmse_m: 0.1
recovery_threshold_m: 0.1
timeout_s: 10
grid:
  fault: {motor: [1, 2, 3], effectiveness: 0.5, at_s: 1.0}
  trajectory: {kind: hover, altitude_m: 0.5, duration_s: 1.0, ramp_s: 0.9}
"""


def test_failed_flights_are_recorded_and_max_flights_resumes(tmp_path):
    path = tmp_path / "bad_reference.yaml"
    path.write_text(BAD_REFERENCE)
    out = tmp_path / "out"
    r = run_campaign(path, "--out", out, "--workers", "1", "--max-flights", "2", "--no-figures")
    assert r.returncode == 1                                  # incomplete, with failures
    assert "2/2 flights, 2 failed" in r.stderr
    files = flight_files(out)
    assert len(files) == 2
    for name in files:
        rec = json.loads((out / "flights" / f"{name}.json").read_text())
        assert rec["status"] == "failed"
        assert "Traceback" in rec["error"] and "ramp_s" in rec["error"]
        assert rec["spec"]["trajectory"]["ramp_s"] == 0.9
    # the rest follows; the failed ones are kept, not flown again
    r = run_campaign(path, "--out", out, "--workers", "1", "--no-figures")
    assert "3 flights, 2 already done, 1 to fly" in r.stderr
    assert len(flight_files(out)) == 3
    report = (out / "report.md").read_text()
    assert "3 failed" in report and "## Failed flights" in report and "ramp_s" in report
    with open(out / "flights.csv") as f:
        assert sum("ramp_s" in line for line in list(f)[1:]) == 3    # each row names the key
    r = run_campaign(path, "--out", out, "--workers", "1", "--no-figures", "--retry-failed")
    assert "3 flights, 0 already done, 3 to fly" in r.stderr


@pytest.mark.parametrize("edit, key, words", [
    (lambda t: t.replace("effectiveness: [1.0, 0.6]", "efectiveness: [1.0, 0.6]"),
     "grid.fault.efectiveness", "unknown key"),
    (lambda t: t.replace("effectiveness: [1.0, 0.6]", "effectiveness: [1.0, 1.6]"),
     "grid.fault.effectiveness[1]", "a number in [0, 1]"),
    (lambda t: t.replace("[trq_nmpc_eso, quad_nmpc]", "[trq_nmpc_eso, quad_nmcp]"),
     "controllers[1]", "quad_nmcp"),
    (lambda t: t.replace("success_rmse_m: 0.1 ", "success_rmse: 0.1 "),
     "success_rmse_m", "is missing"),
    (lambda t: t.replace("kind: hover", "kind: hoover"), "grid.trajectory.kind", "helix"),
    (lambda t: t.replace("at_s: 1.5", "onset_s: 1.5"), "grid.fault.onset_s", "unknown key"),
])
def test_bad_campaign_names_file_and_key(tmp_path, edit, key, words):
    from trq_params import ConfigError

    bad = tmp_path / "typo.yaml"
    text = SMOKE.read_text()
    bad.write_text(edit(text))
    assert bad.read_text() != text
    with pytest.raises(ConfigError) as err:
        load_campaign(bad)
    msg = str(err.value)
    assert str(bad) in msg and f"'{key}'" in msg and words in msg, msg


def test_bad_campaign_exits_2_before_flying(tmp_path):
    bad = tmp_path / "extra.yaml"
    bad.write_text(SMOKE.read_text() + "colour: blue\n")
    r = run_campaign(bad, "--out", tmp_path / "out", timeout=60)
    assert r.returncode == 2
    assert "extra.yaml" in r.stderr and "unknown key 'colour'" in r.stderr
    assert not (tmp_path / "out").exists()


def test_sampled_campaign_is_seeded(tmp_path):
    text = SMOKE.read_text().split("grid:")[0] + (
        "sample:\n  n: 5\n  seed: 3\n"
        "  fault: {motor: [1, 2, 3, 4], effectiveness: {uniform: [0.3, 1.0]}, at_s: 2.0}\n"
        "  wind: {speed_m_s: {uniform: [0.0, 8.0]}, direction_deg: [0.0, 90.0], gusts: [true]}\n")
    path = tmp_path / "sample.yaml"
    path.write_text(text)
    a, b = load_campaign(path), load_campaign(path)
    assert len(a.flights) == 10 and a.flights == b.flights
    effs = {f["fault"]["effectiveness"] for f in a.flights}
    assert len(effs) == 5 and all(0.3 <= e <= 1.0 for e in effs)
    path.write_text(text.replace("seed: 3", "seed: 4"))
    assert load_campaign(path).flights != a.flights


def test_link_axis_impairs_the_offboard_link(tmp_path):
    """grid.link: the offboard link's seeded impairment per flight. A clean link (`{}`) keeps the
    ids and seeds of a campaign without the axis; an impaired one reaches the flight (its truth
    log differs from the clean flight's with the same seed) and the controller is told the
    round trip; a bad key is refused with its name."""
    from trq_params import ConfigError

    base = SMOKE.read_text().replace("effectiveness: [1.0, 0.6]", "effectiveness: 0.6").replace(
        "speed_m_s: [0.0, 4.0]", "speed_m_s: 0.0").replace(
        "[trq_nmpc_eso, quad_nmpc]", "[trq_nmpc_eso]")
    plain, linked = tmp_path / "plain.yaml", tmp_path / "linked.yaml"
    plain.write_text(base)
    linked.write_text(base + "  link: [{}, {loss: 0.1, delay_ms: 20.0}]\n")
    a, b = load_campaign(plain), load_campaign(linked)
    assert len(a.flights) == 1 and len(b.flights) == 2
    clean, lossy = b.flights
    assert clean == a.flights[0] and "link" not in clean
    assert lossy["link"] == {"delay_ms": 20.0, "loss": 0.1} and lossy["id"] != clean["id"]
    row = flight_inputs(lossy)
    assert (row["link_loss"], row["link_delay_ms"], row["link_jitter_ms"]) == (0.1, 20.0, 0.0)
    assert wind_label(row) == "0 m/s, link 10 % lost 20 ms"

    lossy = dict(lossy, seed=clean["seed"])          # the same seed: only the link differs
    logs = tmp_path / "logs"
    recs = [run_flight(spec, str(logs)) for spec in (clean, lossy)]
    assert [r["error"] for r in recs] == [None, None]
    assert all(r["metrics"] is not None for r in recs)
    truth = [(logs / spec["id"] / "flight.csv").read_text() for spec in (clean, lossy)]
    assert truth[0] != truth[1]
    assert [r["applied_delay_s"] for r in recs] == [0.0, pytest.approx(0.04)]

    linked.write_text(base + "  link: {loss: 0.1, delay: 20.0}\n")
    with pytest.raises(ConfigError, match=r"grid\.link\.delay"):
        load_campaign(linked)


def test_sensing_smoke_flies_each_flight_under_its_profile(tmp_path):
    """sensing_smoke: one hover under truth, one under mocap (the controller gets the vehicle's
    estimate); flights.csv says which, the truth flight keeps the id it has without the axis,
    and the report's tables are per profile."""
    import csv

    path = PARAMS / "campaigns" / "sensing_smoke.yaml"
    out = tmp_path / "out"
    r = run_campaign(path, "--out", out, "--workers", "1", "--no-figures")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    with open(out / "flights.csv") as f:
        rows = {row["sensing"]: row for row in csv.DictReader(f)}
    assert set(rows) == {"truth", "mocap"}
    for row in rows.values():
        assert row["status"] == "done" and row["crashed"] == "False", row
        assert row["success"] == "True", row
    assert rows["truth"]["seed"] == rows["mocap"]["seed"]
    assert rows["truth"]["est_rmse_pos_m"] == ""              # no estimator under truth
    assert 0.0 < float(rows["mocap"]["est_rmse_pos_m"]) < 0.05
    plain = tmp_path / "plain.yaml"
    plain.write_text(path.read_text().replace("  sensing: [truth, mocap]\n", ""))
    assert [f["id"] for f in load_campaign(plain).flights] == [rows["truth"]["id"]]
    rec = json.loads((out / "flights" / f"{rows['mocap']['id']}.json").read_text())
    assert rec["spec"]["sensing"] == "mocap"
    report = (out / "report.md").read_text()
    assert "| mocap | trq_nmpc_eso | 1 | 100% |" in report
    assert "## `trq_nmpc_eso` under `mocap`" in report


# --- the in-process flight against the daemons over UDP ---------------------------------------

def _udp_lockstep_flight(daemons, out: Path, scenario) -> None:
    """The two daemons over UDP, set up as trq-scenario does, with the controller listening
    before the vehicle starts (and the vehicle never free-running on wall time): the ideal
    lockstep flight, with which the in-process flight must agree."""
    from trq_lab import scenario as run_scenario

    c = scenario.controllers[0]
    ctrl_yaml, sim_yaml, vehicle_file, _ = run_scenario.prepare(scenario, c, out)
    sim_yaml.write_text(sim_yaml.read_text() + "clock: {mode: lockstep, speed_up: 1.0, "
                        "resend_s: 0.5, free_run_after_s: 3600.0}\n")
    ctrl = daemons.controller("--controller", str(ctrl_yaml), log_dir=out, cwd=ROOT)
    try:
        ctrl.wait_bound(timeout_s=60)                # the controller's socket is bound
        daemons.vehicle(
            "--sim", str(sim_yaml), "--vehicle", str(vehicle_file), "--seed", str(scenario.seed),
            "--wind-speed", str(scenario.wind_speed_m_s), "--wind-dir",
            str(scenario.wind_from_deg), "--mode", "lockstep", "--faults", str(scenario.faults),
            log_dir=out, offboard_target=ctrl.port, cwd=ROOT)
        assert ctrl.wait(120) == 0, ctrl.why()
    finally:
        for proc in daemons.procs:
            proc.stop(signal.SIGINT)


def test_inprocess_flight_reproduces_the_udp_flight(tmp_path, daemons):
    from sil_vehicle.faultscript import load_script
    from trq_lab import harness as inprocess
    from trq_lab import metrics, overlays
    from trq_lab import scenario as run_scenario
    from trq_offboard.config import load_controller

    sc = run_scenario.load_scenario(PARAMS / "scenarios" / "smoke.yaml")
    c = sc.controllers[0]
    # the UDP flight (two processes taking turns: about one core) flies alongside
    errors: list[BaseException] = []

    def udp_flight():
        try:
            _udp_lockstep_flight(daemons, tmp_path / "udp", sc)
        except BaseException as exc:  # re-raised in the test's thread
            errors.append(exc)

    udp_thread = threading.Thread(target=udp_flight)
    udp_thread.start()

    cfg = load_controller(overlays.controller_file(c))
    sim = inprocess.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=sc.seed,
                               wind_speed_m_s=sc.wind_speed_m_s, wind_from_deg=sc.wind_from_deg,
                               gusts=sc.gusts)
    events = load_script(sc.faults, (math.degrees(sim.vehicle.tilt_min_rad),
                                     math.degrees(sim.vehicle.tilt_max_rad)))
    res = inprocess.fly_inprocess(c, sim, events, out_dir=tmp_path / "inprocess",
                                  reference=sc.reference, timeout_s=sc.timeout_s, name=c)
    udp_thread.join(180)
    assert not udp_thread.is_alive() and not errors, errors
    assert res.status == "done", res.summary
    # the link carried the traffic: a target per controller step (plus heartbeats and
    # commands) one way; the other an ODOMETRY per step and the actuators' outputs (50 Hz:
    # every other step), the streams the controller does not read turned off
    assert res.steps > 500 and res.messages[0] > res.steps \
        and res.messages[1] > 1.5 * res.steps

    onset = events[0].at_us
    udp = tmp_path / "udp"
    m_udp = inprocess.flight_metrics(udp, c, onset, sc.recovery_threshold_m)
    m_in = inprocess.flight_metrics(res.out_dir, c, onset, sc.recovery_threshold_m)
    for key in ("crashed", "flight_s", "rmse_pos_m", "max_pos_err_m", "rmse_pos_after_fault_m",
                "rmse_yaw_deg", "max_yaw_err_deg", "recovery_s"):
        a, b = m_udp[key], m_in[key]
        assert (a == b) if isinstance(a, bool) or a is None else math.isclose(a, b, rel_tol=1e-9,
                                                                             abs_tol=1e-12), \
            (key, a, b)
    assert m_in["crashed"] is False and m_in["rmse_pos_m"] < 0.1
    # lockstep is deterministic: the truth is bit-identical over every controller step
    _, steps = metrics.read_csv(udp / "controller.csv")
    last = int(steps["stamp_us"][-1])

    def truth_rows(path):
        rows = [ln for ln in open(path) if not ln.startswith("#")][1:]
        return [ln for ln in rows if int(ln.split(",", 1)[0]) <= last]

    a, b = truth_rows(udp / "flight.csv"), truth_rows(res.flight_csv)
    assert len(a) > 800 and a == b


@pytest.mark.parametrize("path", sorted((PARAMS / "campaigns").glob("*.yaml"))
                         + sorted((ROOT / "docs" / "decisions" / "studies").glob("*.yaml")),
                         ids=lambda p: p.stem)
def test_every_shipped_campaign_loads(path):
    """The campaign files in params/campaigns/, and the studies' beside their records
    (docs/decisions/studies/), load (strict keys, controllers that build) and expand to flights
    with distinct ids."""

    plan = load_campaign(path)
    ids = [f["id"] for f in plan.flights]
    assert ids and len(ids) == len(set(ids)) and plan.name == path.stem


def test_link_delay_sweep_sweeps_the_one_way_delay():
    plan = load_campaign(PARAMS / "campaigns" / "link_delay_sweep.yaml")
    delays = sorted(flight_inputs(f)["link_delay_ms"] for f in plan.flights)
    assert delays == [0.0, 5.0, 10.0, 15.0, 20.0]
    assert {flight_inputs(f)["link_loss"] for f in plan.flights} == {0.0}


def test_summary_median_of_an_even_count_is_the_mean_of_the_middle_two():
    """Six flights of one cell: the median RMSE is the mean of the 3rd and 4th, not the 4th."""
    rmse = [0.043, 0.062, 0.065, 0.068, 0.040, 0.048]
    rows = [dict(controller="c", fault_kind="motor", severity=0.5, wind_speed_m_s=8.0,
                 wind_direction_deg=0.0, wind_gusts=False, success=True, crashed=False,
                 status="ok", rmse_pos_after_fault_m=v) for v in rmse]
    _, _, stats = summarise(None, rows)
    (cell,) = stats.values()
    assert cell["rmse_median"] == pytest.approx((0.048 + 0.062) / 2)
    assert cell["rmse_max"] == 0.068


def test_outage_smoke_turns_the_sensor_off_for_its_window(tmp_path):
    """outage_smoke's trq_nmpc_eso flights, flown as a worker flies them: with the outage the
    vehicle has its motion capture off from 2 s to 3 s (flight.csv's sensor fault mask) and
    nowhere else, the flight is the one without it, row for row, until the outage starts (the
    same seed, the same fault), and its record has the outage's metric; without it, no figure."""
    from sil_vehicle.sensors import faults as sensor_faults
    from trq_lab import metrics as metrics_mod

    plan = load_campaign(PARAMS / "campaigns" / "outage_smoke.yaml")
    specs = {("outage" in f): f for f in plan.flights if f["controller"] == "trq_nmpc_eso"}
    recs = {k: run_flight(s, str(tmp_path)) for k, s in specs.items()}
    for rec in recs.values():
        assert rec["error"] is None and rec["status"] == "done", rec["error"]
        assert rec["metrics"]["crashed"] is False
    assert recs[False]["metrics"]["max_pos_err_outage_m"] is None
    in_outage = recs[True]["metrics"]["max_pos_err_outage_m"]
    assert 0.0 < in_outage <= recs[True]["metrics"]["max_pos_err_m"]
    logs = {k: metrics_mod.read_csv(tmp_path / s["id"] / "flight.csv")[1]
            for k, s in specs.items()}
    t_us, mask = logs[True]["t_us"], logs[True]["sensor_fault_mask"].astype(int)
    off = (mask >> sensor_faults.UNIT_OF["mocap"]) & 1 == 1
    # a row holds the tick that ends at its stamp: the events due at t act from the next row
    window = (t_us > 2_000_000) & (t_us <= 3_000_000)
    assert np.all(off[window]) and not np.any(off[~window])
    assert not np.any(logs[False]["sensor_fault_mask"])
    before = t_us <= 2_000_000
    for col in ("pos_n_m", "pos_e_m", "pos_d_m", "est_pos_n_m"):
        assert np.array_equal(logs[True][col][before], logs[False][col][:before.sum()]), col
