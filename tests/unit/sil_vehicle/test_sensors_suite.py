"""The sensor suite (sil_vehicle.sensors.suite) in lockstep with a 1 kHz physics tick: each
sensor samples at its rate, a delayed reading arrives exactly its delay in ticks after its time
of validity, the same seed replays bit for bit, and the `truth` profile produces nothing."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np
import pytest

from sil_vehicle.sensors import baro, gnss, imu, mag, mocap
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.suite import SensorSuite
from sil_vehicle.sensors.truth import Truth

DT_US = 1000


def moving(t_us: int) -> Truth:
    """A vehicle flying north at 1 m/s and climbing, turning slowly: position is a function of
    time, so a delayed reading shows which tick it was taken at."""
    t = t_us * 1e-6
    yaw = 0.1 * t
    return Truth.of(t_us, (t, 0.5 * t, -2.0 - 0.2 * t), (1.0, 0.5, -0.2),
                    (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)), (0.0, 0.0, 0.1),
                    (0.0, 0.0, -9.80665), (55.0, 55.0, 55.0, 55.0))


def fly(profile: str, seed: int, ticks: int, **kw):
    suite = SensorSuite(load_sensing(profile, 1000), np.random.default_rng(seed), **kw)
    return [(k * DT_US, suite.sample(k * DT_US, moving(k * DT_US))) for k in range(ticks)]


def of_type(flight, cls):
    return [(t, r) for t, out in flight for r in out if isinstance(r, cls)]


def test_rates_are_honoured():
    """At 1 kHz physics: the 1 kHz IMU reads every tick, the 100 Hz magnetometer every 10th,
    the 50 Hz barometer every 20th."""
    flight = fly("gnss", 1, 1000)
    assert [t for t, _ in of_type(flight, imu.ImuReading)] == [k * DT_US for k in range(1000)]
    assert [t for t, _ in of_type(flight, mag.MagReading)] == \
        [k * DT_US for k in range(0, 1000, 10)]
    assert [t for t, _ in of_type(flight, baro.BaroReading)] == \
        [k * DT_US for k in range(0, 1000, 20)]
    assert all(r.t_us == t for t, r in of_type(flight, imu.ImuReading))


def test_gnss_delay_is_exact_in_ticks():
    """gnss profile: 5 Hz, 120 ms. Each reading arrives on the tick 120 ticks after its time of
    validity, and with the noise switched off it holds the truth of that earlier tick."""
    profile = load_sensing("gnss", 1000)
    quiet = replace(profile.gnss, position_white_h_m=0.0, position_white_v_m=0.0,
                    position_markov_h_m=0.0, position_markov_v_m=0.0,
                    velocity_white_h_m_s=0.0, velocity_white_v_m_s=0.0)
    assert quiet.delay_ticks == 120
    suite = SensorSuite(replace(profile, gnss=quiet), np.random.default_rng(2))
    got = []
    for k in range(1200):
        got += [(k * DT_US, r) for r in suite.sample(k * DT_US, moving(k * DT_US))
                if isinstance(r, gnss.GnssReading)]
    assert [t for t, _ in got] == [t0 + 120 * DT_US for t0 in range(0, 1_080_000, 200_000)]
    for t, r in got:
        assert r.arrival_us == t and r.t_us == t - 120_000
        assert np.array_equal(r.pos_ned_m, moving(r.t_us).pos_ned_m)
        assert (r.fix_type, r.satellites, r.eph_m, r.epv_m) == (3, 10, 0.0, 0.0)   # noise off


def test_mocap_latency_and_rtk_fields():
    flight = fly("mocap", 3, 300)
    poses = of_type(flight, mocap.MocapReading)
    assert all(t == r.t_us + 10_000 and r.t_us % 10_000 == 0 for t, r in poses)
    assert not of_type(flight, gnss.GnssReading)
    rtk = of_type(fly("rtk", 3, 400), gnss.GnssReading)
    assert [t for t, _ in rtk] == [110_000, 210_000, 310_000]
    assert all(r.fix_type == 6 and r.eph_m < 0.02 for _, r in rtk)


def as_bytes(flight) -> list[tuple[int, str, bytes]]:
    """Every field of every reading, as raw bytes (bit-for-bit comparison)."""
    out = []
    for t, readings in flight:
        for r in readings:
            for f in fields(r):
                v = getattr(r, f.name)
                out.append((t, f"{type(r).__name__}.{f.name}",
                            np.asarray(v, dtype=float).tobytes()))
    return out


@pytest.mark.parametrize("profile", ["rtk", "mocap"])
def test_same_seed_same_readings_bit_for_bit(profile):
    a, b = as_bytes(fly(profile, 42, 600)), as_bytes(fly(profile, 42, 600))
    assert len(a) > 600 and a == b
    c = as_bytes(fly(profile, 43, 600))
    assert len(c) > 0 and a != c


def test_states_are_frozen_records():
    suite = SensorSuite(load_sensing("rtk", 1000), np.random.default_rng(1), home_alt_m=30.0)
    assert suite.sensors == ("imu", "baro", "mag", "gnss")
    assert suite.params["baro"].home_alt_m == 30.0
    before = dict(suite.states)
    suite.sample(0, moving(0))
    assert suite.states["imu"] is not before["imu"]
    with pytest.raises(Exception):
        suite.states["imu"].gyro_bias_frd_rad_s = None


def test_truth_profile_produces_nothing():
    profile = load_sensing("truth", 1000)
    assert profile.is_truth
    suite = SensorSuite(profile, np.random.default_rng(1))
    assert suite.sensors == () and all(not out for _, out in
                                       [(k, suite.sample(k * DT_US, moving(k * DT_US)))
                                        for k in range(50)])


def test_sample_refuses_a_time_off_the_tick_or_off_the_truth():
    suite = SensorSuite(load_sensing("gnss", 1000), np.random.default_rng(1))
    with pytest.raises(ValueError, match="physics tick"):
        suite.sample(500, moving(500))
    with pytest.raises(ValueError, match="truth.t_us"):
        suite.sample(1000, moving(2000))


def test_a_sensor_s_noise_does_not_depend_on_the_others():
    """rtk and mocap carry the same IMU: from one seed, its readings are the same in both."""
    def imu_bytes(profile):
        return [r for r in as_bytes(fly(profile, 5, 200)) if r[1].startswith("ImuReading")]
    assert imu_bytes("rtk") == imu_bytes("mocap")


def quiet(profile: str):
    """The built-in profile without the IMU's vibration (whose lines the one-sample functions
    do not compute): what the block equivalence below compares."""
    prof = load_sensing(profile, 1000)
    return replace(prof, imu=replace(prof.imu, vibration=None))


def per_sample(profile: str, seed: int, ticks: int, **kw):
    """The suite's contract spelled out with the models' one-sample functions: each sensor's
    child generator, one `draw` per sample, `step` / `sample` / `release` per tick. The suite
    draws its noise in blocks and precomputes the IMU's; this is what it must equal."""
    prof = quiet(profile)
    home = kw.get("home_alt_m", 0.0)
    names = ("imu", "baro", "mag", "gnss", "mocap")
    rngs = dict(zip(names, np.random.default_rng(seed).spawn(5)))
    mods = dict(zip(names, (imu, baro, mag, gnss, mocap)))
    params = {n: getattr(prof, n) for n in names if getattr(prof, n) is not None}
    if "baro" in params:
        params["baro"] = replace(params["baro"], home_alt_m=home)
    states = {n: mods[n].initial(params[n], rngs[n]) for n in names if n in params}
    flight = []
    for k in range(ticks):
        t, truth, out = k * DT_US, moving(k * DT_US), []
        for n in ("imu", "baro", "mag"):
            if n in params and t % params[n].period_us == 0:
                states[n], r = mods[n].step(params[n], states[n], truth, mods[n].draw(rngs[n]))
                out.append(r)
        for n in ("gnss", "mocap"):
            if n in params:
                if t % params[n].period_us == 0:
                    states[n] = mods[n].sample(params[n], states[n], truth,
                                               mods[n].draw(rngs[n]))
                states[n], arrived = mods[n].release(states[n], t)
                out.extend(arrived)
        flight.append((t, out))
    return flight, states


def state_bytes(states) -> dict[str, list[bytes]]:
    return {n: [np.asarray(getattr(s, f.name), dtype=float).tobytes() for f in fields(s)
                if f.name != "pending"] for n, s in states.items()}


@pytest.mark.parametrize("profile", ["mocap", "rtk", "gnss"])
def test_blocks_equal_one_draw_per_sample_bit_for_bit(profile):
    """2500 ticks (the IMU's noise crosses two block boundaries): every reading and the final
    state of every sensor as the one-sample functions give them."""
    ticks = 2500
    expected, states = per_sample(profile, 11, ticks, home_alt_m=30.0)
    suite = SensorSuite(quiet(profile), np.random.default_rng(11), home_alt_m=30.0)
    got = [(k * DT_US, suite.sample(k * DT_US, moving(k * DT_US))) for k in range(ticks)]
    assert as_bytes(got) == as_bytes(expected) and len(as_bytes(got)) > ticks
    assert state_bytes(dict(suite.states)) == state_bytes(states)


def test_an_assigned_imu_state_holds_from_the_next_sample():
    """Assigning suite.states["imu"] mid-block: the next readings continue from it, with the
    noise the block had left (as if the state had been set between one-sample steps)."""
    bias = imu.ImuState(np.array((0.01, -0.02, 0.03)), np.array((0.2, -0.1, 0.05)))
    suite = SensorSuite(quiet("mocap"), np.random.default_rng(4))
    prof = quiet("mocap")
    rng = np.random.default_rng(4).spawn(5)[0]
    s = imu.initial(prof.imu, rng)
    for k in range(300):
        suite.sample(k * DT_US, moving(k * DT_US))
        s, _ = imu.step(prof.imu, s, moving(k * DT_US), imu.draw(rng))
    suite.states["imu"] = bias
    assert np.array_equal(suite.states["imu"].gyro_bias_frd_rad_s, bias.gyro_bias_frd_rad_s)
    s = bias
    for k in range(300, 1500):
        (r, *_), truth = suite.sample(k * DT_US, moving(k * DT_US)), moving(k * DT_US)
        s, expected = imu.step(prof.imu, s, truth, imu.draw(rng))
        assert r == expected


def test_an_imu_state_assigned_before_the_first_sample_is_its_start():
    """A test's way to fix the biases (states["imu"] set on a fresh suite): the readings are the
    one-sample model's from that state with the IMU's own stream after its turn-on draw."""
    bias = imu.ImuState(np.array((0.012, -0.02, 0.015)), np.array((0.25, -0.3, 0.2)))
    prof = quiet("mocap")
    suite = SensorSuite(prof, np.random.default_rng(6))
    suite.states["imu"] = bias
    rng = np.random.default_rng(6).spawn(5)[0]
    imu.initial(prof.imu, rng)
    s = bias
    for k in range(1200):
        truth = moving(k * DT_US)
        (r, *_), (s, expected) = suite.sample(k * DT_US, truth), imu.step(prof.imu, s, truth,
                                                                           imu.draw(rng))
        assert r == expected


def test_an_assigned_delay_line_is_released_when_due():
    """states["mocap"] set with a reading in flight: it arrives at its arrival time."""
    suite = SensorSuite(load_sensing("mocap", 1000), np.random.default_rng(8))
    for k in range(5):
        suite.sample(k * DT_US, moving(k * DT_US))
    flying = mocap.MocapReading(4_000, 7_000, np.zeros(3), np.array((1.0, 0.0, 0.0, 0.0)))
    suite.states["mocap"] = mocap.MocapState((flying,))
    got = {k: [r for r in suite.sample(k * DT_US, moving(k * DT_US))
               if isinstance(r, mocap.MocapReading)] for k in range(5, 9)}
    assert got == {5: [], 6: [], 7: [flying], 8: []}
