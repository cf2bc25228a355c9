"""Fault scripts: timed fault and wind events, in vehicle time, from YAML (`params/faults/*.yaml`).

    events:
      - {at_s: 15.0, motor: 1, effectiveness: 0.5}
      - {at_s: 15.0, motor: 1, time_varying: {a: 0.8, b: 0.2, w: 0.01, phi: 0.0}}
      - {at_s: 20.0, motor: 2, stopped: true}        # stopped: false restores it
      - {at_s: 25.0, servo: 3, stuck_deg: 10.0}       # stuck_deg: null frees it
      - {at_s: 30.0, wind: {speed_m_s: 8.0, direction_deg: 90.0, gusts: true}}
      - {at_s: 32.0, sensor: mocap, failure: off}     # ok|off|stuck|garbage|wrong
      - {at_s: 33.0, sensor: gnss, failure: wrong, size: 5.0}   # metres north
      - {at_s: 40.0, clear: true}                     # every motor, servo and sensor healthy

Each event becomes MAVLink actions: parameter sets (`SIM_*`, PROTOCOL.md) or
MAV_CMD_INJECT_FAILURE commands, so a script means the same thing whether the vehicle plays it
itself (deterministic, `--faults FILE`) or `trq-inject-fault` sends it over the wire.
Each event is validated by `trq_params.loader` against its kind's schema (`trq_params.schema`:
MotorEvent, ServoEvent, WindEvent, SensorEvent, ClearEvent; the first of motor, servo, wind,
sensor, clear it holds decides): errors name the file, the event index, the key, the value and
what was expected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from trq_params.loader import ConfigError, read_yaml, validate
from trq_params.schema import ClearEvent, MotorEvent, SensorEvent, ServoEvent, WindEvent

from sil_vehicle.sensors import faults as sensor_faults

MOTOR = 101          # FAILURE_UNIT_SYSTEM_MOTOR
SERVO = 102          # FAILURE_UNIT_SYSTEM_SERVO
TYPE_OK, TYPE_OFF, TYPE_STUCK = 0, 1, 2


@dataclass(frozen=True)
class ParamAction:
    name: str
    value: float


@dataclass(frozen=True)
class InjectAction:
    unit: int            # MOTOR, SERVO or a sensor unit (sil_vehicle.sensors.faults.UNITS)
    kind: int            # FAILURE_TYPE: TYPE_OK, TYPE_OFF, TYPE_STUCK, ...
    instance: int        # 1..4 (a sensor: 1)
    param4: float = float("nan")     # a servo's stuck angle (deg); a sensor's WRONG size


Action = ParamAction | InjectAction


@dataclass(frozen=True)
class Event:
    at_us: int
    actions: tuple[Action, ...]
    text: str            # what the event does, for logs and reports


# an event's kind is the first of these keys it has
_KINDS = (("motor", MotorEvent), ("servo", ServoEvent), ("wind", WindEvent),
          ("sensor", SensorEvent), ("clear", ClearEvent))


def parse_event(event: Any, tilt_range_deg: tuple[float, float] = (-90.0, 90.0), *,
                file: str = "command line", key: str = "") -> Event:
    """One event mapping (`key`: where it sits in `file`, e.g. `events[2]`) -> Event."""
    if not isinstance(event, dict):
        raise ConfigError(f"{file}: key '{key}': got {event!r}, expected a mapping")
    model = next((m for k, m in _KINDS if k in event), None)
    if model is None:
        raise ConfigError(f"{file}: key '{key}': an event needs one of motor, servo, wind, "
                          "sensor, clear")
    ev = validate(model, event, file, prefix=key, context=tuple(tilt_range_deg))
    actions: list[Action] = []
    text = []
    if isinstance(ev, MotorEvent):
        n = ev.motor
        if ev.effectiveness is not None:
            e = ev.effectiveness
            actions += [ParamAction(f"SIM_MOT{n}_EFF", e), ParamAction(f"SIM_MOT{n}_TVB", 0.0)]
            text.append(f"motor {n} effectiveness {e:g}")
        if ev.time_varying is not None:
            a, b, w, phi = (ev.time_varying.a, ev.time_varying.b, ev.time_varying.w,
                            ev.time_varying.phi)
            actions += [ParamAction(f"SIM_MOT{n}_EFF", a), ParamAction(f"SIM_MOT{n}_TVB", b),
                        ParamAction(f"SIM_MOT{n}_TVW", w), ParamAction(f"SIM_MOT{n}_TVP", phi)]
            text.append(f"motor {n} effectiveness {a:g} - {b:g} sin({w:g} t + {phi:g})")
        if ev.stopped is not None:
            actions.append(InjectAction(MOTOR, TYPE_OFF if ev.stopped else TYPE_OK, n))
            text.append(f"motor {n} {'off' if ev.stopped else 'restored'}")
    elif isinstance(ev, ServoEvent):
        n, value = ev.servo, ev.stuck_deg
        if value is None:
            actions.append(InjectAction(SERVO, TYPE_OK, n))
            text.append(f"servo {n} freed")
        else:
            actions.append(InjectAction(SERVO, TYPE_STUCK, n, float(value)))
            text.append(f"servo {n} stuck at {value:g} deg")
    elif isinstance(ev, WindEvent):
        w = ev.wind
        if w.speed_m_s is not None:
            actions.append(ParamAction("SIM_WIND_SPD", w.speed_m_s))
            text.append(f"wind {w.speed_m_s:g} m/s")
        if w.direction_deg is not None:
            actions.append(ParamAction("SIM_WIND_DIR", w.direction_deg))
            text.append(f"from {w.direction_deg:g} deg")
        if w.gusts is not None:
            actions.append(ParamAction("SIM_GUST_EN", 1.0 if w.gusts else 0.0))
            text.append(f"gusts {'on' if w.gusts else 'off'}")
        if w.gust_sigma_m_s is not None:
            actions.append(ParamAction("SIM_GUST_SIG", w.gust_sigma_m_s))
    elif isinstance(ev, SensorEvent):
        size = float("nan") if ev.size is None else float(ev.size)
        actions.append(InjectAction(sensor_faults.UNIT_OF[ev.sensor],
                                    sensor_faults.KIND_OF[ev.failure], 1, size))
        text.append(f"{ev.sensor} {ev.failure}" + (f" by {size:g}" if ev.size is not None
                                                    else ""))
    else:
        for n in range(1, 5):
            actions += [ParamAction(f"SIM_MOT{n}_EFF", 1.0), ParamAction(f"SIM_MOT{n}_TVB", 0.0),
                        InjectAction(MOTOR, TYPE_OK, n), InjectAction(SERVO, TYPE_OK, n)]
        # every sensor unit healthy: a unit the profile does not carry has nothing to clear
        actions += [InjectAction(unit, TYPE_OK, 0) for unit in sensor_faults.UNITS]
        text.append("all faults cleared")
    return Event(int(round(ev.at_s * 1e6)), tuple(actions), ", ".join(text))


def load_script(path: Path | str,
                tilt_range_deg: tuple[float, float] = (-90.0, 90.0)) -> tuple[Event, ...]:
    """Events sorted by time (stable: events at the same time keep their order)."""
    path = Path(path)
    top = read_yaml(path)
    if "events" not in top:
        raise ConfigError(f"{path}: key 'events' is missing")
    raw = top["events"]
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"{path}: key 'events': got {raw!r}, expected a non-empty list of "
                          "events")
    extra = sorted((k for k in top if k != "events"), key=str)
    if extra:
        raise ConfigError(f"{path}: unknown key '{extra[0]}' (value {top[extra[0]]!r}): "
                          "expected events")
    events = [parse_event(item, tilt_range_deg, file=str(path), key=f"events[{i}]")
              for i, item in enumerate(raw)]
    return tuple(sorted(events, key=lambda e: e.at_us))
