"""The IMU as an airframe gives it (sil_vehicle.sensors.imu through the suite): rotor harmonics
at their frequencies and, above the output rate's Nyquist frequency, at their aliases with the
chip's attenuation; full scales with per-axis clip flags and counts; delta angle and velocity
over each output interval equal to the integral of the truth at every rate the schema allows;
jittered stamps and missing samples seeded and reproducible; the profile's bad values refused
with the file and the key."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from trq_params.loader import ConfigError

from sil_vehicle.config import PARAMS_DIR, load_vehicle
from sil_vehicle.sensors import imu
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.suite import SensorSuite
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2, Truth

G = STANDARD_GRAVITY_M_S2
VEHICLE = load_vehicle(PARAMS_DIR / "vehicle" / "trq.yaml")
ROTOR = imu.RotorModel.of_vehicle(VEHICLE)


def quiet_imu(**over) -> imu.ImuParams:
    """The built-in IMU without noise, biases or vibration, then `over`."""
    p = load_sensing("mocap", 1000).imu
    quiet = dict(gyro_noise_density_rad_s_rthz=0.0, gyro_bias_random_walk_rad_s2_rthz=0.0,
                 gyro_turn_on_bias_rad_s=0.0, accel_noise_density_m_s2_rthz=0.0,
                 accel_bias_random_walk_m_s3_rthz=0.0, accel_turn_on_bias_m_s2=0.0,
                 vibration=None)
    return replace(p, **(quiet | over))


def suite_of(p: imu.ImuParams, seed: int = 1, vehicle=VEHICLE) -> SensorSuite:
    prof = load_sensing("mocap", 1000)
    prof = replace(prof, imu=p, baro=None, mag=None, mocap=None)
    return SensorSuite(prof, np.random.default_rng(seed), vehicle=vehicle)


def hover(t_us: int, motor_pct: float, rates=(0.0, 0.0, 0.0), force=(0.0, 0.0, -G),
          motors: int = 4) -> Truth:
    """The vehicle level and still; `motors` of its rotors at motor_pct, the rest stopped."""
    return Truth.of(t_us, (0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), rates, force,
                    (motor_pct,) * motors + (0.0,) * (4 - motors))


def readings(suite: SensorSuite, ticks: int, truth_at) -> list[imu.ImuReading]:
    out = []
    for k in range(ticks):
        out += [r for r in suite.sample(k * 1000, truth_at(k * 1000))
                if isinstance(r, imu.ImuReading)]
    return out


def one_line(of: str, times: int, accel: float) -> imu.ImuVibration:
    return imu.ImuVibration((imu.ImuHarmonic(of, times, (accel, 0.0, 0.0), (0.0, 0.0, 0.0)),),
                            smear_hz=0.0)


def line_of(x: np.ndarray, rate_hz: float) -> tuple[float, float]:
    """(frequency, amplitude) of the strongest line of `x`: its frequency from the spectrum's
    peak (Hann window, to a bin), its amplitude from a least-squares sinusoid at that frequency
    refined on a fine grid around it (exact for a steady line)."""
    x = x - x.mean()
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    k = int(np.argmax(spec[1:])) + 1
    t = np.arange(len(x)) / rate_hz
    best = (0.0, 0.0)
    for f in np.linspace((k - 1) * rate_hz / len(x), (k + 1) * rate_hz / len(x), 81):
        basis = np.stack((np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)), axis=1)
        coef = np.linalg.lstsq(basis, x, rcond=None)[0]
        amp = float(np.hypot(*coef))
        if amp > best[1]:
            best = (float(f), amp)
    return best


@pytest.mark.parametrize("of,times,rate_hz", [("rotor", 1, 1000), ("blade_pass", 1, 1000),
                                              ("blade_pass", 2, 1000), ("blade_pass", 2, 500),
                                              ("blade_pass", 1, 200)])
def test_a_harmonic_shows_at_its_frequency_or_its_alias_attenuated_by_the_chip(of, times,
                                                                               rate_hz):
    """One rotor at full throttle (max_rad_s, 159 Hz), the others stopped: one line at times x the rotor or blade-pass
    frequency. Its strongest spectral line is at the frequency folded into the output band
    (within a bin), and its amplitude is the line's times the chip's response |G(f)| times the
    output interval's averaging (within 1 %); above the output
    Nyquist frequency (blade pass x2 = 637 Hz at 1 kHz: 363 Hz) it is there only as its alias."""
    amp = 5.0
    p = quiet_imu(vibration=one_line(of, times, amp), rate_hz=rate_hz)
    n = times * (ROTOR.blades if of == "blade_pass" else 1)
    f = n * ROTOR.max_rad_s / (2 * math.pi)
    r = readings(suite_of(p), 4000, lambda t: hover(t, 100.0, motors=1))
    x = np.array([q.accel[0] for q in r])
    assert np.allclose([q.accel[1] for q in r], 0.0)
    got_f, got_a = line_of(x, rate_hz)
    alias = abs(f - rate_hz * round(f / rate_hz))
    assert got_f == pytest.approx(alias, abs=0.05)
    # the output sample averages ticks_per_sample ticks: that boxcar at the physics rate
    m = p.ticks_per_sample
    wt = 2 * math.pi * f / p.physics_rate_hz
    box = abs(np.sum(np.exp(-1j * wt * np.arange(m)))) / m
    expected = amp * abs(imu.response(p, f)) * box
    assert got_a == pytest.approx(expected, rel=0.01)
    assert expected < amp          # the filter and the averaging attenuate every line


def test_the_chip_response_is_its_filter_at_low_frequency_and_falls_above_the_cutoff():
    p = load_sensing("mocap", 1000).imu
    g = np.abs(imu.response(p, [0.0, 10.0, 585.0, 2000.0, 3900.0]))
    assert g[0] == pytest.approx(1.0) and g[1] == pytest.approx(1.0, abs=1e-3)
    # at the cutoff: the Butterworth's -3 dB times the tick's averaging of eight 8 kHz samples
    box = abs(np.mean(np.exp(-2j * math.pi * 585.0 / 8000 * np.arange(8))))
    assert g[2] == pytest.approx(box / math.sqrt(2), rel=1e-6)
    assert g[3] < 0.1 and g[4] < 0.01


def test_vibration_scales_with_rotor_speed_squared_and_is_off_with_the_motors():
    """The line's amplitude is proportional to the thrust fraction (speed squared); idle rotors
    add nothing. One line at 1x rotor, compared at the same frequency's response."""
    p = quiet_imu(vibration=one_line("rotor", 1, 4.0))
    off = readings(suite_of(p), 200, lambda t: hover(t, 0.0))
    assert all(q.accel == (0.0, 0.0, -G) for q in off)
    for pct in (60.0, 100.0):
        frac = float(ROTOR.thrust_fraction([pct])[0])
        f = ROTOR.max_rad_s * math.sqrt(frac) / (2 * math.pi)
        x = np.array([q.accel[0] for q in readings(suite_of(p), 4000,
                                                   lambda t: hover(t, pct, motors=1))])
        got_f, got_a = line_of(x, 1000)
        assert got_f == pytest.approx(f, abs=0.05)
        assert got_a == pytest.approx(4.0 * frac * abs(imu.response(p, f)), rel=0.01)


def test_smear_widens_the_line_and_replays_with_the_seed():
    p = quiet_imu(vibration=replace(one_line("rotor", 1, 4.0), smear_hz=5.0))
    a = [q.accel for q in readings(suite_of(p, 3), 3000, lambda t: hover(t, 100.0))]
    b = [q.accel for q in readings(suite_of(p, 3), 3000, lambda t: hover(t, 100.0))]
    c = [q.accel for q in readings(suite_of(p, 4), 3000, lambda t: hover(t, 100.0))]
    assert a == b and a != c
    sharp = quiet_imu(vibration=one_line("rotor", 1, 4.0))
    x0 = np.array([q.accel[0] for q in readings(suite_of(sharp), 3000, lambda t: hover(t, 100.0))])
    x1 = np.array([q[0] for q in a])
    # the smeared line's peak bin holds less of its power than the sharp one's
    assert line_of(x1, 1000)[1] < 0.9 * line_of(x0, 1000)[1]


def test_the_smeared_line_keeps_its_skirts_away_from_zero_hertz():
    """One rotor line at 124 Hz (hover speed), smeared 1 Hz as the profiles ship it: what
    the accelerometer reads below 2 Hz, where the estimator integrates it into position, is a
    small part of what white speed jitter (a Lorentzian line, the rotor's time constant 0) puts
    there, and under a thousandth of the line; the line itself keeps its size."""
    p = quiet_imu(vibration=replace(one_line("rotor", 1, 4.0), smear_hz=1.0))
    white = replace(VEHICLE, motor_time_constant_s=0.0)
    assert VEHICLE.motor_time_constant_s > 0.0

    def low_and_total(vehicle) -> tuple[float, float]:
        r = readings(suite_of(p, 5, vehicle), 20_000, lambda t: hover(t, 76.8, motors=1))
        x = np.array([q.accel[0] for q in r])
        spec = np.abs(np.fft.rfft(x - x.mean())) ** 2
        f = np.fft.rfftfreq(len(x), 1e-3)
        return math.sqrt(spec[f < 2.0].sum() / spec.sum()), float(x.std())

    band, total = low_and_total(VEHICLE)
    band_white, total_white = low_and_total(white)
    assert band < 1e-3 and band < 0.2 * band_white
    assert total == pytest.approx(total_white, rel=0.05)


def test_full_scale_clips_per_axis_flags_the_reading_and_counts():
    """A gyro x rate beyond 2000 deg/s and an accel z beyond 16 g for 3 ticks (10 to 12 ms; the
    IMU at 500 Hz, two ticks a reading): those axes read
    the full scale and are flagged in the readings whose interval holds them; the counts are
    the clipped ticks per axis; the other axes are untouched."""
    p = quiet_imu(rate_hz=500)
    fs_g, fs_a = math.radians(2000.0), 16 * G
    suite = suite_of(p)

    def truth(t):
        hit = 10_000 <= t < 13_000
        return hover(t, 50.0, rates=(60.0 if hit else 0.1, -0.2, 0.0),
                     force=(1.0, 0.0, -300.0 if hit else -G))
    r = readings(suite, 30, truth)
    hit = [q for q in r if q.gyro_clipped != (False,) * 3]
    assert [q.t_us for q in hit] == [10_000, 12_000]       # ticks 9-10 and 11-12
    assert all(q.gyro_clipped == (True, False, False) for q in hit)
    assert all(q.accel_clipped == (False, False, True) for q in hit)
    # t 12 000 covers ticks 11 000 and 12 000, both clipped: the full scale exactly
    mid = hit[1]
    assert mid.gyro[0] == pytest.approx(fs_g) and mid.accel[2] == pytest.approx(-fs_a)
    assert mid.gyro[1] == pytest.approx(-0.2) and mid.accel[0] == pytest.approx(1.0)
    assert suite.imu_clips == imu.ImuClips(accel=(0, 0, 3), gyro=(3, 0, 0))
    assert all(q.accel_clipped == (False,) * 3 for q in r if q not in hit)


@pytest.mark.parametrize("rate_hz", [1000, 500, 250, 200, 125, 100, 50])
def test_deltas_over_each_interval_integrate_the_truth_at_every_rate(rate_hz):
    """Every divisor of the physics rate the schema allows: the readings' intervals tile time,
    each stamped at its end, and the sum of their delta angles and delta velocities equals the
    integral of the truth's tick rates and forces (each held over its tick)."""
    p = quiet_imu(rate_hz=rate_hz)
    suite = suite_of(p)

    def truth(t):
        s = t * 1e-6
        return hover(t, 50.0, rates=(math.sin(7 * s), 0.3 * s, -0.5),
                     force=(math.cos(3 * s), 0.2, -G + s))
    ticks = 1000
    r = readings(suite, ticks, truth)
    period = 1_000_000 // rate_hz
    assert [q.t_us for q in r] == list(range(0, ticks * 1000, period))
    assert all(q.dt_us == period for q in r[1:])
    # from the first full interval on: ticks after r[0] up to the last reading
    last = r[-1].t_us // 1000
    want_a = sum(np.array(truth(k * 1000).rates) for k in range(1, last + 1)) * 1e-3
    want_v = sum(np.array(truth(k * 1000).force) for k in range(1, last + 1)) * 1e-3
    assert np.allclose(sum(q.delta_angle_frd_rad for q in r[1:]), want_a, rtol=0, atol=1e-12)
    assert np.allclose(sum(q.delta_velocity_frd_m_s for q in r[1:]), want_v, rtol=0, atol=1e-11)


def test_missing_samples_merge_into_the_next_interval_seeded():
    """With dropout_probability 0.2: about a fifth of the samples do not arrive (within 4
    sigma), the next one's dt_us covers the missing ones, the intervals still tile time and
    integrate the truth; the same seed drops the same samples, another seed others."""
    p = quiet_imu(rate_hz=250, dropout_probability=0.2)

    def truth(t):
        return hover(t, 50.0, rates=(0.1 * t * 1e-6, 0.0, 0.0))
    a = readings(suite_of(p, 5), 8000, truth)
    b = readings(suite_of(p, 5), 8000, truth)
    c = readings(suite_of(p, 6), 8000, truth)
    assert a == b and [q.t_us for q in a] != [q.t_us for q in c]
    n = 8000 // 4
    lost = n - len(a)
    assert abs(lost - 0.2 * n) < 4 * math.sqrt(n * 0.2 * 0.8)
    stamps = [q.t_us for q in a]
    assert all(q.dt_us == t1 - t0 for q, t0, t1 in zip(a[1:], stamps, stamps[1:]))
    assert max(q.dt_us for q in a) >= 8000
    total = sum(q.delta_angle_frd_rad[0] for q in a[1:])
    want = sum(0.1 * k * 1e-3 for k in range(stamps[0] // 1000 + 1, stamps[-1] // 1000 + 1)) * 1e-3
    assert total == pytest.approx(want, rel=1e-9)


def test_jittered_stamps_are_seeded_and_dt_follows_them():
    p = quiet_imu(rate_hz=500, timestamp_jitter_us=20.0)
    a = readings(suite_of(p, 7), 4000, lambda t: hover(t, 50.0))
    b = readings(suite_of(p, 7), 4000, lambda t: hover(t, 50.0))
    assert a == b
    err = np.array([q.t_us - k * 2000 for k, q in enumerate(a)])
    assert np.std(err) == pytest.approx(20.0, rel=0.15) and np.all(err == np.round(err))
    assert all(q1.dt_us == q1.t_us - q0.t_us for q0, q1 in zip(a, a[1:]))


def test_without_vibration_jitter_or_dropouts_the_suite_is_the_one_tick_model():
    """The short path (one tick per sample) against imu.step, reading for reading."""
    p = load_sensing("mocap", 1000).imu
    p = replace(p, vibration=None)
    suite = suite_of(p, 9)
    rng = np.random.default_rng(9).spawn(5)[0]
    s = imu.initial(p, rng)
    for k in range(1200):
        t = hover(k * 1000, 50.0, rates=(0.01 * k, 0.0, 0.0))
        (r,) = suite.sample(k * 1000, t)
        s, want = imu.step(p, s, t, imu.draw(rng))
        assert r == want and r.dt_us == 1000


# --- the profile's errors -------------------------------------------------------------------

def overlay(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "sensing.yaml"
    path.write_text(f"extends: builtin:sensing/mocap\n{text}", encoding="utf-8")
    return path


@pytest.mark.parametrize("text,key", [
    ("imu: {internal_rate_hz: 1500}\n", "imu.internal_rate_hz"),
    ("imu: {anti_alias_cutoff_hz: 4000.0}\n", "imu.anti_alias_cutoff_hz"),
    ("imu: {accel_full_scale_g: -16.0}\n", "imu.accel_full_scale_g"),
    ("imu: {dropout_probability: 1.5}\n", "imu.dropout_probability"),
    ("imu: {rate_hz: 300}\n", "imu.rate_hz"),
    ("imu: {accel_vibration_m_s2: 0.3}\n", "imu.accel_vibration_m_s2"),
    ("imu: {vibration: {smear_hz: -1.0}}\n", "imu.vibration.smear_hz"),
    ("imu: {vibration: {harmonics: []}}\n", "imu.vibration.harmonics"),
])
def test_bad_imu_values_name_the_file_and_key(tmp_path, text, key):
    path = overlay(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_sensing(path, 1000)
    assert str(path) in str(info.value) and key in str(info.value)


def test_a_harmonic_beyond_the_internal_rate_is_refused_naming_file_and_key(tmp_path):
    """Blade pass x 8 at full speed (2546 Hz) above a 4 kHz chip's Nyquist frequency (2000 Hz):
    refused when the vehicle is known (the suite), naming the sensing file and the harmonic."""
    path = overlay(tmp_path, "imu:\n  internal_rate_hz: 4000\n  anti_alias_cutoff_hz: 500.0\n"
                             "  vibration:\n    smear_hz: 1.0\n    harmonics:\n"
                             "      - {of: rotor, times: 1, accel_m_s2: [1, 1, 1], "
                             "gyro_rad_s: [0, 0, 0]}\n"
                             "      - {of: blade_pass, times: 8, accel_m_s2: [1, 1, 1], "
                             "gyro_rad_s: [0, 0, 0]}\n")
    prof = load_sensing(path, 1000)
    with pytest.raises(ValueError) as info:
        SensorSuite(prof, np.random.default_rng(1), vehicle=VEHICLE)
    msg = str(info.value)
    assert str(path) in msg and "imu.vibration.harmonics[1]" in msg and "2000" in msg


def test_the_builtin_vibration_is_the_published_figure():
    """The accelerometer's vibration at full speed: 15 m/s^2 RMS per axis (ArduPilot's IRIS
    figure, the profile's comment), from four rotors' three lines."""
    p = load_sensing("gnss", 1000).imu
    assert p.accel_vibration_m_s2 == pytest.approx(15.0, rel=0.01)
    assert (p.accel_full_scale_g, p.gyro_full_scale_deg_s) == (16.0, 2000.0)
    assert [(h.of, h.times) for h in p.vibration.harmonics] == [
        ("rotor", 1), ("blade_pass", 1), ("blade_pass", 2)]


def test_an_imu_state_set_mid_block_with_vibration_holds_and_the_lines_run_on():
    """states["imu"] assigned between two vibration blocks' ticks (tick 1234, not a block
    boundary), with the shipped vibration: the next tick's bias is the assigned one, the
    suite runs on across its noise and vibration blocks, and the same assignment on the same
    seed replays bit for bit."""
    bias = imu.ImuState(np.array((0.01, -0.02, 0.03)), np.array((0.2, -0.1, 0.05)))

    def fly():
        suite = suite_of(load_sensing("mocap", 1000).imu, 12)
        out = readings(suite, 1234, lambda t: hover(t, 70.0))
        suite.states["imu"] = bias
        assert np.array_equal(suite.states["imu"].accel_bias_frd_m_s2, bias.accel_bias_frd_m_s2)
        for k in range(1234, 3100):
            out += [r for r in suite.sample(k * 1000, hover(k * 1000, 70.0))]
        return out
    a, b = fly(), fly()
    assert len(a) == 3100 and a == b
