"""The one loader (trq_params.loader) and its schemas (trq_params.schema): `extends:` resolves
every path against the file that wrote it, by path or by `builtin:KIND/NAME`; both daemons read
the vehicle file with the same dialect and schema; every error names the file, the dotted key,
the value and what was expected."""

from __future__ import annotations

import datetime
from pathlib import Path

import pytest
import yaml

import sil_vehicle.config as sim_config
import trq_offboard.config as ctrl_config
import trq_params
from trq_params import loader, schema
from trq_params.loader import ConfigError

CTRL = trq_params.builtin("controller", "trq_nmpc_eso")
TRQ = trq_params.builtin("vehicle", "trq")


def write(path: Path, data: dict | str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False),
                    encoding="utf-8")
    return path


def test_one_error_class():
    assert sim_config.ConfigError is ctrl_config.ConfigError is ConfigError
    assert issubclass(ConfigError, ValueError)


@pytest.mark.parametrize("ref", [str(CTRL), "builtin:controller/trq_nmpc_eso"])
def test_user_file_extends_a_builtin_controller(tmp_path, ref):
    """A user's file elsewhere inherits the parent's relative `vehicle` and `observer.file`
    (written in params/controller/) resolved next to the parent, not next to the user's file."""
    user = write(tmp_path / "my" / "ctrl.yaml", {"extends": ref, "name": "mine",
                                                  "horizon": {"steps": 10}})
    cfg = ctrl_config.load_controller(user)
    assert cfg.name == "mine" and cfg.horizon_steps == 10 and cfg.step_s == 0.05
    assert Path(cfg.vehicle.file) == TRQ.resolve()
    assert Path(cfg.eso.file) == (CTRL.parent / "eso.yaml").resolve()
    assert cfg.file == str(user.resolve())
    shipped = ctrl_config.load_controller(CTRL)
    assert cfg.eso == shipped.eso and cfg.vehicle == shipped.vehicle


def test_child_paths_resolve_against_the_child(tmp_path):
    """A path the user's file writes itself is relative to the user's file."""
    write(tmp_path / "v" / "heavy.yaml", {"extends": "builtin:vehicle/trq", "mass_kg": 2.5})
    user = write(tmp_path / "c" / "ctrl.yaml", {"extends": "builtin:controller/trq_nmpc_eso",
                                                "vehicle": "../v/heavy.yaml"})
    cfg = ctrl_config.load_controller(user)
    assert cfg.vehicle.mass_kg == 2.5 and Path(cfg.vehicle.file) == tmp_path / "v" / "heavy.yaml"
    assert Path(cfg.eso.file) == (CTRL.parent / "eso.yaml").resolve()


def test_path_keys_come_from_the_schema():
    assert loader.path_keys(schema.ControllerFile) == ("vehicle", "observer.file")
    assert loader.path_keys(schema.SimFile) == ("vehicle", "sensing")
    assert loader.name_keys(schema.SimFile) == ("sensing",)     # a bare name stays a name
    assert loader.path_keys(schema.VehicleFile) == ()


def test_builtin_extends_of_an_unknown_name(tmp_path):
    user = write(tmp_path / "c.yaml", {"extends": "builtin:controller/nope"})
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'extends'.*nope.*trq_nmpc_eso"):
        ctrl_config.load_controller(user)


@pytest.mark.parametrize("load", [sim_config.load_vehicle, ctrl_config.load_vehicle_model],
                         ids=["sil_vehicle", "trq_offboard"])
@pytest.mark.parametrize("word", ["no", "off", "yes", "on"])
def test_yaml_11_booleans_rejected_by_both_daemons(tmp_path, load, word):
    path = write(tmp_path / "v.yaml", f"extends: {TRQ}\ntilt:\n  locked: {word}\n")
    with pytest.raises(ConfigError) as info:
        load(path)
    assert str(info.value) == (f"{path}: key 'tilt.locked': got '{word}', "
                               "expected true or false")


@pytest.mark.parametrize("text, line", [
    ("name: a\nspin:\n  inner: nmpc\n  horizon_steps: 20\n  inner: lqr\n", 3),
    ("name: a\nname: b\n", 1),
    ("faults: [{at_s: 1.0, at_s: 2.0}]\n", 1)])
def test_a_key_given_twice_is_refused_naming_it_and_its_lines(tmp_path, text, line):
    """A key twice in one mapping (block or flow) is an error naming the file, the key and the
    line of its first use (PyYAML alone keeps the last and says nothing); the same key in two
    mappings is no duplicate."""
    path = write(tmp_path / "c.yaml", text)
    with pytest.raises(ConfigError, match="given twice") as info:
        loader.read_yaml(path)
    assert str(info.value).startswith(f"{path}: ")
    assert f"first on line {line})" in str(info.value)
    assert loader.read_yaml(write(tmp_path / "ok.yaml", "a: {x: 1}\nb: {x: 2}\n")) == {
        "a": {"x": 1}, "b": {"x": 2}}


def test_both_daemons_read_the_same_vehicle(tmp_path):
    path = write(tmp_path / "v.yaml", {"extends": "builtin:vehicle/quad", "mass_kg": 1.9})
    sim, ctrl = sim_config.load_vehicle(path), ctrl_config.load_vehicle_model(path)
    assert sim.mass_kg == ctrl.mass_kg == 1.9 and sim.tilt_locked and ctrl.tilt_locked
    assert sim.hover_throttle_pct == pytest.approx(ctrl.hover_throttle_pct)


@pytest.mark.parametrize("over, message", [
    ({"rotors": [{"name": "a", "azimuth_deg": 45.0, "spin": "ccw", "tilt_axis": [1, 0, 0]}]
      + [{"name": n, "azimuth_deg": 0.0, "spin": "cw"} for n in "bcd"]},
     "unknown key 'rotors[0].tilt_axis' (value [1, 0, 0]): expected one of name, azimuth_deg, "
     "spin"),
    ({"motor": {"idle_pct": "ten"}},
     "key 'motor.idle_pct': got 'ten', expected a number in [0, 50]"),
    ({"inertia_kg_m2": {"zz": 200.0}},
     "key 'inertia_kg_m2.zz': got 200.0, expected a number in [1e-06, 100]"),
    ({"rotors": [{"name": "a", "azimuth_deg": 45.0, "spin": "sideways"}] * 4},
     "key 'rotors[0].spin': got 'sideways', expected one of ccw|cw"),
], ids=["unknown key", "wrong type", "out of range", "not a choice"])
def test_errors_name_file_key_value_expectation(tmp_path, over, message):
    path = write(tmp_path / "bad.yaml", {"extends": str(TRQ), **over})
    for load in (sim_config.load_vehicle, ctrl_config.load_vehicle_model):
        with pytest.raises(ConfigError) as info:
            load(path)
        assert str(info.value) == f"{path}: {message}"


def test_controller_errors_name_the_nested_key(tmp_path):
    path = write(tmp_path / "c.yaml", {"extends": "builtin:controller/nmpc",
                                       "solver": {"max_iterations": 0}})
    with pytest.raises(ConfigError) as info:
        ctrl_config.load_controller(path)
    assert str(info.value) == (f"{path.resolve()}: key 'solver.max_iterations': got 0, "
                               "expected an integer in [1, 100]")


def test_extends_cycle_through_three_files(tmp_path):
    write(tmp_path / "a.yaml", {"extends": "b.yaml"})
    write(tmp_path / "b.yaml", {"extends": "sub/c.yaml"})
    c = write(tmp_path / "sub" / "c.yaml", {"extends": "../a.yaml"})
    with pytest.raises(ConfigError, match=r"c\.yaml: key 'extends': cycle through .*a\.yaml"):
        loader.read(tmp_path / "a.yaml")
    assert c.exists()


def test_extends_of_a_missing_file(tmp_path):
    path = write(tmp_path / "a.yaml", {"extends": "gone.yaml"})
    with pytest.raises(ConfigError, match=r"a\.yaml: key 'extends': no such file .*gone\.yaml"):
        loader.read(path)


def test_validate_a_mapping_in_hand():
    """The API for callers that hold a mapping already (a scenario's or campaign's part)."""
    data = loader.read_yaml(TRQ)
    v = loader.validate(schema.VehicleFile, data, "memory")
    assert v.name == "trq" and isinstance(v, schema.VehicleFile)
    with pytest.raises(ConfigError, match=r"^memory: key 'x\.mass_kg' is missing$"):
        loader.validate(schema.VehicleFile, {k: w for k, w in data.items() if k != "mass_kg"},
                        "memory", prefix="x")
    with pytest.raises(Exception):
        v.mass_kg = 3.0                     # frozen


def test_a_file_read_again_is_a_new_document_and_follows_the_file(tmp_path):
    """The parse is kept per text (loader._parsed): what a caller does to what it read does
    not reach the next read, and a file rewritten with other text is read anew."""
    path = write(tmp_path / "p.yaml", "a: {x: [1, 2]}\nb: 2024-01-02\n")
    first = loader.read_yaml(path)
    first["a"]["x"].append(3)
    first["a"]["y"] = 0
    assert loader.read_yaml(path) == {"a": {"x": [1, 2]}, "b": datetime.date(2024, 1, 2)}
    write(path, "a: {x: [5]}\n")
    assert loader.read_yaml(path) == {"a": {"x": [5]}}
