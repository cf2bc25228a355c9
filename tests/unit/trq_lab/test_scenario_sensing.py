"""A scenario's sensing profile (trq_lab.scenario): the `sensing:` key (optional: mocap, never
the truth), checked at load, handed to each vehicle it starts as `--sensing`, recorded as the
profile flown; the diagnosis time as a scenario target."""

from __future__ import annotations

from pathlib import Path

import pytest
import trq_params
import yaml

from trq_lab import scenario as sc
from trq_params import ConfigError


def scenario_file(folder: Path, **keys) -> Path:
    data = yaml.safe_load(trq_params.builtin("scenarios", "smoke").read_text())
    data["faults"] = str(trq_params.builtin("faults", "motor1_smoke"))
    data.update(keys)
    path = folder / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def command(scenario: sc.Scenario, tmp_path: Path) -> list[str]:
    run = sc.Run("trq_nmpc_eso", 0, tmp_path)
    return sc.vehicle_command(scenario, run, False, tmp_path / "sim.yaml",
                              tmp_path / "trq.yaml", [], 1234)


def test_left_out_a_scenario_flies_mocap(tmp_path):
    s = sc.load_scenario(scenario_file(tmp_path))
    assert s.sensing == sc.SENSING_DEFAULT == "mocap"
    cmd = command(s, tmp_path)
    assert cmd[cmd.index("--sensing") + 1] == "mocap"


def test_truth_only_when_named(tmp_path):
    s = sc.load_scenario(scenario_file(tmp_path, sensing="truth"))
    cmd = command(s, tmp_path)
    assert cmd[cmd.index("--sensing") + 1] == "truth"


@pytest.mark.parametrize("path", sorted(Path(trq_params.builtin("scenarios", "smoke")).parent
                                        .glob("*.yaml")), ids=lambda p: p.stem)
def test_no_built_in_scenario_flies_the_truth(path):
    assert sc.load_scenario(path).sensing != "truth"


def test_a_name_goes_to_each_vehicle(tmp_path):
    s = sc.load_scenario(scenario_file(tmp_path, sensing="mocap"))
    assert s.sensing == "mocap"
    cmd = command(s, tmp_path)
    assert cmd[cmd.index("--sensing") + 1] == "mocap"


def test_a_relative_path_is_the_scenario_files(tmp_path):
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump(
        {"extends": "builtin:sensing/rtk", "name": "mine"}))
    s = sc.load_scenario(scenario_file(tmp_path, sensing="mine.yaml"))
    assert s.sensing == str(tmp_path / "mine.yaml")


def test_an_unknown_name_fails_at_load(tmp_path):
    path = scenario_file(tmp_path, sensing="sonar")
    with pytest.raises(ConfigError) as err:
        sc.load_scenario(path)
    assert str(path) in str(err.value) and "key 'sensing'" in str(err.value)
    assert "'sonar'" in str(err.value)


def test_the_command_line_option_is_checked_before_any_flight(tmp_path, capsys):
    assert sc.main(["smoke", "--out", str(tmp_path), "--sensing", "sonar"]) == 2
    assert "--sensing" in capsys.readouterr().err and not (tmp_path / "metrics.json").exists()


def test_the_in_process_vehicle_gets_it_too():
    from trq_lab.harness import sim_params
    from trq_params import builtin
    vehicle = builtin("vehicle", "trq")
    assert sim_params(vehicle, 100, seed=1, sensing="mocap").sensing.name == "mocap"
    assert sim_params(vehicle, 100, seed=1).sensing.name == "mocap"      # the sim file's


def test_the_profile_flown_is_the_scenarios_or_the_default(tmp_path):
    assert sc.sensing_flown(sc.load_scenario(scenario_file(tmp_path))) == "mocap"
    assert sc.sensing_flown(sc.load_scenario(scenario_file(tmp_path, sensing="rtk"))) == "rtk"


def test_the_diagnosis_time_is_a_scenario_target(tmp_path):
    s = sc.load_scenario(scenario_file(tmp_path, targets={"trq_nmpc_eso": {"diagnosis_s": 2.0}}))
    assert s.targets["trq_nmpc_eso"]["diagnosis_s"] == 2.0
    path = scenario_file(tmp_path, targets={"trq_nmpc_eso": {"diagnosis_s": -1.0}})
    with pytest.raises(ConfigError, match=r"targets.trq_nmpc_eso.diagnosis_s"):
        sc.load_scenario(path)
