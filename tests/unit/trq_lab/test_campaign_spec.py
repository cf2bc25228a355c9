"""trq_lab.campaign.spec: an axis's keys are its schema's dotted paths (one name per key, with the
schema's types and ranges), and a time-varying fault is planned through the fault script's own
parser."""

from __future__ import annotations

import pytest
from conftest import PARAMS
from trq_params import ConfigError
from trq_params.loader import leaf_types
from trq_params.schema import AXIS_MODELS, Plant

from trq_lab.campaign.flight import severity
from trq_lab.campaign.spec import AXIS_KEYS, PLANT_NEUTRAL, load_campaign
from trq_lab.overlays import PLANT_PARAMS

# a smoke campaign of one controller over a time-varying fault
TV = (PARAMS / "campaigns" / "smoke.yaml").read_text().split("grid:")[0].replace(
    "[trq_nmpc_eso, quad_nmpc]", "[trq_nmpc_eso]") + (
    "grid:\n  fault: {motor: 1, time_varying.a: 0.8, time_varying.b: [0.1, 0.2],\n"
    "          time_varying.w: 1.0, at_s: 1.0}\n")


def test_the_axes_keys_are_the_schemas_paths():
    for axis, models in AXIS_MODELS.items():
        assert set(AXIS_KEYS[axis]) == set().union(*(leaf_types(m) for m in models)), axis
    assert {"time_varying.b", "time_varying.w", "time_varying.phi"} <= set(AXIS_KEYS["fault"])
    b = AXIS_KEYS["fault"]["time_varying.b"]
    assert (b.kind, b.lo, b.hi) == ("float", 0.0, 1.0)
    assert set(PLANT_NEUTRAL) == set(PLANT_PARAMS) == set(Plant.model_fields)
    assert AXIS_KEYS["fault"]["motor"].kind == "int"


def test_a_time_varying_fault_is_planned_by_its_dotted_keys(tmp_path):
    path = tmp_path / "tv.yaml"
    path.write_text(TV)
    plan = load_campaign(path)
    assert [f["fault"]["time_varying.b"] for f in plan.flights] == [0.1, 0.2]
    assert [severity(f["fault"]) for f in plan.flights] == [("motor", 0.3), ("motor", 0.4)]
    path.write_text(TV.replace("time_varying.w: 1.0", "tv_w_rad_s: 1.0"))
    with pytest.raises(ConfigError, match=r"unknown key 'grid.fault.tv_w_rad_s'.*time_varying.w"):
        load_campaign(path)
    path.write_text(TV.replace("time_varying.w: 1.0,", ""))
    with pytest.raises(ConfigError, match=r"'grid.fault.time_varying.w' is missing"):
        load_campaign(path)


def test_the_shipped_campaigns_load():
    for path in sorted((PARAMS / "campaigns").glob("*.yaml")):
        assert load_campaign(path).flights, path


def test_a_controller_path_is_read_against_the_campaign_files_folder(tmp_path, monkeypatch):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "fast.yaml").write_text(
        "extends: builtin:controller/trq_nmpc_eso\nname: fast\n")
    path = tmp_path / "tv.yaml"
    path.write_text(TV.replace("[trq_nmpc_eso]", "[trq_nmpc_eso, mine/fast.yaml]"))
    monkeypatch.chdir(PARAMS)                       # anywhere but the campaign's folder
    plan = load_campaign(path)
    assert plan.controllers == ("trq_nmpc_eso", str(tmp_path / "mine" / "fast.yaml"))
    assert {f["controller"] for f in plan.flights} == set(plan.controllers)
    path.write_text(TV.replace("[trq_nmpc_eso]", "[trq_nmpc_eso, mine/slow.yaml]"))
    with pytest.raises(ConfigError, match=r"controllers\[1\].*slow.yaml"):
        load_campaign(path)
