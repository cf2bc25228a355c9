"""The vibration lines' skirts (docs/decisions/2026-12-06-vibration-line-skirts.md): what the
`mocap` IMU reads below 1 Hz at rest in the air, and what the vehicle's filter makes of it in
open loop, with the rotors' speed jitter band-limited (the vehicle's motor time constant, as
shipped), white (time constant 0, the walk before) or without the lines.

    python docs/results/vibration_skirts/skirts.py            # all three, seeds 1 and 3

The IMU: every rotor at the hover's 76.8 %, no white noise or biases, 40 s; the RMS per axis in
0-1 Hz, 1-10 Hz and 100-600 Hz (the lines). The filter: the vehicle held still at 2 m, the
sensors and filter as the vehicle runs them (motors off for the first 2 s, then at 76.8 %),
the estimate's position error RMS per axis from 15 s to 40 s.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sil_vehicle.config import PARAMS_DIR, load_vehicle
from sil_vehicle.estimator.eskf import Eskf
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.suite import SensorSuite
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2 as G, Truth

HOVER_PCT = 76.8
VEHICLE = load_vehicle(PARAMS_DIR / "vehicle" / "trq.yaml")
CASES = {"band-limited (shipped)": (VEHICLE, True),
         "white jitter (before)": (replace(VEHICLE, motor_time_constant_s=0.0), True),
         "no lines": (VEHICLE, False)}


def profile(lines: bool, quiet: bool):
    p = load_sensing("mocap", 1000)
    imu = p.imu if lines else replace(p.imu, vibration=None)
    if quiet:
        imu = replace(imu, gyro_noise_density_rad_s_rthz=0.0, accel_noise_density_m_s2_rthz=0.0,
                      gyro_bias_random_walk_rad_s2_rthz=0.0,
                      accel_bias_random_walk_m_s3_rthz=0.0, gyro_turn_on_bias_rad_s=0.0,
                      accel_turn_on_bias_m_s2=0.0)
    return replace(p, imu=imu)


def truth(t_us: int, motors: float) -> Truth:
    return Truth(t_us, (0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                 (0.0, 0.0, 0.0), (0.0, 0.0, -G), (motors,) * 4)


def imu_bands(vehicle, lines: bool, seed: int) -> np.ndarray:
    suite = SensorSuite(profile(lines, quiet=True), np.random.default_rng(seed), vehicle=vehicle)
    acc = [r.accel for k in range(1, 40_001)
           for r in suite.sample(k * 1000, truth(k * 1000, HOVER_PCT))
           if isinstance(r, ImuReading)]
    a = np.array(acc)[2000:]
    a[:, 2] += G
    f = np.fft.rfftfreq(len(a), 1e-3)
    spec = np.abs(np.fft.rfft(a, axis=0)) * 2 / len(a)
    return np.array([[np.sqrt((spec[(f >= lo) & (f < hi), i] ** 2).sum() / 2) for i in range(3)]
                     for lo, hi in ((0.0, 1.0), (1.0, 10.0), (100.0, 600.0))])


def filter_error(vehicle, lines: bool, seed: int) -> np.ndarray:
    prof = profile(lines, quiet=False)
    suite = SensorSuite(prof, np.random.default_rng([seed, 1]), vehicle=vehicle)
    est = Eskf(EstimatorParams.from_profile(prof))
    err = []
    for k in range(1, 40_001):
        t = k * 1000
        est.step(t, suite.sample(t, truth(t, HOVER_PCT if t >= 2_000_000 else 0.0)))
        if t % 10_000 == 0 and t > 15_000_000:
            err.append(est.output().pos_ned_m - (0.0, 0.0, -2.0))
    return np.sqrt((np.array(err) ** 2).mean(axis=0))


def main() -> None:
    for name, (vehicle, lines) in CASES.items():
        b = imu_bands(vehicle, lines, 3)
        print(f"{name}: the IMU, m/s^2 RMS per axis: 0-1 Hz {np.round(b[0], 4)}, "
              f"1-10 Hz {np.round(b[1], 4)}, the lines {np.round(b[2], 2)}")
        for seed in (1, 2):
            e = filter_error(vehicle, lines, seed)
            print(f"    the filter, seed {seed}: position error RMS per axis "
                  f"{np.round(e * 1e3, 2)} mm")


if __name__ == "__main__":
    main()
