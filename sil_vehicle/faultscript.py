"""Fault scripts: timed fault and wind events, in vehicle time, from YAML (`params/faults/*.yaml`).

    events:
      - {at_s: 15.0, motor: 1, effectiveness: 0.5}
      - {at_s: 15.0, motor: 1, time_varying: {a: 0.8, b: 0.2, w: 0.01, phi: 0.0}}
      - {at_s: 20.0, motor: 2, stopped: true}        # stopped: false restores it
      - {at_s: 25.0, servo: 3, stuck_deg: 10.0}       # stuck_deg: null frees it
      - {at_s: 30.0, wind: {speed_m_s: 8.0, direction_deg: 90.0, gusts: true}}
      - {at_s: 40.0, clear: true}                     # every motor and servo healthy

Each event becomes MAVLink actions: parameter sets (`SIM_*`, PROTOCOL.md) or
MAV_CMD_INJECT_FAILURE commands, so a script means the same thing whether the vehicle plays it
itself (deterministic, `--faults FILE`) or `tools/inject_fault.py` sends it over the wire.
Errors name the file, the event index, the key, the value and what was expected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from sil_vehicle.yamlcheck import ConfigError, Section, load_yaml

MOTOR = 101          # FAILURE_UNIT_SYSTEM_MOTOR
SERVO = 102          # FAILURE_UNIT_SYSTEM_SERVO
TYPE_OK, TYPE_OFF, TYPE_STUCK = 0, 1, 2


@dataclass(frozen=True)
class ParamAction:
    name: str
    value: float


@dataclass(frozen=True)
class InjectAction:
    unit: int            # MOTOR or SERVO
    kind: int            # TYPE_OK, TYPE_OFF, TYPE_STUCK
    instance: int        # 1..4
    angle_deg: float = float("nan")


Action = ParamAction | InjectAction


@dataclass(frozen=True)
class Event:
    at_us: int
    actions: tuple[Action, ...]
    text: str            # what the event does, for logs and reports


def parse_event(sec: Section, tilt_range_deg: tuple[float, float] = (-90.0, 90.0)) -> Event:
    at_s = sec.float("at_s", 0.0, 1e6)
    actions: list[Action] = []
    text = []
    if sec.has("motor"):
        n = sec.int("motor", 1, 4)
        if sec.has("effectiveness"):
            e = sec.float("effectiveness", 0.0, 1.0)
            actions += [ParamAction(f"SIM_MOT{n}_EFF", e), ParamAction(f"SIM_MOT{n}_TVB", 0.0)]
            text.append(f"motor {n} effectiveness {e:g}")
        if sec.has("time_varying"):
            tv = sec.section("time_varying")
            a, b = tv.float("a", 0.0, 1.0), tv.float("b", 0.0, 1.0)
            w, phi = tv.float("w", 0.0, 1000.0), tv.float("phi", -10.0, 10.0, default=0.0)
            tv.done()
            actions += [ParamAction(f"SIM_MOT{n}_EFF", a), ParamAction(f"SIM_MOT{n}_TVB", b),
                        ParamAction(f"SIM_MOT{n}_TVW", w), ParamAction(f"SIM_MOT{n}_TVP", phi)]
            text.append(f"motor {n} effectiveness {a:g} - {b:g} sin({w:g} t + {phi:g})")
        if sec.has("stopped"):    # (not "off": YAML 1.1 reads a bare off as false)
            off = sec.bool("stopped")
            actions.append(InjectAction(MOTOR, TYPE_OFF if off else TYPE_OK, n))
            text.append(f"motor {n} {'off' if off else 'restored'}")
        if not actions:
            raise sec.fail("motor", n, "with effectiveness, time_varying or stopped")
    elif sec.has("servo"):
        n = sec.int("servo", 1, 4)
        value = sec.raw("stuck_deg")
        if value is None:
            actions.append(InjectAction(SERVO, TYPE_OK, n))
            text.append(f"servo {n} freed")
        else:
            lo, hi = tilt_range_deg
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not lo <= value <= hi:
                raise sec.fail("stuck_deg", value, f"null or an angle in [{lo:g}, {hi:g}] deg")
            actions.append(InjectAction(SERVO, TYPE_STUCK, n, float(value)))
            text.append(f"servo {n} stuck at {value:g} deg")
    elif sec.has("wind"):
        w = sec.section("wind")
        if w.has("speed_m_s"):
            v = w.float("speed_m_s", 0.0, 40.0)
            actions.append(ParamAction("SIM_WIND_SPD", v))
            text.append(f"wind {v:g} m/s")
        if w.has("direction_deg"):
            d = w.float("direction_deg", -360.0, 360.0)
            actions.append(ParamAction("SIM_WIND_DIR", d))
            text.append(f"from {d:g} deg")
        if w.has("gusts"):
            g = w.bool("gusts")
            actions.append(ParamAction("SIM_GUST_EN", 1.0 if g else 0.0))
            text.append(f"gusts {'on' if g else 'off'}")
        if w.has("gust_sigma_m_s"):
            actions.append(ParamAction("SIM_GUST_SIG", w.float("gust_sigma_m_s", 0.0, 20.0)))
        w.done()
        if not actions:
            raise sec.fail("wind", {}, "speed_m_s, direction_deg, gusts or gust_sigma_m_s")
    elif sec.has("clear"):
        if not sec.bool("clear"):
            raise sec.fail("clear", False, "true")
        for n in range(1, 5):
            actions += [ParamAction(f"SIM_MOT{n}_EFF", 1.0), ParamAction(f"SIM_MOT{n}_TVB", 0.0),
                        InjectAction(MOTOR, TYPE_OK, n), InjectAction(SERVO, TYPE_OK, n)]
        text.append("all faults cleared")
    else:
        raise ConfigError(f"{sec.file}: key '{sec.prefix.rstrip('.')}': an event needs one of "
                          "motor, servo, wind, clear")
    sec.done()
    return Event(int(round(at_s * 1e6)), tuple(actions), ", ".join(text))


def load_script(path: Path | str, tilt_range_deg: tuple[float, float] = (-90.0, 90.0)) -> tuple[Event, ...]:
    """Events sorted by time (stable: events at the same time keep their order)."""
    path = Path(path)
    top = Section(load_yaml(path), path)
    raw = top.raw("events")
    if not isinstance(raw, list) or not raw:
        raise top.fail("events", raw, "a non-empty list of events")
    events = [parse_event(Section(item, path, f"events[{i}]."), tilt_range_deg)
              for i, item in enumerate(raw)]
    top.done()
    return tuple(sorted(events, key=lambda e: e.at_us))
