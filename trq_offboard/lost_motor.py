"""A whole motor lost: its detection from the motors' effectiveness estimate, and what the
controller changes once it is detected (issue 40, item 2).

Detection (`LostMotorDetector`). In: per control step, the time (s) and the motors'
effectiveness estimate e (4: effectiveness.py's observer; its floor `min` is where a motor that
stops ends) and the throttles commanded (4, %). Out: the motor (1..4) declared lost, or None.
Motor n is declared lost once
    e_n <= below                              (the estimate at the observer's floor, near 0)
    and its command >= min_command_pct        (a motor commanded near idle shows no loss)
has held for `hold_s` without a break (any step above `below` restarts the count), or, with
`within_s` set, for `hold_s` in all within the last `within_s` (each step at or below counting
the time since the step before it, at most half of `hold_s` so that one step after a long gap
never decides alone; the current step among them): on a lossy link a late or lost command throws
a lost motor's estimate back above `below` for a period or two, which no longer restarts the
count. The first motor to qualify is latched: a lost motor is not re-armed in flight, and one
motor is switched at a time (a second motor lost keeps its loss in the observer's d).

Why this signal and these figures: docs/decisions/2026-12-05-lost-motor-first-flights.md
(the paper's 50 % fault reads e near 0.5; a 0 % fault drives e to its floor within a few
control periods; on a lossy link a lost or late command reads, for one to three control periods,
as a motor's deficit, down to the floor: the hold outlasts these). The count within a window,
and what the link's delay costs any controller of a lost motor:
docs/decisions/2026-12-06-lost-motor-tilt-bound.md.

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

Two motors lost (`PairLossDetector`, with `pair_excess_m_s2` set). The effectiveness observer
puts a deficit on one motor at a time and reads no yaw, so two opposite motors (their roll and
pitch torques cancel) leave every estimate near 1, and two adjacent ones read as one. The
commanded-against-measured test: per control step the observer's d (the accelerations the
nominal model misses: vertical NED, body p, q, r) against each motor's share of the model's
accelerations at its output (`motor_contributions`). The vertical deficit beyond what the
strongest single motor could explain, stopped whole,
    excess = d_down - max_i (upward acceleration of motor i at its output)
averaged over the last `hold_s`, at or above `pair_excess_m_s2`, says more than one motor is
lost; the pair is the one whose loss best explains d over the window's steps with an excess
(least squares on the vertical and the three angular parts, the angular ones divided by
`pair_angular_scale_rad_s2`: yaw tells the opposite pairs apart, both of one sense), both of its
motors commanded at least `min_command_pct`. One motor lost gives an excess near or below 0 (its
own deficit is one of the candidates); the paper's 50 % less than that by half a motor. Latched.
What flies it: the failed NMPC with both rotors out (the controller); why:
docs/decisions/2026-12-05-lost-motor-on-seeds.md.

Pure: no clock, no I/O; the same inputs give the same detection.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from trq_offboard.config import ControllerConfig, LostMotorConfig

__all__ = ["LostMotorDetector", "PairLossDetector", "PAIRS", "motor_contributions",
           "pair_code", "failed_config", "status_text"]

# the pairs of motors (PX4 quad X: 1 front right, 2 rear left, 3 front left, 4 rear right):
# the two opposite ones first (1-2 both ccw, 3-4 both cw), then the four adjacent ones
PAIRS = ((1, 2), (3, 4), (1, 3), (2, 4), (1, 4), (2, 3))


def pair_code(pair: tuple[int, int]) -> int:
    """The controller's `lost_motor` figure of a pair: 10 i + j (12: motors 1 and 2)."""
    return 10 * pair[0] + pair[1]


def motor_contributions(accel, x, y) -> np.ndarray:
    """Each motor's share of the model's accelerations at the actuators' outputs y: (4, 4),
    column i what motor i adds (its output against its throttle at 0, where the model's curves
    give c0: 0.19 N less than a stopped rotor's 0 on the TRQ) to [the vertical (NED down,
    m/s^2), the body p, q, r accelerations (rad/s^2)]; `accel` the prediction model's (x, u) ->
    [dv/dt, domega/dt], y its input vector (the throttles last, %). The five inputs (y, and y
    with each motor at 0) go through one call of `accel` mapped over five columns (it runs every
    control step before any loss)."""
    y = np.asarray(y, float)
    nt = len(y) - 4
    ys = np.repeat(y[:, None], 5, axis=1)
    for i in range(4):
        ys[nt + i, i + 1] = 0.0
    xs = np.repeat(np.asarray(x, float).reshape(-1, 1), 5, axis=1)
    acc = np.asarray(_mapped5(accel)(xs, ys))[2:6]
    return acc[:, 0:1] - acc[:, 1:]


_MAPPED: dict[int, tuple] = {}


def _mapped5(accel):
    """`accel` mapped over five columns, built once per function (kept with it)."""
    got = _MAPPED.get(id(accel))
    if got is None or got[0] is not accel:
        got = _MAPPED[id(accel)] = (accel, accel.map(5))
    return got[1]


@dataclass
class PairLossDetector:
    """Two motors lost (the module docstring): `update` per control step, latched."""
    cfg: LostMotorConfig
    lost: tuple[int, int] | None = None            # the pair declared lost, latched
    detected_s: float | None = None
    _window: list = dataclasses.field(default_factory=list)   # (t_s, excess, residuals (6))

    def reset(self) -> None:
        self.lost, self.detected_s = None, None
        self._window = []

    def update(self, t_s: float, d4, contributions, command_pct) -> tuple[int, int] | None:
        """The pair declared lost, or None. d4: the observer's d (vertical NED down m/s^2, body
        p, q, r rad/s^2); contributions: `motor_contributions` at this step; command_pct: the
        four throttles commanded (%)."""
        if self.lost is not None:
            return self.lost
        c = self.cfg
        d4 = np.asarray(d4, float)
        contrib = np.asarray(contributions, float)
        # the strongest single motor's loss: its upward acceleration (contribution < 0: down)
        excess = float(d4[0] - max(0.0, float(np.max(-contrib[0]))))
        scale = np.array([1.0] + [c.pair_angular_scale_rad_s2] * 3)
        resid = np.array([float(np.sum(((d4 + contrib[:, i - 1] + contrib[:, j - 1]) / scale)
                                       ** 2)) for i, j in PAIRS])
        self._window.append((float(t_s), excess, resid))
        t_lo = t_s - c.hold_s - 1e-9
        self._window = [w for w in self._window if w[0] >= t_lo]
        if t_s - self._window[0][0] < c.hold_s - 1e-9:
            return None
        if np.mean([w[1] for w in self._window]) < c.pair_excess_m_s2:
            return None
        # the pair: the least squares over the window's steps with an excess (the loss's own)
        pair = PAIRS[int(np.argmin(np.sum([w[2] for w in self._window if w[1] > 0.0],
                                          axis=0)))]
        if min(command_pct[pair[0] - 1], command_pct[pair[1] - 1]) < c.min_command_pct:
            return None
        self.lost, self.detected_s = pair, float(t_s)
        return pair


@dataclass
class LostMotorDetector:
    cfg: LostMotorConfig
    lost: int | None = None                       # the motor declared lost (1..4), latched
    detected_s: float | None = None               # when
    _since_s: list = dataclasses.field(default_factory=lambda: [None] * 4)
    # within_s: the steps at or below per motor in the window, (t_s, the time it counts)
    _below: list = dataclasses.field(default_factory=lambda: [[] for _ in range(4)])
    _last_s: float | None = None

    def reset(self) -> None:
        self.lost, self.detected_s = None, None
        self._since_s = [None] * 4
        self._below = [[] for _ in range(4)]
        self._last_s = None

    def update(self, t_s: float, effectiveness, command_pct) -> int | None:
        """The motor declared lost (1..4), latched, or None; see the module docstring."""
        if self.lost is not None:
            return self.lost
        c = self.cfg
        if c.within_s is not None:
            return self._update_within(t_s, effectiveness, command_pct)
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

    def _update_within(self, t_s: float, effectiveness, command_pct) -> int | None:
        c = self.cfg
        step_s = (0.0 if self._last_s is None
                  else min(max(0.0, t_s - self._last_s), 0.5 * c.hold_s))
        self._last_s = t_s
        for i, (e, u) in enumerate(zip(effectiveness, command_pct)):
            window = [w for w in self._below[i] if w[0] > t_s - c.within_s + 1e-9]
            self._below[i] = window
            if not (e <= c.below and u >= c.min_command_pct):
                continue
            window.append((t_s, step_s))
            if sum(w[1] for w in window) >= c.hold_s - 1e-9:
                self.lost, self.detected_s = i + 1, t_s
                return self.lost
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
    `response` "nmpc" (the failed NMPC) or "spin" (the spinning controller, spin.py); a pair
    (`motor` 10 i + j: `pair_code`) flies the failed NMPC on the two rotors left."""
    if motor > 10:
        return f"motors {motor // 10} and {motor % 10} lost: full thrust, descending"
    if response == "spin":
        return f"motor {motor} lost: spinning, holding position, landing"
    return f"motor {motor} lost: yaw given up, descending to land"
