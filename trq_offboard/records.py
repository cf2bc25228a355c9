"""Typed records exchanged across the controller's module boundaries (frozen, units in names)."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

Vec3 = tuple[float, float, float]
Vec4 = tuple[float, float, float, float]


@dataclass(frozen=True)
class StateEstimate:
    """Measured vehicle state handed to the controller (from telemetry)."""
    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    euler_rad: Vec3                    # roll, pitch, yaw (ZYX), rad
    rates_frd_rad_s: Vec3              # p, q, r body FRD

    def as_vector(self) -> np.ndarray:
        """The model state x (12)."""
        return np.array([*self.pos_ned_m, *self.vel_ned_m_s, *self.euler_rad,
                         *self.rates_frd_rad_s], dtype=float)

    @staticmethod
    def from_vector(x) -> "StateEstimate":
        x = [float(v) for v in np.asarray(x, dtype=float).reshape(-1)]
        return StateEstimate(tuple(x[0:3]), tuple(x[3:6]), tuple(x[6:9]), tuple(x[9:12]))


@dataclass(frozen=True)
class ActuatorCommand:
    """What the controller commands: throttle 0..100 % per motor, tilt (rad) per servo,
    in PX4 quad X order (motor 1 front right, 2 rear left, 3 front left, 4 rear right)."""
    throttle_pct: Vec4
    tilt_rad: Vec4


@dataclass(frozen=True)
class ReferenceSample:
    """Where the vehicle should be at one instant."""
    pos_ned_m: Vec3
    vel_ned_m_s: Vec3
    yaw_rad: float
    phase: str = "hover"


class SolveStatus(enum.Enum):
    OK = "ok"                          # converged (or the iteration budget gave a usable step)
    FAILED = "failed"                  # no usable solution; the plan must not be used


@dataclass(frozen=True)
class SolveInfo:
    status: SolveStatus
    iterations: int
    solve_time_s: float                # wall time of the solve (perf_counter), a measurement
    cost: float                        # objective value of the returned plan (nan if failed)
    message: str = ""


class CommandSource(enum.Enum):
    NMPC = "nmpc"                      # first input of this step's solution
    SHIFTED_PLAN = "shifted_plan"      # the solver failed: previous plan, shifted in time
    HOVER = "hover"                    # no usable plan: the allocation's hover command
    SPIN = "spin"                      # a motor lost: the spinning controller's (spin.py)


@dataclass(frozen=True)
class StepTimes:
    """CPU time (ns, of the calling thread: an injected clock, Controller's cpu_ns) of the parts
    of one Controller.step, in the order they run; their sum is the step's. A measurement: it
    never changes what is flown."""
    observer_ns: int = 0               # the actuators' walk, the ESO's b0 and update, its d;
                                       # in a regular period also the motor effectiveness
                                       # observer and d less its share (one compiled call:
                                       # trq_offboard/observer_period.py)
    effectiveness_ns: int = 0          # the motor effectiveness observer and d less its share
                                       # (in a regular period: the plan's throttle scale and
                                       # the walk from the estimated outputs)
    predictor_ns: int = 0              # the delay predictor (0 when it does not run)
    feedback_ns: int = 0               # reference, warm start, the solver's feedback, the command


@dataclass
class PeriodTimes:
    """CPU time (ns) of one control period of the flight loop (trq_offboard/loop.py), by part,
    filled in as the period runs (the step's parts in StepInfo.cpu): the preparation phase after
    the command, the wire (the telemetry's decode into a state, the target's encode and send),
    the log, and the whole period: the CPU of every thread of the process from this step's start
    to the next one's (the parts, the event loop, the transport's frame parse, heartbeats); -1
    until known."""
    prepare_ns: int = -1
    wire_ns: int = -1
    log_ns: int = -1
    period_ns: int = -1


@dataclass(frozen=True)
class PositionFix:
    """A GNSS fix in the vehicle's NED frame (trq_offboard/link/gnss.py)."""
    t_us: int                          # its time of validity (GPS_RAW_INT time_usec)
    pos_ned_m: Vec3
    std_ned_m: Vec3                    # its 1-sigma errors per axis (nan: not stated)


@dataclass(frozen=True)
class SensorSamples:
    """The raw sensors the flight loop received since the last step, for the fused filter
    (trq_offboard/fused.py), with the vehicle's time of the state the step answers."""
    stamp_us: int                                    # the state's time (ODOMETRY time_usec)
    # HIGHRES_IMU: (time_usec, the mean specific force, body FRD, over the interval since
    # the message before it)
    accel_frd_m_s2: tuple[tuple[int, Vec3], ...] = ()
    poses_ned_m: tuple[tuple[int, Vec3], ...] = ()   # ATT_POS_MOCAP: (time of validity us, pos)
    fixes: tuple[PositionFix, ...] = ()              # GPS_RAW_INT, 3D fix or better, in NED


@dataclass(frozen=True)
class EstimatorHealth:
    """The fused filter's health after one period (trq_offboard/fused.py)."""
    pos_ned_m: Vec3                    # its estimate, which the controller flew on
    vel_ned_m_s: Vec3
    test_ratio: float                  # the last pose's innovation test ratio (nan: none yet)
    pos_var_m2: float                  # the position's variance, trace / 3
    dead_reckoning: bool               # no pose for the filter's dropout_s
    rejected: int                      # poses rejected by the gate so far
    resets: int = 0                    # position resets to a pose after a dropout so far
    accel_rejected: int = 0            # periods whose accelerometer mean the gate rejected


@dataclass(frozen=True)
class StepInfo:
    source: CommandSource
    solve: SolveInfo
    disturbance: tuple[float, ...]     # d (6): the observer's estimate (the prediction model gets
                                       # it less the motors' share with motor_effectiveness)
    output_error: float                # (y_hat - y)^T (y_hat - y) of the observer (0 if none)
    clipped: int                       # actuator values clipped by the last line of defence
    clip_count_total: int
    failures_total: int
    # the motors' estimated effectiveness (motor_effectiveness; 1 without its observer)
    effectiveness: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    cpu: StepTimes = StepTimes()       # the step's CPU time by part
    estimator: EstimatorHealth | None = None   # the fused filter's (None: the autopilot's)
    lost_motor: int = 0                # the motor declared lost (1..4; a pair 10 i + j), 0: none
