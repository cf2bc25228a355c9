"""The sensor models' statistics against their figures (sil_vehicle.sensors), each over many
samples from a seeded generator, with the tolerance stated beside each check: white noise std =
density * sqrt(rate), a bias random walk's variance growing linearly with time, a Gauss-Markov
process's stationary std and its correlation, the gravity an accelerometer at rest reads."""

from __future__ import annotations

import math
from pathlib import Path
from dataclasses import replace
from types import SimpleNamespace as R

import numpy as np
import pytest

import sil_vehicle.sensors as pkg
from sil_vehicle.sensors import baro, delay, gnss, imu, mag, mocap, noise
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2, Truth, specific_force_frd

G = STANDARD_GRAVITY_M_S2
REST = Truth.at_rest()


def imu_params(**over) -> imu.ImuParams:
    base = dict(rate_hz=1000, gyro_noise_density_rad_s_rthz=0.0,
                gyro_bias_random_walk_rad_s2_rthz=0.0, gyro_turn_on_bias_rad_s=0.0,
                accel_noise_density_m_s2_rthz=0.0,
                accel_bias_random_walk_m_s3_rthz=0.0, accel_turn_on_bias_m_s2=0.0)
    return imu.ImuParams(**(base | over))


def run_imu(p: imu.ImuParams, n: int, truth: Truth = REST, seed: int = 1):
    rng = np.random.default_rng(seed)
    s = imu.initial(p, rng)
    gyro, accel = np.empty((n, 3)), np.empty((n, 3))
    for k in range(n):
        s, r = imu.step(p, s, truth, imu.draw(rng))
        gyro[k], accel[k] = r.gyro_frd_rad_s, r.accel_frd_m_s2
    return gyro, accel


def test_discretisation_formulas():
    assert noise.white_std(2e-3, 400) == pytest.approx(2e-3 * 20.0)
    assert noise.random_walk_std(3e-4, 0.01) == pytest.approx(3e-5)
    a, b = noise.markov_coefficients(2.0, 10.0, 0.1)
    assert a == pytest.approx(math.exp(-0.01))
    assert b == pytest.approx(2.0 * math.sqrt(1 - a * a))
    assert b * b / (1 - a * a) == pytest.approx(4.0)     # stationary variance sigma^2 exactly


def test_imu_white_noise_std_is_density_times_sqrt_rate():
    """20 000 samples x 3 axes: the sample std is within 2 % (its own spread is about 0.3 %)."""
    p = imu_params(gyro_noise_density_rad_s_rthz=1.8665e-4, accel_noise_density_m_s2_rthz=1.86e-3)
    gyro, accel = run_imu(p, 20_000)
    assert np.std(gyro) == pytest.approx(1.8665e-4 * math.sqrt(1000), rel=0.02)
    assert np.std(accel - REST.specific_force_frd_m_s2) == pytest.approx(
        1.86e-3 * math.sqrt(1000), rel=0.02)
    assert np.all(np.abs(np.mean(gyro, axis=0)) < 5 * p.gyro_white_rad_s / math.sqrt(20_000))


def test_imu_bias_random_walk_variance_grows_linearly():
    """One walk of 60 000 samples: the variance of its increments over n samples is n * rw^2 * dt,
    for n = 1, 10, 100 (non-overlapping increments; tolerance 5 %, 10 %, 25 % for their number)."""
    rw = 3.9e-5
    p = imu_params(rate_hz=1000, gyro_bias_random_walk_rad_s2_rthz=rw)
    gyro, _ = run_imu(p, 60_000)
    step_var = rw * rw / 1000
    for n, tol in ((1, 0.05), (10, 0.10), (100, 0.25)):
        inc = gyro[n::n] - gyro[:-n:n]
        assert np.var(inc) == pytest.approx(n * step_var, rel=tol), n


def test_imu_turn_on_bias_is_drawn_once_with_its_sigma():
    """500 IMUs started from one seed each: the turn-on biases' std within 10 %, and a bias
    holds still when there is no random walk."""
    p = imu_params(gyro_turn_on_bias_rad_s=0.0087, accel_turn_on_bias_m_s2=0.196)
    rng = np.random.default_rng(3)
    biases = np.array([imu.initial(p, rng).accel_bias_frd_m_s2 for _ in range(500)])
    assert np.std(biases) == pytest.approx(0.196, rel=0.10)
    gyro, _ = run_imu(p, 50)
    assert np.all(gyro == gyro[0]) and np.any(gyro[0] != 0.0)


def test_level_vehicle_at_rest_reads_minus_g_on_body_z():
    assert np.array_equal(REST.specific_force_frd_m_s2, [0.0, 0.0, -G])
    _, accel = run_imu(imu_params(), 10)
    assert np.array_equal(accel, np.tile([0.0, 0.0, -G], (10, 1)))
    # with the built-in profile's noise and biases: the mean is -g on z within the turn-on bias
    _, accel = run_imu(replace(load_sensing("gnss", 1000).imu, vibration=None), 2000)
    assert np.all(np.abs(accel.mean(axis=0) - [0.0, 0.0, -G]) < 5 * 0.196)
    # rolled 90 degrees right wing down: body y points down, so the upward reading is along -y
    q = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)
    assert np.allclose(specific_force_frd(np.array(q), np.zeros(3), G), [0.0, -G, 0.0])


def test_gauss_markov_stationary_std_and_correlation():
    """50 000 samples with tau = 10 samples: std within 5 %, lag-1 correlation within 0.01 of
    exp(-dt / tau)."""
    a, b = noise.markov_coefficients(1.5, 0.1, 0.01)
    rng = np.random.default_rng(5)
    x, out = 1.5 * rng.standard_normal(), np.empty(50_000)
    for k, w in enumerate(rng.standard_normal(50_000)):
        out[k] = x
        x = a * x + b * w
    assert np.std(out) == pytest.approx(1.5, rel=0.05)
    assert np.corrcoef(out[1:], out[:-1])[0, 1] == pytest.approx(a, abs=0.01)


def gnss_params(**over) -> gnss.GnssParams:
    base = dict(rate_hz=10, delay_ticks=0, dt_us=1000, fix_type=6, satellites=20,
                position_white_h_m=0.0, position_white_v_m=0.0, position_markov_h_m=0.0,
                position_markov_v_m=0.0, position_markov_tau_s=1.0, velocity_white_h_m_s=0.0,
                velocity_white_v_m_s=0.0)
    return gnss.GnssParams(**(base | over))


def test_gnss_error_std_matches_its_accuracy_fields():
    """20 000 samples, tau = 10 samples: each axis's error std within 8 % of eph (north, east)
    and epv (down), which are sqrt(markov^2 + white^2)."""
    p = gnss_params(position_markov_h_m=2.0, position_markov_v_m=4.0, position_white_h_m=0.5,
                    position_white_v_m=1.0, velocity_white_h_m_s=0.05, velocity_white_v_m_s=0.1)
    rng = np.random.default_rng(7)
    s = gnss.initial(p, rng)
    pos, vel = np.empty((20_000, 3)), np.empty((20_000, 3))
    for k in range(20_000):
        s = gnss.sample(p, s, Truth.at_rest(k * 100_000), gnss.draw(rng))
        s, (r,) = gnss.release(s, k * 100_000)
        pos[k], vel[k] = r.pos_ned_m, r.vel_ned_m_s
    assert r.eph_m == pytest.approx(math.hypot(2.0, 0.5))
    assert r.epv_m == pytest.approx(math.hypot(4.0, 1.0))
    assert np.std(pos, axis=0) == pytest.approx([r.eph_m, r.eph_m, r.epv_m], rel=0.08)
    assert np.std(vel, axis=0) == pytest.approx([0.05, 0.05, 0.1], rel=0.03)


def test_baro_noise_and_drift():
    """Noise only: the altitude's std is noise_m (3 %); the pressure is the ISA pressure of the
    altitude above the home's; a drift alone has its stationary std (10 %, tau = 20 samples)."""
    p = baro.BaroParams(rate_hz=50, noise_m=0.2, drift_sigma_m=0.0, drift_tau_s=1.0,
                        home_alt_m=30.0)
    rng = np.random.default_rng(9)
    s = baro.initial(p, rng)
    up5 = Truth.of(0, (0.0, 0.0, -5.0), (0.0,) * 3, (1.0, 0.0, 0.0, 0.0), (0.0,) * 3,
                   (0.0, 0.0, -G), (0.0,) * 4)
    alts = []
    for _ in range(10_000):
        s, r = baro.step(p, s, up5, baro.draw(rng))
        alts.append(r.pressure_alt_m)
    assert np.mean(alts) == pytest.approx(35.0, abs=0.02)
    assert np.std(alts) == pytest.approx(0.2, rel=0.03)
    assert r.pressure_pa == pytest.approx(baro.isa_pressure_pa(r.pressure_alt_m))
    assert baro.isa_pressure_pa(0.0) == 101_325.0 and 101_325.0 - baro.isa_pressure_pa(35.0) \
        == pytest.approx(35.0 * 1.225 * 9.80665, rel=0.01)
    p = baro.BaroParams(rate_hz=50, noise_m=0.0, drift_sigma_m=0.5, drift_tau_s=0.4)
    s = baro.initial(p, rng)
    alts = []
    for _ in range(40_000):
        s, r = baro.step(p, s, REST, baro.draw(rng))
        alts.append(r.pressure_alt_m)
    assert np.std(alts) == pytest.approx(0.5, rel=0.10)


def test_mag_reads_the_earth_field_in_body_axes():
    p = mag.MagParams(rate_hz=100, field_gauss=0.49, declination_rad=math.radians(1.0),
                      inclination_rad=math.radians(66.0), noise_density_gauss_rthz=4e-4,
                      bias_random_walk_gauss_s_rthz=0.0, turn_on_bias_gauss=0.0)
    m_ned = p.field_ned_gauss
    assert np.linalg.norm(m_ned) == pytest.approx(0.49)
    assert m_ned[2] > 0 and math.degrees(math.atan2(m_ned[1], m_ned[0])) == pytest.approx(1.0)
    rng = np.random.default_rng(11)
    s = mag.initial(p, rng)
    yaw90 = Truth.at_rest(quat_wxyz=(math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)))
    out = []
    for _ in range(20_000):
        s, r = mag.step(p, s, yaw90, mag.draw(rng))
        out.append(r.field_frd_gauss)
    out = np.array(out)
    # facing east: north lies to the left (-y), east ahead (+x)
    assert out.mean(axis=0) == pytest.approx([m_ned[1], -m_ned[0], m_ned[2]], abs=1e-4)
    assert np.std(out - out.mean(axis=0)) == pytest.approx(4e-4 * 10.0, rel=0.02)


def test_mocap_noise_and_dropout_rate():
    """10 000 samples: the dropout fraction within 10 % of 0.2 (its spread is 2 %); position
    noise std within 3 %; the quaternions stay unit and close to the truth."""
    p = mocap.MocapParams(rate_hz=100, latency_ticks=0, dt_us=1000, position_noise_m=5e-4,
                          attitude_noise_rad=2e-3, dropout_probability=0.2)
    rng = np.random.default_rng(13)
    s, pos, quats = mocap.initial(p, rng), [], []
    for k in range(10_000):
        t = k * 10_000
        s = mocap.sample(p, s, Truth.at_rest(t), mocap.draw(rng))
        s, out = mocap.release(s, t)
        pos += [r.pos_ned_m for r in out]
        quats += [r.quat_wxyz for r in out]
    assert 1 - len(pos) / 10_000 == pytest.approx(0.2, rel=0.10)
    assert np.std(pos) == pytest.approx(5e-4, rel=0.03)
    quats = np.array(quats)
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0)
    angle = 2 * np.arccos(np.clip(quats[:, 0], -1, 1))
    assert np.sqrt(np.mean(angle ** 2)) == pytest.approx(2e-3 * math.sqrt(3), rel=0.05)


def test_mocap_scripted_windows_drop_exactly_their_samples():
    p = mocap.MocapParams(rate_hz=100, latency_ticks=0, dt_us=1000, position_noise_m=0.0,
                          attitude_noise_rad=0.0, dropout_probability=0.0,
                          dropout_windows_us=((100_000, 150_000),))
    rng = np.random.default_rng(0)
    s, got = mocap.initial(p, rng), []
    for k in range(30):
        t = k * 10_000
        s = mocap.sample(p, s, Truth.at_rest(t), mocap.draw(rng))
        s, out = mocap.release(s, t)
        got += [r.t_us for r in out]
    assert got == [k * 10_000 for k in range(30) if not 10 <= k < 15]


def test_delay_line_releases_in_order_and_refuses_to_overflow():
    assert delay.capacity(120, 200) == 1 and delay.capacity(110, 100) == 2
    line = delay.push(delay.push((), R(arrival_us=5), 2), R(arrival_us=9), 2)
    with pytest.raises(RuntimeError, match="delay line full"):
        delay.push(line, R(arrival_us=12), 2)
    rest, out = delay.release(line, 8)
    assert [r.arrival_us for r in out] == [5] and [r.arrival_us for r in rest] == [9]
    assert delay.release(rest, 8) == (rest, ())


def test_the_package_map_names_every_module():
    """sil_vehicle.sensors' docstring lists each of its modules as `    name      what it is`."""
    modules = {p.stem for p in Path(pkg.__file__).parent.glob("*.py")} - {"__init__"}
    named = {line.split()[0] for line in pkg.__doc__.splitlines()
             if line.startswith("    ") and not line.startswith("     ")}
    assert modules == named


def test_a_block_of_normals_is_the_stream_of_one_draw_per_sample():
    """What the suite's blocks rely on: a (K, n) draw gives the numbers of K draws of n, in
    order, and leaves the generator where they would."""
    for n in (imu.NOISE, baro.NOISE, mag.NOISE, gnss.NOISE):
        a, b = np.random.default_rng(21), np.random.default_rng(21)
        block = a.standard_normal((300, n))
        assert block.tobytes() == np.array([b.standard_normal(n) for _ in range(300)]).tobytes()
        assert a.standard_normal() == b.standard_normal()


def test_mocap_draw_is_six_normals_then_a_uniform():
    a, b = np.random.default_rng(22), np.random.default_rng(22)
    for _ in range(200):
        assert mocap.draw(a).tobytes() == np.concatenate(
            (b.standard_normal(6), b.random(1))).tobytes()


def test_imu_noise_block_equals_one_step_per_sample():
    """imu.noise_block's whole-block arithmetic (the bias walk by np.add.accumulate) against
    the model's equations one tick at a time in NumPy, bit for bit."""
    p = load_sensing("gnss", 1000).imu
    rng = np.random.default_rng(24)
    s0 = imu.initial(p, rng)
    w = rng.standard_normal((500, imu.NOISE))
    adds, bias = imu.noise_block(p, s0, w)
    bg, ba = s0.gyro_bias_frd_rad_s, s0.accel_bias_frd_m_s2
    for k in range(500):
        expected = np.concatenate((bg + p.gyro_white_rad_s * w[k, 0:3],
                                   ba + p.accel_white_m_s2 * w[k, 3:6]))
        assert adds[k].tobytes() == expected.tobytes()
        bg = bg + p.gyro_bias_step_rad_s * w[k, 6:9]
        ba = ba + p.accel_bias_step_m_s2 * w[k, 9:12]
    assert bias[-1, :3].tobytes() == bg.tobytes() and bias[-1, 3:].tobytes() == ba.tobytes()


def test_perturb_quat_is_the_norm_formulation():
    """noise.perturb_quat's spelled-out norms against np.linalg.norm, bit for bit."""
    rng = np.random.default_rng(26)
    for _ in range(2000):
        q = rng.standard_normal(4)
        q = q / np.linalg.norm(q)
        angle = 2e-3 * rng.standard_normal(3)
        theta = float(np.linalg.norm(angle))
        s = math.sin(theta / 2) / theta
        dw, dx, dy, dz = math.cos(theta / 2), *(s * angle)
        w, x, y, z = q
        e = np.array((w * dw - x * dx - y * dy - z * dz, w * dx + x * dw + y * dz - z * dy,
                      w * dy - x * dz + y * dw + z * dx, w * dz + x * dy - y * dx + z * dw))
        e = e / np.linalg.norm(e)
        assert noise.perturb_quat(tuple(q.tolist()), angle).tobytes() == e.tobytes()
