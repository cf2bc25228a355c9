"""Sensor faults: what MAV_CMD_INJECT_FAILURE's sensor units do to the readings.

PX4's failure injection (SYS_FAILURE_EN, `failure <unit> <type>`) names the units and types
that MAVLink's FAILURE_UNIT and FAILURE_TYPE enumerate; this vehicle takes these:

    unit (param1)                       sensor     instance (param3): 0 (all) or 1
    0 FAILURE_UNIT_SENSOR_GYRO          imu        the gyro half of the IMU reading
    1 FAILURE_UNIT_SENSOR_ACCEL         imu        the accelerometer half
    2 FAILURE_UNIT_SENSOR_MAG           mag
    3 FAILURE_UNIT_SENSOR_BARO          baro
    4 FAILURE_UNIT_SENSOR_GPS           gnss
    6 FAILURE_UNIT_SENSOR_VIO           mocap      (the external vision pose PX4 fuses)

    type (param2)   what the sensor then delivers
    0 OK            its own readings again
    1 OFF           nothing (an IMU with its gyro or its accelerometer off delivers nothing:
                    both halves come from one chip and one message)
    2 STUCK         readings on time, every value held at the last reading before the fault
    3 GARBAGE       readings on time, values uniform over the sensor's full range (GARBAGE_RANGE)
    4 WRONG         readings on time, off by a constant: param4 the size in the unit's SI unit
                    (NaN: WRONG_DEFAULT): gyro rad/s and accel m/s^2 added on every axis, mag
                    the field turned by that many degrees about the body's down axis, baro
                    metres of altitude, gnss and mocap metres north

The faults act on the readings as they arrive (a delayed sensor's reading measured before the
fault but arriving after it is hit too: the receiver's output is what fails). Garbage draws from
the generator the vehicle injects (its own child, so that faults never shift the sensors' own
noise). Nothing here runs while no fault is active.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from sil_vehicle.sensors import baro, gnss, imu, mag, mocap

__all__ = ["UNITS", "OK", "OFF", "STUCK", "GARBAGE", "WRONG", "KIND_NAMES", "SensorFault",
           "SensorFaults"]

# MAVLink FAILURE_UNIT -> the unit's name here
UNITS = {0: "gyro", 1: "accel", 2: "mag", 3: "baro", 4: "gnss", 6: "mocap"}
UNIT_OF = {name: unit for unit, name in UNITS.items()}
# the unit's sensor in the suite (the profile's key)
SENSOR = {"gyro": "imu", "accel": "imu", "mag": "mag", "baro": "baro", "gnss": "gnss",
          "mocap": "mocap"}
OK, OFF, STUCK, GARBAGE, WRONG = 0, 1, 2, 3, 4       # MAVLink FAILURE_TYPE
KIND_NAMES = {OK: "ok", OFF: "off", STUCK: "stuck", GARBAGE: "garbage", WRONG: "wrong"}
KIND_OF = {name: kind for kind, name in KIND_NAMES.items()}

# WRONG's size when param4 is NaN, in the unit's SI unit (see the module's docstring)
WRONG_DEFAULT = {"gyro": 0.1, "accel": 1.0, "mag": 90.0, "baro": 10.0, "gnss": 10.0,
                 "mocap": 0.5}
# GARBAGE's range: +-value per axis; the full scales of common parts (a +-2000 deg/s gyro, a
# +-16 g accelerometer, a +-4 gauss magnetometer), baro altitude and positions as far as the
# field's limits make sense
GARBAGE_RANGE = {"gyro": math.radians(2000.0), "accel": 16 * 9.80665, "mag": 4.0,
                 "baro": 5000.0, "gnss": 1000.0, "mocap": 10.0}
GNSS_GARBAGE_VEL_M_S = 50.0
# a reading's sensor (but the IMU's, which two units share), and its dataclass fields
_NAME = {baro.BaroReading: "baro", mag.MagReading: "mag", gnss.GnssReading: "gnss",
         mocap.MocapReading: "mocap"}
_FIELDS = {name: {f.name for f in fields(cls)} for cls, name in _NAME.items()}


@dataclass(frozen=True)
class SensorFault:
    unit: str                   # a name of UNITS
    kind: int                   # OFF, STUCK, GARBAGE, WRONG
    size: float = math.nan      # WRONG's size (NaN: WRONG_DEFAULT)
    held: object = None         # STUCK: the reading whose values it holds (None: none yet)

    def describe(self) -> str:
        text = f"{self.unit} {KIND_NAMES[self.kind]}"
        if self.kind == WRONG:
            text += f" by {self.wrong_size:g}"
        return text

    @property
    def wrong_size(self) -> float:
        return WRONG_DEFAULT[self.unit] if math.isnan(self.size) else self.size


class SensorFaults:
    """The active sensor faults, applied to each tick's readings (`apply`)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self.active: dict[str, SensorFault] = {}       # by unit name

    def set(self, unit: str, kind: int, size: float = math.nan, latest=None) -> None:
        """Start (or, with OK, end) a fault on `unit`; `latest` is the sensor's newest reading,
        the one a STUCK fault holds."""
        if unit not in SENSOR or kind not in KIND_NAMES:
            raise ValueError(f"sensor fault: unit {unit!r} and kind {kind!r}: expected one of "
                             f"{sorted(SENSOR)} and one of {sorted(KIND_NAMES)}")
        if kind == OK:
            self.active.pop(unit, None)
        else:
            self.active[unit] = SensorFault(unit, kind, size, latest if kind == STUCK else None)

    def describe(self) -> str:
        return ", ".join(f.describe() for f in self.active.values()) or "none"

    def apply(self, readings: list) -> list:
        """The readings as the faulty sensors deliver them (the same list when none is hit)."""
        if not self.active:
            return readings
        out = []
        for r in readings:
            r = self._one(r)
            if r is not None:
                out.append(r)
        return out

    def _one(self, r):
        active = self.active
        if isinstance(r, imu.ImuReading):
            gyro, accel = active.get("gyro"), active.get("accel")
            if gyro is None and accel is None:
                return r
            if OFF in (getattr(gyro, "kind", None), getattr(accel, "kind", None)):
                return None
            return replace(r, gyro=self._vector(gyro, r.gyro, "gyro"),
                           accel=self._vector(accel, r.accel, "accel"))
        name = _NAME[type(r)]
        f = active.get(name)
        if f is None:
            return r
        if f.kind == OFF:
            return None
        if f.kind == STUCK:         # the held values, on this reading's times
            times = {k: getattr(r, k) for k in ("t_us", "arrival_us") if k in _FIELDS[name]}
            return r if f.held is None else replace(f.held, **times)
        if name == "baro":
            alt = (self._uniform(GARBAGE_RANGE["baro"], 1)[0] if f.kind == GARBAGE
                   else r.pressure_alt_m + f.wrong_size)
            return baro.BaroReading(r.t_us, baro.isa_pressure_pa(alt), alt,
                                    baro.isa_temperature_degc(alt))
        if name == "mag":
            if f.kind == GARBAGE:
                return replace(r, field_frd_gauss=self._uniform(GARBAGE_RANGE["mag"], 3))
            c, s = math.cos(math.radians(f.wrong_size)), math.sin(math.radians(f.wrong_size))
            x, y, z = r.field_frd_gauss
            return replace(r, field_frd_gauss=np.array((c * x - s * y, s * x + c * y, z)))
        if f.kind == WRONG:
            return replace(r, pos_ned_m=r.pos_ned_m + np.array((f.wrong_size, 0.0, 0.0)))
        pos = self._uniform(GARBAGE_RANGE[name], 3)
        if name == "gnss":
            return replace(r, pos_ned_m=pos, vel_ned_m_s=self._uniform(GNSS_GARBAGE_VEL_M_S, 3))
        q = self._rng.standard_normal(4)
        return replace(r, pos_ned_m=pos, quat_wxyz=q / np.linalg.norm(q))

    def _vector(self, f: SensorFault | None, v, unit: str):
        """An IMU half (gyro or accel, 3 floats) as the fault `f` delivers it."""
        if f is None:
            return v
        if f.kind == STUCK:
            held = f.held
            return v if held is None else getattr(held, unit)
        if f.kind == GARBAGE:
            return tuple(float(x) for x in self._uniform(GARBAGE_RANGE[unit], 3))
        d = f.wrong_size
        return (v[0] + d, v[1] + d, v[2] + d)

    def _uniform(self, half_range: float, n: int) -> np.ndarray:
        return self._rng.uniform(-half_range, half_range, n)
