"""The sensing profile chosen for the vehicle (sil_vehicle.config, sil_vehicle.daemon): by the
sim file's `sensing:` key (a built-in name or a path, relative to the file that writes it), then
by `--sensing`; an unknown name or a bad profile is a ConfigError naming the file (or the
command line), the key and the value."""

from __future__ import annotations

import pytest
import yaml

from sil_vehicle import daemon
from sil_vehicle.config import ConfigError, load_sim

from conftest import SIM_DEFAULT


def sim_file(folder, **keys):
    path = folder / "sim.yaml"
    path.write_text(yaml.safe_dump({"extends": str(SIM_DEFAULT), **keys}))
    return path


def test_the_default_is_mocap_as_the_scenarios_fly():
    """A vehicle started by hand sees what the scenarios' vehicles see (issue 39 item 8), not the
    oracle `truth`."""
    sim = load_sim(SIM_DEFAULT)
    assert sim.sensing is not None and sim.sensing.name == "mocap"
    assert not sim.sensing.is_truth and sim.senses


def test_truth_is_a_profile_without_sensors(tmp_path):
    sim = load_sim(sim_file(tmp_path, sensing="truth"))
    assert sim.sensing is not None and sim.sensing.name == "truth"
    assert sim.sensing.is_truth and not sim.senses


def test_the_sim_file_names_a_builtin_profile(tmp_path):
    sim = load_sim(sim_file(tmp_path, sensing="mocap"))
    assert sim.sensing.name == "mocap" and sim.senses
    assert sim.sensing.physics_rate_hz == sim.physics_rate_hz == 1000
    assert sim.sensing.mocap.latency_ticks == 10 and sim.sensing.gnss is None


def test_a_relative_path_is_the_writing_files(tmp_path):
    (tmp_path / "sensors").mkdir()
    (tmp_path / "sensors" / "mine.yaml").write_text(yaml.safe_dump(
        {"extends": "builtin:sensing/rtk", "name": "mine"}))
    sim = load_sim(sim_file(tmp_path, sensing="sensors/mine.yaml"))
    assert sim.sensing.name == "mine" and sim.sensing.gnss.fix_type == 6
    assert sim.sensing.file == str(tmp_path / "sensors" / "mine.yaml")


def test_an_unknown_name_is_named_with_the_file_and_key(tmp_path):
    path = sim_file(tmp_path, sensing="vicon")
    with pytest.raises(ConfigError) as err:
        load_sim(path)
    msg = str(err.value)
    assert str(path) in msg and "key 'sensing'" in msg and "'vicon'" in msg
    assert "mocap" in msg and "truth" in msg            # what exists


def test_a_bad_profile_names_both_files_and_keys(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"extends": "builtin:sensing/mocap", "mocap": {
        "rate_hz": 300}}))
    path = sim_file(tmp_path, sensing=str(bad))
    with pytest.raises(ConfigError) as err:
        load_sim(path)
    msg = str(err.value)
    assert str(path) in msg and "key 'sensing'" in msg and str(bad) in msg
    assert "mocap.rate_hz" in msg and "300" in msg        # the profile's own check, at 1 kHz


def test_a_missing_profile_file(tmp_path):
    with pytest.raises(ConfigError, match=r"key 'sensing'.*nowhere\.yaml"):
        load_sim(sim_file(tmp_path, sensing=str(tmp_path / "nowhere.yaml")))


def test_the_command_line_overrides_the_sim_file(tmp_path):
    sim = load_sim(sim_file(tmp_path, sensing="mocap"))
    args = daemon.build_parser().parse_args(["--sensing", "rtk"])
    assert daemon.apply_overrides(sim, args).sensing.name == "rtk"
    args = daemon.build_parser().parse_args([])
    assert daemon.apply_overrides(sim, args).sensing.name == "mocap"


def test_an_unknown_name_on_the_command_line(capsys):
    args = daemon.build_parser().parse_args(["--sensing", "lidar"])
    with pytest.raises(ConfigError, match=r"command line: key '--sensing': got 'lidar'"):
        daemon.apply_overrides(load_sim(SIM_DEFAULT), args)
    assert daemon.main(["--sensing", "lidar", "--no-log"]) == 2
    assert "--sensing" in capsys.readouterr().err


def test_sensing_options_have_help():
    action = next(a for a in daemon.build_parser()._actions if "--sensing" in a.option_strings)
    assert "truth" in action.help and "mocap" in action.help
