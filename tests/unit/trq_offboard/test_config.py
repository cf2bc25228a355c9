"""Strict loading of params/ YAML by trq_offboard.config (independent of sil_vehicle)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from trq_offboard.config import ConfigError, load_controller, load_eso, load_vehicle_model
from trq_params.loader import read_yaml     # the loader's YAML 1.2 dialect: `off` stays a string

from conftest import ROOT

PARAMS = ROOT / "params"


def test_shipped_files_load():
    trq = load_vehicle_model(PARAMS / "vehicle/trq.yaml")
    quad = load_vehicle_model(PARAMS / "vehicle/quad.yaml")
    assert not trq.tilt_locked and quad.tilt_locked and quad.mass_kg == trq.mass_kg
    assert trq.hover_throttle_pct == pytest.approx(76.82, abs=0.01)
    assert trq.tilt_max_rad == pytest.approx(math.radians(30))
    for name, obs in (("trq_nmpc_eso", "nonlinear"), ("trq_nmpc", "none"),
                      ("quad_nmpc", "none")):
        cfg = load_controller(PARAMS / f"controller/{name}.yaml")
        assert cfg.name == name and cfg.observer == obs
        assert cfg.horizon_steps == 20 and cfg.step_s == 0.05 and cfg.control_rate_hz == 100
        assert (cfg.eso is None) == (obs == "none")
    assert load_controller(PARAMS / "controller/quad_nmpc.yaml").vehicle.tilt_locked
    assert load_eso(PARAMS / "controller/eso.yaml").substeps >= 1


def _write(tmp_path: Path, name: str, data: dict) -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data))
    return p


def _vehicle_dict() -> dict:
    return yaml.safe_load((PARAMS / "vehicle/trq.yaml").read_text())


def test_unknown_key_names_file_and_key(tmp_path):
    d = _vehicle_dict()
    d["motor"]["idle_pcnt"] = 10.0
    p = _write(tmp_path, "v.yaml", d)
    with pytest.raises(ConfigError, match=r"v\.yaml.*motor\.idle_pcnt"):
        load_vehicle_model(p)


def test_missing_key(tmp_path):
    d = _vehicle_dict()
    del d["drag"]["quadratic_N_s2_m2"]
    with pytest.raises(ConfigError, match=r"drag\.quadratic_N_s2_m2' is missing"):
        load_vehicle_model(_write(tmp_path, "v.yaml", d))


def test_out_of_range_names_value_and_range(tmp_path):
    d = _vehicle_dict()
    d["tilt"]["max_deg"] = 120.0
    with pytest.raises(ConfigError, match=r"tilt\.max_deg.*120.*\[0, 90\]"):
        load_vehicle_model(_write(tmp_path, "v.yaml", d))
    d = _vehicle_dict()
    d["mass_kg"] = True
    with pytest.raises(ConfigError, match="mass_kg"):
        load_vehicle_model(_write(tmp_path, "v.yaml", d))


def test_extends_merges_and_detects_cycles(tmp_path):
    base = _write(tmp_path, "base.yaml", _vehicle_dict())
    child = _write(tmp_path, "child.yaml", {"extends": "base.yaml", "mass_kg": 2.0,
                                             "tilt": {"locked": True}})
    vm = load_vehicle_model(child)
    assert vm.mass_kg == 2.0 and vm.tilt_locked and vm.tilt_max_rad == pytest.approx(
        math.radians(30))
    _write(tmp_path, "a.yaml", {"extends": "b.yaml"})
    _write(tmp_path, "b.yaml", {"extends": "a.yaml"})
    with pytest.raises(ConfigError, match="cycle"):
        load_vehicle_model(tmp_path / "a.yaml")
    assert base.exists()


def test_controller_file_errors(tmp_path):
    src = read_yaml(PARAMS / "controller/nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    src["observer"]["file"] = str(PARAMS / "controller/eso.yaml")
    ok = _write(tmp_path, "c.yaml", src)
    assert load_controller(ok).horizon_steps == 20
    bad = dict(src, horizon={"steps": 20, "step_s": 0.005})      # shorter than a control period
    with pytest.raises(ConfigError, match=r"horizon\.step_s"):
        load_controller(_write(tmp_path, "c2.yaml", bad))
    bad = dict(src, weights=dict(src["weights"], position=[1.0, 2.0]))
    with pytest.raises(ConfigError, match=r"weights\.position.*list of 3"):
        load_controller(_write(tmp_path, "c3.yaml", bad))
    bad = dict(src, solver=dict(src["solver"], kind="acados"))
    with pytest.raises(ConfigError, match=r"solver\.kind"):
        load_controller(_write(tmp_path, "c4.yaml", bad))


def test_solver_qp_keys(tmp_path):
    src = read_yaml(PARAMS / "controller/nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    src["observer"]["file"] = str(PARAMS / "controller/eso.yaml")
    cfg = load_controller(_write(tmp_path, "c.yaml", src))
    assert cfg.solver.hpipm_interface == "direct" and cfg.solver.hpipm_mode == "auto"
    assert cfg.solver.hpipm_options == ()
    bad = dict(src, solver=dict(src["solver"], hpipm_options={"mu_0": 0.1}))
    with pytest.raises(ConfigError, match=r"solver\.hpipm_options\.mu_0.*mu0, tol_stat"):
        load_controller(_write(tmp_path, "c2.yaml", bad))
    bad = dict(src, solver=dict(src["solver"], hpipm_options={"ric_alg": 2}))
    with pytest.raises(ConfigError, match=r"hpipm_options\.ric_alg.*\[0, 1\]"):
        load_controller(_write(tmp_path, "c3.yaml", bad))
    bad = dict(src, solver=dict(src["solver"], hessian="exact", hpipm_mode="speed_abs"))
    with pytest.raises(ConfigError, match=r"solver\.hpipm_mode.*multipliers"):
        load_controller(_write(tmp_path, "c4.yaml", bad))
    bad = dict(src, solver=dict(src["solver"], qp_max_iterations=0))
    with pytest.raises(ConfigError, match=r"solver\.qp_max_iterations.*\[1, 1000\]"):
        load_controller(_write(tmp_path, "c5.yaml", bad))
    bad = dict(src, tilt_rate_limit="horizon")          # removed (2026-12-05): unknown
    with pytest.raises(ConfigError, match=r"tilt_rate_limit"):
        load_controller(_write(tmp_path, "c6.yaml", bad))


def test_an_observer_bandwidth_per_axis_is_read_and_checked(tmp_path):
    """omega_o_rad_s is one number or three (x, y, z; roll, pitch, yaw): three are kept as
    such, checked against the substeps' bound by their largest, refused in another length by
    name, and refused with the body-rate observer of rates_lowpass_hz (one bandwidth)."""
    src = read_yaml(PARAMS / "controller/nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    eso = read_yaml(PARAMS / "controller/eso_paper.yaml")
    eso["rotational"]["omega_o_rad_s"] = [70.0, 70.0, 85.0]
    src["observer"] = {"kind": "nonlinear", "file": str(_write(tmp_path, "e.yaml", eso))}
    assert load_controller(_write(tmp_path, "c.yaml", src)).eso.rotational.omega_o_rad_s \
        == (70.0, 70.0, 85.0)
    eso["rotational"]["omega_o_rad_s"] = [70.0, 85.0]
    src["observer"]["file"] = str(_write(tmp_path, "e2.yaml", eso))
    with pytest.raises(ConfigError, match=r"e2\.yaml: key 'rotational\.omega_o_rad_s'.*a number, "
                                          r"or a list of 3 numbers"):
        load_controller(_write(tmp_path, "c2.yaml", src))
    eso["rotational"]["omega_o_rad_s"] = [70.0, 70.0, 150.0]   # past substeps x rate, 100
    src["observer"]["file"] = str(_write(tmp_path, "e3.yaml", dict(eso, substeps=1)))
    with pytest.raises(ConfigError, match=r"e3\.yaml: key 'rotational\.omega_o_rad_s'.*at most"):
        load_controller(_write(tmp_path, "c3.yaml", src))
    rates = read_yaml(PARAMS / "controller/eso.yaml")
    rates["rotational"]["omega_o_rad_s"] = [100.0, 100.0, 120.0]
    src["observer"]["file"] = str(_write(tmp_path, "e4.yaml", rates))
    src["rates_lowpass_hz"] = 40.0
    with pytest.raises(ConfigError, match=r"e4\.yaml: key 'rotational\.omega_o_rad_s'.*one "
                                          r"number: the body-rate observer"):
        load_controller(_write(tmp_path, "c4.yaml", src))
