"""Actuator faults of the truth plant, as data.

Motor i produces throttle e_i(t) * command, e_i(t) = a_i - b_i sin(w_i t + phi_i) clamped to
[0, 1], t the vehicle time in seconds (the paper's 0.8 - 0.2 sin(0.01 t)); a motor that is off
produces nothing whatever e_i says, and restoring it brings e_i back. A stuck tilt servo holds
its angle whatever it is commanded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class MotorFault:
    effectiveness: float = 1.0     # a
    amplitude: float = 0.0         # b
    omega_rad_s: float = 0.0       # w
    phase_rad: float = 0.0         # phi
    off: bool = False

    def factor(self, t_s: float) -> float:
        if self.off:
            return 0.0
        if self.amplitude == 0.0:
            e = self.effectiveness
        else:
            e = self.effectiveness - self.amplitude * math.sin(self.omega_rad_s * t_s + self.phase_rad)
        return 0.0 if e < 0.0 else 1.0 if e > 1.0 else e

    @property
    def healthy(self) -> bool:
        return not self.off and self.effectiveness == 1.0 and self.amplitude == 0.0


@dataclass(frozen=True)
class ServoFault:
    stuck: bool = False
    angle_rad: float = 0.0


@dataclass(frozen=True)
class Faults:
    motors: tuple[MotorFault, ...] = (MotorFault(),) * 4
    servos: tuple[ServoFault, ...] = (ServoFault(),) * 4

    def with_motor(self, index: int, **changes) -> "Faults":
        motors = list(self.motors)
        motors[index] = replace(motors[index], **changes)
        return replace(self, motors=tuple(motors))

    def with_servo(self, index: int, **changes) -> "Faults":
        servos = list(self.servos)
        servos[index] = replace(servos[index], **changes)
        return replace(self, servos=tuple(servos))

    def describe(self) -> str:
        parts = []
        for i, m in enumerate(self.motors, 1):
            if m.off:
                parts.append(f"motor {i} off")
            elif not m.healthy:
                tv = f" - {m.amplitude:g} sin({m.omega_rad_s:g} t + {m.phase_rad:g})" if m.amplitude else ""
                parts.append(f"motor {i} eff {m.effectiveness:g}{tv}")
        for i, s in enumerate(self.servos, 1):
            if s.stuck:
                parts.append(f"servo {i} stuck at {math.degrees(s.angle_rad):.1f} deg")
        return ", ".join(parts) or "none"
