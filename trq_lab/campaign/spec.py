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
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, NamedTuple, Optional

import numpy as np
import trq_params
from pydantic import create_model
from sil_vehicle.faultscript import Event, parse_event
from sil_vehicle.sensors.faults import SENSOR as SENSOR_OF_UNIT
from trq_offboard.config import load_controller
from trq_params import ConfigError, schema
from trq_params.loader import Num, Vec, chain, leaf_types, load, range_of, read_yaml, validate
from trq_params.schema import (AXES, AXIS_MODELS, OUTAGE_METRICS, CampaignFile, CampaignGrid,
                               OutageAxis, Plant, SensingAxis, SensingFile, Strict)

from trq_lab.harness import SIM_DEFAULT
from trq_lab.overlays import controller_file, perturbed_vehicle, vehicle_data
from trq_lab.scenario import check_sensing

PARAMS = trq_params.DIR


class AxisKey(NamedTuple):
    """One key of an axis: the schema's field type (its checks and its wording) and what a draw
    needs of it: its kind (int, float, bool, vec or text) and its range (numbers and vectors)."""
    type: Any
    kind: str
    lo: float = -math.inf
    hi: float = math.inf


def _axis_key(tp: Any) -> AxisKey:
    """An axis key of a schema field type: its kind from the type, its range from its Range."""
    base = typing.get_args(tp)[0] if typing.get_origin(tp) is Annotated else tp
    bounds = range_of(tp)
    if base is bool:
        return AxisKey(tp, "bool")
    if bounds is None:
        return AxisKey(tp, "text")
    kind = {int: "int", float: "float"}.get(base, "vec" if base is not Any else "float")
    # a field checked by its model (a servo's angle against the vehicle's tilt range): its Range
    checked = tp if base is not Any else Num(bounds.lo, bounds.hi)
    return AxisKey(checked, kind, bounds.lo, bounds.hi)


def _axis_keys(models) -> dict[str, AxisKey]:
    """The keys of an axis, derived from its schema models (AXIS_MODELS): their dotted paths."""
    out: dict[str, AxisKey] = {}
    for model in models:
        for key, tp in leaf_types(model).items():
            out.setdefault(key, _axis_key(tp))
    return out


AXIS_KEYS = {axis: _axis_keys(models) for axis, models in AXIS_MODELS.items()}
FAULT_KEYS, WIND_KEYS, TRAJECTORY_KEYS, LINK_KEYS, PLANT_KEYS, SENSING_KEYS, OUTAGE_KEYS = (
    AXIS_KEYS[a] for a in AXES)
# the axes whose points may be `none` (no fault, no outage): None in a cell, and when left out
NONE_AXES = ("fault", "outage")
MOTOR_KEYS, SERVO_KEYS = (set(leaf_types(m)) - {"at_s"} for m in AXIS_MODELS["fault"])
PLANT_NEUTRAL = Plant().model_dump()
WIND_DEFAULT = {"speed_m_s": 0.0, "direction_deg": 0.0, "gusts": False}
SENSING_DEFAULT = SensingAxis().profile  # a spec's sensing when the campaign names none
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
    sensings: tuple[str, ...] = (SENSING_DEFAULT,)     # the profiles its flights fly under
    # trq_params.schema.FlightTarget each, its `sensing` as the flights carry it (None: all)
    flight_targets: tuple = ()
    # the outages its flights fly with (`outage_label`): ("none",) without the axis
    outages: tuple[str, ...] = ("none",)
    # trq_params.schema.PairedTarget each, its `against` and `sensing` resolved
    paired_targets: tuple = ()


def _axis_models(axis: str):
    """The models of one axis: one value per key, and a list of values per key."""
    keys = AXIS_KEYS[axis]
    point = create_model(f"{axis}_point", __base__=Strict,
                         **{k: (Optional[spec.type], None) for k, spec in keys.items()})
    lists = create_model(f"{axis}_lists", __base__=Strict,
                         **{k: (Optional[list[spec.type]], None) for k, spec in keys.items()})
    return point, lists


_VALUE_MODELS = {axis: _axis_models(axis) for axis in AXES}


@functools.cache
def _normal_model():
    """{normal: [mean, sd]}: a normal draw, truncated to the key's range (drawn again until it
    falls inside); the mean within the range and sd > 0 are checked by `_axis_values`."""
    return create_model("normal", __base__=Strict, normal=(Vec(2), ...))


@functools.cache
def _uniform_model(lo, hi):
    """{uniform: [lo, hi]}: a continuous draw within the key's range."""
    return create_model("uniform", __base__=Strict,
                        uniform=(Vec(2, lo, hi), ...))


def _axis_values(raw_axis: Any, file, where: str, axis: str,
                 sampling: bool) -> dict[str, list | dict]:
    """Each key of one axis mapping -> its list of values (grid) or its distribution (sample):
    a list (choice), {"uniform": [lo, hi]} or {"normal": [mean, sd]}. Scalars become one-element
    lists. Checked with the schema's field types: errors name the file and the dotted key
    (`grid.fault.motor[1]`)."""
    keys = AXIS_KEYS[axis]
    point, lists = _VALUE_MODELS[axis]
    if not isinstance(raw_axis, dict):
        raise ConfigError(f"{file}: key '{where}': got {raw_axis!r}, expected a mapping")
    unknown = sorted((k for k in raw_axis if k not in keys), key=str)
    if unknown:
        raise ConfigError(f"{file}: unknown key '{where}.{unknown[0]}' (value "
                          f"{raw_axis[unknown[0]]!r}): expected one of {', '.join(keys)}")
    out: dict[str, list | dict] = {}
    for key in sorted(raw_axis, key=str):
        _, kind, lo, hi = keys[key]
        raw = raw_axis[key]
        if sampling and isinstance(raw, dict):
            if kind not in ("float", "int"):
                raise ConfigError(f"{file}: key '{where}.{key}': got {raw!r}, expected a value "
                                  "or a list of values to choose from")
            if "normal" in raw:
                mean, sd = validate(_normal_model(), raw, file, prefix=f"{where}.{key}").normal
                if not (sd > 0.0 and lo <= mean <= hi):
                    raise ConfigError(f"{file}: key '{where}.{key}.normal': got "
                                      f"{[mean, sd]}, expected [mean, sd] with sd > 0 and the "
                                      f"mean in [{lo:g}, {hi:g}]")
                out[key] = {"normal": [mean, sd]}
                continue
            bounds = validate(_uniform_model(lo, hi), raw, file,
                              prefix=f"{where}.{key}").uniform
            if bounds[0] > bounds[1]:
                raise ConfigError(f"{file}: key '{where}.{key}.uniform': got {list(bounds)}, "
                                  "expected [lo, hi] with lo <= hi")
            out[key] = {"uniform": list(bounds)}
            continue
        is_list = isinstance(raw, list) and not (kind == "vec" and raw and
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
    """All points of one grid axis (None: no fault, no outage)."""
    if axis not in grid:
        return [None] if axis in NONE_AXES else [{}]
    raw = grid[axis]
    items = raw if isinstance(raw, list) else [raw]
    if not items:
        raise ConfigError(f"{file}: key 'grid.{axis}': got {raw!r}, expected a mapping or a "
                          "non-empty list of mappings")
    points: list[dict | None] = []
    for i, item in enumerate(items):
        where = f"grid.{axis}" + (f"[{i}]" if isinstance(raw, list) else "")
        if axis in NONE_AXES and item == "none":
            points.append(None)
            continue
        values = _axis_values(item, file, where, axis, sampling=False)
        names = list(values)
        for combo in itertools.product(*(values[k] for k in names)):
            point = dict(zip(names, combo))
            if axis == "fault":
                fault_event(point, file, where)
            elif axis == "outage":
                outage_events(point, file, where)
            points.append(point)
    return points


def nested(point: dict) -> dict:
    """A flat mapping of dotted keys (an axis point: `time_varying.b`) as the nested mapping the
    schema reads ({"time_varying": {"b": ...}})."""
    out: dict[str, Any] = {}
    for key, value in point.items():
        *parents, leaf = key.split(".")
        node = out
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


def fault_event(fault: dict | None, file, where: str, tilt_range_deg=(-90.0, 90.0)):
    """The sil_vehicle fault-script Event of a campaign fault (its keys the dotted paths of the
    fault script's MotorEvent or ServoEvent, validated by the fault script's own parser), or
    None. One kind of action per fault: an effectiveness, a time-varying one, or stopped."""
    if fault is None:
        return None
    f = dict(fault)
    prefix = f"{where}."

    def fail(key, expected):
        return ConfigError(f"{file}: key '{prefix}{key}': got {f.get(key)!r}, expected {expected}")

    if "at_s" not in f:
        raise ConfigError(f"{file}: missing key '{prefix}at_s' (the fault onset)")
    if ("motor" in f) == ("servo" in f):
        raise ConfigError(f"{file}: key '{where}': a fault needs one of motor or servo "
                          f"(got {sorted(f)})")
    kind, own, other = (("motor", MOTOR_KEYS, "servo") if "motor" in f
                        else ("servo", SERVO_KEYS, "motor"))
    for key in sorted(f):
        if key != "at_s" and key not in own:
            raise fail(key, f"no {other} key in a {kind} fault")
    if kind == "motor":
        acts = [a for a in ("effectiveness", "time_varying", "stopped")
                if any(k.split(".")[0] == a for k in f)]
        if not acts:
            raise ConfigError(f"{file}: missing key '{prefix}effectiveness' (or time_varying.*, "
                              "or stopped)")
        if len(acts) > 1:
            second = next(k for k in sorted(f) if k.split(".")[0] == acts[1])
            raise fail(second, "one of effectiveness, time_varying or stopped, not "
                       + " and ".join(acts))
    elif "stuck_deg" not in f:
        raise ConfigError(f"{file}: missing key '{prefix}stuck_deg'")
    return parse_event(nested(f), tilt_range_deg, file=str(file), key=where)


def outage_events(outage: dict | None, file, where: str) -> tuple[Event, ...]:
    """The fault-script Events of a campaign outage: its sensor off at at_s, ok again at
    at_s + duration_s (each validated by the fault script's own parser); () for none. Every key
    is needed (trq_params.schema.OutageAxis): a missing or bad one is a ConfigError naming the
    file and the key."""
    if outage is None:
        return ()
    validate(OutageAxis, outage, file, prefix=where)
    start_us, end_us = outage_window_us(outage)
    return tuple(parse_event({"at_s": t_us * 1e-6, "sensor": outage["sensor"], "failure": kind},
                             file=str(file), key=where)
                 for t_us, kind in ((start_us, "off"), (end_us, "ok")))


def outage_window_us(outage: dict) -> tuple[int, int]:
    """(start, end) of an outage in integer vehicle microseconds: the sensor off from start, its
    own readings again from end."""
    start_us = int(round(outage["at_s"] * 1e6))
    return start_us, start_us + int(round(outage["duration_s"] * 1e6))


def outage_label(outage: dict | None) -> str:
    """An outage as the tables name it: `none`, or `mocap 14-15 s` (off from, ok again at)."""
    if outage is None:
        return "none"
    return (f"{outage['sensor']} {outage['at_s']:g}-"
            f"{outage['at_s'] + outage['duration_s']:g} s")


@functools.cache
def carried_sensors(profile: str) -> frozenset[str]:
    """The sensors a sensing profile carries (its sections that are not null: imu, mocap, ...;
    not its `estimator:`, the autopilot's tuning); `profile` as `_sensing` returns it, already
    checked."""
    f = load(trq_params.resolve("sensing", profile), SensingFile)
    return frozenset(k for k in SensingFile.model_fields
                     if k not in ("name", "description", "estimator")
                     and getattr(f, k) is not None)


def carries(profile: str, outage: dict | None) -> bool:
    """Whether a flight under `profile` can have `outage`: none, or its sensor carried (else
    the vehicle would refuse the fault and the flight fly without it)."""
    return outage is None or SENSOR_OF_UNIT[outage["sensor"]] in carried_sensors(profile)


def _check_outage(outage: dict | None, profiles, file, where: str) -> None:
    """An outage's sensor must be carried by one of `profiles` (a grid's, or a draw's one)."""
    if any(carries(p, outage) for p in profiles):
        return
    carried = {p: carried_sensors(p) for p in profiles}
    raise ConfigError(f"{file}: key '{where}.sensor': got {outage['sensor']!r}, expected a "
                      "sensor that the sensing profile carries (" + "; ".join(
                          f"{Path(p).stem}: {', '.join(sorted(c)) or 'none'}"
                          for p, c in carried.items()) + ")")


def _sample_axis(values: dict | None, axis: str, rng) -> dict | None:
    """One draw of one axis: every key drawn in sorted order from its own distribution."""
    if values is None:
        return None if axis in NONE_AXES else {}
    point = {}
    for key in sorted(values):
        v = values[key]
        if isinstance(v, dict) and "normal" in v:
            _, kind, lo, hi = AXIS_KEYS[axis][key]
            mean, sd = v["normal"]
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
            kind = AXIS_KEYS[axis][key].kind
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


def identity(spec: dict) -> dict:
    """What a flight's id hashes: its spec without the id, and without its sensing when that is
    the default (truth), so that a campaign without the axis keeps the ids it always had."""
    return {k: v for k, v in spec.items()
            if k != "id" and not (k == "sensing" and v == SENSING_DEFAULT)}


def flight_id(spec: dict) -> str:
    text = json.dumps(identity(spec), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _sensing_shorthand(raw: Any) -> Any:
    """The sensing axis written as a profile or a list of profiles: its `profile` key."""
    if isinstance(raw, str) or (isinstance(raw, list) and raw
                                and not any(isinstance(x, dict) for x in raw)):
        return {"profile": raw}
    return raw


def _sensing(point: dict | None, file: Path, where: str) -> str:
    """The profile of a sensing point as a flight gets it (a built-in name, or a path made
    absolute against the campaign file's folder), loaded once against the physics rate: a
    ConfigError naming the file, the key and the value."""
    value = (point or {}).get("profile", SENSING_DEFAULT)
    if not trq_params.is_name(value):
        value = str(file.parent / value)
    return check_sensing(value, str(file), where)


def sensing_digest(profile: str) -> str:
    """A digest of a sensing profile's files (the file and the files it extends)."""
    return _file_digest(chain(trq_params.resolve("sensing", profile)))




def _axes(section: CampaignGrid) -> dict[str, Any]:
    """The axes a grid or sample names (an axis written as null is named, and then fails)."""
    return {axis: (_sensing_shorthand(getattr(section, axis)) if axis == "sensing"
                   else getattr(section, axis))
            for axis in AXES if axis in section.model_fields_set}


def load_campaign(path: Path) -> Campaign:
    path = Path(path)
    top = validate(CampaignFile, read_yaml(path), path)
    # a controller given by path is read against the campaign file's folder (as its sensing
    # profiles are), made absolute so that a flight finds it from any working directory
    controllers = tuple(_controller_ref(c, path) for c in top.controllers)
    digests = {}
    for i, c in enumerate(controllers):
        try:
            digests[c] = controller_inputs(c)[1]
        except ConfigError as exc:
            raise ConfigError(f"{path}: key 'controllers[{i}]': {c!r} does not load: "
                              f"{exc}") from exc
    vehicles = {c: controller_vehicle(c) for c in controllers}
    cells: list[tuple] = []
    if top.grid is not None:
        grid = _axes(top.grid)
        cells += list(itertools.product(*(_grid_axis(grid, path, axis) for axis in AXES)))
    has_plant = any(s is not None and "plant" in _axes(s) for s in (top.grid, top.sample))
    if top.grid is not None:
        for plant in {json.dumps(c[4], sort_keys=True): c[4] for c in cells}.values():
            _check_plant(plant, vehicles, path, "grid.plant")
    profiles: dict[str, str] = {}         # a sensing point -> its profile, each loaded once

    def profile_of(point: dict | None, where: str) -> str:
        key = json.dumps(point, sort_keys=True)
        if key not in profiles:
            profiles[key] = _sensing(point, path, where)
        return profiles[key]

    cells = [(*c[:5], profile_of(c[5], "grid.sensing"), c[6]) for c in cells]
    # a grid's outage flies under the profiles that carry its sensor (`sensing: [mocap, rtk]`
    # with a mocap and a gnss outage: each under its own), and must have one
    grid_profiles = list(dict.fromkeys(c[5] for c in cells))
    for outage in {json.dumps(c[6], sort_keys=True): c[6] for c in cells}.values():
        _check_outage(outage, grid_profiles, path, "grid.outage")
    cells = [c for c in cells if carries(c[5], c[6])]
    if top.sample is not None:
        dists = {axis: _axis_values(raw, path, f"sample.{axis}", axis, sampling=True)
                 for axis, raw in _axes(top.sample).items()}
        rng = np.random.default_rng(top.sample.seed)
        # the outage draws from its own generator: a sample with the axis draws every other
        # axis as the same sample without it (its flights pair with and without an outage)
        rngs = {"outage": np.random.default_rng([top.sample.seed, AXES.index("outage")])}
        for k in range(top.sample.n):
            point = tuple(_sample_axis(dists.get(axis), axis, rngs.get(axis, rng))
                          for axis in AXES)
            try:
                fault_event(point[0], path, f"sample.fault (draw {k})")
            except ConfigError as exc:
                raise ConfigError(f"{exc} (a sampled fault must be valid whatever is "
                                  "drawn)") from exc
            _check_plant(point[4], vehicles, path, f"sample.plant (draw {k})")
            profile = profile_of(point[5], "sample.sensing")
            try:
                outage_events(point[6], path, "sample.outage")
                _check_outage(point[6], [profile], path, "sample.outage")
            except ConfigError as exc:
                raise ConfigError(f"{exc} (draw {k}: a sampled outage must be valid whatever "
                                  "is drawn)") from exc
            cells.append((*point[:5], profile, point[6]))
    name, description, seed = top.name, top.description, top.seed
    success, threshold, timeout, repeats = (top.success_rmse_m, top.recovery_threshold_m,
                                            top.timeout_s, top.repeats)
    models = top.controller_model if isinstance(top.controller_model, list) else \
        [top.controller_model]
    flights = []
    seen = set()
    profile_digests: dict[str, str] = {}
    for fault, wind, traj, link, plant, sensing, outage in cells:
        wind = {**WIND_DEFAULT, **(wind or {})}
        for r in range(repeats):
            cell = {"fault": fault, "wind": wind, "trajectory": traj or {}, "repeat": r}
            if link:            # only then: a clean link keeps the ids and seeds it always had
                cell["link"] = link
            text = json.dumps({"campaign_seed": seed, **cell}, sort_keys=True)
            fseed = int(hashlib.sha256(text.encode()).hexdigest()[:8], 16) % 2**31
            # neither the plant nor the sensing profile nor the outage is in the seed: every
            # plant, profile and outage of a cell meets the same seeds (common random numbers)
            for model in models:
                extra: dict[str, Any] = {"plant": plant} if has_plant else {}
                if outage is not None:      # only then: no outage keeps the ids it always had
                    extra["outage"] = outage
                if model != "nominal":
                    extra["controller_model"] = model
                for c in controllers:
                    digest = digests[c]
                    if sensing != SENSING_DEFAULT:      # the profile's files are read too
                        if sensing not in profile_digests:      # once a profile, not a flight
                            profile_digests[sensing] = sensing_digest(sensing)
                        digest = hashlib.sha256((digest + profile_digests[sensing]).encode()
                                                ).hexdigest()[:16]
                    spec = {"controller": c, **cell, **extra, "sensing": sensing,
                            "seed": fseed, "timeout_s": timeout,
                            "recovery_threshold_m": threshold, "params_digest": digest}
                    spec["id"] = flight_id(spec)
                    if spec["id"] in seen:
                        continue                  # the same flight listed twice: fly it once
                    seen.add(spec["id"])
                    flights.append(spec)
    sensings = tuple(dict.fromkeys(f["sensing"] for f in flights))
    outages = tuple(dict.fromkeys(outage_label(f.get("outage")) for f in flights))
    return Campaign(name, path, description, seed, tuple(controllers), success, threshold,
                    timeout, repeats, tuple(flights), top.targets, has_plant, sensings,
                    _flight_targets(top.flight_targets, sensings, outages, path), outages,
                    _paired_targets(top.paired_targets, tuple(controllers), sensings, outages,
                                    path))


def _controller_ref(c: str, file: Path) -> str:
    """A controller as the flights carry it: a built-in name, or a path made absolute against
    the campaign file's folder (targets name it as the campaign's `controllers` list does)."""
    return c if trq_params.is_name(c) else str((file.parent / c).resolve())


def _paired_targets(targets, controllers: tuple[str, ...], sensings: tuple[str, ...],
                    outages: tuple[str, ...], file: Path) -> tuple:
    """The paired targets with `against` set (the first controller when not given) and their
    sensing profile as the flights carry it; a controller, profile or outage the campaign does
    not fly is a ConfigError naming the file, the key and the value."""
    out = []
    flown = {label.split()[0] for label in outages}
    for i, t in enumerate(targets):
        key = f"paired_targets[{i}]"
        refs = {}
        for field in ("controller", "against"):
            value = getattr(t, field)
            refs[field] = None if value is None else _controller_ref(value, file)
            if value is not None and refs[field] not in controllers:
                raise ConfigError(f"{file}: key '{key}.{field}': got {value!r}, expected one "
                                  "of the campaign's controllers (" + ", ".join(controllers)
                                  + ")")
        against = refs["against"] or controllers[0]
        if against == refs["controller"]:
            raise ConfigError(f"{file}: key '{key}.against': got {against!r}, expected another "
                              "controller than the target's own")
        out.append(_scoped(t, key, sensings, flown, file, against=against,
                           controller=refs["controller"]))
    return tuple(out)


def _flight_targets(targets, sensings: tuple[str, ...], outages: tuple[str, ...],
                    file: Path) -> tuple:
    """The flight targets with their sensing profile as the flights carry it (a built-in name,
    or a path made absolute against the campaign file's folder): one the campaign flies, else a
    ConfigError naming the file, the key and the value. An outage a target names must be one
    the campaign flies; a target on an outage's metric must name one."""
    out = []
    flown = {label.split()[0] for label in outages}       # the sensors (and `none`)
    for i, t in enumerate(targets):
        on = next((m for m in (t.metric, t.per) if m in OUTAGE_METRICS), None)
        if on is not None and t.outage in (None, "none"):
            raise ConfigError(f"{file}: key 'flight_targets[{i}].outage': got {t.outage!r}, "
                              f"expected the outage's sensor ({on} is a metric of the flights "
                              "with an outage)")
        out.append(_scoped(t, f"flight_targets[{i}]", sensings, flown, file,
                           controller=_controller_ref(t.controller, file)))
    return tuple(out)


def _scoped(t, key: str, sensings: tuple[str, ...], flown: set[str], file: Path, **update):
    """A target (flight or paired) with its sensing profile as the flights carry it (a built-in
    name, or a path made absolute against the campaign file's folder) and `update`; an outage
    (`flown`: the sensors, and `none`) or profile the campaign does not fly is a ConfigError
    naming the file, the key and the value."""
    if t.outage is not None and t.outage not in flown:
        raise ConfigError(f"{file}: key '{key}.outage': got {t.outage!r}, expected one of the "
                          "outages the campaign flies (" + ", ".join(sorted(flown)) + ")")
    if t.sensing is not None:
        profile = _sensing({"profile": t.sensing}, file, f"{key}.sensing")
        if profile not in sensings:
            raise ConfigError(f"{file}: key '{key}.sensing': got {t.sensing!r}, expected one "
                              "of the profiles the campaign flies (" + ", ".join(sensings)
                              + ")")
        update["sensing"] = profile
    return t.model_copy(update=update) if update else t
