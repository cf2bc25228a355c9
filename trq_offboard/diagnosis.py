"""The controller's diagnosis for the ground station: what it believes of each motor, as MAVLink
messages a ground station shows without any plug-in.

In: per control step, the vehicle's time of the state answered (us) and the motors' estimated
effectiveness (StepInfo.effectiveness, 1 without the effectiveness observer). Out: the messages
to send this step:

    NAMED_VALUE_FLOAT  MOT1_EFF .. MOT4_EFF (0..1), every `period_us` of vehicle time
                       (MAVProxy: graph NAMED_VALUE_FLOAT[MOT1_EFF].value; QGroundControl:
                       the MAVLink inspector)
    STATUSTEXT         WARNING "motor N at P %" once the estimate has stayed below
                       `warn_below` for `hold_us`; NOTICE "motor N back at P %" once it has
                       stayed above `rearm_above` as long. Once per crossing: a dip shorter than
                       `hold_us` (a lost command on a bad link) says nothing, and a motor that
                       stays weak is announced once.

Pure: no clock, no I/O; the same steps give the same messages.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["Diagnosis", "EFF_NAMES"]

EFF_NAMES = tuple(f"MOT{n}_EFF" for n in range(1, 5))


@dataclass
class _Motor:
    low: bool = False                 # announced as weak
    since_us: int | None = None       # when the estimate last crossed to the other side


class Diagnosis:
    def __init__(self, period_us: int = 250_000, warn_below: float = 0.8,
                 rearm_above: float = 0.9, hold_us: int = 100_000) -> None:
        if not 0.0 < warn_below < rearm_above <= 1.0:
            raise ValueError(f"thresholds: expected 0 < warn_below < rearm_above <= 1, got "
                             f"{warn_below}, {rearm_above}")
        self.period_us = period_us
        self.warn_below = warn_below
        self.rearm_above = rearm_above
        self.hold_us = hold_us
        self._last_us: int | None = None
        self._motors = [_Motor() for _ in EFF_NAMES]

    def messages(self, stamp_us: int, effectiveness) -> list:
        out = []
        if self._last_us is None or stamp_us - self._last_us >= self.period_us:
            self._last_us = stamp_us
            out += [mavlink.MAVLink_named_value_float_message(
                (stamp_us // 1000) & 0xFFFFFFFF, name.encode("ascii"), float(e))
                for name, e in zip(EFF_NAMES, effectiveness)]
        for n, (motor, e) in enumerate(zip(self._motors, effectiveness), start=1):
            crossed = e > self.rearm_above if motor.low else e < self.warn_below
            if not crossed:
                motor.since_us = None
                continue
            if motor.since_us is None:
                motor.since_us = stamp_us
            if stamp_us - motor.since_us >= self.hold_us:
                motor.low, motor.since_us = not motor.low, None
                severity, text = ((mavlink.MAV_SEVERITY_WARNING, f"motor {n} at {e:.0%}")
                                  if motor.low else
                                  (mavlink.MAV_SEVERITY_NOTICE, f"motor {n} back at {e:.0%}"))
                out.append(mavlink.MAVLink_statustext_message(
                    severity, text.replace("%", " %").encode("ascii")))
        return out
