"""The campaign file: its axes, checked key by key, and the flights it plans.

In: a campaign file (its schema, `trq_params.schema.CampaignFile`; the axes' keys below). Out: a
`Campaign`, its flights as JSON-able specs with stable ids and seeds. It flies nothing.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trq_params
from pydantic import create_model
from sil_vehicle.faultscript import parse_event
from trq_offboard.config import load_controller
from trq_params import ConfigError, schema
from trq_params.loader import Choice, Flag, Int, Num, Vec, chain, read_yaml, validate
from trq_params.schema import AXES, CampaignFile, CampaignGrid, Strict

from trq_lab.harness import SIM_DEFAULT
from trq_lab.overlays import controller_file, perturbed_vehicle, vehicle_data

PARAMS = trq_params.DIR
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
AXIS_KEYS = {"fault": FAULT_KEYS, "wind": WIND_KEYS, "trajectory": TRAJECTORY_KEYS,
             "link": LINK_KEYS, "plant": PLANT_KEYS}
WIND_DEFAULT = {"speed_m_s": 0.0, "direction_deg": 0.0, "gusts": False}
SAMPLE_DIGITS = 4            # sampled numbers are rounded: readable tables, stable ids

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
    targets: Any = None                # trq_params.schema.CampaignTargets or None
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
                fault_event(point, file, where)
            points.append(point)
    return points


def fault_event(fault: dict | None, file, where: str, tilt_range_deg=(-90.0, 90.0)):
    """The sil_vehicle fault-script Event of a campaign fault (validated by the fault script's
    own parser), or None."""
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
    path = controller_file(name)
    files = chain(path)
    cfg = load_controller(path)
    files += [Path(cfg.vehicle.file), Path(cfg.eso.file) if cfg.eso else PARAMS / "controller" /
              "eso.yaml", SIM_DEFAULT]
    return path, _file_digest(files)


def controller_vehicle(name: str) -> str:
    """The airframe file of a controller (its model's, and the simulated vehicle's)."""
    return load_controller(controller_file(name)).vehicle.file


def _check_plant(plant: dict, vehicles: dict[str, str], file, where: str) -> None:
    """Every controller's airframe with `plant` applied must be a valid vehicle file."""
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




def _axes(section: CampaignGrid) -> dict[str, Any]:
    """The axes a grid or sample names (an axis written as null is named, and then fails)."""
    return {axis: getattr(section, axis) for axis in AXES if axis in section.model_fields_set}


def load_campaign(path: Path) -> Campaign:
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
                fault_event(point[0], path, f"sample.fault (draw {k})")
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
