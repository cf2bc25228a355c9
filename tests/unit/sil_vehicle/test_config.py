"""Parameter loading (sil_vehicle.config on trq_params.loader): the real files load into the
expected records, and every kind of mistake is a ConfigError naming the file and the dotted key.

Bad files are written into tmp_path; they reuse the real ones with `extends:` (an absolute path
computed from this file) or are full copies with one key changed.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
import yaml

from sil_vehicle.config import (STREAMS, ConfigError, VehicleParams, load_sim, load_vehicle)

from conftest import QUAD_YAML, SIM_DEFAULT, TRQ_YAML


# --- the real files -------------------------------------------------------------------------

def test_trq_values(trq):
    assert trq.name == "trq"
    assert trq.mass_kg == 2.1
    assert trq.inertia_kg_m2 == (0.01241, 0.01241, 0.02365)
    assert trq.thrust_N.c2 == 0.0007 and trq.thrust_N.c1 == 0.0157 and trq.thrust_N.c0 == -0.1891
    assert not trq.tilt_locked
    assert math.isclose(trq.tilt_max_rad, math.radians(30))
    assert trq.tilt_limit_rad == trq.tilt_max_rad
    assert math.isclose(trq.servo_rate_limit_rad_s, math.radians(300.0))
    assert [r.spin for r in trq.rotors] == [1, 1, -1, -1]
    # rotor i at l (cos az, sin az, 0), tilt axis along the arm
    r1 = trq.rotors[0]
    assert r1.name == "front_right"
    s = 0.23 * math.sqrt(0.5)
    assert r1.position_frd_m == pytest.approx((s, s, 0.0), abs=1e-15)
    assert r1.tilt_axis_frd == pytest.approx((math.sqrt(0.5), math.sqrt(0.5), 0.0), abs=1e-15)
    r3 = trq.rotors[2]           # front left: x > 0, y < 0
    assert r3.position_frd_m == pytest.approx((s, -s, 0.0), abs=1e-15)


def test_hover_throttle(trq):
    # 0.0007 z^2 + 0.0157 z - 0.1891 = 2.1 * 9.80665 / 4 = 5.14849125 N, by hand: 76.8249 %
    assert trq.hover_throttle_pct == pytest.approx(76.8249, abs=1e-4)
    assert trq.thrust_N(trq.hover_throttle_pct) * 4 == pytest.approx(2.1 * 9.80665, rel=1e-12)


def test_hover_throttle_recomputed_on_replace(trq):
    heavier = dataclasses.replace(trq, mass_kg=2.5)
    assert heavier.hover_throttle_pct > trq.hover_throttle_pct
    assert heavier.thrust_N(heavier.hover_throttle_pct) * 4 == pytest.approx(2.5 * 9.80665,
                                                                              rel=1e-12)


def test_quad_equals_trq_but_locked(trq, quad):
    assert quad.name == "quad" and trq.name == "trq"
    assert quad.tilt_locked and not trq.tilt_locked
    differing = {"name", "file", "tilt_locked"}      # file: where each was read from
    for f in dataclasses.fields(VehicleParams):
        if f.name not in differing:
            assert getattr(quad, f.name) == getattr(trq, f.name), f.name


def test_default_sim(sim):
    assert sim.physics_rate_hz == 1000 and sim.dt_us == 1000
    assert sim.control_rate_hz == 100 and sim.ticks_per_control == 10
    assert sim.clock_mode == "lockstep"
    assert sim.vehicle.name == "trq"
    assert [link.name for link in sim.links] == ["gcs", "offboard"]
    off = sim.link("offboard")
    assert off.rate("ODOMETRY") == sim.control_rate_hz and str(off.bind) == "127.0.0.1:14580"
    assert [s for s, _ in off.rates_hz] == list(STREAMS)
    for link in sim.links:
        for _, hz in link.rates_hz:
            assert hz == 0 or sim.physics_rate_hz % hz == 0
    assert sim.crash_speed_m_s == 2.5 and math.isclose(sim.crash_tilt_rad, math.pi / 2)
    with pytest.raises(KeyError):
        sim.link("nope")


def test_sim_vehicle_override():
    sim = load_sim(SIM_DEFAULT, QUAD_YAML)
    assert sim.vehicle.name == "quad" and sim.vehicle.tilt_locked


# --- errors -----------------------------------------------------------------------------------

def write(tmp_path, name: str, data: dict):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def trq_copy() -> dict:
    return yaml.safe_load(TRQ_YAML.read_text(encoding="utf-8"))


def sim_over(**over) -> dict:
    """A sim file extending the real default; the vehicle as an absolute path (see
    test_inherited_vehicle_path_is_relative_to_the_file_that_names_it)."""
    return {"extends": str(SIM_DEFAULT), "vehicle": str(TRQ_YAML), **over}


def assert_config_error(loader, path, *fragments):
    with pytest.raises(ConfigError) as info:
        loader(path)
    text = str(info.value)
    assert path.name in text, text
    for fragment in fragments:
        assert fragment in text, text
    return text


@pytest.mark.parametrize("over, key", [
    ({"mass_kg": 1000.0}, "'mass_kg'"),                                   # out of range
    ({"mass_kg": "heavy"}, "'mass_kg'"),                                  # wrong type
    ({"mass_kg": True}, "'mass_kg'"),                                     # bool is not a number
    ({"mass_kg": float("nan")}, "'mass_kg'"),
    ({"gravity_m_s2": 3.7}, "'gravity_m_s2'"),                            # Mars: out of range
    ({"inertia_kg_m2": {"zz": 0.0}}, "'inertia_kg_m2.zz'"),
    ({"rotor_curves": {"thrust_N": {"c2": 0.0}}}, "'rotor_curves.thrust_N.c2'"),  # open bound
    ({"motor": {"idle_pctt": 5.0}}, "'motor.idle_pctt'"),                  # unknown key
    ({"unexpected": 1}, "'unexpected'"),
    ({"tilt": {"locked": "yes"}}, "'tilt.locked'"),                       # string, not bool
    ({"tilt": {"min_deg": 10.0}}, "'tilt.min_deg'"),
    ({"motor": 5}, "'motor'"),                                            # not a mapping
])
def test_vehicle_errors_via_extends(tmp_path, over, key):
    path = write(tmp_path, "bad_vehicle.yaml", {"extends": str(TRQ_YAML), **over})
    assert_config_error(load_vehicle, path, key)


def test_vehicle_missing_key(tmp_path):
    data = trq_copy()
    del data["drag"]["quadratic_N_s2_m2"]
    path = write(tmp_path, "no_drag.yaml", data)
    text = assert_config_error(load_vehicle, path, "'drag.quadratic_N_s2_m2'")
    assert "missing" in text


def test_vehicle_wrong_rotor_count_and_spin(tmp_path):
    data = trq_copy()
    data["rotors"] = data["rotors"][:3]
    assert_config_error(load_vehicle, write(tmp_path, "three.yaml", data), "'rotors'")
    data = trq_copy()
    data["rotors"][1]["spin"] = "clockwise"
    assert_config_error(load_vehicle, write(tmp_path, "spin.yaml", data), "'rotors[1].spin'")


def test_vehicle_that_cannot_fly(tmp_path):
    path = write(tmp_path, "heavy.yaml", {"extends": str(TRQ_YAML), "mass_kg": 20.0})
    assert_config_error(load_vehicle, path, "'rotor_curves.thrust_N'", "cannot fly")


@pytest.mark.parametrize("over, key", [
    ({"links": {"gcs": {"bind": "localhost"}}}, "'links.gcs.bind'"),               # no port
    ({"links": {"offboard": {"target": "127.0.0.1:70000"}}}, "'links.offboard.target'"),
    ({"links": {"gcs": {"bind": "127.0.0.1:port"}}}, "'links.gcs.bind'"),
    ({"telemetry": {"gcs": {"ATTITUDE": 30}}}, "'telemetry.gcs.ATTITUDE'"),         # 1000 % 30
    ({"telemetry": {"gcs": {"ATTITUDE": 2000}}}, "'telemetry.gcs.ATTITUDE'"),       # > physics
    ({"telemetry": {"offboard": {"ODOMETRY": 25}}}, "'telemetry.offboard.ODOMETRY'"),
    ({"telemetry": {"gcs": {"ATTITUDE": 25.0}}}, "'telemetry.gcs.ATTITUDE'"),       # not an int
    ({"telemetry": {"gcs": {"SCALED_IMU": 10}}}, "'telemetry.gcs.SCALED_IMU'"),     # unknown
    ({"control_rate_hz": 0}, "'control_rate_hz'"),
    ({"control_rate_hz": 30}, "'control_rate_hz'"),
    ({"physics_rate_hz": 768}, "'physics_rate_hz'"),            # 1e6 / 768 is not whole us
    ({"log": {"rate_hz": 7}}, "'log.rate_hz'"),
    ({"clock": {"mode": "fast"}}, "'clock.mode'"),
    ({"faults": {"motor_effectiveness": [1.0, 1.0, 1.0]}}, "'faults.motor_effectiveness'"),
    ({"faults": {"motor_effectiveness": [1.0, 1.0, 1.0, 1.5]}}, "'faults.motor_effectiveness'"),
    ({"seed": -1}, "'seed'"),
    ({"wind": {"gusts": {"enabled": 1}}}, "'wind.gusts.enabled'"),
])
def test_sim_errors_via_extends(tmp_path, over, key):
    path = write(tmp_path, "bad_sim.yaml", sim_over(**over))
    assert_config_error(load_sim, path, key)


def test_sim_via_extends_loads(tmp_path):
    path = write(tmp_path, "fast.yaml", sim_over(control_rate_hz=100,
                                                 telemetry={"offboard": {"ODOMETRY": 100}}))
    sim = load_sim(path)
    assert sim.control_rate_hz == 100 and sim.ticks_per_control == 10
    assert sim.link("offboard").rate("ODOMETRY") == 100
    assert sim.link("gcs").rate("ATTITUDE") == 25           # inherited
    assert sim.file == str(path)


def test_sim_missing_key(tmp_path):
    data = yaml.safe_load(SIM_DEFAULT.read_text(encoding="utf-8"))
    data["vehicle"] = str(TRQ_YAML)
    del data["ground"]["crash_speed_m_s"]
    path = write(tmp_path, "no_crash.yaml", data)
    assert_config_error(load_sim, path, "missing", "'ground.crash_speed_m_s'")


def test_extends_cycle(tmp_path):
    write(tmp_path, "a.yaml", {"extends": "b.yaml", "name": "a"})
    b = write(tmp_path, "b.yaml", {"extends": "a.yaml", "name": "b"})
    assert_config_error(load_vehicle, b, "'extends'", "cycle")


def test_extends_self(tmp_path):
    path = write(tmp_path, "self.yaml", {"extends": "self.yaml"})
    assert_config_error(load_vehicle, path, "'extends'", "cycle")


def test_extends_not_a_string_and_missing_file(tmp_path):
    path = write(tmp_path, "num.yaml", {"extends": 3})
    assert_config_error(load_vehicle, path, "'extends'")
    path = write(tmp_path, "ghost.yaml", {"extends": "ghost_base.yaml"})
    with pytest.raises(ConfigError, match="ghost_base.yaml"):
        load_vehicle(path)


def test_not_yaml_and_not_a_mapping(tmp_path):
    bad = tmp_path / "broken.yaml"
    bad.write_text("mass_kg: [1, 2\n", encoding="utf-8")
    assert_config_error(load_vehicle, bad, "not valid YAML")
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n", encoding="utf-8")
    assert_config_error(load_vehicle, listy, "mapping")


def test_config_error_is_a_value_error():
    assert issubclass(ConfigError, ValueError)


def test_inherited_vehicle_path_is_relative_to_the_file_that_names_it(tmp_path):
    # default.yaml says `vehicle: ../vehicle/trq.yaml`, meant relative to params/sim/; a settings
    # file elsewhere that only extends it must still get trq.yaml
    path = write(tmp_path, "scenario.yaml", {"extends": str(SIM_DEFAULT), "seed": 7})
    sim = load_sim(path)
    assert sim.vehicle.name == "trq" and sim.seed == 7


def test_landing_gear_errors_name_the_key(tmp_path):
    data = trq_copy()
    data["landing_gear"]["points"] = data["landing_gear"]["points"][:2]        # cannot stand
    assert_config_error(load_vehicle, write(tmp_path, "two_feet.yaml", data),
                        "'landing_gear.points'", "3 to 8")
    data = trq_copy()
    for p in data["landing_gear"]["points"]:
        p["x_m"] = abs(p["x_m"]) + 0.05                                     # all in front
    assert_config_error(load_vehicle, write(tmp_path, "ahead.yaml", data),
                        "'landing_gear.points'", "around the centre of mass")
    data = trq_copy()
    data["landing_gear"]["stick_stiffness_N_m"] = -1.0
    assert_config_error(load_vehicle, write(tmp_path, "negative.yaml", data),
                        "'landing_gear.stick_stiffness_N_m'")


def test_landing_gear_derived_figures(trq):
    assert trq.tip_over_rad == pytest.approx(math.atan2(0.12, 0.10))
    g = trq.gear
    # at rest level the lowest points carry the weight: compression m g / (n k) below them
    assert g.ground_down_m == pytest.approx(0.10 - 2.1 * 9.80665 / (4 * 8000.0))
    assert g.reach_down_m < 0.0 < g.ground_down_m
