"""Sensing profiles: which sensors the vehicle carries and their figures, loaded from
`params/sensing/*.yaml` (built-in files found by name: truth, mocap, rtk, gnss) into frozen
records of the sensor modules.

    load_sensing("mocap", 1000)            the built-in profile, for a 1 kHz physics tick
    load_sensing("my/sensing.yaml", 1000)  a user's file (it may `extends: builtin:sensing/rtk`)

The file is validated by `trq_params.loader` against `trq_params.schema.SensingFile`,
with the physics rate passed as context, so every bad value is a `ConfigError` naming the file,
the key, the value and what was expected: a negative noise density, a rate that does not divide
the physics rate, a delay beyond the estimator's buffer (DELAY_BUFFER_MS) or not a whole number
of ticks. An unknown profile name is `trq_params.UnknownName` (a ConfigError) listing the names
that exist. Units are converted here (degrees to radians, milliseconds to ticks).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import trq_params
from trq_params import loader
from trq_params.schema import DELAY_BUFFER_MS, Ekf2, SensingFile

from sil_vehicle.sensors.baro import BaroParams
from sil_vehicle.sensors.gnss import GnssParams
from sil_vehicle.sensors.imu import ImuHarmonic, ImuParams, ImuVibration
from sil_vehicle.sensors.mag import MagParams
from sil_vehicle.sensors.mocap import MocapParams

__all__ = ["SensingProfile", "load_sensing", "DELAY_BUFFER_MS"]


@dataclass(frozen=True)
class SensingProfile:
    name: str
    file: str
    physics_rate_hz: int
    imu: ImuParams | None
    baro: BaroParams | None
    mag: MagParams | None
    gnss: GnssParams | None
    mocap: MocapParams | None
    # the vehicle's estimator's tuning (the file's `estimator:`; PX4's EKF2 defaults when left
    # out): read by sil_vehicle.estimator.params, never by a sensor model
    estimator: Ekf2 = Ekf2()

    @property
    def dt_us(self) -> int:
        return 1_000_000 // self.physics_rate_hz

    @property
    def is_truth(self) -> bool:
        """No sensor at all: the vehicle keeps its truth-plus-noise state stream."""
        return not any((self.imu, self.baro, self.mag, self.gnss, self.mocap))


def load_sensing(name_or_path: str | Path, physics_rate_hz: int) -> SensingProfile:
    """A sensing profile by built-in name or path, checked against `physics_rate_hz`."""
    if isinstance(physics_rate_hz, bool) or not isinstance(physics_rate_hz, int) \
            or physics_rate_hz <= 0 or 1_000_000 % physics_rate_hz:
        raise ValueError(f"physics_rate_hz: got {physics_rate_hz!r}, expected a rate in Hz "
                         "whose period is a whole microsecond")
    path = trq_params.resolve("sensing", name_or_path)
    f = loader.load(path, SensingFile, context={"physics_rate_hz": physics_rate_hz})
    dt_us = 1_000_000 // physics_rate_hz
    ticks = lambda ms: ms * 1000 // dt_us          # noqa: E731  (whole: checked by the schema)
    imu = baro = mag = gnss = mocap = None
    if f.imu is not None:
        d = f.imu.model_dump(exclude={"vibration"})
        v = f.imu.vibration
        vibration = None if v is None else ImuVibration(
            tuple(ImuHarmonic(h.of, h.times, tuple(h.accel_m_s2), tuple(h.gyro_rad_s))
                  for h in v.harmonics), v.smear_hz)
        imu = ImuParams(physics_rate_hz=physics_rate_hz, vibration=vibration, **d)
    if f.baro is not None:
        baro = BaroParams(**f.baro.model_dump())
    if f.mag is not None:
        m = f.mag
        mag = MagParams(m.rate_hz, m.field_gauss, math.radians(m.declination_deg),
                        math.radians(m.inclination_deg), m.noise_density_gauss_rthz,
                        m.bias_random_walk_gauss_s_rthz, m.turn_on_bias_gauss)
    if f.gnss is not None:
        g = f.gnss.model_dump()
        gnss = GnssParams(delay_ticks=ticks(g.pop("delay_ms")), dt_us=dt_us, **g)
    if f.mocap is not None:
        c = f.mocap
        mocap = MocapParams(c.rate_hz, ticks(c.latency_ms), dt_us, c.position_noise_m,
                            c.attitude_noise_rad, c.dropout_probability,
                            tuple((w.start_ms * 1000, w.end_ms * 1000)
                                  for w in c.dropout_windows))
    return SensingProfile(f.name, str(path), physics_rate_hz, imu, baro, mag, gnss, mocap,
                          f.estimator)
