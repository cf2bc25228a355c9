"""The companion's own ground-contact test for the end of a landing: the plan asks to be lower
than the estimate says the vehicle is, and the estimate does not move vertically.

Why: the controller ends a landing when its estimate reaches the ground and stops
(`loop._touched_down`), or when the vehicle's land detector says ON_GROUND. Under GNSS the
estimate's height can be tenths of a metre off, so the first never fires on a vehicle standing on
its gear; the second needs the rotors' thrust at a minimum for a second, which a controller still
pushing towards a point below the ground (and chasing a horizontal estimate that wanders) never
gives. The vehicle was left thrashing on its gear until it tipped over
(docs/decisions/2026-12-05-landing-on-a-wrong-height.md).

This is PX4's multicopter land detector's "hit ground" under climb-rate control: a commanded
descent with no vertical movement is ground contact. Here the command is the plan's position:
in the landing it aims LAND_BELOW_M under the ground, then goes on down at a crawl
(reference.LAND_CRAWL_M_S). `ref_down - est_down` above BELOW_MARGIN_M while the estimated
vertical speed stays under Z_VEL_MAX_M_S is contact; held HOLD_S, it is the ground and the
motors go to idle. A vehicle in the air cannot stay still with its plan a tenth of a metre below
it: the controller descends.

Figures: Z_VEL_MAX_M_S is PX4's LNDMC_Z_VEL_MAX default. HOLD_S is PX4's ground-contact stage, a
third of LNDMC_TRIG_TIME, after which PX4's position controller stops chasing a horizontal
setpoint; a tilt on the gear held longer already leans the vehicle towards a tip-over.
BELOW_MARGIN_M is half the plan's LAND_BELOW_M, a choice. A vertical speed above RESET_VEL_M_S
(PX4 widens its bound 2.5 times once it believes the ground) restarts the count; below it, a
bounce on the gear does not. Pure: a state machine of its inputs.
"""

from __future__ import annotations

from dataclasses import dataclass

from trq_offboard.reference import LAND_BELOW_M

Z_VEL_MAX_M_S = 0.25
RESET_VEL_M_S = 2.5 * Z_VEL_MAX_M_S
BELOW_MARGIN_M = 0.5 * LAND_BELOW_M
HOLD_S = 1.0 / 3.0
LANDING_PHASES = ("land", "landed")


@dataclass
class GroundContact:
    """Feed it every control step; `update` says whether the ground is reached."""

    since_s: float | None = None

    def update(self, t_s: float, phase: str, ref_down_m: float, est_down_m: float,
               est_vel_down_m_s: float) -> bool:
        pressing = (phase in LANDING_PHASES and ref_down_m - est_down_m > BELOW_MARGIN_M)
        speed = abs(est_vel_down_m_s)
        if not pressing or speed > RESET_VEL_M_S:
            self.since_s = None
            return False
        if self.since_s is None:
            if speed >= Z_VEL_MAX_M_S:
                return False
            self.since_s = t_s
        return t_s - self.since_s >= HOLD_S

    def reset(self) -> None:
        self.since_s = None
