"""A whole motor lost: its detection from the motors' effectiveness estimate, and what the
controller changes once it is detected (issue 40, item 2).

Detection (`LostMotorDetector`). In: per control step, the time (s) and the motors'
effectiveness estimate e (4: effectiveness.py's observer; its floor `min` is where a motor that
stops ends) and the throttles commanded (4, %). Out: the motor (1..4) declared lost, or None.
Motor n is declared lost once
    e_n <= below                              (the estimate at the observer's floor, near 0)
    and its command >= min_command_pct        (a motor commanded near idle shows no loss)
has held for `hold_s` without a break (any step above `below` restarts the count). The first
motor to qualify is latched: a lost motor is not re-armed in flight, and one motor is switched
at a time (a second motor lost keeps its loss in the observer's d).

Why this signal and these figures: docs/decisions/2026-12-05-lost-motor-first-flights.md
(the paper's 50 % fault reads e near 0.5; a 0 % fault drives e to its floor within a few
control periods; on a lossy link a lost or late command reads, for one to three control periods,
as a motor's deficit, down to the floor: the hold outlasts these).

The failed configuration (`failed_config`): the controller's NMPC rebuilt with the dead rotor's
throttle bounded to [0, 0] (its thrust fixed at 0, through Ocp.set_throttle_scale), yaw given up
(weight `yaw_weight` on the yaw angle and the yaw rate), a body-rate bound `max_body_rate_rad_s`
that lets the vehicle spin (optionally governed: the yaw rate weighted `spin_weight` towards
`spin_rate_rad_s` in the direction it spins), optionally its own horizon (`horizon_steps`, `horizon_step_s`: the
controller switches its grid with the solver), and a descent reference: the horizontal position where the loss was
detected, down at `descent_speed_m_s` to the ground (Controller._reference_states).

The response (`response`): the failed configuration above (nmpc), or the spinning controller of
the controller file's `spin:` section (spin: trq_offboard/spin.py, flown by Controller._spin_step
from the detection of one motor; docs/decisions/2026-12-05-lost-motor-spin-in-the-loop.md).

Pure: no clock, no I/O; the same inputs give the same detection.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from trq_offboard.config import ControllerConfig, LostMotorConfig

__all__ = ["LostMotorDetector", "failed_config", "status_text"]


@dataclass
class LostMotorDetector:
    cfg: LostMotorConfig
    lost: int | None = None                       # the motor declared lost (1..4), latched
    detected_s: float | None = None               # when
    _since_s: list = dataclasses.field(default_factory=lambda: [None] * 4)

    def reset(self) -> None:
        self.lost, self.detected_s = None, None
        self._since_s = [None] * 4

    def update(self, t_s: float, effectiveness, command_pct) -> int | None:
        """The motor declared lost (1..4), latched, or None; see the module docstring."""
        if self.lost is not None:
            return self.lost
        c = self.cfg
        for i, (e, u) in enumerate(zip(effectiveness, command_pct)):
            if e <= c.below and u >= c.min_command_pct:
                if self._since_s[i] is None:
                    self._since_s[i] = t_s
                if t_s - self._since_s[i] >= c.hold_s - 1e-9:
                    self.lost, self.detected_s = i + 1, t_s
                    return self.lost
            else:
                self._since_s[i] = None
        return None


def failed_config(cfg: ControllerConfig) -> ControllerConfig:
    """The controller's config for its NMPC with a motor lost: yaw and yaw rate weighted
    `yaw_weight` (the yaw rate `spin_weight` when given), the body-rate bound raised to `max_body_rate_rad_s` (the dead rotor's bounds
    are set on the solver's OCP, not here)."""
    lm = cfg.lost_motor
    w = cfg.weights
    weights = dataclasses.replace(
        w, euler=(w.euler[0], w.euler[1], lm.yaw_weight),
        rates=(w.rates[0], w.rates[1],
               lm.yaw_weight if lm.spin_weight is None else lm.spin_weight))
    return dataclasses.replace(
        cfg, weights=weights, max_rate_rad_s=lm.max_body_rate_rad_s, name=cfg.name + "_failed",
        horizon_steps=lm.horizon_steps or cfg.horizon_steps,
        step_s=lm.horizon_step_s or cfg.step_s)


def status_text(motor: int, response: str = "nmpc") -> str:
    """The STATUSTEXT announcing the loss and what the controller does (at most 50 chars):
    `response` "nmpc" (the failed NMPC) or "spin" (the spinning controller, spin.py)."""
    if response == "spin":
        return f"motor {motor} lost: spinning, holding position, landing"
    return f"motor {motor} lost: yaw given up, descending to land"
