"""The simulated motion-capture system's MAVLink identity and the companion's forwarding of its
pose to the autopilot, the same for both ends (sil_vehicle/PROTOCOL.md, "The motion capture's
path").

On a rig the motion-capture PC streams each pose to the companion computer, and the companion
forwards it to the autopilot as external vision (PX4 takes VISION_POSITION_ESTIMATE or
ODOMETRY). The mocap PC is its own MAVLink system: `MOCAP_SYSTEM_ID`, component
`MOCAP_COMPONENT_ID`; the companion forwards as ODOMETRY with `VISION_ESTIMATOR_TYPE`. The
numbers are a choice (MAVLink names no id for a motion-capture system).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["MOCAP_SYSTEM_ID", "MOCAP_COMPONENT_ID", "VISION_ESTIMATOR_TYPE", "WIRINGS"]

MOCAP_SYSTEM_ID = 200
MOCAP_COMPONENT_ID = mavlink.MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY     # 197
VISION_ESTIMATOR_TYPE = mavlink.MAV_ESTIMATOR_TYPE_MOCAP
# where the motion capture's pose enters: the companion (which forwards it to the autopilot,
# as on a rig) or the autopilot directly (a rig wired that way: the vehicle sends ATT_POS_MOCAP)
WIRINGS = ("companion", "autopilot")
