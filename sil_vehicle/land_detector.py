"""The vehicle's land detector, shaped as PX4's multicopter land detector (ground contact ->
maybe landed -> landed, each held for a while), its state sent as EXTENDED_SYS_STATE's
`landed_state` (sil_vehicle/PROTOCOL.md). A pure state machine of its inputs: the vehicle's
(estimated, or under `truth` the plant's) velocity and rates, and the rotors' thrust over the
weight; it never reads the ground contact itself, as an autopilot cannot.

    ground contact  vertical speed below Z_VEL_MAX_M_S, horizontal below XY_VEL_MAX_M_S, thrust
                    below LOW_THRUST (less than hover: the ground carries the rest)
    maybe landed    ground contact held GROUND_CONTACT_S, thrust below MINIMAL_THRUST, rates
                    below ROT_MAX_RAD_S
    landed          maybe landed held LANDED_S; disarmed is landed
    take-off        leaving `landed` (thrust at or above LOW_THRUST), until TAKEOFF_S later
    landing         in the air with ground contact seen (descending slowly on low thrust)

Figures: Z_VEL_MAX_M_S is PX4's LNDMC_Z_VEL_MAX default (0.25 m/s), ROT_MAX its LNDMC_ROT_MAX
(20 deg/s), LANDED_S its one second of landed trigger time; the rest are choices. `landed`
here is the wire's report only: the plant's `VehicleState.landed` (resting on the gear) still
decides the disarm refusal and the failsafe, as before
(docs/decisions/2026-12-05-ground-contact.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# MAV_LANDED_STATE
UNDEFINED, ON_GROUND, IN_AIR, TAKEOFF, LANDING = 0, 1, 2, 3, 4

Z_VEL_MAX_M_S = 0.25
XY_VEL_MAX_M_S = 1.5          # a choice
ROT_MAX_RAD_S = math.radians(20.0)
LOW_THRUST = 0.9              # of the weight, a choice
MINIMAL_THRUST = 0.3          # of the weight, a choice
GROUND_CONTACT_S = 0.35       # a choice
LANDED_S = 1.0
TAKEOFF_S = 1.0               # a choice


@dataclass
class LandDetector:
    state: int = ON_GROUND
    _contact_since_s: float | None = None
    _maybe_since_s: float | None = None
    _takeoff_at_s: float = -math.inf

    @property
    def landed(self) -> bool:
        return self.state == ON_GROUND

    def ground_contact(self, t_s: float) -> bool:
        """On the ground, or its ground contact held GROUND_CONTACT_S (PX4's ground_contact)."""
        return self.state == ON_GROUND or (self._contact_since_s is not None
                                           and t_s - self._contact_since_s >= GROUND_CONTACT_S)

    def update(self, t_s: float, armed: bool, vel_ned_m_s, rates_frd_rad_s,
               thrust_over_weight: float) -> int:
        """The new landed state after the inputs at time t_s."""
        if not armed:
            self._contact_since_s = self._maybe_since_s = None
            self.state = ON_GROUND
            return self.state
        vn, ve, vd = vel_ned_m_s
        contact = (abs(vd) < Z_VEL_MAX_M_S and math.hypot(vn, ve) < XY_VEL_MAX_M_S
                   and thrust_over_weight < LOW_THRUST)
        if self.state == ON_GROUND:
            if thrust_over_weight >= LOW_THRUST or vd < -Z_VEL_MAX_M_S:
                self.state, self._takeoff_at_s = TAKEOFF, t_s
                self._contact_since_s = self._maybe_since_s = None
            return self.state
        self._contact_since_s = (self._contact_since_s if self._contact_since_s is not None
                                 else t_s) if contact else None
        held = self._contact_since_s is not None and t_s - self._contact_since_s >= GROUND_CONTACT_S
        maybe = (held and thrust_over_weight < MINIMAL_THRUST
                 and math.sqrt(sum(w * w for w in rates_frd_rad_s)) < ROT_MAX_RAD_S)
        self._maybe_since_s = (self._maybe_since_s if self._maybe_since_s is not None
                               else t_s) if maybe else None
        if self._maybe_since_s is not None and t_s - self._maybe_since_s >= LANDED_S:
            self.state = ON_GROUND
        elif self._contact_since_s is not None:
            self.state = LANDING
        elif t_s - self._takeoff_at_s < TAKEOFF_S:
            self.state = TAKEOFF
        else:
            self.state = IN_AIR
        return self.state

    @property
    def maybe_landed(self) -> bool:
        return self._maybe_since_s is not None
