"""A log's EKF2 parameters as the vehicle's filter's: the schema's `Ekf2` record (PX4's shipped
defaults, trq_params.schema.Ekf2, overridden by the log's own EKF2_* values) through the
vehicle's own builder `EstimatorParams.ekf2`, so the replay runs the filter exactly as a profile
with that `estimator:` section would (the scaling, the reported-accuracy floors, the delays from
arrival and the height reference are the builder's: docs/decisions/2026-12-05-ekf2-defaults.md).

    ekf2 = ekf2_record(log.params, file=log.file)   # Ekf2, PX4's defaults where the log is silent
    params = estimator_params(ekf2, sources)

What the replay adds, the log's facts the schema does not hold:
    - which sensors the log has (`Sources`), the IMU grid's rate, the earth field measured at
      rest (EKF2 takes it from its world magnetic model; the replay from the log, declination
      EKF2_MAG_DECL) and the height at alignment;
    - without a real position source, EKF2's fake position (the origin at rest, EKF2_NOAID_NOISE,
      no delay) on the GNSS channel, the barometer then keeping the height (as EKF2 does when
      unaided);
    - older logs' names: EKF2_HGT_MODE is EKF2_HGT_REF before PX4 v1.14 (the same codes).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from pydantic import ValidationError
from trq_params.schema import EKF2_KEYS, Ekf2

from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.sensors.profile import load_sensing
from trq_lab.reallogs.ulog import LogError

__all__ = ["EXTRA_DEFAULTS", "Sources", "ekf2_record", "extra_values", "estimator_params"]

# the EKF2 parameters the replay reads that the schema's Ekf2 does not hold (PX4's defaults,
# src/modules/ekf2/module.yaml): the declination the measured field is turned by, and the fake
# position's noise when unaided
EXTRA_DEFAULTS: dict[str, float] = {"EKF2_MAG_DECL": 0.0, "EKF2_NOAID_NOISE": 10.0}
_RENAMED = {"EKF2_HGT_MODE": "EKF2_HGT_REF"}     # the older logs' name: the newer one


@dataclass(frozen=True)
class Sources:
    """What the replay feeds the filter, and the figures it takes from the log itself."""
    imu_rate_hz: int
    gnss: bool                  # real fixes; False: EKF2's fake position at rest instead
    baro: bool
    mag: bool
    vision: bool
    mag_field_ned_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    init_pos_d_m: float = 0.0
    mag_declination_rad: float = 0.0


def ekf2_record(log_params: Mapping[str, float], *, file: str = "the log") -> Ekf2:
    """The schema's Ekf2 with the log's own values where it carries them (PX4's defaults
    elsewhere); a value outside the schema's range is a LogError naming the file and key."""
    given = {_RENAMED.get(k, k): v for k, v in log_params.items()}
    values: dict = {}
    for key in EKF2_KEYS:
        if key in given:
            default = Ekf2.model_fields[key].default
            v = given[key]
            values[key] = int(round(v)) if isinstance(default, int) else float(v)
    try:
        return Ekf2(**values)
    except (ValidationError, ValueError) as exc:
        raise LogError(f"{file}: its EKF2 parameters are outside the vehicle's schema "
                       f"(trq_params.schema.Ekf2): {' '.join(str(exc).split())}") from exc


def extra_values(log_params: Mapping[str, float]) -> dict[str, float]:
    """EXTRA_DEFAULTS with the log's own values where it carries them."""
    return {k: float(log_params.get(k, v)) for k, v in EXTRA_DEFAULTS.items()}


def estimator_params(ekf2: Ekf2, src: Sources, *, noaid_noise_m: float = 10.0
                     ) -> EstimatorParams:
    """The vehicle's filter tuned by `ekf2` (EstimatorParams.ekf2) for the sensors of `src`.
    The builder reads of a profile only which sensors it carries and the field's model; the
    profile here is the built-in `gnss` one (IMU, barometer, magnetometer, GNSS) with the
    mocap's section of `mocap`, each set to None where the log lacks the sensor, its own
    figures unused. Without GNSS or vision the GNSS channel is EKF2's fake position
    (`noaid_noise_m`, EKF2_NOAID_NOISE) with no delay and the barometer as the height."""
    base = load_sensing("gnss", 1000)
    fake = not src.gnss and not src.vision
    profile = dataclasses.replace(
        base, name="log", estimator=ekf2,
        gnss=base.gnss if (src.gnss or fake) else None,
        baro=base.baro if src.baro else None, mag=base.mag if src.mag else None,
        mocap=load_sensing("mocap", 1000).mocap if src.vision else None)
    over: dict = dict(imu_rate_hz=src.imu_rate_hz, init_pos_d_m=src.init_pos_d_m)
    if src.mag:
        over.update(mag_field_ned_gauss=src.mag_field_ned_gauss,
                    mag_declination_rad=src.mag_declination_rad)
    if fake:
        n = noaid_noise_m
        over.update(gnss_pos_noise_ne_m=n, gnss_pos_noise_d_m=n, gnss_vel_noise_ne_m_s=n,
                    gnss_vel_noise_d_m_s=n, gnss_delay_us=0, gnss_hgt_walk_m_s_rthz=0.0,
                    horizon_us=0, height_ref="baro" if src.baro else "gnss")
    try:
        return EstimatorParams.ekf2(profile, **over)
    except ValueError as exc:
        raise LogError(f"the filter cannot be set from the log's EKF2 parameters and sensors "
                       f"{src}: {exc}") from exc


