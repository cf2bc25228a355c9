"""One campaign flight, on a worker: the harness's closed loop, its metrics, its faulted trim.

In: a flight's spec (`spec.load_campaign`). Out: its record (inputs, metrics, status, the error's
traceback if any); `run_flight` never raises. A worker needs only the installed packages.
`rescore` measures a flown flight again from its kept logs (a metric added after it flew).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import socket
import tempfile
import time
import traceback
from pathlib import Path

from trq_offboard.config import load_controller, with_rates_lowpass
from trq_offboard.controller import Controller

from trq_lab import harness as inprocess
from trq_lab import scenario as run_scenario
from trq_lab.analysis import envelope
from trq_lab.campaign.spec import fault_event, identity, outage_events, outage_window_us
from trq_lab.overlays import write_controller_overlay, write_vehicle_overlay

def worst_effectiveness(fault: dict) -> float:
    """A motor fault's lowest effectiveness: a - b of a time-varying one, 0 for a stopped motor
    (not clipped)."""
    if fault.get("stopped"):
        return 0.0
    if "time_varying.a" in fault:
        return fault["time_varying.a"] - fault.get("time_varying.b", 0.0)
    return fault["effectiveness"]


def severity(fault: dict | None) -> tuple[str, float]:
    """(kind, severity): motor -> the worst loss of effectiveness 1 - min(a - b, ...) (1 for a
    stopped motor), servo -> |stuck angle| in deg, none -> 0."""
    if fault is None:
        return "none", 0.0
    if "motor" in fault:
        if fault.get("stopped"):
            return "motor", 1.0
        worst = max(0.0, worst_effectiveness(fault))
        return "motor", round(1.0 - min(1.0, worst), 6)
    return "servo", abs(float(fault["stuck_deg"]))


def plant_id(spec: dict) -> str:
    """What the flights of one plant share (all but the controller; the sensing profile too,
    kept out at its default as in the flight's id): a short hash, so that a table or a figure
    can pair the controllers' flights on the same plant."""
    keep = {k: v for k, v in identity(spec).items() if k not in ("controller", "params_digest")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:8]


def fault_factors(fault: dict | None) -> tuple[tuple[float, ...], tuple[tuple[int, float], ...]]:
    """(motor factors, stuck tilts) of a campaign fault for trq_lab.analysis.envelope: a motor's
    worst effectiveness (a - b of a time-varying one, 0 stopped), a stuck servo's angle."""
    factors = [1.0] * 4
    stuck: list[tuple[int, float]] = []
    if fault is not None and "motor" in fault:
        factors[fault["motor"] - 1] = min(1.0, max(0.0, worst_effectiveness(fault)))
    elif fault is not None:
        stuck.append((fault["servo"] - 1, math.radians(fault["stuck_deg"])))
    return tuple(factors), tuple(stuck)


@functools.lru_cache(maxsize=64)
def _envelope_cached(vp, factors: tuple, wind_m_s: float, wind_from_deg: float,
                     stuck: tuple) -> dict:
    out = envelope.analyse(vp, list(factors), wind_m_s, wind_from_deg,
                           tilt_fixed_rad=dict(stuck) or None)
    m = envelope.throttle_margins(out, vp)
    return {"feasible": out["feasible"], "motor_factors": list(factors),
            "stuck_tilt": [[i + 1, round(math.degrees(a), 3)] for i, a in stuck],
            "throttle_pct": out["trim"]["throttle_pct"], "tilt_deg": out["trim"]["tilt_deg"],
            "roll_deg": out["trim"]["roll_deg"], "pitch_deg": out["trim"]["pitch_deg"],
            "throttle_margin_up_pct": m["up_pct"], "throttle_margin_down_pct": m["down_pct"],
            "min_throttle_margin_pct": m["min_pct"],
            "wrench_margin": {k: (None if v is None else float(v))
                              for k, v in out["margin"].items()}}


def flight_envelope(vp, fault: dict | None, wind: dict) -> dict:
    """The faulted hover trim of the simulated airframe `vp` (a plant's, perturbed) in the
    flight's mean wind, and its margins (trq_lab.analysis.envelope); computed once per process
    for a plant, a fault and a wind (the controllers of a plant share it)."""
    factors, stuck = fault_factors(fault)
    key = dataclasses.replace(vp, file="")          # the same airframe wherever its file lives
    return dict(_envelope_cached(key, factors, float(wind["speed_m_s"]),
                                 float(wind["direction_deg"]), stuck))


def flight_script(spec: dict, tilt_range_deg: tuple[float, float] = (-90.0, 90.0)
                  ) -> tuple[tuple, int | None, tuple[int, int] | None]:
    """(fault-script events, the fault's onset, the outage's window) of a flight: its fault's
    event and its outage's two sensor events (off, then ok), in time order (the vehicle plays
    them so); the onset (vehicle microseconds) is the fault's alone, as the metrics after the
    fault take it, None without a fault; the window (start, end in microseconds) None without
    an outage."""
    where = f"flight {spec['id']}"
    event = fault_event(spec["fault"], where, "fault", tilt_range_deg)
    outage = spec.get("outage")
    events = ((event,) if event is not None else ()) + outage_events(outage, where, "outage")
    return (tuple(sorted(events, key=lambda e: e.at_us)),
            event.at_us if event is not None else None,
            outage_window_us(outage) if outage else None)


def run_flight(spec: dict, log_dir: str | None = None) -> dict:
    """Fly one campaign flight (trq_lab.harness) and return its record; never raises: an
    error is recorded with its traceback. A worker needs only the installed packages."""
    wall0, cpu0 = time.perf_counter(), time.thread_time()
    record = {"id": spec["id"], "spec": spec, "status": "failed", "error": None, "metrics": None,
              "wall_s": None, "sim_s": None, "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        with tempfile.TemporaryDirectory(prefix=f"flight-{spec['id']}-") as tmp:
            out = Path(log_dir) / spec["id"] if log_dir else Path(tmp)
            ctl_yaml = inprocess.prepare_controller(spec["controller"], spec["trajectory"], out)
            cfg = load_controller(ctl_yaml)
            vehicle_file = cfg.vehicle.file
            controller = None                    # the harness's cached Controller of cfg
            if "plant" in spec:                  # the simulated airframe, perturbed
                vehicle_file = write_vehicle_overlay(cfg.vehicle.file, spec["plant"],
                                                     out / "plant")
                if spec.get("controller_model") == "plant":     # and the model with it
                    ctl_yaml = write_controller_overlay(
                        ctl_yaml, None, out / "model", "the controller's model: the plant",
                        vehicle=vehicle_file)
                    cfg = load_controller(ctl_yaml)
                    controller = "build"         # its own, not cached: one model per plant
            link = spec.get("link")
            if link:            # the controller is told the link's round trip, as by the runner
                cfg = dataclasses.replace(
                    cfg, applied_delay_s=run_scenario.command_delay_s(link, False))
            record["applied_delay_s"] = cfg.applied_delay_s
            if spec.get("sensing") is not None:   # the published rates' low-pass, likewise
                cfg = with_rates_lowpass(cfg, run_scenario.rates_lowpass_hz(spec["sensing"]),
                                         "sensing")
            w = spec["wind"]
            if controller == "build":
                controller = Controller(cfg)
            sim = inprocess.sim_params(vehicle_file, cfg.control_rate_hz, seed=spec["seed"],
                                       wind_speed_m_s=w["speed_m_s"],
                                       wind_from_deg=w["direction_deg"], gusts=w["gusts"],
                                       gust_sigma_m_s=w.get("gust_sigma_m_s"),
                                       offboard_impair=link or None,
                                       sensing=spec.get("sensing"))
            vp = sim.vehicle
            events, onset, window = flight_script(
                spec, (math.degrees(vp.tilt_min_rad), math.degrees(vp.tilt_max_rad)))
            try:                # the envelope never fails the flight: its error is recorded
                record["envelope"] = flight_envelope(vp, spec["fault"], w)
            except Exception:
                record["envelope"] = {"error": traceback.format_exc().strip().splitlines()[-1]}
            res = inprocess.fly_inprocess(cfg if controller is None else controller, sim,
                                          events, out_dir=out,
                                          timeout_s=spec["timeout_s"], name=spec["controller"])
            record["metrics"] = inprocess.flight_metrics(
                res.out_dir, spec["controller"], onset, spec["recovery_threshold_m"],
                outage_us=window)
            record.update(status=res.status, sim_s=round(res.sim_s, 6), summary=res.summary)
    except Exception:  # recorded, never lost: the campaign goes on
        record["error"] = traceback.format_exc()
    record["wall_s"] = round(time.perf_counter() - wall0, 3)
    record["cpu_s"] = round(time.thread_time() - cpu0, 3)    # this worker thread's CPU time
    return record


def rescore(record: dict, log_dir: Path) -> dict:
    """A flown flight's record with its metrics computed again, by the current trq_lab.metrics,
    from its kept logs (log_dir/<id>/flight.csv and controller.csv: `--keep-logs`), the fault's
    onset and the outage's window taken from its spec as when it flew. The record as it was when
    it has no metrics (a failed flight) or its logs are not there; every other field kept."""
    spec = record["spec"]
    logs = Path(log_dir) / spec["id"]
    if record.get("metrics") is None or not all(
            (logs / name).is_file() for name in ("flight.csv", "controller.csv")):
        return record
    _, onset, window = flight_script(spec)
    metrics = inprocess.flight_metrics(logs, spec["controller"], onset,
                                       spec["recovery_threshold_m"], outage_us=window)
    return {**record, "metrics": metrics}
