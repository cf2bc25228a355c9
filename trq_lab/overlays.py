"""The controller overlay every tool and test flies: a YAML file that `extends:` a controller of
params/controller/, with absolute paths (so it can live in any output folder) and, optionally,
another reference. One writer, used by run_scenario, inprocess, stress and the tests. And the
vehicle overlay of a campaign's plant: an airframe file with factors and offsets applied
(`write_vehicle_overlay`), for the simulated vehicle and, when asked, the controller's model."""

from __future__ import annotations

from pathlib import Path

import trq_params
from trq_params.loader import dump as dump_yaml


def controller_file(controller: str | Path) -> Path:
    """A path, or a name of params/controller/ (trq_nmpc_eso, trq_nmpc, quad_nmpc)."""
    path = Path(controller)
    if path.suffix in (".yaml", ".yml"):
        return path.resolve()
    return trq_params.resolve("controller", controller)


def run_dir(out: Path, controller: str | Path) -> Path:
    """Where a controller's flight is written under `out`: its name, or for a controller given
    as a file path the file's stem (a path would otherwise leave `out`)."""
    c = str(controller)
    return out / (c if trq_params.is_name(c) else Path(c).stem)


def write_controller_overlay(controller: str | Path, reference: dict | None, out_dir: Path,
                             comment: str = "", vehicle: str | Path | None = None) -> Path:
    """Write out_dir/controller.yaml and return its path; raises the controller's ConfigError
    if the result is not a valid controller file. `vehicle`: another airframe file for the
    controller's model (default: the one the controller names)."""
    from trq_offboard.config import load_controller

    base = controller_file(controller)
    cfg = load_controller(base)
    model = Path(vehicle if vehicle is not None else cfg.vehicle.file).resolve()
    overlay = {"extends": str(base), "vehicle": str(model),
               "observer": {"file": str(Path(cfg.eso.file).resolve()) if cfg.eso else
                            str(trq_params.builtin("controller", "eso"))}}
    if reference:
        overlay["reference"] = dict(reference)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "controller.yaml"
    path.write_text((f"# {comment}\n" if comment else "")
                    + dump_yaml(overlay))
    load_controller(path)
    return path


# --- a perturbed airframe: the plant of an identification-error campaign ----------------------

# What each plant key of a campaign changes in a vehicle file: a factor on every number at the
# dotted keys (a curve's three coefficients together: its value at every throttle scales), or an
# offset (idle, in throttle percent, where a factor would also move the zero).
PLANT_PARAMS: dict[str, tuple[str, tuple[str, ...]]] = {
    "mass_scale": ("scale", ("mass_kg",)),
    "inertia_scale": ("scale", ("inertia_kg_m2.xx", "inertia_kg_m2.yy", "inertia_kg_m2.zz")),
    "arm_length_scale": ("scale", ("arm_length_m",)),
    "thrust_scale": ("scale", ("rotor_curves.thrust_N.c2", "rotor_curves.thrust_N.c1",
                               "rotor_curves.thrust_N.c0")),
    "torque_scale": ("scale", ("rotor_curves.torque_Nm.c2", "rotor_curves.torque_Nm.c1",
                               "rotor_curves.torque_Nm.c0")),
    "motor_lag_scale": ("scale", ("motor.time_constant_s",)),
    "motor_rate_scale": ("scale", ("motor.rate_limit_pct_s",)),
    "servo_lag_scale": ("scale", ("tilt.servo_time_constant_s",)),
    "servo_rate_scale": ("scale", ("tilt.servo_rate_limit_deg_s",)),
    "drag_scale": ("scale", ("drag.quadratic_N_s2_m2",)),
    "idle_offset_pct": ("offset", ("motor.idle_pct",)),
}


def perturbed_vehicle(data: dict, plant: dict[str, float]) -> dict:
    """A vehicle file's mapping (its `extends:` chain merged) with the plant's factors and
    offsets applied (PLANT_PARAMS); `data` is not modified. Unknown plant keys: KeyError."""
    import copy

    out = copy.deepcopy(data)
    for key in sorted(plant):
        op, paths = PLANT_PARAMS[key]
        for dotted in paths:
            *parents, leaf = dotted.split(".")
            node = out
            for p in parents:
                node = node[p]
            node[leaf] = node[leaf] * plant[key] if op == "scale" else node[leaf] + plant[key]
    return out


def vehicle_data(vehicle_file: str | Path) -> dict:
    """The mapping of a vehicle file with its `extends:` chain merged (as the loader reads it)."""
    from trq_params.loader import read

    return read(vehicle_file)


def write_vehicle_overlay(vehicle_file: str | Path, plant: dict[str, float], out_dir: Path) -> Path:
    """Write out_dir/<the vehicle file's name>: the airframe with `plant` applied (the name kept,
    so the logs and metrics name the same vehicle), and return its path; raises the loader's
    ConfigError if the result is not a valid vehicle file."""
    from trq_params import schema
    from trq_params.loader import load

    data = perturbed_vehicle(vehicle_data(vehicle_file), plant)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / Path(vehicle_file).name
    path.write_text(f"# {Path(vehicle_file).resolve()} with the plant {plant}\n" + dump_yaml(data))
    load(path, schema.VehicleFile)
    return path
