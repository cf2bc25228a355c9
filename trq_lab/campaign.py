#!/usr/bin/env python3
"""Fault campaigns at scale: a grid and/or a seeded random sample of flights over fault, wind,
trajectory, link, plant and controller, flown on Dask (a LocalCluster by default, or an existing cluster).

    trq-campaign smoke --out out/campaign_smoke --workers 2
    trq-campaign CAMPAIGN.yaml --out DIR [--workers N | --scheduler tcp://HOST:8786]
                             [--max-flights N] [--retry-failed] [--keep-logs] [--report-only]
                             [--dry-run]

Each flight is the scenario runner's lockstep vehicle and controller code, flown in one process
(trq_lab.harness: `Sitl` and `OffboardFlight` joined by an in-memory link carrying the same
MAVLink bytes), and measured by trq_lab.metrics as the scenario runner measures a run.

Outputs in DIR:
    flights/<id>.json   one per flight flown (inputs, metrics, status, error traceback if any),
                        <id> a stable hash of the flight's inputs and of the parameter files it
                        reads: a rerun skips every flight that has one (failed ones too, unless
                        --retry-failed), so an interrupted campaign resumes where it stopped
    flights.csv         one row per flight of the campaign flown so far: inputs and metrics
    report.md           success rate and position RMSE per controller against fault severity
                        and wind (tables), where each controller stops coping, and the figures
    success.png, rmse.png   the heat maps
    metrics.json        the report's summary per controller (and the targets missed), which
                        trq-results turns into the README's campaigns row
With a plant axis, report.md also sets every flight against its plant's faulted trim
(trq_lab.plants: envelope classes, rank correlations, paired comparison, targets), with
margin.png, rmse_dist.png and params.png.

Campaign file (strict: an unknown or misspelt key is an error naming the file and the key):

    name: smoke
    description: ...
    seed: 1                   # flight seeds derive from it and from the flight's fault, wind,
                              # trajectory and repeat (all controllers of a cell share a seed)
    controllers: [trq_nmpc_eso, quad_nmpc]      # names in params/controller/ (or YAML paths)
    success_rmse_m: 0.1       # success: not crashed and position RMSE after the fault below this
    recovery_threshold_m: 0.1 # trq_lab.metrics's recovery time threshold
    timeout_s: 120            # simulated seconds; a flight still flying then is a 'timeout'
    repeats: 1                # optional: fly every cell with this many seeds
    grid:                     # every combination; in an axis a list of values is a dimension
      fault: {motor: [1, 2], effectiveness: [1.0, 0.5], at_s: 4.0}
      wind: {speed_m_s: [0.0, 8.0], direction_deg: 0.0}
      trajectory: {kind: hover, altitude_m: 1.0, duration_s: 2.0}
    sample:                   # n seeded random flights; a list is a choice, {uniform: [lo, hi]}
      n: 20                   # a continuous draw
      seed: 5
      fault: {motor: [1, 2, 3, 4], effectiveness: {uniform: [0.3, 1.0]}, at_s: 4.0}

An axis of `grid` may also be a list of such mappings (their union); `none` in the fault axis is
a flight without a fault. Axes left out: no fault, no wind, the controller file's reference, a
clean link, the airframe file as it is. In `sample` a number may also be {normal: [mean, sd]}
(truncated to the key's range).
Fault keys: at_s and either motor (1..4) with effectiveness (a), optional time-varying terms
tv_b, tv_w_rad_s, tv_phi_rad (e = a - b sin(w t + phi)), or stopped: true; or servo (1..4) with
stuck_deg. Wind keys: speed_m_s, direction_deg (from, clockwise from north), gusts,
gust_sigma_m_s. Link keys (the offboard link's seeded impairment, as a scenario's
offboard_link; the controller is told its round trip as applied_delay_s, as by the scenario
runner): loss, delay_ms, jitter_ms, duplicate, reorder. Plant keys (the SIMULATED airframe
only, each controller's own file: trq_lab.overlays.PLANT_PARAMS): mass_scale, inertia_scale,
arm_length_scale, thrust_scale, torque_scale (a curve's coefficients together), motor_lag_scale,
motor_rate_scale, servo_lag_scale, servo_rate_scale, drag_scale, idle_offset_pct; every plant is
checked against every controller's airframe when the campaign is read (a plant that cannot lift
the weight is an error naming the draw). The plant enters the flight's spec (and so its id) but
not its seed: the plants of a cell meet the same noise and gusts. `controller_model: plant` (or
[nominal, plant], both) gives the controller's model the plant's airframe too; default nominal.
`targets` (optional): {controller, min_margin_pct, rmse_after_fault_m, share, better: [{worse,
share}]}, judged in the report (trq_lab.plants). Trajectory keys: those of the controller file's `reference` (kind, altitude_m,
climb_speed_m_s, hold_s, duration_s, ramp_s, radius_m, period_s, helix_climb_m, step_ned_m, land);
their types are checked when the campaign is read, their values and combinations (ramp_s at most
half of duration_s, ...) by the controller's own loader when the flight is prepared: an invalid
one is a failed flight, recorded with the loader's message.

Exit status: 0 when every flight of the campaign has flown without an error, 1 otherwise, 2 on a
bad campaign file or command line.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import itertools
import json
import math
import os
import socket
import statistics
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import trq_params
from pydantic import create_model, model_validator
from trq_params import ConfigError
from trq_params.loader import Choice, Flag, Int, Invalid, Num, Text, Vec, chain, read_yaml, validate
from trq_params.schema import Strict

PARAMS = trq_params.DIR
AXES = ("fault", "wind", "trajectory", "link", "plant")
REFERENCE_KINDS = ("hover", "step", "circle", "helix", "figure8")

# key: (kind, lo, hi); kind: int | float | bool | vec3 | kind
FAULT_KEYS = {"motor": ("int", 1, 4), "servo": ("int", 1, 4), "at_s": ("float", 0.0, 1e6),
              "effectiveness": ("float", 0.0, 1.0), "tv_b": ("float", 0.0, 1.0),
              "tv_w_rad_s": ("float", 0.0, 1000.0), "tv_phi_rad": ("float", -10.0, 10.0),
              "stopped": ("bool", None, None), "stuck_deg": ("float", -90.0, 90.0)}
WIND_KEYS = {"speed_m_s": ("float", 0.0, 40.0), "direction_deg": ("float", -360.0, 360.0),
             "gusts": ("bool", None, None), "gust_sigma_m_s": ("float", 0.0, 20.0)}
TRAJECTORY_KEYS = {"kind": ("kind", None, None), "altitude_m": ("float", None, None),
                   "climb_speed_m_s": ("float", None, None), "hold_s": ("float", None, None),
                   "duration_s": ("float", None, None), "ramp_s": ("float", None, None),
                   "radius_m": ("float", None, None), "period_s": ("float", None, None),
                   "helix_climb_m": ("float", None, None), "step_ned_m": ("vec3", None, None),
                   "land": ("bool", None, None)}
# the offboard link's impairment (sil_vehicle.impair.ImpairParams, as a scenario's offboard_link)
LINK_KEYS = {"loss": ("float", 0.0, 1.0), "delay_ms": ("float", 0.0, 10_000.0),
             "jitter_ms": ("float", 0.0, 10_000.0), "duplicate": ("float", 0.0, 1.0),
             "reorder": ("float", 0.0, 1.0)}
# the simulated airframe's parameters (trq_lab.overlays.PLANT_PARAMS says what each changes):
# factors, and an offset for idle; the ranges keep a plant physical, the vehicle schema then
# checks the airframe that results (a thrust curve that still lifts the weight, ...)
PLANT_KEYS = {"mass_scale": ("float", 0.5, 2.0), "inertia_scale": ("float", 0.2, 5.0),
              "arm_length_scale": ("float", 0.5, 2.0), "thrust_scale": ("float", 0.5, 2.0),
              "torque_scale": ("float", 0.2, 5.0), "motor_lag_scale": ("float", 0.0, 10.0),
              "motor_rate_scale": ("float", 0.1, 10.0), "servo_lag_scale": ("float", 0.0, 10.0),
              "servo_rate_scale": ("float", 0.1, 10.0), "drag_scale": ("float", 0.0, 10.0),
              "idle_offset_pct": ("float", -20.0, 20.0)}
PLANT_NEUTRAL = {k: (0.0 if k.endswith("_offset_pct") else 1.0) for k in PLANT_KEYS}
CONTROLLER_MODELS = ("nominal", "plant")
AXIS_KEYS = {"fault": FAULT_KEYS, "wind": WIND_KEYS, "trajectory": TRAJECTORY_KEYS,
             "link": LINK_KEYS, "plant": PLANT_KEYS}
WIND_DEFAULT = {"speed_m_s": 0.0, "direction_deg": 0.0, "gusts": False}
SAMPLE_DIGITS = 4            # sampled numbers are rounded: readable tables, stable ids


# --- the campaign file -------------------------------------------------------------------------

@dataclass(frozen=True)
class Campaign:
    name: str
    file: Path
    description: str
    seed: int
    controllers: tuple[str, ...]
    success_rmse_m: float
    recovery_threshold_m: float
    timeout_s: float
    repeats: int
    flights: tuple[dict, ...]          # flight specs (JSON-able), controllers included
    targets: Any = None                # _PlantTargets or None
    has_plant: bool = False            # a plant axis: every spec has "plant"


def _field(kind: str, lo, hi):
    """The loader's field type of one axis key (its checks and its wording)."""
    if kind == "int":
        return Int(lo, hi)
    if kind == "float":
        return Num(-math.inf if lo is None else lo, math.inf if hi is None else hi)
    if kind == "bool":
        return Flag
    if kind == "vec3":
        return Vec(3)
    return Choice(*REFERENCE_KINDS)


def _axis_models(axis: str):
    """The models of one axis: one value per key, and a list of values per key."""
    keys = AXIS_KEYS[axis]
    point = create_model(f"{axis}_point", __base__=Strict,
                         **{k: (_field(*spec) | None, None) for k, spec in keys.items()})
    lists = create_model(f"{axis}_lists", __base__=Strict,
                         **{k: (list[_field(*spec)] | None, None) for k, spec in keys.items()})
    return point, lists


AXIS_MODELS = {axis: _axis_models(axis) for axis in AXES}


@functools.cache
def _normal_model():
    """{normal: [mean, sd]}: a normal draw, truncated to the key's range (drawn again until it
    falls inside); the mean within the range and sd > 0 are checked by `_axis_values`."""
    return create_model("normal", __base__=Strict, normal=(Vec(2), ...))


@functools.cache
def _uniform_model(lo, hi):
    """{uniform: [lo, hi]}: a continuous draw within the key's range."""
    return create_model("uniform", __base__=Strict,
                        uniform=(Vec(2, -math.inf if lo is None else lo,
                                     math.inf if hi is None else hi), ...))


def _axis_values(raw_axis: Any, file, where: str, axis: str,
                 sampling: bool) -> dict[str, list | dict]:
    """Each key of one axis mapping -> its list of values (grid) or its distribution (sample):
    a list (choice), {"uniform": [lo, hi]} or {"normal": [mean, sd]}. Scalars become one-element
    lists. Checked with
    the loader's field types: errors name the file and the dotted key (`grid.fault.motor[1]`)."""
    keys = AXIS_KEYS[axis]
    point, lists = AXIS_MODELS[axis]
    if not isinstance(raw_axis, dict):
        raise ConfigError(f"{file}: key '{where}': got {raw_axis!r}, expected a mapping")
    unknown = sorted((k for k in raw_axis if k not in keys), key=str)
    if unknown:
        raise ConfigError(f"{file}: unknown key '{where}.{unknown[0]}' (value "
                          f"{raw_axis[unknown[0]]!r}): expected one of {', '.join(keys)}")
    out: dict[str, list | dict] = {}
    for key in sorted(raw_axis, key=str):
        kind, lo, hi = keys[key]
        raw = raw_axis[key]
        if sampling and isinstance(raw, dict):
            if kind not in ("float", "int"):
                raise ConfigError(f"{file}: key '{where}.{key}': got {raw!r}, expected a value "
                                  "or a list of values to choose from")
            if "normal" in raw:
                mean, sd = validate(_normal_model(), raw, file, prefix=f"{where}.{key}").normal
                lo_, hi_ = (-math.inf if lo is None else lo), (math.inf if hi is None else hi)
                if not (sd > 0.0 and lo_ <= mean <= hi_):
                    raise ConfigError(f"{file}: key '{where}.{key}.normal': got "
                                      f"{[mean, sd]}, expected [mean, sd] with sd > 0 and the "
                                      f"mean in [{lo_:g}, {hi_:g}]")
                out[key] = {"normal": [mean, sd]}
                continue
            bounds = validate(_uniform_model(lo, hi), raw, file,
                              prefix=f"{where}.{key}").uniform
            if bounds[0] > bounds[1]:
                raise ConfigError(f"{file}: key '{where}.{key}.uniform': got {list(bounds)}, "
                                  "expected [lo, hi] with lo <= hi")
            out[key] = {"uniform": list(bounds)}
            continue
        is_list = isinstance(raw, list) and not (kind == "vec3" and raw and
                                                 not isinstance(raw[0], list))
        if is_list and not raw:
            raise ConfigError(f"{file}: key '{where}.{key}': got [], expected a value or a "
                              "non-empty list of values")
        if is_list:
            values = list(getattr(validate(lists, {key: raw}, file, prefix=where), key))
        else:
            values = [getattr(validate(point, {key: raw}, file, prefix=where), key)]
        out[key] = [list(v) if isinstance(v, tuple) else v for v in values]
    return out


def _grid_axis(grid: dict, file, axis: str) -> list[dict | None]:
    """All points of one grid axis (None: no fault)."""
    if axis not in grid:
        return [None] if axis == "fault" else [{}]
    raw = grid[axis]
    items = raw if isinstance(raw, list) else [raw]
    if not items:
        raise ConfigError(f"{file}: key 'grid.{axis}': got {raw!r}, expected a mapping or a "
                          "non-empty list of mappings")
    points: list[dict | None] = []
    for i, item in enumerate(items):
        where = f"grid.{axis}" + (f"[{i}]" if isinstance(raw, list) else "")
        if axis == "fault" and item == "none":
            points.append(None)
            continue
        values = _axis_values(item, file, where, axis, sampling=False)
        names = list(values)
        for combo in itertools.product(*(values[k] for k in names)):
            point = dict(zip(names, combo))
            if axis == "fault":
                _fault_event(point, file, where)
            points.append(point)
    return points


def _fault_event(fault: dict | None, file, where: str, tilt_range_deg=(-90.0, 90.0)):
    """The sil_vehicle fault-script Event of a campaign fault (validated by the fault script's
    own parser), or None."""
    from sil_vehicle.faultscript import parse_event

    if fault is None:
        return None
    f = dict(fault)
    prefix = f"{where}."

    def fail(key, expected):
        return ConfigError(f"{file}: key '{prefix}{key}': got {f.get(key)!r}, expected {expected}")

    if "at_s" not in f:
        raise ConfigError(f"{file}: missing key '{prefix}at_s' (the fault onset)")
    event: dict[str, Any] = {"at_s": f["at_s"]}
    if ("motor" in f) == ("servo" in f):
        raise ConfigError(f"{file}: key '{where}': a fault needs one of motor or servo "
                          f"(got {sorted(f)})")
    if "motor" in f:
        event["motor"] = f["motor"]
        for key in ("stuck_deg",):
            if key in f:
                raise fail(key, "no servo key in a motor fault")
        tv = [k for k in ("tv_b", "tv_w_rad_s", "tv_phi_rad") if k in f]
        if "stopped" in f:
            if "effectiveness" in f or tv:
                raise fail("stopped", "either stopped or effectiveness, not both")
            event["stopped"] = f["stopped"]
        elif "effectiveness" not in f:
            raise ConfigError(f"{file}: missing key '{prefix}effectiveness' (or stopped)")
        elif tv:
            event["time_varying"] = {"a": f["effectiveness"], "b": f.get("tv_b", 0.0),
                                     "w": f.get("tv_w_rad_s", 0.0),
                                     "phi": f.get("tv_phi_rad", 0.0)}
        else:
            event["effectiveness"] = f["effectiveness"]
    else:
        event["servo"] = f["servo"]
        for key in ("effectiveness", "tv_b", "tv_w_rad_s", "tv_phi_rad", "stopped"):
            if key in f:
                raise fail(key, "no motor key in a servo fault")
        if "stuck_deg" not in f:
            raise ConfigError(f"{file}: missing key '{prefix}stuck_deg'")
        event["stuck_deg"] = f["stuck_deg"]
    return parse_event(event, tilt_range_deg, file=str(file), key=where)


def _sample_axis(values: dict | None, axis: str, rng) -> dict | None:
    """One draw of one axis: every key drawn in sorted order from its own distribution."""
    if values is None:
        return None if axis == "fault" else {}
    point = {}
    for key in sorted(values):
        v = values[key]
        if isinstance(v, dict) and "normal" in v:
            kind, lo, hi = AXIS_KEYS[axis][key]
            mean, sd = v["normal"]
            lo = -math.inf if lo is None else lo
            hi = math.inf if hi is None else hi
            for _ in range(10_000):
                x = float(rng.normal(mean, sd))
                if lo <= x <= hi:
                    break
            else:
                x = min(max(mean, lo), hi)   # unreachable for a mean in range and sd > 0
            point[key] = int(round(x)) if kind == "int" else round(x, SAMPLE_DIGITS)
        elif isinstance(v, dict):
            lo, hi = v["uniform"]
            x = float(rng.uniform(lo, hi))
            kind = AXIS_KEYS[axis][key][0]
            point[key] = int(round(x)) if kind == "int" else round(x, SAMPLE_DIGITS)
        else:
            point[key] = v[int(rng.integers(len(v)))]
    return point


def _file_digest(paths) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(str(Path(p).name).encode())
        h.update(Path(p).read_bytes())
    return h.hexdigest()[:16]


def controller_inputs(name: str) -> tuple[Path, str]:
    """(controller file, digest of every parameter file a flight with it reads: the file and the
    files it extends, its airframe, its observer gains, the default sim settings)."""
    from trq_lab.harness import SIM_DEFAULT
    from trq_lab.overlays import controller_file
    from trq_offboard.config import load_controller

    path = controller_file(name)
    files = chain(path)
    cfg = load_controller(path)
    files += [Path(cfg.vehicle.file), Path(cfg.eso.file) if cfg.eso else PARAMS / "controller" /
              "eso.yaml", SIM_DEFAULT]
    return path, _file_digest(files)


def controller_vehicle(name: str) -> str:
    """The airframe file of a controller (its model's, and the simulated vehicle's)."""
    from trq_lab.overlays import controller_file
    from trq_offboard.config import load_controller

    return load_controller(controller_file(name)).vehicle.file


def _check_plant(plant: dict, vehicles: dict[str, str], file, where: str) -> None:
    """Every controller's airframe with `plant` applied must be a valid vehicle file."""
    from trq_params import schema

    from trq_lab.overlays import perturbed_vehicle, vehicle_data

    if not plant:
        return
    for vfile in sorted(set(vehicles.values())):
        try:
            validate(schema.VehicleFile, perturbed_vehicle(vehicle_data(vfile), plant), vfile)
        except ConfigError as exc:
            raise ConfigError(f"{file}: key '{where}': got {plant}, expected a plant with "
                              f"which the airframe stays valid: {exc}") from None


def flight_id(spec: dict) -> str:
    text = json.dumps({k: v for k, v in spec.items() if k != "id"}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class _Grid(Strict):
    """Every combination of the axes' values (each axis checked by `_axis_values`)."""
    fault: Any = None
    wind: Any = None
    trajectory: Any = None
    link: Any = None
    plant: Any = None


class _Sample(_Grid):
    """n seeded random draws of the axes' distributions."""
    n: Int(1, 10_000_000)
    seed: Int(0, 2**31 - 1)


class _Paired(Strict):
    """`controller` does better than `worse` (a lower RMSE after the fault, or it flies where
    the other crashes) on at least `share` of the flights both flew on the same plant."""
    worse: Text
    share: Num(0.0, 1.0)


class _PlantTargets(Strict):
    """A campaign's targets: among the flights of `controller` whose faulted trim keeps at least
    `min_margin_pct` of throttle margin on every motor, at least `share` stay within
    `rmse_after_fault_m`; and the paired comparisons."""
    controller: Text
    min_margin_pct: Num(0.0, 100.0)
    rmse_after_fault_m: Num(1e-5, 100.0)
    share: Num(0.0, 1.0)
    better: list[_Paired] = []


class CampaignFile(Strict):
    """A campaign file (params/campaigns/*.yaml); the axes are checked key by key afterwards."""
    name: Text
    description: Text
    seed: Int(0, 2**31 - 1)
    controllers: list[Text]
    success_rmse_m: Num(0.001, 100.0)
    recovery_threshold_m: Num(0.001, 100.0)
    timeout_s: Num(1.0, 36000.0)
    repeats: Int(1, 1000) = 1
    controller_model: Any = "nominal"
    targets: _PlantTargets | None = None
    grid: _Grid | None = None
    sample: _Sample | None = None

    @model_validator(mode="after")
    def _flights(self) -> "CampaignFile":
        if not self.controllers or len(set(self.controllers)) != len(self.controllers):
            raise Invalid("controllers", self.controllers,
                          "a non-empty list of distinct controller names")
        for i, c in enumerate(self.controllers):
            if not trq_params.exists("controller", c):
                raise Invalid(f"controllers[{i}]", c, "a built-in controller name or a "
                              "controller YAML path")
        if self.grid is None and self.sample is None:
            raise Invalid("grid", None, "a grid (or a sample): a campaign needs flights")
        models = self.controller_model
        if not (models in CONTROLLER_MODELS or (
                isinstance(models, list) and models and len(set(models)) == len(models)
                and all(m in CONTROLLER_MODELS for m in models))):
            raise Invalid("controller_model", models, "one of " + "|".join(CONTROLLER_MODELS)
                          + " or a list of distinct ones")
        t = self.targets
        if t is not None:
            for key, name in [("targets.controller", t.controller)] + [
                    (f"targets.better[{i}].worse", b.worse) for i, b in enumerate(t.better)]:
                if name not in self.controllers:
                    raise Invalid(key, name, "one of the campaign's controllers ("
                                  + ", ".join(self.controllers) + ")")
        return self


def _axes(section: _Grid) -> dict[str, Any]:
    """The axes a grid or sample names (an axis written as null is named, and then fails)."""
    return {axis: getattr(section, axis) for axis in AXES if axis in section.model_fields_set}


def load_campaign(path: Path) -> Campaign:
    import numpy as np

    path = Path(path)
    top = validate(CampaignFile, read_yaml(path), path)
    digests = {}
    for i, c in enumerate(top.controllers):
        try:
            digests[c] = controller_inputs(c)[1]
        except ConfigError as exc:
            raise ConfigError(f"{path}: key 'controllers[{i}]': {c!r} does not load: "
                              f"{exc}") from exc
    vehicles = {c: controller_vehicle(c) for c in top.controllers}
    cells: list[tuple] = []
    if top.grid is not None:
        grid = _axes(top.grid)
        cells += list(itertools.product(*(_grid_axis(grid, path, axis) for axis in AXES)))
    has_plant = any(s is not None and "plant" in _axes(s) for s in (top.grid, top.sample))
    if top.grid is not None:
        for plant in {json.dumps(c[4], sort_keys=True): c[4] for c in cells}.values():
            _check_plant(plant, vehicles, path, "grid.plant")
    if top.sample is not None:
        dists = {axis: _axis_values(raw, path, f"sample.{axis}", axis, sampling=True)
                 for axis, raw in _axes(top.sample).items()}
        rng = np.random.default_rng(top.sample.seed)
        for k in range(top.sample.n):
            point = tuple(_sample_axis(dists.get(axis), axis, rng) for axis in AXES)
            try:
                _fault_event(point[0], path, f"sample.fault (draw {k})")
            except ConfigError as exc:
                raise ConfigError(f"{exc} (a sampled fault must be valid whatever is "
                                  "drawn)") from exc
            _check_plant(point[4], vehicles, path, f"sample.plant (draw {k})")
            cells.append(point)
    name, description, seed, controllers = top.name, top.description, top.seed, top.controllers
    success, threshold, timeout, repeats = (top.success_rmse_m, top.recovery_threshold_m,
                                            top.timeout_s, top.repeats)
    models = top.controller_model if isinstance(top.controller_model, list) else \
        [top.controller_model]
    flights = []
    seen = set()
    for fault, wind, traj, link, plant in cells:
        wind = {**WIND_DEFAULT, **(wind or {})}
        for r in range(repeats):
            cell = {"fault": fault, "wind": wind, "trajectory": traj or {}, "repeat": r}
            if link:            # only then: a clean link keeps the ids and seeds it always had
                cell["link"] = link
            text = json.dumps({"campaign_seed": seed, **cell}, sort_keys=True)
            fseed = int(hashlib.sha256(text.encode()).hexdigest()[:8], 16) % 2**31
            # the plant is not in the seed: every plant of a cell meets the same noise and
            # gusts (common random numbers), so what differs between plants is the plant's
            for model in models:
                extra: dict[str, Any] = {"plant": plant} if has_plant else {}
                if model != "nominal":
                    extra["controller_model"] = model
                for c in controllers:
                    spec = {"controller": c, **cell, **extra, "seed": fseed,
                            "timeout_s": timeout, "recovery_threshold_m": threshold,
                            "params_digest": digests[c]}
                    spec["id"] = flight_id(spec)
                    if spec["id"] in seen:
                        continue                  # the same flight listed twice: fly it once
                    seen.add(spec["id"])
                    flights.append(spec)
    return Campaign(name, path, description, seed, tuple(controllers), success, threshold,
                    timeout, repeats, tuple(flights), top.targets, has_plant)


# --- one flight, on a worker -------------------------------------------------------------------

def severity(fault: dict | None) -> tuple[str, float]:
    """(kind, severity): motor -> the worst loss of effectiveness 1 - min(a - b, ...) (1 for a
    stopped motor), servo -> |stuck angle| in deg, none -> 0."""
    if fault is None:
        return "none", 0.0
    if "motor" in fault:
        if fault.get("stopped"):
            return "motor", 1.0
        worst = max(0.0, fault["effectiveness"] - fault.get("tv_b", 0.0))
        return "motor", round(1.0 - min(1.0, worst), 6)
    return "servo", abs(float(fault["stuck_deg"]))


def flight_inputs(spec: dict) -> dict:
    """The flat input columns of a flight's row."""
    fault = spec["fault"] or {}
    kind, sev = severity(spec["fault"])
    row = {"id": spec["id"], "controller": spec["controller"], "fault_kind": kind,
           "severity": sev}
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


def plant_id(spec: dict) -> str:
    """What the flights of one plant share (all but the controller): a short hash, so that a
    table or a figure can pair the controllers' flights on the same plant."""
    keep = {k: v for k, v in spec.items() if k not in ("id", "controller", "params_digest")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:8]


def _fault_factors(fault: dict | None) -> tuple[tuple[float, ...], tuple[tuple[int, float], ...]]:
    """(motor factors, stuck tilts) of a campaign fault for trq_lab.analysis.envelope: a motor's
    worst effectiveness (a - b of a time-varying one, 0 stopped), a stuck servo's angle."""
    factors = [1.0] * 4
    stuck: list[tuple[int, float]] = []
    if fault is not None and "motor" in fault:
        worst = 0.0 if fault.get("stopped") else fault["effectiveness"] - fault.get("tv_b", 0.0)
        factors[fault["motor"] - 1] = min(1.0, max(0.0, worst))
    elif fault is not None:
        stuck.append((fault["servo"] - 1, math.radians(fault["stuck_deg"])))
    return tuple(factors), tuple(stuck)


@functools.lru_cache(maxsize=64)
def _envelope_cached(vp, factors: tuple, wind_m_s: float, wind_from_deg: float,
                     stuck: tuple) -> dict:
    from trq_lab.analysis import envelope

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
    factors, stuck = _fault_factors(fault)
    key = dataclasses.replace(vp, file="")          # the same airframe wherever its file lives
    return dict(_envelope_cached(key, factors, float(wind["speed_m_s"]),
                                 float(wind["direction_deg"]), stuck))


def run_flight(spec: dict, log_dir: str | None = None) -> dict:
    """Fly one campaign flight (trq_lab.harness) and return its record; never raises: an
    error is recorded with its traceback. A worker needs only the installed packages."""
    import tempfile

    wall0, cpu0 = time.perf_counter(), time.thread_time()
    record = {"id": spec["id"], "spec": spec, "status": "failed", "error": None, "metrics": None,
              "wall_s": None, "sim_s": None, "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        from trq_lab import harness as inprocess
        from trq_offboard.config import load_controller

        with tempfile.TemporaryDirectory(prefix=f"flight-{spec['id']}-") as tmp:
            out = Path(log_dir) / spec["id"] if log_dir else Path(tmp)
            ctl_yaml = inprocess.prepare_controller(spec["controller"], spec["trajectory"], out)
            cfg = load_controller(ctl_yaml)
            vehicle_file = cfg.vehicle.file
            controller = None                    # the harness's cached Controller of cfg
            if "plant" in spec:                  # the simulated airframe, perturbed
                from trq_lab.overlays import write_controller_overlay, write_vehicle_overlay
                vehicle_file = write_vehicle_overlay(cfg.vehicle.file, spec["plant"],
                                                     out / "plant")
                if spec.get("controller_model") == "plant":     # and the model with it
                    from trq_offboard.controller import Controller
                    ctl_yaml = write_controller_overlay(
                        ctl_yaml, None, out / "model", "the controller's model: the plant",
                        vehicle=vehicle_file)
                    cfg = load_controller(ctl_yaml)
                    controller = "build"         # its own, not cached: one model per plant
            link = spec.get("link")
            if link:            # the controller is told the link's round trip, as by the runner
                from trq_lab import scenario as run_scenario
                cfg = dataclasses.replace(
                    cfg, applied_delay_s=run_scenario.command_delay_s(link, False))
            record["applied_delay_s"] = cfg.applied_delay_s
            w = spec["wind"]
            if controller == "build":
                controller = Controller(cfg)
            sim = inprocess.sim_params(vehicle_file, cfg.control_rate_hz, seed=spec["seed"],
                                       wind_speed_m_s=w["speed_m_s"],
                                       wind_from_deg=w["direction_deg"], gusts=w["gusts"],
                                       gust_sigma_m_s=w.get("gust_sigma_m_s"),
                                       offboard_impair=link or None)
            vp = sim.vehicle
            event = _fault_event(spec["fault"], f"flight {spec['id']}", "fault",
                                 (math.degrees(vp.tilt_min_rad), math.degrees(vp.tilt_max_rad)))
            events = (event,) if event is not None else ()
            try:                # the envelope never fails the flight: its error is recorded
                record["envelope"] = flight_envelope(vp, spec["fault"], w)
            except Exception:
                record["envelope"] = {"error": traceback.format_exc().strip().splitlines()[-1]}
            res = inprocess.fly_inprocess(cfg if controller is None else controller, sim,
                                          events, out_dir=out,
                                          timeout_s=spec["timeout_s"], name=spec["controller"])
            onset = event.at_us if event is not None else None
            record["metrics"] = inprocess.flight_metrics(res.out_dir, spec["controller"], onset,
                                                         spec["recovery_threshold_m"])
            record.update(status=res.status, sim_s=round(res.sim_s, 6), summary=res.summary)
    except Exception:  # recorded, never lost: the campaign goes on
        record["error"] = traceback.format_exc()
    record["wall_s"] = round(time.perf_counter() - wall0, 3)
    record["cpu_s"] = round(time.thread_time() - cpu0, 3)    # this worker thread's CPU time
    return record


# --- results -----------------------------------------------------------------------------------

def _write_json(path: Path, doc: dict) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=str) + "\n")
    os.replace(tmp, path)


def load_results(out: Path) -> dict[str, dict]:
    results = {}
    for p in sorted((out / "flights").glob("*.json")):
        try:
            doc = json.loads(p.read_text())
        except (OSError, ValueError):
            continue                               # a torn file: the flight is flown again
        results[doc.get("id", p.stem)] = doc
    return results


METRIC_KEYS = ("vehicle", "crashed", "flight_s", "rmse_pos_m", "max_pos_err_m",
               "rmse_pos_after_fault_m", "rmse_vert_after_fault_m", "max_sink_after_fault_m",
               "rmse_yaw_deg", "max_yaw_err_deg", "recovery_s",
               "solve_ms_p50", "solve_ms_p99")


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
    import csv

    if not rows:
        path.write_text("")
        return
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})


# --- report ------------------------------------------------------------------------------------

def _bins(values: list[float], max_distinct: int = 12, n_bins: int = 8):
    """A function value -> (sort key, label): distinct values if few, equal-width bins if many."""
    distinct = sorted(set(values))
    if len(distinct) <= max_distinct:
        return lambda v: (v, f"{v:g}")
    lo, hi = distinct[0], distinct[-1]
    width = (hi - lo) / n_bins or 1.0

    def f(v):
        k = min(int((v - lo) / width), n_bins - 1)
        a, b = lo + k * width, lo + (k + 1) * width
        return (a, f"{a:.3g}-{b:.3g}")
    return f


def _link_label(r: dict) -> str:
    """'' for a clean link, else what is impaired (loss %, delay and jitter ms, ...)."""
    parts = []
    if r.get("link_loss"):
        parts.append(f"{100 * r['link_loss']:g} % lost")
    if r.get("link_delay_ms"):
        parts.append(f"{r['link_delay_ms']:g} ms")
    if r.get("link_jitter_ms"):
        parts.append(f"+-{r['link_jitter_ms']:g} ms jitter")
    if r.get("link_duplicate"):
        parts.append(f"{100 * r['link_duplicate']:g} % dup")
    if r.get("link_reorder"):
        parts.append(f"{100 * r['link_reorder']:g} % reordered")
    return ", link " + " ".join(parts) if parts else ""


def _wind_label(r: dict) -> str:
    s = f"{r['wind_speed_m_s']:g} m/s"
    if r["wind_speed_m_s"]:
        s += f" from {r['wind_direction_deg']:g}"
    if r["wind_gusts"]:
        s += " gusts"
    return s + _link_label(r)


def cells(rows: list[dict]):
    """Group the rows by (controller, wind key, severity key): the heat-map cells."""
    sev_of = {kind: _bins([r["severity"] for r in rows if r["fault_kind"] == kind])
              for kind in {r["fault_kind"] for r in rows}}
    def conditions(r):                 # the wind and the link a flight met
        return (r["wind_speed_m_s"], r["wind_direction_deg"], r["wind_gusts"],
                *(r.get(f"link_{k}", 0.0) for k in LINK_KEYS))
    wind_distinct = {conditions(r) for r in rows}
    speed_bin = _bins([r["wind_speed_m_s"] for r in rows])
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        if len(wind_distinct) <= 12:
            wkey = (conditions(r), _wind_label(r))
        else:
            k, label = speed_bin(r["wind_speed_m_s"])
            wkey = ((k, *conditions(r)[3:]), f"{label} m/s{_link_label(r)}")
        skey, slabel = sev_of[r["fault_kind"]](r["severity"])
        kind_label = {"motor": "motor loss", "servo": "servo stuck deg", "none": "no fault"}
        sev = ((r["fault_kind"], skey), f"{kind_label[r['fault_kind']]} {slabel}"
               if r["fault_kind"] != "none" else "no fault")
        out.setdefault((r["controller"], wkey, sev), []).append(r)
    return out


def _rmse_of(r: dict) -> float | None:
    v = r.get("rmse_pos_after_fault_m")
    return v if v is not None else r.get("rmse_pos_m")


def summarise(campaign: Campaign, rows: list[dict]):
    groups = cells(rows)
    winds = sorted({k[1] for k in groups}, key=lambda w: w[0])
    sevs = sorted({k[2] for k in groups}, key=lambda s: s[0])
    stats = {}
    for key, rs in groups.items():
        ok = sum(r["success"] for r in rs)
        rm = [v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None]
        stats[key] = {"n": len(rs), "ok": ok, "rate": ok / len(rs),
                      "crashed": sum(bool(r["crashed"]) for r in rs),
                      "failed": sum(r["status"] == "failed" for r in rs),
                      "rmse_median": float(statistics.median(rm)) if rm else None,
                      "rmse_max": max(rm) if rm else None}
    return winds, sevs, stats


def coping_limit(campaign, winds, sevs, stats, controller, wind) -> str:
    """The largest motor-loss severity up to which every flight of this controller and wind
    succeeded (every smaller severity as well)."""
    last = None
    for sev in sevs:
        if sev[0][0] != "motor":
            continue
        s = stats.get((controller, wind, sev))
        if s is None:
            continue
        if s["ok"] < s["n"]:
            break
        last = sev
    return "none" if last is None else last[1].replace("motor loss ", "")


def heatmaps(campaign: Campaign, winds, sevs, stats, out: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    made = []
    ctrls = list(campaign.controllers)
    for what, fname, title in (("rate", "success.png", "success rate"),
                               ("rmse_median", "rmse.png", "median position RMSE after fault, m")):
        fig, axes = plt.subplots(1, len(ctrls), figsize=(2.2 + 0.7 * len(sevs) * len(ctrls),
                                                         1.6 + 0.45 * len(winds)),
                                 squeeze=False, sharey=True)
        grid_all = []
        for c in ctrls:
            g = np.full((len(winds), len(sevs)), np.nan)
            for i, w in enumerate(winds):
                for j, s in enumerate(sevs):
                    st = stats.get((c, w, s))
                    if st is not None and st[what] is not None:
                        g[i, j] = st[what]
            grid_all.append(g)
        finite = np.concatenate([g[np.isfinite(g)] for g in grid_all]) if grid_all else []
        for ax, c, g in zip(axes[0], ctrls, grid_all):
            if what == "rate":
                im = ax.imshow(g, vmin=0.0, vmax=1.0, cmap="RdYlGn", aspect="auto")
            else:
                from matplotlib.colors import LogNorm
                lo = max(float(np.min(finite)), 1e-4) if len(finite) else 1e-3
                hi = max(float(np.max(finite)), lo * 10) if len(finite) else 1.0
                im = ax.imshow(g, norm=LogNorm(lo, hi), cmap="viridis_r", aspect="auto")
            for i in range(g.shape[0]):
                for j in range(g.shape[1]):
                    if np.isfinite(g[i, j]):
                        txt = f"{g[i, j]:.0%}" if what == "rate" else f"{g[i, j]:.3f}"
                        ax.text(j, i, txt, ha="center", va="center", fontsize=7)
            ax.set_title(c, fontsize=9)
            ax.set_xticks(range(len(sevs)))
            ax.set_xticklabels([s[1].replace("motor loss ", "") for s in sevs], rotation=60,
                               fontsize=7)
            ax.set_xlabel("motor effectiveness lost" if all(s[0][0] in ("motor", "none")
                                                            for s in sevs) else "fault", fontsize=8)
            ax.set_yticks(range(len(winds)))
            ax.set_yticklabels([w[1] for w in winds], fontsize=7)
        axes[0][0].set_ylabel("wind", fontsize=8)
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
        fig.suptitle(f"{campaign.name}: {title} (success: not crashed, RMSE after fault < "
                     f"{campaign.success_rmse_m:g} m)" if what == "rate" else
                     f"{campaign.name}: {title}", fontsize=9, y=1.04)
        path = out / fname
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        made.append(path)
    return made


def _fmt(v, spec="{:.3f}") -> str:
    return "-" if v is None else spec.format(v)


def write_report(campaign: Campaign, rows: list[dict], out: Path, run_info: dict | None = None,
                 figures: bool = True) -> Path:
    lines = [f"# Campaign `{campaign.name}`", "", campaign.description.strip(), ""]
    n_plan = len(campaign.flights)
    failed = [r for r in rows if r["status"] == "failed"]
    lines += [f"{len(rows)} of {n_plan} flights flown; {sum(r['success'] for r in rows)} "
              f"successful, {sum(bool(r['crashed']) for r in rows)} crashed, {len(failed)} "
              f"failed (errors in `flights/<id>.json`). Success: not crashed, landed and "
              f"position RMSE after the fault below {campaign.success_rmse_m:g} m. Controllers: "
              + ", ".join(f"`{c}`" for c in campaign.controllers) + ".", ""]
    if run_info:
        lines += [f"Last run: {run_info['flown']} flights in {run_info['wall_s']:.0f} s on "
                  f"{run_info['workers']} worker(s): **{run_info['flights_per_hour']:.0f} "
                  f"flights/hour**.", ""]
    summary: dict = {"campaign": campaign.name, "description": campaign.description.strip(),
                     "planned": n_plan, "flights": len(rows),
                     "failed": len(failed), "success_rmse_m": campaign.success_rmse_m}
    if not rows:
        (out / "report.md").write_text("\n".join(lines) + "\n")
        _write_json(out / "metrics.json", summary)
        return out / "report.md"
    winds, sevs, stats = summarise(campaign, rows)
    lines += ["## Success rate per controller", "",
              "| controller | flights | success | crashed | failed | median RMSE after fault m |",
              "|---|---|---|---|---|---|"]
    for c in campaign.controllers:
        rs = [r for r in rows if r["controller"] == c]
        if not rs:
            continue
        rm = sorted(v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None)
        lines.append(f"| {c} | {len(rs)} | {sum(r['success'] for r in rs) / len(rs):.0%} | "
                     f"{sum(bool(r['crashed']) for r in rs)} | "
                     f"{sum(r['status'] == 'failed' for r in rs)} | "
                     f"{_fmt(statistics.median(rm) if rm else None)} |")
    lines.append("")
    if campaign.has_plant:
        from trq_lab import plants

        plant_lines, plant_summary = plants.report(campaign, rows, out, figures)
        lines += plant_lines
        summary.update(plant_summary)
    else:
        summary["controllers"] = {}
        for c in campaign.controllers:
            rs = [r for r in rows if r["controller"] == c]
            rm = [v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None]
            if rs:
                summary["controllers"][c] = {
                    "flights": len(rs), "success_rate": sum(r["success"] for r in rs) / len(rs),
                    "crashed": sum(bool(r["crashed"]) for r in rs),
                    "rmse_median_m": float(statistics.median(rm)) if rm else None}
    _write_json(out / "metrics.json", summary)
    if campaign.has_plant and len(winds) * len(sevs) == 1:
        figures = False                  # one cell: the cell tables and heat maps say nothing
        stats = {}
    head = "| wind | " + " | ".join(s[1] for s in sevs) + " |"
    rule = "|---|" + "---|" * len(sevs)
    for c in campaign.controllers:
        if not any(k[0] == c for k in stats):
            continue
        lines += [f"## `{c}`", "", "Success rate (successful / flown) and, below, the median "
                  "position RMSE after the fault (m) of the flights that did not crash, per wind "
                  "(rows) and fault severity (columns).", "", head, rule]
        for w in winds:
            cellv = []
            for s in sevs:
                st = stats.get((c, w, s))
                cellv.append("" if st is None else f"{st['rate']:.0%} ({st['ok']}/{st['n']})")
            lines.append(f"| {w[1]} | " + " | ".join(cellv) + " |")
        lines += ["", head, rule]
        for w in winds:
            cellv = []
            for s in sevs:
                st = stats.get((c, w, s))
                cellv.append("" if st is None else _fmt(st["rmse_median"]))
            lines.append(f"| {w[1]} | " + " | ".join(cellv) + " |")
        lines.append("")
    if stats and any(s[0][0] == "motor" for s in sevs):
        lines += ["## Where each controller stops coping", "",
                  "The largest loss of motor effectiveness up to which every flight (every motor, "
                  "every smaller loss) succeeded.", "",
                  "| wind | " + " | ".join(campaign.controllers) + " |",
                  "|---|" + "---|" * len(campaign.controllers)]
        for w in winds:
            lines.append(f"| {w[1]} | " + " | ".join(
                coping_limit(campaign, winds, sevs, stats, c, w) for c in campaign.controllers)
                + " |")
        lines.append("")
        first = campaign.controllers[0]
        worse = []
        for (c, w, s), st in stats.items():
            if c == first:
                continue
            mine = stats.get((first, w, s))
            if mine is not None and mine["rate"] < st["rate"]:
                worse.append(f"{w[1]}, {s[1]}: `{first}` {mine['rate']:.0%} < `{c}` "
                             f"{st['rate']:.0%}")
        lines += [f"`{first}` copes at least as often as every other controller in every cell."
                  if not worse else f"Cells where `{first}` succeeds less often than another "
                  "controller:", ""] + [f"- {x}" for x in sorted(worse)] + [""]
    if figures:
        for p in heatmaps(campaign, winds, sevs, stats, out):
            lines += [f"![{p.stem}]({p.name})", ""]
    if failed:
        lines += ["## Failed flights", ""]
        for r in failed[:20]:
            lines.append(f"- `{r['id']}` ({r['controller']}): {r['error']}")
        if len(failed) > 20:
            lines.append(f"- ... and {len(failed) - 20} more")
        lines.append("")
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return out / "report.md"


# --- running -----------------------------------------------------------------------------------

class Progress:
    """One line: flights done of the total, failures, throughput and ETA."""

    def __init__(self, total: int, stream=sys.stderr, every_s: float = 2.0) -> None:
        self.total, self.stream, self.every_s = total, stream, every_s
        self.done = self.failed = 0
        self.t0 = time.monotonic()
        self._last = 0.0
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def update(self, failed: bool, force: bool = False) -> None:
        self.done += 1
        self.failed += failed
        now = time.monotonic()
        if not force and now - self._last < self.every_s and self.done < self.total:
            return
        self._last = now
        self.stream.write(("\r" if self.tty else "") + self.line() + ("" if self.tty else "\n"))
        self.stream.flush()

    def line(self) -> str:
        el = time.monotonic() - self.t0
        rate = self.done / el if el > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        eta_s = "--" if not math.isfinite(eta) else time.strftime("%H:%M:%S", time.gmtime(eta))
        return (f"  [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} flights, "
                f"{self.failed} failed, {rate * 3600:.0f}/h, elapsed "
                f"{time.strftime('%H:%M:%S', time.gmtime(el))}, ETA {eta_s}")

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()



def run_campaign(campaign: Campaign, out: Path, *, workers: int | None = None,
                 scheduler: str | None = None, max_flights: int | None = None,
                 retry_failed: bool = False, keep_logs: bool = False,
                 stream=sys.stderr) -> dict:
    """Fly the flights of `campaign` not yet in out/flights; return run info."""
    from dask.distributed import Client, LocalCluster, as_completed

    (out / "flights").mkdir(parents=True, exist_ok=True)
    done = load_results(out)
    todo = [s for s in campaign.flights
            if s["id"] not in done or (retry_failed and done[s["id"]].get("error"))]
    skipped = len(campaign.flights) - len(todo)
    if max_flights is not None:
        todo = todo[:max_flights]
    info = {"planned": len(campaign.flights), "skipped": skipped, "flown": 0, "failed": 0,
            "wall_s": 0.0, "workers": 0, "flights_per_hour": 0.0, "cluster_start_s": 0.0,
            "cpu_s": 0.0, "sim_s": 0.0}
    print(f"campaign: {campaign.name}: {len(campaign.flights)} flights, {skipped} already done, "
          f"{len(todo)} to fly", file=stream, flush=True)
    if not todo:
        return info
    t_start = time.monotonic()
    cluster = None
    if scheduler:
        client = Client(scheduler)
    else:
        import logging
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    try:
        nworkers = len(client.scheduler_info()["workers"])
        info["workers"] = nworkers
        info["cluster_start_s"] = round(time.monotonic() - t_start, 2)
        print(f"campaign: {nworkers} worker(s) on {client.scheduler.address}", file=stream,
              flush=True)
        log_dir = str(out / "logs") if keep_logs else None
        t0 = time.monotonic()
        futures = [client.submit(run_flight, spec, log_dir, key=f"flight-{spec['id']}",
                                 pure=False) for spec in todo]
        by_key = {f.key: s for f, s in zip(futures, todo)}
        progress = Progress(len(todo), stream)
        for fut in as_completed(futures):
            spec = by_key[fut.key]
            try:
                rec = fut.result()
            except Exception:  # the worker died (or the task could not start): keep the error
                rec = {"id": spec["id"], "spec": spec, "status": "failed", "metrics": None,
                       "error": traceback.format_exc(), "wall_s": None, "sim_s": None,
                       "worker": None}
            rec["finished_unix_s"] = round(time.time(), 3)
            _write_json(out / "flights" / f"{spec['id']}.json", rec)
            info["flown"] += 1
            info["failed"] += bool(rec.get("error"))
            info["cpu_s"] += rec.get("cpu_s") or 0.0
            info["sim_s"] += rec.get("sim_s") or 0.0
            progress.update(bool(rec.get("error")))
            fut.release()
        progress.close()
        info["wall_s"] = round(time.monotonic() - t0, 2)
        info["flights_per_hour"] = round(3600.0 * info["flown"] / max(info["wall_s"], 1e-9), 1)
        # how much of its cores the cluster got (a shared machine gives less than 100 %)
        info["cpu_share"] = round(info["cpu_s"] / max(info["wall_s"] * nworkers, 1e-9), 3)
        info["cpu_s"] = round(info["cpu_s"], 2)
        info["sim_s"] = round(info["sim_s"], 2)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-campaign", description=__doc__.splitlines()[0])
    ap.add_argument("campaign", help="a built-in campaign by name (" + ", ".join(
        trq_params.names("campaigns")) + ") or a campaign YAML by path")
    ap.add_argument("--out", type=Path, required=True, help="output directory (resumable)")
    ap.add_argument("--workers", type=int, default=None,
                    help="LocalCluster worker processes, one thread each (default: all cores)")
    ap.add_argument("--scheduler", default=None,
                    help="an existing Dask scheduler, tcp://HOST:8786 (then --workers is ignored)")
    ap.add_argument("--max-flights", type=int, default=None,
                    help="fly at most this many of the flights not yet done, then stop")
    ap.add_argument("--retry-failed", action="store_true",
                    help="fly again the flights recorded with an error")
    ap.add_argument("--keep-logs", action="store_true",
                    help="keep each flight's flight.csv and controller.csv in DIR/logs/<id>/ "
                         "(the workers must see DIR)")
    ap.add_argument("--report-only", action="store_true",
                    help="fly nothing: rewrite flights.csv and report.md from DIR/flights")
    ap.add_argument("--dry-run", action="store_true", help="list the flights and exit")
    ap.add_argument("--no-figures", action="store_true", help="skip the heat-map PNGs")
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error("--workers: expected at least 1")
    if args.max_flights is not None and args.max_flights < 0:
        ap.error("--max-flights: expected 0 or more")
    try:
        campaign = load_campaign(trq_params.resolve("campaigns", args.campaign))
    except ConfigError as exc:
        print(f"campaign: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        for s in campaign.flights:
            r = flight_inputs(s)
            plant = "" if "plant" not in s else " plant " + ",".join(
                f"{k}={v:g}" for k, v in sorted(s["plant"].items())) + (
                " (model: the plant)" if s.get("controller_model") == "plant" else "")
            print(f"{s['id']} {s['controller']:14s} fault {r['fault_kind']} {r['severity']:g} "
                  f"wind {_wind_label(r)} traj {r['traj_kind']} seed {s['seed']}{plant}")
        print(f"campaign: {campaign.name}: {len(campaign.flights)} flights")
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    info = None
    if not args.report_only:
        info = run_campaign(campaign, args.out, workers=args.workers, scheduler=args.scheduler,
                            max_flights=args.max_flights, retry_failed=args.retry_failed,
                            keep_logs=args.keep_logs)
        if info["flown"]:
            print(f"campaign: flew {info['flown']} flights ({info['failed']} failed) in "
                  f"{info['wall_s']:.1f} s on {info['workers']} worker(s) (cluster start "
                  f"{info['cluster_start_s']:.1f} s): {info['flights_per_hour']:.0f} flights/hour")
            print(f"campaign: the flights used {info['cpu_s']:.0f} CPU s for {info['sim_s']:.0f} "
                  f"simulated s ({info['cpu_s'] / max(info['flown'], 1):.1f} CPU s a flight); the "
                  f"workers got {info['cpu_share']:.0%} of their cores")
        _write_json(args.out / "last_run.json", info)
    elif (args.out / "last_run.json").is_file():      # --report-only: the last run's figures
        try:
            info = json.loads((args.out / "last_run.json").read_text())
        except ValueError:
            info = None
    results = load_results(args.out)
    rows = rows_of(campaign, results)
    write_csv(rows, args.out / "flights.csv")
    report = write_report(campaign, rows, args.out, info if info and info.get("flown") else None,
                          figures=not args.no_figures)
    print(f"campaign: {len(rows)} of {len(campaign.flights)} flights in "
          f"{args.out / 'flights.csv'}, "
          f"report {report}")
    complete = len(rows) == len(campaign.flights)
    return 0 if complete and not any(r["status"] == "failed" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
