"""Sensing profiles (params/sensing/, sil_vehicle.sensors.profile.load_sensing): the built-in
files load by name and carry their figures; every bad input named in issue 33 is a ConfigError
whose message names the file, the key and the value (and what was expected)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import trq_params
from trq_params import loader
from trq_params.loader import ConfigError
from trq_params.schema import DELAY_BUFFER_MS, SensingFile

from sil_vehicle.sensors.profile import load_sensing

BUILTIN = ("gnss", "mocap", "rtk", "truth")


def overlay(tmp_path: Path, text: str, base: str = "gnss") -> Path:
    path = tmp_path / "sensing.yaml"
    path.write_text(f"extends: builtin:sensing/{base}\n{text}", encoding="utf-8")
    return path


def test_builtin_profiles_by_name():
    assert trq_params.names("sensing") == BUILTIN
    assert trq_params.builtin("sensing", "mocap").name == "mocap.yaml"
    for name in BUILTIN:
        p = load_sensing(name, 1000)
        assert p.name == name and p.physics_rate_hz == 1000 and p.file.endswith(f"{name}.yaml")
    gnss, rtk, mocap = (load_sensing(n, 1000) for n in ("gnss", "rtk", "mocap"))
    assert gnss.imu.gyro_noise_density_rad_s_rthz == 1.8665e-4 and gnss.imu.rate_hz == 1000
    assert (gnss.gnss.rate_hz, gnss.gnss.delay_ticks, gnss.gnss.fix_type) == (5, 120, 3)
    assert (rtk.gnss.rate_hz, rtk.gnss.delay_ticks, rtk.gnss.fix_type) == (10, 110, 6)
    assert rtk.imu == gnss.imu and mocap.gnss is None and mocap.mocap.latency_ticks == 10
    assert mocap.mag.inclination_rad == pytest.approx(math.radians(66.0))
    # another physics rate: the same delay is fewer ticks
    assert load_sensing("gnss", 2000).gnss.delay_ticks == 240


def test_every_figure_has_a_comment():
    """Each key with a number in a built-in profile says where it comes from, on its line or in
    the comment block just above it."""
    for name in BUILTIN:
        lines = trq_params.builtin("sensing", name).read_text(encoding="utf-8").splitlines()
        for i, line in enumerate(lines):
            key, sep, value = line.partition(":")
            value = value.split("#")[0].strip()
            if not sep or not value or not value[0].isdigit() and value[0] != "-":
                continue
            commented = "#" in line or any(lines[j].lstrip().startswith("#")
                                           for j in range(max(0, i - 3), i))
            assert commented, f"{name}.yaml: {line.strip()!r} has no source comment"


def expect_error(path: Path, key: str, value: str, *expected: str, rate: int = 1000) -> None:
    with pytest.raises(ConfigError) as info:
        load_sensing(path, rate)
    msg = str(info.value)
    for part in (str(path), f"'{key}'", value, *expected):
        assert part in msg, f"{part!r} not in {msg!r}"


def test_negative_noise_density(tmp_path):
    path = overlay(tmp_path, "imu:\n  gyro_noise_density_rad_s_rthz: -1.0e-4\n")
    expect_error(path, "imu.gyro_noise_density_rad_s_rthz", "-0.0001", "[0, 1]")


def test_rate_that_does_not_divide_the_physics_rate(tmp_path):
    path = overlay(tmp_path, "mag:\n  rate_hz: 300\n")
    expect_error(path, "mag.rate_hz", "300", "divides the physics rate (1000 Hz)")
    # a rate above the physics rate, and a built-in profile against another physics rate
    expect_error(overlay(tmp_path, "baro:\n  rate_hz: 2000\n"), "baro.rate_hz", "2000", "1000")
    expect_error(trq_params.builtin("sensing", "gnss"), "imu.rate_hz", "1000", "(800 Hz)",
                 rate=800)


def test_delay_beyond_the_filter_buffer(tmp_path):
    path = overlay(tmp_path, f"gnss:\n  delay_ms: {DELAY_BUFFER_MS + 1}\n")
    expect_error(path, "gnss.delay_ms", str(DELAY_BUFFER_MS + 1), f"[0, {DELAY_BUFFER_MS}]",
                 "buffer")
    path = overlay(tmp_path, "mocap:\n  latency_ms: 900\n", base="mocap")
    expect_error(path, "mocap.latency_ms", "900", "buffer")


def test_delay_that_is_not_a_whole_number_of_ticks(tmp_path):
    """At 800 Hz a tick is 1250 us: 121 ms is 96.8 ticks (the IMU is left out: 1 kHz does not
    divide 800 Hz)."""
    path = overlay(tmp_path, "imu: null\ngnss:\n  delay_ms: 121\n")
    expect_error(path, "gnss.delay_ms", "121", "whole number of physics ticks (1250 us)",
                 rate=800)
    assert load_sensing(overlay(tmp_path, "imu: null\n"), 800).gnss.delay_ticks == 96


def test_unknown_profile_name():
    with pytest.raises(trq_params.UnknownName) as info:
        load_sensing("indoor", 1000)
    msg = str(info.value)
    assert "sensing" in msg and "'indoor'" in msg and "gnss, mocap, rtk, truth" in msg
    assert isinstance(info.value, ConfigError)


def test_unknown_and_missing_keys_and_bad_windows(tmp_path):
    path = overlay(tmp_path, "imu:\n  gyro_noise: 0.1\n")
    expect_error(path, "imu.gyro_noise", "0.1", "expected one of rate_hz")
    path = tmp_path / "bare.yaml"
    path.write_text("name: bare\ndescription: no sensors written\nimu: null\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bare.yaml: key 'baro' is missing"):
        load_sensing(path, 1000)
    path = overlay(tmp_path, "mocap:\n  dropout_windows: [{start_ms: 500, end_ms: 100}]\n",
                   base="mocap")
    expect_error(path, "mocap.dropout_windows[0]", "500", "end_ms after start_ms (500)")


def test_a_bad_physics_rate_is_the_caller_s_error():
    with pytest.raises(ValueError, match="physics_rate_hz"):
        load_sensing("gnss", 3000)


def test_the_schema_without_physics_rate_still_bounds_the_delay(tmp_path):
    path = overlay(tmp_path, "gnss:\n  delay_ms: 700\n")
    with pytest.raises(ConfigError, match="gnss.delay_ms"):
        loader.load(path, SensingFile)
    assert loader.load(trq_params.builtin("sensing", "rtk"), SensingFile).gnss.delay_ms == 110
