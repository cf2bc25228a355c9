"""The vehicle's parameters over the MAVLink parameter protocol: the settings a user changes
while flying (wind, gusts, motor effectiveness and time-varying fault terms, motors off, stuck
servos) and, under a sensing profile, its estimator's EKF2_* parameters (`ekf2_params`; their
ranges and defaults are the schema's, trq_params.schema.Ekf2). Every value is a REAL32; a value
outside its range, or one the setter refuses (a ValueError: an EKF2 parameter that needs a
restart), is refused and nothing changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, get_args

from trq_params.loader import range_of
from trq_params.schema import EKF2_KEYS, Ekf2

from sil_vehicle.vehicle import Vehicle


@dataclass(frozen=True)
class Param:
    name: str               # at most 16 characters
    lo: float
    hi: float
    unit: str
    doc: str
    get: Callable[[Vehicle], float]
    set: Callable[[Vehicle, float], None]


def _wind(field: str) -> tuple[Callable[[Vehicle], float], Callable[[Vehicle, float], None]]:
    keys = ("wind_speed_m_s", "wind_from_deg", "gusts_enabled", "gust_sigma_m_s", "gust_length_m")

    def get(v: Vehicle) -> float:
        return float(getattr(v, field))

    def set_(v: Vehicle, value: float) -> None:
        now = {k: getattr(v, k) for k in keys}
        now[field] = bool(value) if field == "gusts_enabled" else value
        v.set_wind(*(now[k] for k in keys))

    return get, set_


def _motor(i: int, field: str) -> tuple[Callable[[Vehicle], float], Callable[[Vehicle, float], None]]:
    def get(v: Vehicle) -> float:
        return float(getattr(v.faults.motors[i], field))

    def set_(v: Vehicle, value: float) -> None:
        v.faults = v.faults.with_motor(i, **{field: bool(value) if field == "off" else value})

    return get, set_


def _servo(i: int, field: str) -> tuple[Callable[[Vehicle], float], Callable[[Vehicle, float], None]]:
    def get(v: Vehicle) -> float:
        s = v.faults.servos[i]
        return float(s.stuck) if field == "stuck" else math.degrees(s.angle_rad)

    def set_(v: Vehicle, value: float) -> None:
        if field == "stuck":
            v.faults = v.faults.with_servo(i, stuck=bool(value))
        else:
            v.faults = v.faults.with_servo(i, angle_rad=math.radians(value))

    return get, set_


def build_params(vehicle: Vehicle) -> tuple[Param, ...]:
    vp = vehicle.vp
    out = [
        Param("SIM_WIND_SPD", 0.0, 40.0, "m/s", "mean wind speed", *_wind("wind_speed_m_s")),
        Param("SIM_WIND_DIR", -360.0, 360.0, "deg", "direction the wind blows from",
              *_wind("wind_from_deg")),
        Param("SIM_GUST_EN", 0.0, 1.0, "bool", "Dryden gusts on (1) or off (0)",
              *_wind("gusts_enabled")),
        Param("SIM_GUST_SIG", 0.0, 20.0, "m/s", "gust intensity (std. dev.)",
              *_wind("gust_sigma_m_s")),
        Param("SIM_GUST_LEN", 1.0, 2000.0, "m", "gust length scale", *_wind("gust_length_m")),
    ]
    for i in range(4):
        n = i + 1
        out += [
            Param(f"SIM_MOT{n}_EFF", 0.0, 1.0, "", f"motor {n} effectiveness a",
                  *_motor(i, "effectiveness")),
            Param(f"SIM_MOT{n}_TVB", 0.0, 1.0, "", f"motor {n} time-varying amplitude b",
                  *_motor(i, "amplitude")),
            Param(f"SIM_MOT{n}_TVW", 0.0, 1000.0, "rad/s", f"motor {n} time-varying omega w",
                  *_motor(i, "omega_rad_s")),
            Param(f"SIM_MOT{n}_TVP", -10.0, 10.0, "rad", f"motor {n} time-varying phase phi",
                  *_motor(i, "phase_rad")),
            Param(f"SIM_MOT{n}_OFF", 0.0, 1.0, "bool", f"motor {n} off (1)", *_motor(i, "off")),
        ]
    for i in range(4):
        n = i + 1
        out += [
            Param(f"SIM_SRV{n}_STK", 0.0, 1.0, "bool", f"tilt servo {n} stuck (1)",
                  *_servo(i, "stuck")),
            Param(f"SIM_SRV{n}_ANG", math.degrees(vp.tilt_min_rad), math.degrees(vp.tilt_max_rad),
                  "deg", f"tilt servo {n} stuck angle", *_servo(i, "angle")),
        ]
    return tuple(out)


def ekf2_params(get: Callable[[], Ekf2], set_: Callable[[Ekf2], None]) -> tuple[Param, ...]:
    """The estimator's EKF2_* parameters: `get` gives the tuning in force, `set_` applies a new
    one (raising ValueError to refuse it). An integer parameter takes a whole REAL32 only."""
    out = []
    for key in EKF2_KEYS:
        info = Ekf2.model_fields[key]
        rng = range_of(info.annotation) or next(
            (m for m in info.metadata if hasattr(m, "lo")), None)
        whole = get_args(info.annotation)[:1] == (int,) or info.annotation is int

        def get_(v, key=key) -> float:
            return float(getattr(get(), key))

        def put(v, value: float, key=key, whole=whole) -> None:
            if whole and not float(value).is_integer():
                raise ValueError(f"{key}={value:g}: a whole number")
            now = get().model_dump()
            now[key] = int(value) if whole else float(value)
            set_(Ekf2.model_validate(now))

        lo, hi = (rng.lo, rng.hi) if rng is not None else (-math.inf, math.inf)
        doc = (info.description or key).split("\n")[0]
        out.append(Param(key, lo, hi, "", doc, get_, put))
    return tuple(out)


class ParamTable:
    def __init__(self, vehicle: Vehicle, extra: tuple[Param, ...] = ()) -> None:
        self.vehicle = vehicle
        self.params = build_params(vehicle) + tuple(extra)
        self._index = {p.name: i for i, p in enumerate(self.params)}

    def __len__(self) -> int:
        return len(self.params)

    def index(self, name: str) -> int | None:
        return self._index.get(name)

    def value(self, index: int) -> float:
        return self.params[index].get(self.vehicle)

    def set(self, name: str, value: float) -> tuple[int | None, str | None]:
        """(index, error). On an error nothing changes."""
        i = self._index.get(name)
        if i is None:
            return None, f"unknown parameter {name}"
        p = self.params[i]
        if not math.isfinite(value) or not p.lo <= value <= p.hi:
            return i, f"{name}={value:g} out of [{p.lo:g}, {p.hi:g}]"
        try:
            p.set(self.vehicle, value)
        except ValueError as exc:
            return i, f"{name}={value:g} refused: {exc}"
        return i, None

    def extend(self, extra: tuple[Param, ...]) -> None:
        """More parameters, after those already in the table."""
        self.params = self.params + tuple(extra)
        self._index = {p.name: i for i, p in enumerate(self.params)}
