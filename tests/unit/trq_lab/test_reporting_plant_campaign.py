"""The plant axis of trq-campaign (identification errors) without flying: the perturbed airframe
(trq_lab.overlays), the axis's keys, ranges and draws (trq_lab.campaign.spec), the envelope per
flight (trq_lab.analysis.envelope), the report's statistics (trq_lab.reporting.plant_campaign)
and the README's campaigns row (trq_lab.reporting.results)."""

from __future__ import annotations

import json
import math

import pytest
from conftest import PARAMS, QUAD_YAML, TRQ_YAML

from trq_lab.campaign.flight import fault_factors, flight_envelope, plant_id
from trq_lab.campaign.spec import Campaign, flight_id, load_campaign
from trq_lab.campaign.store import flight_inputs
from trq_lab.overlays import perturbed_vehicle, vehicle_data, write_vehicle_overlay
from trq_lab.reporting import plant_campaign as plants
from trq_lab.reporting import results

SMOKE = PARAMS / "campaigns" / "smoke.yaml"
IDENT = PARAMS / "campaigns" / "identification_errors.yaml"
IDENT_SMOKE = PARAMS / "campaigns" / "identification_smoke.yaml"


# --- the perturbed airframe ---------------------------------------------------------------------

def test_perturbed_vehicle_scales_and_offsets_the_named_numbers():
    base = vehicle_data(TRQ_YAML)
    plant = {"mass_scale": 1.05, "inertia_scale": 0.7, "thrust_scale": 1.1, "torque_scale": 0.8,
             "motor_lag_scale": 1.5, "servo_lag_scale": 0.7, "motor_rate_scale": 2.0,
             "servo_rate_scale": 0.5, "drag_scale": 3.0, "arm_length_scale": 1.2,
             "idle_offset_pct": -2.0}
    v = perturbed_vehicle(base, plant)
    assert v["mass_kg"] == pytest.approx(2.1 * 1.05)
    assert v["inertia_kg_m2"] == pytest.approx({"xx": 0.01241 * 0.7, "yy": 0.01241 * 0.7,
                                                "zz": 0.02365 * 0.7})
    assert v["rotor_curves"]["thrust_N"] == pytest.approx(
        {"c2": 0.0007 * 1.1, "c1": 0.0157 * 1.1, "c0": -0.1891 * 1.1})
    assert v["rotor_curves"]["torque_Nm"] == pytest.approx(
        {"c2": 2.0e-6 * 0.8, "c1": 0.0007 * 0.8, "c0": -0.008 * 0.8})
    assert v["motor"] == pytest.approx({"idle_pct": 8.0, "time_constant_s": 0.045,
                                        "rate_limit_pct_s": 3000.0})
    assert v["tilt"]["servo_time_constant_s"] == pytest.approx(0.028)
    assert v["tilt"]["servo_rate_limit_deg_s"] == pytest.approx(150.0)
    assert v["drag"]["quadratic_N_s2_m2"] == pytest.approx(0.09375)
    assert v["arm_length_m"] == pytest.approx(0.276)
    assert base == vehicle_data(TRQ_YAML)                    # the input is left alone
    for key in ("name", "gravity_m_s2", "rotors"):
        assert v[key] == base[key]


def test_a_neutral_plant_is_the_airframe_itself(tmp_path):
    import dataclasses

    from sil_vehicle.config import load_vehicle

    for path in (TRQ_YAML, QUAD_YAML):
        out = write_vehicle_overlay(path, {}, tmp_path / path.stem)
        assert out.name == path.name                         # the vehicle keeps its name
        a, b = load_vehicle(path), load_vehicle(out)
        assert dataclasses.replace(a, file="") == dataclasses.replace(b, file="")


def test_a_perturbed_airframe_reaches_the_simulated_vehicle(tmp_path):
    from sil_vehicle.config import load_vehicle

    vp = load_vehicle(write_vehicle_overlay(TRQ_YAML, {"mass_scale": 1.05, "thrust_scale": 0.9},
                                            tmp_path))
    nominal = load_vehicle(TRQ_YAML)
    assert vp.mass_kg == pytest.approx(1.05 * nominal.mass_kg)
    assert vp.thrust_N(60.0) == pytest.approx(0.9 * nominal.thrust_N(60.0))
    assert vp.hover_throttle_pct > nominal.hover_throttle_pct      # derived again


# --- the plant axis in a campaign file ----------------------------------------------------------

def _sampled(tmp_path, plant_yaml: str, n: int = 4, extra: str = "") -> Campaign:
    text = SMOKE.read_text().split("grid:")[0] + extra + (
        f"sample:\n  n: {n}\n  seed: 3\n  fault: {{motor: 1, effectiveness: 0.6, at_s: 1.5}}\n"
        f"  plant: {plant_yaml}\n")
    path = tmp_path / "plants.yaml"
    path.write_text(text)
    return load_campaign(path)


def test_sampled_plants_are_seeded_recorded_and_share_the_cell_seed(tmp_path):
    plan = _sampled(tmp_path, "{mass_scale: {uniform: [0.95, 1.05]}, "
                              "inertia_scale: {normal: [1.0, 0.2]}, motor_lag_scale: [0.7, 1.5]}")
    again = _sampled(tmp_path, "{mass_scale: {uniform: [0.95, 1.05]}, "
                               "inertia_scale: {normal: [1.0, 0.2]}, motor_lag_scale: [0.7, 1.5]}")
    assert plan.flights == again.flights and len(plan.flights) == 8 and plan.has_plant
    draws = [f["plant"] for f in plan.flights if f["controller"] == "trq_nmpc_eso"]
    assert len({json.dumps(d, sort_keys=True) for d in draws}) == 4
    assert all(0.95 <= d["mass_scale"] <= 1.05 and 0.2 <= d["inertia_scale"] <= 5.0
               and d["motor_lag_scale"] in (0.7, 1.5) for d in draws)
    assert len({f["seed"] for f in plan.flights}) == 1        # common random numbers
    assert len({f["id"] for f in plan.flights}) == 8
    for f in plan.flights:                                     # the id is the spec's hash
        assert f["id"] == flight_id({k: v for k, v in f.items() if k != "id"})
    row = flight_inputs(plan.flights[0])
    assert row["plant_mass_scale"] == plan.flights[0]["plant"]["mass_scale"]
    assert row["plant_thrust_scale"] == 1.0 and row["plant_idle_offset_pct"] == 0.0
    assert row["controller_model"] == "nominal"
    pair = [f for f in plan.flights if f["plant"] == plan.flights[0]["plant"]]
    assert {plant_id(f) for f in pair} == {row["plant_id"]} and len(pair) == 2


def test_a_truncated_normal_stays_in_the_keys_range(tmp_path):
    plan = _sampled(tmp_path, "{inertia_scale: {normal: [4.8, 1.0]}}", n=40)
    values = [f["plant"]["inertia_scale"] for f in plan.flights]
    assert all(0.2 <= v <= 5.0 for v in values) and max(values) > 4.8 > min(values)


def test_the_controllers_model_can_be_the_plant(tmp_path):
    plan = _sampled(tmp_path, "{mass_scale: {uniform: [0.95, 1.05]}}", n=2,
                    extra="controller_model: [nominal, plant]\n")
    assert len(plan.flights) == 8
    models = [f.get("controller_model", "nominal") for f in plan.flights]
    assert models.count("plant") == 4 and models.count("nominal") == 4
    assert "controller_model" not in plan.flights[0]           # nominal: the key is absent


def test_campaigns_without_a_plant_axis_keep_their_specs(tmp_path):
    """No plant axis: no 'plant' key, the ids and seeds as before (the spec's sensing, truth,
    is not in the id); `plant: {}` flies the same cells with the same seeds (its ids differ:
    the spec says a plant was asked for)."""
    plan = load_campaign(SMOKE)
    assert not plan.has_plant
    assert all(set(f) == {"controller", "fault", "wind", "trajectory", "repeat", "seed",
                          "sensing", "timeout_s", "recovery_threshold_m", "params_digest", "id"}
               and f["sensing"] == "truth" for f in plan.flights)
    path = tmp_path / "with_plant.yaml"
    path.write_text(SMOKE.read_text() + "  plant: {}\n")
    with_plant = load_campaign(path)
    assert [f["seed"] for f in with_plant.flights] == [f["seed"] for f in plan.flights]
    for a, b in zip(plan.flights, with_plant.flights):
        assert b["plant"] == {} and {k: v for k, v in b.items() if k not in ("plant", "id")} \
            == {k: v for k, v in a.items() if k != "id"}


def test_the_shipped_identification_campaigns():
    full, smoke = load_campaign(IDENT), load_campaign(IDENT_SMOKE)
    assert full.controllers == ("trq_nmpc_eso", "trq_nmpc", "quad_nmpc") == smoke.controllers
    assert len(full.flights) == 300 and 8 <= len(smoke.flights) <= 12
    assert [f["id"] for f in smoke.flights] == [f["id"] for f in full.flights[:9]]
    draws = [f["plant"] for f in full.flights]
    for key, lo, hi in (("mass_scale", 0.95, 1.05), ("inertia_scale", 0.7, 1.3),
                        ("thrust_scale", 0.9, 1.1), ("torque_scale", 0.8, 1.2),
                        ("motor_lag_scale", 0.7, 1.5), ("servo_lag_scale", 0.7, 1.5)):
        assert all(lo <= d[key] <= hi for d in draws), key
    f = full.flights[0]
    assert f["fault"] == {"motor": 1, "effectiveness": 0.5, "at_s": 12.0}
    assert f["wind"]["speed_m_s"] == 8.0 and f["trajectory"] == {"kind": "helix"}
    assert full.targets.controller == "trq_nmpc_eso" and full.targets.min_margin_pct == 5.0


BASE = SMOKE.read_text().split("grid:")[0]


@pytest.mark.parametrize("section, key, words", [
    ("grid:\n  plant: {mas_scale: 1.1}\n", "grid.plant.mas_scale", "unknown key"),
    ("grid:\n  plant: {mass_scale: [1.0, 2.5]}\n", "grid.plant.mass_scale[1]",
     "a number in [0.5, 2]"),
    ("sample:\n  n: 2\n  seed: 1\n  plant: {mass_scale: {uniform: [0.9, 2.5]}}\n",
     "sample.plant.mass_scale.uniform", "numbers in [0.5, 2]"),
    ("sample:\n  n: 2\n  seed: 1\n  plant: {mass_scale: {normal: [1.0, 0.0]}}\n",
     "sample.plant.mass_scale.normal", "sd > 0"),
    ("sample:\n  n: 2\n  seed: 1\n  plant: {mass_scale: {normal: [3.0, 0.1]}}\n",
     "sample.plant.mass_scale.normal", "the mean in [0.5, 2]"),
    ("grid:\n  plant: {thrust_scale: 0.6}\n", "grid.plant", "cannot fly"),
    ("sample:\n  n: 3\n  seed: 1\n  plant: {idle_offset_pct: {uniform: [-15.0, -12.0]}}\n",
     "sample.plant (draw 0)", "motor.idle_pct"),
    ("controller_model: wrong\ngrid:\n  plant: {}\n", "controller_model", "nominal|plant"),
    ("targets: {controller: trq_nmpc, min_margin_pct: 5.0, rmse_after_fault_m: 0.02, "
     "share: 0.95}\ngrid:\n  plant: {}\n", "targets.controller", "one of the campaign's"),
])
def test_a_bad_plant_names_file_key_value_and_expected(tmp_path, section, key, words):
    from trq_params import ConfigError

    path = tmp_path / "bad_plant.yaml"
    path.write_text(BASE + section)
    with pytest.raises(ConfigError) as err:
        load_campaign(path)
    msg = str(err.value)
    assert str(path) in msg and f"'{key}'" in msg and words in msg, msg


# --- the envelope per flight ------------------------------------------------------------------

@pytest.fixture(scope="module")
def trq_vp():
    from sil_vehicle.config import load_vehicle
    return load_vehicle(TRQ_YAML)


def test_fault_factors_of_each_kind_of_fault():
    assert fault_factors(None) == ((1.0,) * 4, ())
    assert fault_factors({"motor": 2, "effectiveness": 0.6, "at_s": 1.0}) == \
        ((1.0, 0.6, 1.0, 1.0), ())
    assert fault_factors({"motor": 1, "time_varying.a": 0.8, "time_varying.b": 0.2,
                          "time_varying.w": 1.0, "at_s": 1.0})[0][0] == pytest.approx(0.6)
    assert fault_factors({"motor": 4, "stopped": True, "at_s": 1.0})[0][3] == 0.0
    assert fault_factors({"servo": 3, "stuck_deg": 10.0, "at_s": 1.0}) == \
        ((1.0,) * 4, ((2, math.radians(10.0)),))


def test_flight_envelope_of_the_paper_fault(trq_vp):
    env = flight_envelope(trq_vp, {"motor": 1, "effectiveness": 0.5, "at_s": 12.0},
                                   {"speed_m_s": 8.0, "direction_deg": 0.0, "gusts": False})
    assert env["feasible"] and env["motor_factors"] == [0.5, 1.0, 1.0, 1.0]
    up = [100.0 - z for z in env["throttle_pct"]]
    down = [z - trq_vp.idle_pct for z in env["throttle_pct"]]
    assert env["throttle_margin_up_pct"] == pytest.approx(up, abs=0.01)
    assert env["min_throttle_margin_pct"] == pytest.approx(min(up + down), abs=0.01)
    assert 0.0 < env["min_throttle_margin_pct"] < 5.0   # the faulted trim is near full throttle
    json.dumps(env)                                      # recorded as it is in the flight's JSON


def test_less_thrust_leaves_no_trim_and_more_leaves_more_margin(tmp_path):
    from sil_vehicle.config import load_vehicle

    fault = {"motor": 1, "effectiveness": 0.5, "at_s": 12.0}
    wind = {"speed_m_s": 8.0, "direction_deg": 0.0, "gusts": False}
    margin = {}
    for s in (0.9, 1.0, 1.1):
        vp = load_vehicle(write_vehicle_overlay(TRQ_YAML, {"thrust_scale": s}, tmp_path / str(s)))
        margin[s] = flight_envelope(vp, fault, wind)["min_throttle_margin_pct"]
    assert margin[0.9] is None and margin[1.1] > margin[1.0] + 3.0


def test_a_stuck_servo_holds_its_tilt_in_the_trim(trq_vp):
    from trq_lab.analysis import envelope

    out = envelope.analyse(trq_vp, [1.0] * 4, 0.0, 0.0, tilt_fixed_rad={1: math.radians(12.0)})
    assert out["feasible"] and out["trim"]["tilt_deg"][1] == pytest.approx(12.0, abs=0.01)
    free = envelope.analyse(trq_vp, [1.0] * 4, 0.0, 0.0)
    assert free["trim"]["tilt_deg"][1] == pytest.approx(0.0, abs=0.1)


# --- the report's statistics ------------------------------------------------------------------

def test_rank_and_spearman_against_hand_values():
    assert plants.rank([10.0, 30.0, 20.0, 20.0]).tolist() == [1.0, 4.0, 2.5, 2.5]
    assert plants.rank([1.0, math.inf, math.inf]).tolist() == [1.0, 2.5, 2.5]
    x, y = [1, 2, 3, 4, 5], [2, 1, 4, 3, 5]
    d2 = sum((a - b) ** 2 for a, b in zip(x, y))               # no ties: 1 - 6 sum d^2 / n(n^2-1)
    assert plants.spearman(x, y) == pytest.approx(1 - 6 * d2 / (5 * 24))
    assert plants.spearman(x, [v ** 3 for v in x]) == pytest.approx(1.0)
    assert plants.spearman(x, [-v for v in x]) == pytest.approx(-1.0)
    assert math.isnan(plants.spearman(x, [1.0] * 5))
    # a crash (inf) ranks as the worst: a monotone relation stays perfect
    assert plants.spearman([1, 2, 3, 4], [0.1, 0.2, 0.3, math.inf]) == pytest.approx(1.0)


def _row(controller, plant, rmse, margin, mass, crashed=False):
    return {"controller": controller, "plant_id": plant, "plant_mass_scale": mass,
            "plant_thrust_scale": 1.0, "status": "crashed" if crashed else "done",
            "crashed": crashed, "rmse_pos_after_fault_m": rmse,
            "success": not crashed and rmse < 0.02, "env_feasible": margin is not None,
            "env_min_margin_pct": margin, "controller_model": "nominal"}


class _Targets:
    controller, min_margin_pct, rmse_after_fault_m, share = "a", 5.0, 0.02, 0.95

    class better:                                      # one paired target
        worse, share = "b", 0.95
    better = [better]


class _Campaign:
    name, controllers, success_rmse_m, targets = "synthetic", ("a", "b"), 0.02, _Targets


def test_plant_report_separates_the_envelope_from_the_controller(tmp_path):
    rows = []
    # plants 0..7 with margin: a within 0.02 on all but plant 7; b worse everywhere but plant 6
    for i in range(8):
        rows.append(_row("a", f"p{i}", 0.05 if i == 7 else 0.005 + 0.001 * i, 13.0 - i, 1.0))
        rows.append(_row("b", f"p{i}", 0.001 if i == 6 else 0.5, 13.0 - i, 1.0))
    # plants 8, 9: no trim, a crashes on 9; plant 10: thin margin
    rows += [_row("a", "p8", 0.3, None, 1.05), _row("b", "p8", 0.4, None, 1.05),
             _row("a", "p9", None, None, 1.04, crashed=True),
             _row("b", "p9", None, None, 1.04, crashed=True),
             _row("a", "p10", 0.015, 2.0, 1.03), _row("b", "p10", 0.3, 2.0, 1.03)]
    lines, summary = plants.report(_Campaign, rows, tmp_path, figures=True)
    text = "\n".join(lines)
    assert summary["target_rmse"] == {"plants": 8, "within": 7, "share": 7 / 8, "target": 0.95,
                                      "met": False}
    paired = summary["target_paired"]["b"]
    assert (paired["pairs"], paired["better"]) == (11, 9) and not paired["met"]   # p6, p9 not
    assert summary["misses"] == {"no trim": 2, "margin < 5 %": 0, "margin >= 5 %": 1}
    assert len(summary["failures"]) == 2
    assert summary["headline"] == ("a within 0.02 m on 88% of 8 plants with >= 5 % margin: "
                                   "missed; better than b on 82% of 11 plants (89% of the 9 "
                                   "with a trim): missed")
    assert "**Missed:**" in text and "`p7`" in text          # the controller's miss is listed
    assert summary["controllers"]["a"]["envelope"] == {"no trim": 2, "margin < 5 %": 1,
                                                       "margin >= 5 %": 8}
    assert summary["spearman"]["a"]["mass_scale"] > 0.5      # heavier plants: larger errors
    assert summary["spearman"]["a"]["trim margin"] < -0.5
    for name in ("margin.png", "rmse_dist.png"):
        assert f"({name})" in text and (tmp_path / name).read_bytes()[:4] == b"\x89PNG"


# --- the README's campaigns row -----------------------------------------------------------------

def test_results_campaigns_block(tmp_path):
    res = tmp_path / "results"
    (res / "sc").mkdir(parents=True)
    (res / "sc" / "metrics.json").write_text(json.dumps(
        {"scenario": "sc", "runs": [{"controller": "trq_nmpc_eso", "crashed": False,
                                     "rmse_pos_after_fault_m": 0.002, "max_yaw_err_deg": 0.2}],
         "failures": []}))
    (res / "camp").mkdir()
    (res / "camp" / "metrics.json").write_text(json.dumps(
        {"campaign": "camp", "flights": 6, "plants": 2, "failures": [
            "trq_nmpc_eso: share within 0.02 m = 0.8765432 (target >= 0.95)"],
         "controllers": {"trq_nmpc": {"success_rate": 0.0, "rmse_median_m": 1.5},
                         "trq_nmpc_eso": {"success_rate": 0.5, "rmse_median_m": 0.0123}}}))
    text = ("<!-- results:scenarios begin -->\n<!-- results:scenarios end -->\n"
            "<!-- results:campaigns begin -->\n<!-- results:campaigns end -->\n")
    out = results.update_text(text, res)
    scen, camp = out.split("<!-- results:campaigns begin -->")
    assert "`sc`" in scen and "camp" not in scen.replace("campaigns", "")
    assert "| `camp` | 6 (2 plants) | 50% / 0.0123 | 0% / 1.5000 |" in camp
    (res / "camp" / "report.md").write_text("# Campaign\n")     # the name links to its report
    out = results.update_text(text, res, base=tmp_path)
    assert "| [`camp`](results/camp/report.md) | 6 (2 plants) |" in out
    assert "missed: trq_nmpc_eso: share within 0.02 m = 0.8765 (target >= 0.95)" in camp
    assert camp.index("trq_nmpc_eso success") < camp.index("trq_nmpc success")
    doc = json.loads((res / "camp" / "metrics.json").read_text())
    (res / "camp" / "metrics.json").write_text(json.dumps({**doc, "headline": "all met"}))
    assert "| all met |" in results.update_text(text, res)    # the campaign's own words win


def test_trq_envelope_takes_a_plant(tmp_path, capsys):
    from trq_lab.analysis import envelope

    out = {}
    for name, plant in (("nominal", []), ("heavier", ["--plant", "mass_scale=1.03"])):
        path = tmp_path / f"{name}.json"
        assert envelope.main(["--motor", "1", "--eff", "0.5", "--wind", "8", *plant,
                              "--json", str(path)]) == 0
        out[name] = json.loads(path.read_text())["trim"]["throttle_pct"]
    assert max(out["heavier"]) > max(out["nominal"])          # 3 % more weight: less margin
    assert "throttle margin: up" in capsys.readouterr().out
    assert envelope.main(["--plant", "mass=1.1"]) == 2
    assert "KEY one of mass_scale" in capsys.readouterr().err
    assert envelope.main(["--plant", "thrust_scale=0.5"]) == 2
    assert "cannot fly" in capsys.readouterr().err
