"""Typed schema of a sensing profile (`params/sensing/*.yaml`): which sensors the simulated
vehicle carries and their error figures. Read by `sil_vehicle.sensors.profile.load_sensing`.

    SensingFile      params/sensing/*.yaml   (sil_vehicle)

Kept apart from `trq_params.schema` for now (the integrator moves it there); it follows the same
rules: strict, frozen, no unknown key, values in the units their key names (degrees stay
degrees), ranges through the loader's Num/Int. A sensor set to `null` is absent; every section
must be written (a missing key is an error, not an absent sensor).

Checks that need the simulation's physics rate (a sensor rate divides it, a delay is a whole
number of ticks) run when the loader passes `context={"physics_rate_hz": N}`, and raise
`loader.Invalid` with the full dotted key, so the error names the file, the key, the value and
what was expected. A delay beyond DELAY_BUFFER_MS (the delayed-measurement buffer the estimator
keeps) is refused with or without that context.
"""

from __future__ import annotations

from typing import Annotated, Any, Optional

from pydantic import BeforeValidator, ValidationInfo, model_validator
from trq_params.loader import Int, Invalid, Num, Text, expect
from trq_params.schema import Strict

__all__ = ["SensingFile", "DELAY_BUFFER_MS"]

DELAY_BUFFER_MS = 500
"""The longest delay (ms) a delayed measurement may have: the history the estimator keeps to
fuse it at its time of validity. Both daemons may read it from here."""

_RATE = Int(1, 10_000)        # Hz; then checked against the physics rate (context)
_DELAY = Int(0, 10_000)       # ms; then checked against DELAY_BUFFER_MS and the physics tick


class Imu(Strict):
    """Gyro and accelerometer (sil_vehicle.sensors.imu states the model)."""
    rate_hz: _RATE
    gyro_noise_density_rad_s_rthz: Num(0.0, 1.0)
    gyro_bias_random_walk_rad_s2_rthz: Num(0.0, 1.0)
    gyro_turn_on_bias_rad_s: Num(0.0, 1.0)
    gyro_vibration_rad_s: Num(0.0, 10.0)
    accel_noise_density_m_s2_rthz: Num(0.0, 10.0)
    accel_bias_random_walk_m_s3_rthz: Num(0.0, 10.0)
    accel_turn_on_bias_m_s2: Num(0.0, 10.0)
    accel_vibration_m_s2: Num(0.0, 100.0)


class Baro(Strict):
    rate_hz: _RATE
    noise_m: Num(0.0, 100.0)
    drift_sigma_m: Num(0.0, 100.0)
    drift_tau_s: Num(0.0, 1e6, open_lo=True)


class Mag(Strict):
    rate_hz: _RATE
    field_gauss: Num(0.0, 1.0, open_lo=True)
    declination_deg: Num(-180.0, 180.0)
    inclination_deg: Num(-90.0, 90.0)
    noise_density_gauss_rthz: Num(0.0, 1.0)
    bias_random_walk_gauss_s_rthz: Num(0.0, 1.0)
    turn_on_bias_gauss: Num(0.0, 1.0)


class Gnss(Strict):
    rate_hz: _RATE
    delay_ms: _DELAY
    fix_type: Int(3, 6)       # MAVLink GPS_FIX_TYPE: 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: Int(0, 64)
    position_white_h_m: Num(0.0, 100.0)
    position_white_v_m: Num(0.0, 100.0)
    position_markov_h_m: Num(0.0, 100.0)
    position_markov_v_m: Num(0.0, 100.0)
    position_markov_tau_s: Num(0.0, 1e6, open_lo=True)
    velocity_white_h_m_s: Num(0.0, 10.0)
    velocity_white_v_m_s: Num(0.0, 10.0)


class Window(Strict):
    """[start_ms, end_ms): no pose arrives for a sample taken in this span."""
    start_ms: Int(0, 2**62)
    end_ms: Int(0, 2**62)

    @model_validator(mode="after")
    def _ordered(self) -> "Window":
        if self.end_ms <= self.start_ms:
            raise expect(f"end_ms after start_ms ({self.start_ms})")
        return self


def _windows(value: Any) -> tuple[Any, ...]:
    if not isinstance(value, (list, tuple)):
        raise expect("a list of {start_ms, end_ms} mappings (empty for none)")
    return tuple(value)


class Mocap(Strict):
    """Motion capture: pose only."""
    rate_hz: _RATE
    latency_ms: _DELAY
    position_noise_m: Num(0.0, 1.0)
    attitude_noise_rad: Num(0.0, 1.0)
    dropout_probability: Num(0.0, 1.0)
    dropout_windows: Annotated[tuple[Window, ...], BeforeValidator(_windows)]


_SENSORS = ("imu", "baro", "mag", "gnss", "mocap")


class SensingFile(Strict):
    """A sensing profile: each sensor's section, or null when the vehicle does not carry it."""
    name: Text
    description: Text
    imu: Optional[Imu]
    baro: Optional[Baro]
    mag: Optional[Mag]
    gnss: Optional[Gnss]
    mocap: Optional[Mocap]

    @model_validator(mode="after")
    def _timing(self, info: ValidationInfo) -> "SensingFile":
        for key, delay in (("gnss.delay_ms", self.gnss and self.gnss.delay_ms),
                           ("mocap.latency_ms", self.mocap and self.mocap.latency_ms)):
            if delay and delay > DELAY_BUFFER_MS:
                raise Invalid(key, delay, f"a delay in [0, {DELAY_BUFFER_MS}] ms (the "
                                          "estimator's delayed-measurement buffer)")
        physics = (info.context or {}).get("physics_rate_hz") if info else None
        if physics is None:
            return self
        tick_us = 1_000_000 // physics
        for name in _SENSORS:
            section = getattr(self, name)
            if section is None:
                continue
            hz = section.rate_hz
            if hz > physics or physics % hz:
                raise Invalid(f"{name}.rate_hz", hz, f"a rate in Hz that divides the physics "
                                                     f"rate ({physics} Hz)")
        for key, delay in (("gnss.delay_ms", self.gnss and self.gnss.delay_ms),
                           ("mocap.latency_ms", self.mocap and self.mocap.latency_ms)):
            if delay and (delay * 1000) % tick_us:
                raise Invalid(key, delay, f"a whole number of physics ticks ({tick_us} us)")
        return self
