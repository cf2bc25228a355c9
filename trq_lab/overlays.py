"""The controller overlay every tool and test flies: a YAML file that `extends:` a controller of
params/controller/, with absolute paths (so it can live in any output folder) and, optionally,
another reference. One writer, used by run_scenario, inprocess, stress and the tests."""

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


def write_controller_overlay(controller: str | Path, reference: dict | None, out_dir: Path,
                             comment: str = "") -> Path:
    """Write out_dir/controller.yaml and return its path; raises the controller's ConfigError
    if the result is not a valid controller file."""
    from trq_offboard.config import load_controller

    base = controller_file(controller)
    cfg = load_controller(base)
    overlay = {"extends": str(base), "vehicle": str(Path(cfg.vehicle.file).resolve()),
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
