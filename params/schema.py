"""Typed schemas of the parameter files: what each file may hold, its types and ranges.

One model per kind of file, read by `trq_params.loader.load(path, Model)`:

    VehicleFile      params/vehicle/*.yaml   (both daemons: the one vehicle-file parser)
    SimFile          params/sim/*.yaml       (sil_vehicle)
    ControllerFile   params/controller/*.yaml, the controllers (trq_offboard)
    EsoFile          params/controller/eso*.yaml, the observer's gains (trq_offboard)
    MotorEvent, ServoEvent, WindEvent, SensorEvent, ClearEvent
                     an event of params/faults/*.yaml (sil_vehicle.faultscript)
    ScenarioFile     params/scenarios/*.yaml (trq_lab.scenario)
    CampaignFile     params/campaigns/*.yaml (trq_lab.campaign)
    SensingFile      params/sensing/*.yaml   (sil_vehicle.sensors)

The models are strict and frozen and forbid unknown keys. Values keep the units of the file
(degrees stay degrees): the daemons' config modules convert them and compute derived quantities
when they build their records. Checks that span several keys of one file live here too, as
model validators raising `loader.Invalid` with the full dotted key; checks that span files (a
controller's rate against its observer's gains) stay with the daemon that joins the files.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Optional

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationInfo,
                      field_validator, model_validator)
from trq_params import exists, is_name
from trq_params.loader import (Choice, Flag, Int, Invalid, Items, NameOrPath, Num, NumOrVec,
                               PathStr, Range, Text, Vec, expect)

__all__ = ["Strict", "VehicleFile", "SimFile", "ControllerFile", "EsoFile", "MotorEvent",
           "ServoEvent", "WindEvent", "SensorEvent", "ClearEvent", "ScenarioFile",
           "CampaignFile", "FlightTarget", "FLIGHT_METRICS", "SensingFile", "Ekf2", "EKF2_KEYS",
           "STREAMS",
           "HPIPM_OPTIONS", "DELAY_BUFFER_MS", "parse_endpoint", "throttle_curve"]


class Strict(BaseModel):
    """Base of every schema: strict types, no unknown key, frozen."""
    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)


# --------------------------------------------------------------------------------------------
# vehicle
# --------------------------------------------------------------------------------------------

class Inertia(Strict):
    xx: Num(1e-6, 100.0)
    yy: Num(1e-6, 100.0)
    zz: Num(1e-6, 100.0)


def throttle_curve(c2, c1, c0, zeta_pct):
    """c2 zeta^2 + c1 zeta + c0 at zeta, the throttle in percent, in Horner's form: the one
    throttle curve of the vehicle file's checks and of both daemons (sil_vehicle.config.Quadratic,
    trq_offboard.config.Curve). Plain arithmetic: floats, NumPy arrays or CasADi expressions."""
    return (c2 * zeta_pct + c1) * zeta_pct + c0


class QuadraticCurve(Strict):
    """c2 zeta^2 + c1 zeta + c0, zeta the throttle in percent."""
    c2: Num(0.0, 1.0, open_lo=True)
    c1: Num(-10.0, 10.0)
    c0: Num(-10.0, 10.0)

    def value(self, zeta_pct: float) -> float:
        return throttle_curve(self.c2, self.c1, self.c0, zeta_pct)


class RotorCurves(Strict):
    thrust_N: QuadraticCurve
    torque_Nm: QuadraticCurve


class Rotor(Strict):
    name: Text
    azimuth_deg: Num(-180.0, 180.0)
    spin: Choice("ccw", "cw")


class Motor(Strict):
    idle_pct: Num(0.0, 50.0)
    time_constant_s: Num(0.0, 1.0)
    rate_limit_pct_s: Num(1.0, 1e6)


class Tilt(Strict):
    locked: Flag
    min_deg: Num(-90.0, 0.0)
    max_deg: Num(0.0, 90.0)
    servo_time_constant_s: Num(0.0, 1.0)
    servo_rate_limit_deg_s: Num(1.0, 1e5)


class Drag(Strict):
    quadratic_N_s2_m2: Num(0.0, 10.0)


class GearPoint(Strict):
    """A point of the landing gear that can touch the ground, body FRD from the centre of mass."""
    name: Text
    x_m: Num(-5.0, 5.0)
    y_m: Num(-5.0, 5.0)
    z_m: Num(-5.0, 5.0)


def _as_tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


class LandingGear(Strict):
    """Ground contact (sil_vehicle.dynamics.contact): spring-damper and friction per point."""
    points: Annotated[tuple[GearPoint, ...], BeforeValidator(_as_tuple)]
    stiffness_N_m: Num(1.0, 1e7)
    damping_N_s_m: Num(0.0, 1e5)
    friction: Num(0.0, 5.0)
    stick_stiffness_N_m: Num(1.0, 1e7)
    stick_damping_N_s_m: Num(0.0, 1e5)

    @model_validator(mode="after")
    def _stands(self) -> "LandingGear":
        if not 3 <= len(self.points) <= MAX_GEAR_POINTS:
            raise Invalid("landing_gear.points", len(self.points),
                          f"3 to {MAX_GEAR_POINTS} contact points")
        low = max(p.z_m for p in self.points)
        feet = sorted(((p.x_m, p.y_m) for p in self.points if p.z_m == low),
                      key=lambda f: math.atan2(f[1], f[0]))
        inside = len(feet) >= 3 and low > 0.0 and all(
            x1 * y2 - x2 * y1 > 0.0 for (x1, y1), (x2, y2) in zip(feet, feet[1:] + feet[:1]))
        if not inside:
            raise Invalid("landing_gear.points", [p.name for p in self.points],
                          "at least 3 lowest points (largest z_m, below the centre of mass) "
                          "around the centre of mass, so that the vehicle can stand")
        return self


MAX_GEAR_POINTS = 8       # the compiled tick's array holds this many (sil_vehicle/dynamics/tick.c)


class RotorSpeed(Strict):
    """The rotors' speed, for what depends on it (the IMU's vibration harmonics): the speed at
    full throttle and the blades per propeller. Below full throttle the speed follows the thrust
    curve, thrust proportional to speed squared (sil_vehicle.sensors.imu)."""
    max_rad_s: Num(1.0, 1e5)
    blades: Int(2, 8)


class VehicleFile(Strict):
    """An airframe. Rotor order is PX4 quad X (motor 1..4)."""
    name: Text
    mass_kg: Num(0.05, 100.0)
    inertia_kg_m2: Inertia
    gravity_m_s2: Num(9.7, 9.9)
    arm_length_m: Num(0.01, 5.0)
    rotor_curves: RotorCurves
    rotors: Annotated[tuple[Rotor, ...], Items(4)]
    motor: Motor
    tilt: Tilt
    drag: Drag
    landing_gear: LandingGear
    rotor_speed: Optional[RotorSpeed] = None      # absent: no rotor-speed-driven model

    @model_validator(mode="after")
    def _can_fly(self) -> "VehicleFile":
        thrust = self.rotor_curves.thrust_N
        if thrust.value(self.motor.idle_pct) <= 0.0:
            raise Invalid("motor.idle_pct", self.motor.idle_pct,
                          "a throttle where rotor_curves.thrust_N > 0")
        weight = self.mass_kg * self.gravity_m_s2
        if 4.0 * thrust.value(100.0) <= weight:
            raise Invalid("rotor_curves.thrust_N", thrust.model_dump(),
                          f"full throttle to lift the weight {weight:.2f} N (it gives "
                          f"{4.0 * thrust.value(100.0):.2f} N: the vehicle cannot fly)")
        return self


# --------------------------------------------------------------------------------------------
# simulation
# --------------------------------------------------------------------------------------------

# Telemetry streams the vehicle can send, by MAVLink message name. HIGHRES_IMU and ATT_POS_MOCAP
# are the raw sensors of a sensing profile, ESTIMATOR_STATUS its estimator's health
# (sil_vehicle/PROTOCOL.md): sent only when the profile carries them, 0 (off) when a file leaves
# them out.
STREAMS = ("HEARTBEAT", "SYS_STATUS", "ODOMETRY", "ATTITUDE", "LOCAL_POSITION_NED",
           "SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS", "GLOBAL_POSITION_INT", "GPS_RAW_INT",
           "HOME_POSITION", "HIGHRES_IMU", "ATT_POS_MOCAP", "ESTIMATOR_STATUS",
           "EXTENDED_SYS_STATE")

_RATE = Int(0, 10_000)      # then checked against physics_rate_hz by SimFile


class StreamRates(Strict):
    HEARTBEAT: _RATE
    SYS_STATUS: _RATE
    ODOMETRY: _RATE
    ATTITUDE: _RATE
    LOCAL_POSITION_NED: _RATE
    SERVO_OUTPUT_RAW: _RATE
    ACTUATOR_OUTPUT_STATUS: _RATE
    GLOBAL_POSITION_INT: _RATE
    GPS_RAW_INT: _RATE
    HOME_POSITION: _RATE
    HIGHRES_IMU: _RATE = 0
    ATT_POS_MOCAP: _RATE = 0
    ESTIMATOR_STATUS: _RATE = 0
    EXTENDED_SYS_STATE: _RATE = 0       # the land detector's landed_state (PX4 sends it at 1 Hz)


class Telemetry(Strict):
    gcs: StreamRates
    offboard: StreamRates


def parse_endpoint(text: Any) -> tuple[str, int]:
    """`HOST:PORT` -> (host, port); raises the field error of an endpoint otherwise."""
    host, sep, port = str(text).rpartition(":")
    if not isinstance(text, str) or not sep or not host or not port.isdigit() \
            or not 0 <= int(port) <= 65535:
        raise expect("HOST:PORT with a port in [0, 65535]")
    return host, int(port)


def _endpoint(value: Any) -> str:
    parse_endpoint(value)
    return value


Endpoint = Annotated[str, BeforeValidator(_endpoint)]


class Impair(Strict):
    loss: Num(0.0, 1.0) = 0.0
    delay_ms: Num(0.0, 10_000.0) = 0.0
    jitter_ms: Num(0.0, 10_000.0) = 0.0
    duplicate: Num(0.0, 1.0) = 0.0
    reorder: Num(0.0, 1.0) = 0.0


class Link(Strict):
    bind: Endpoint
    target: Endpoint
    impair: Optional[Impair] = None


class Links(Strict):
    gcs: Link
    offboard: Link


class Clock(Strict):
    mode: Choice("lockstep", "realtime")
    speed_up: Num(0.01, 1000.0)
    resend_s: Num(0.01, 60.0)
    free_run_after_s: Num(0.05, 3600.0)


class Gusts(Strict):
    enabled: Flag
    sigma_m_s: Num(0.0, 20.0)
    length_m: Num(1.0, 2000.0)


class Wind(Strict):
    speed_m_s: Num(0.0, 40.0)
    direction_deg: Num(-360.0, 360.0)
    gusts: Gusts


class Noise(Strict):
    position_m: Num(0.0, 10.0)
    velocity_m_s: Num(0.0, 10.0)
    attitude_rad: Num(0.0, 1.0)
    rates_rad_s: Num(0.0, 10.0)


class Faults(Strict):
    motor_effectiveness: Vec(4, 0.0, 1.0)
    motor_tv_amplitude: Vec(4, 0.0, 1.0)
    motor_tv_omega_rad_s: Vec(4, 0.0, 1000.0)
    motor_tv_phase_rad: Vec(4, -10.0, 10.0)


class Ground(Strict):
    crash_speed_m_s: Num(0.1, 100.0)
    crash_tilt_deg: Num(10.0, 180.0)


class Home(Strict):
    lat_deg: Num(-90.0, 90.0)
    lon_deg: Num(-180.0, 180.0)
    alt_m: Num(-500.0, 9000.0)


class Log(Strict):
    dir: Text
    rate_hz: _RATE


class SimFile(Strict):
    """Simulation settings; `vehicle` names the airframe file."""
    vehicle: PathStr
    physics_rate_hz: Int(500, 10_000)
    control_rate_hz: _RATE
    seed: Int(0, 2**63 - 1)
    physics_core: Choice("auto", "compiled", "python") = "auto"
    # the sensing profile (params/sensing): a built-in name or a path; checked, against the
    # physics rate, when sil_vehicle.config loads the file
    sensing: NameOrPath = "truth"
    # where the motion capture's pose enters (a profile with one): `companion`, a simulated
    # mocap PC streams it to the companion, which forwards it to the autopilot as external
    # vision (trq_wire.mocap, as on a rig; the shipped default.yaml); `autopilot`, the vehicle's
    # estimator takes it and sends ATT_POS_MOCAP (a rig wired that way)
    mocap_wiring: Choice("autopilot", "companion") = "autopilot"
    clock: Clock
    telemetry: Telemetry
    links: Links
    wind: Wind
    noise: Noise
    faults: Faults
    ground: Ground
    home: Home
    log: Log

    @model_validator(mode="after")
    def _rates(self) -> "SimFile":
        physics = self.physics_rate_hz
        if 1_000_000 % physics:
            raise Invalid("physics_rate_hz", physics, "a rate whose period is a whole microsecond")

        def check(key: str, hz: int) -> None:
            if hz > physics or (hz and physics % hz):
                raise Invalid(key, hz, f"0 or a rate in Hz that divides physics_rate_hz "
                                       f"({physics})")
        check("control_rate_hz", self.control_rate_hz)
        if self.control_rate_hz == 0:
            raise Invalid("control_rate_hz", 0, "a rate > 0")
        for name in ("gcs", "offboard"):
            rates = getattr(self.telemetry, name)
            for stream in STREAMS:
                check(f"telemetry.{name}.{stream}", getattr(rates, stream))
        if self.telemetry.offboard.ODOMETRY != self.control_rate_hz:
            raise Invalid("telemetry.offboard.ODOMETRY", self.telemetry.offboard.ODOMETRY,
                          f"control_rate_hz ({self.control_rate_hz}): the offboard state stream "
                          "paces the control loop and the lockstep")
        check("log.rate_hz", self.log.rate_hz)
        return self


# --------------------------------------------------------------------------------------------
# observer
# --------------------------------------------------------------------------------------------

class EsoGroup(Strict):
    # the group's bandwidth, or one per axis (x, y, z; roll, pitch, yaw)
    omega_o_rad_s: NumOrVec(3, 0.1, 500.0)
    delta: Num(1e-6, 10.0)


class EsoTranslational(EsoGroup):
    output: Choice("position", "velocity") = "position"


class EsoRotational(EsoGroup):
    output: Choice("angles", "rates") = "angles"


class MaxDisturbance(Strict):
    translational_m_s2: Num(0.0, 100.0)
    rotational_rad_s2: Num(0.0, 1000.0)


class EsoFile(Strict):
    kind: Choice("nonlinear", "linear")
    alpha: Vec(3, 0.05, 1.0)
    translational: EsoTranslational
    rotational: EsoRotational
    substeps: Int(1, 1000)
    max_disturbance: MaxDisturbance


# --------------------------------------------------------------------------------------------
# controller
# --------------------------------------------------------------------------------------------

class Observer(Strict):
    kind: Choice("none", "nonlinear", "linear")
    file: PathStr


class Effectiveness(Strict):
    """The motor effectiveness observer; it reads the observer's disturbance."""
    estimate: Choice("on", "off")
    bandwidth_rad_s: Num(1.0, 2000.0) = 250.0
    min: Num(0.01, 1.0) = 0.1
    substeps: Int(1, 1000) = 10


class LostMotor(Strict):
    """A whole motor lost (trq_offboard/lost_motor.py): detected from the motors' effectiveness
    estimate (needs motor_effectiveness on), then `response` flies it: the NMPC's failed
    configuration, or the spinning controller of the file's `spin:` section."""
    detect: Choice("on", "off")
    below: Num(0.0, 0.45) = 0.2                # effectiveness at or below: the motor lost
    hold_s: Num(0.0, 2.0) = 0.05               # ... held this long, without a break
    # ... or (set) this long in all within the last within_s s: a step back above `below`
    # no longer restarts the count (null: without a break)
    within_s: Optional[Num(0.0, 2.0)] = None
    min_command_pct: Num(0.0, 100.0) = 20.0    # ... while commanded at least this
    yaw_weight: Num(0.0, 1e6) = 0.0            # the failed NMPC's weight on yaw and yaw rate
    max_body_rate_rad_s: Num(0.1, 100.0) = 30.0  # the failed NMPC's body-rate bound
    descent_speed_m_s: Num(0.05, 5.0) = 1.0    # the descent to the ground once lost
    # the spin governed (null: free): the yaw rate's weight and its target's magnitude (rad/s, in
    # the direction the vehicle spins); the yaw angle keeps yaw_weight
    spin_weight: Optional[Num(0.0, 1e6)] = None
    spin_rate_rad_s: Num(0.0, 100.0) = 0.0
    # the failed NMPC's horizon (null: the controller's): a step that resolves the spin
    horizon_steps: Optional[Int(2, 200)] = None
    horizon_step_s: Optional[Num(1e-3, 1.0)] = None
    # what flies once one motor is lost: the failed NMPC above (nmpc), or the spinning
    # relaxed-hover controller of the file's `spin:` section (spin; trq_offboard/spin.py), which
    # holds the position, then lands; two motors lost keep the failed NMPC
    response: Choice("nmpc", "spin") = "nmpc"
    # two motors lost (trq_offboard/lost_motor.py PairLossDetector; null: not looked for): the
    # observer's vertical deficit beyond the strongest single motor's, averaged over hold_s, at
    # or above this (m/s^2); the angular parts' scale in the pair's least squares (rad/s^2)
    pair_excess_m_s2: Optional[Num(0.1, 20.0)] = None
    pair_angular_scale_rad_s2: Num(0.1, 1000.0) = 5.0

    @model_validator(mode="after")
    def _window_holds_the_hold(self) -> "LostMotor":
        if self.within_s is not None and self.within_s < self.hold_s:
            raise Invalid("lost_motor.within_s", self.within_s,
                          f"at least hold_s ({self.hold_s:g} s): the window the time at or "
                          "below is counted in")
        return self


class Estimator(Strict):
    """Where the controller's position and velocity come from (trq_offboard/fused.py): the
    vehicle's ODOMETRY as it is (`autopilot`, the default), or the companion's fused filter on
    the motion capture pose and the raw IMU, which the controller then asks the vehicle for
    (`fused`; its parameters below, defaults for the `mocap` profile's sensors)."""
    kind: Choice("autopilot", "fused") = "autopilot"
    mocap_std_m: Num(1e-6, 1.0) = 0.0005               # the pose's noise, 1 sigma per axis
    accel_std_m_s2: Num(1e-4, 100.0) = 0.16            # one HIGHRES_IMU's, per axis
    model_acc_density_m_s2_rthz: Num(0.0, 100.0) = 0.01    # the model's white error
    residual_walk_m_s3_rthz: Num(1e-6, 1e3) = 1.0      # a_r's random walk
    accel_bias_std_m_s2: Num(1e-4, 10.0) = 0.2         # its bias at the start, 1 sigma
    accel_bias_walk_m_s3_rthz: Num(0.0, 10.0) = 0.01   # its bias's random walk
    pose_gate: Num(1.0, 1e6) = 25.0                    # chi-square (3 dof) gate on a pose
    dropout_s: Num(0.0, 10.0) = 0.05                   # no pose this long: dead reckoning
    imu_rate_hz: Int(1, 200) = 125                     # HIGHRES_IMU asked of the vehicle
    mocap_rate_hz: Int(1, 1000) = 100                  # ATT_POS_MOCAP asked of the vehicle
    history: Int(2, 100) = 8                           # control periods kept (delayed pose)
    # the known input: the model's acceleration under the commands in effect plus the part of
    # the observer's disturbance that the effectiveness observer explains as the motors'
    # (`motors`: the model flown with the motors' estimated effectiveness; without that
    # observer, nothing), or plus the observer's whole disturbance (`observer`: its noise comes
    # back through the filter), or the model's alone (`none`); a_r carries what it leaves out
    disturbance_input: Choice("observer", "motors", "none") = "motors"
    # the autopilot's velocity (ODOMETRY) fused as a measurement of v, 1 sigma; 0: not fused
    autopilot_vel_std_m_s: Num(0.0, 10.0) = 0.0
    # the position source: the motion capture pose (ATT_POS_MOCAP) or a GNSS receiver's fix
    # (GPS_RAW_INT, 3D fix or better, in NED around HOME_POSITION: trq_offboard/link/gnss.py)
    position_source: Choice("mocap", "gnss") = "mocap"
    gnss_rate_hz: Int(1, 50) = 10                      # GPS_RAW_INT asked of the vehicle
    # a fix's noise, 1 sigma horizontal and vertical; 0: the fix's own h_acc / v_acc
    gnss_std_m: Vec(2, 0.0, 100.0) = (0.0, 0.0)
    # the oldest fix fused (its time of validity behind the state's time: the receiver's
    # delay and the wait for the next control period); the history kept covers it
    gnss_max_age_s: Num(0.0, 2.0) = 0.25
    # the receiver's delay: GPS_RAW_INT is stamped at its arrival (as PX4 stamps it), its time
    # of validity is this much earlier (EKF2_GPS_DELAY's role; PX4's default 110 ms)
    gnss_delay_s: Num(0.0, 1.0) = 0.11
    # a period's accelerometer mean rejected past this chi-square (3 dof) gate, unless the
    # last accel_reject_max periods were (then taken); a choice (trq_offboard/fused.py)
    accel_gate: Num(1.0, 1e9) = 100.0
    accel_reject_max: Int(1, 100) = 3
    # after a dropout, poses outside pose_gate: this many mutually consistent in a row reset
    # the position to the last (as EKF2 resets to a measurement); a choice
    regain_poses: Int(3, 100) = 3

    @model_validator(mode="after")
    def _only_fused(self) -> "Estimator":
        if self.kind == "autopilot":
            extra = sorted(self.model_fields_set - {"kind"})
            if extra:
                raise Invalid(f"estimator.{extra[0]}", getattr(self, extra[0]),
                              "no fused filter parameter with kind autopilot (set kind: fused)")
        if self.position_source == "mocap":
            extra = sorted(k for k in self.model_fields_set if k.startswith("gnss_"))
            if extra:
                raise Invalid(f"estimator.{extra[0]}", getattr(self, extra[0]),
                              "no GNSS parameter with position_source mocap (set "
                              "position_source: gnss)")
        return self


class Horizon(Strict):
    steps: Int(2, 200)
    step_s: Num(1e-3, 1.0)


class WeightsFile(Strict):
    position: Vec(3, 0.0, 1e6)
    velocity: Vec(3, 0.0, 1e6)
    euler: Vec(3, 0.0, 1e6)
    rates: Vec(3, 0.0, 1e6)
    terminal_factor: Num(0.0, 1e4)
    tilt: Num(0.0, 1e6)
    throttle: Num(0.0, 1e6)
    tilt_rate: Num(0.0, 1e6)
    output_error: Num(0.0, 1e6)


class Constraints(Strict):
    max_roll_pitch_deg: Num(1.0, 89.0)
    max_body_rate_rad_s: Num(0.1, 50.0)


# HPIPM's further IPM arguments (d_ocp_qp_ipm_arg_set_<name>) a solver file may set
HPIPM_OPTIONS = ("mu0", "tol_stat", "tol_eq", "tol_ineq", "tol_comp", "reg_prim", "ric_alg",
                 "pred_corr", "split_step")


class HpipmOptions(Strict):
    mu0: Optional[Num(1e-8, 1e8)] = None
    tol_stat: Optional[Num(1e-14, 1.0)] = None
    tol_eq: Optional[Num(1e-14, 1.0)] = None
    tol_ineq: Optional[Num(1e-14, 1.0)] = None
    tol_comp: Optional[Num(1e-14, 1.0)] = None
    reg_prim: Optional[Num(0.0, 1.0)] = None
    ric_alg: Optional[Int(0, 1)] = None
    pred_corr: Optional[Int(0, 1)] = None
    split_step: Optional[Int(0, 1)] = None

    def pairs(self) -> tuple[tuple[str, float], ...]:
        """The options the file set, as (name, value), in the order of HPIPM_OPTIONS."""
        return tuple((n, getattr(self, n)) for n in HPIPM_OPTIONS if getattr(self, n) is not None)


class SolverFile(Strict):
    kind: Choice("rti", "sqp", "ipopt")
    hessian: Choice("gauss_newton", "exact")
    max_iterations: Int(1, 100)
    tolerance: Num(0.0, 1.0)
    qp_solver: Choice("qrqp", "osqp", "hpipm")
    regularization: Num(0.0, 1e3)
    ipopt_max_iterations: Int(1, 10_000)
    codegen: Choice("auto", "off") = "auto"
    hpipm_interface: Choice("direct", "conic") = "direct"
    hpipm_mode: Choice("auto", "speed_abs", "speed", "balance", "robust") = "auto"
    qp_max_iterations: Int(1, 1000) = 50
    hpipm_options: HpipmOptions = Field(default_factory=HpipmOptions)


class ReferenceFile(Strict):
    kind: Choice("hover", "step", "circle", "helix", "figure8")
    altitude_m: Num(0.2, 100.0)
    climb_speed_m_s: Num(0.05, 5.0)
    hold_s: Num(0.0, 600.0)
    duration_s: Num(0.0, 3600.0)
    ramp_s: Num(0.0, 60.0)
    radius_m: Num(0.0, 50.0)
    period_s: Num(1.0, 600.0)
    helix_climb_m: Num(-20.0, 20.0)
    step_ned_m: Vec(3, -20.0, 20.0)
    land: Flag


class SpinWeights(Strict):
    """The lost-motor spin controller's LQR weights (trq_offboard/spin.py): states in rad/s, the
    primary axis in rad, the actuators in % / 100 and rad, the force along the axis in N."""
    rates: Vec(2, 0.0, 1e6)               # the rates normal to the axis (nutation)
    spin: Num(0.0, 1e6)                   # the spin rate's error
    axis: Num(0.0, 1e6)                   # the primary axis' direction error
    force: Num(0.0, 1e6)                  # the force along the axis' error
    actuator: Vec(2, 0.0, 1e6)            # throttle, tilt (the lagged outputs' deviation)
    input: Vec(2, 1e-9, 1e6)              # throttle, tilt (the commands' deviation)


class SpinPosition(Strict):
    """Its position loop (a cascade outside the LQR): accelerations per m, per m/s, per m s."""
    kp_s2: Vec(2, 0.0, 100.0)             # horizontal, vertical
    kd_s: Vec(2, 0.0, 100.0)
    ki_s3: Vec(2, 0.0, 100.0)
    max_lean_deg: Num(0.0, 60.0)          # the axis' largest lean asked for
    climb_force_N: Num(0.0, 50.0)         # the largest force along the axis above the trim's
    sink_force_N: Num(0.0, 50.0)          # the largest force below it
    max_integral_m_s2: Num(0.0, 20.0)


class SpinLanding(Strict):
    """Its descent reference (trq_offboard/spin.py landing_reference) and touchdown."""
    hold_s: Num(0.0, 600.0)               # position held at the failure point first
    descent_speed_m_s: Num(0.05, 5.0)
    final_height_m: Num(0.0, 20.0)        # below it, the slower final speed
    final_speed_m_s: Num(0.05, 5.0)
    contact_height_m: Num(0.0, 1.0)       # motors off within it of the ground, when still
    contact_speed_m_s: Num(0.0, 5.0)
    final_spin_rate_rad_s: Num(5.0, 60.0)  # the spin below final_height_m (a smaller cone)


class Spin(Strict):
    """The lost-motor spinning controller (trq_offboard/spin.py; docs/decisions/
    2026-12-05-lost-motor-spin-controller.md)."""
    spin_rate_rad_s: Num(5.0, 60.0)
    control_rate_hz: Int(20, 1000)
    weights: SpinWeights
    position: SpinPosition
    landing: SpinLanding
    # the inner loop about the orbit: the LQR, or an NMPC on the same body-frame model kept
    # nonlinear, its actuator bounds as constraints, the LQR's P as its terminal cost
    # (trq_offboard/spin_nmpc.py); its horizon in control periods
    inner: Choice("lqr", "nmpc") = "lqr"
    horizon_steps: Int(1, 200) = 20
    # the observer's estimate of what the model misses (the controller's ESO) fed forward: its
    # acceleration into the position loop, its angular acceleration into the inner loop's
    # operating point and model, through a first-order low-pass of this time constant (s); null:
    # not used (the position loop's integral alone)
    observer_lowpass_s: Optional[Num(0.0, 10.0)] = None
    # for this long after the switch the estimate is not taken (the low-pass holds its start):
    # the observer still carries the lost motor's deficit until it has re-converged on the model
    # without it
    observer_settle_s: Num(0.0, 10.0) = 0.1


_ON_OFF_AUTO = Choice("on", "off", "auto")


class ControllerFile(Strict):
    """A controller; `vehicle` and `observer.file` name the other files it reads."""
    name: Text
    vehicle: PathStr
    observer: Observer
    applied_input: Choice("commanded", "outputs")
    applied_delay_s: Num(0.0, 1.0)
    # the autopilot's low-pass on the body rates it publishes (PX4's IMU_GYRO_CUTOFF, Hz; 0: raw),
    # which the body-rate observer carries in its output (trq_offboard/rate_observer.py)
    rates_lowpass_hz: Num(0.0, 1000.0) = 0.0
    delay_compensation: Choice("predict", "none", "auto") = "auto"
    lagged_actuators: _ON_OFF_AUTO = "auto"
    actuator_states: _ON_OFF_AUTO = "auto"
    motor_effectiveness: Optional[Effectiveness] = None
    lost_motor: Optional[LostMotor] = None
    estimator: Estimator = Field(default_factory=Estimator)
    control_rate_hz: Int(1, 1000)
    horizon: Horizon
    weights: WeightsFile
    constraints: Constraints
    solver: SolverFile
    reference: ReferenceFile
    spin: Optional[Spin] = None           # the lost-motor controller (trq_offboard/spin.py)

    @model_validator(mode="after")
    def _consistent(self) -> "ControllerFile":
        eff = self.motor_effectiveness
        if eff is not None and eff.estimate == "on":
            if self.observer.kind == "none":
                raise Invalid("motor_effectiveness.estimate", "on",
                              "off with observer.kind none (the motor effectiveness observer "
                              "reads the extended state observer's disturbance)")
            if self.applied_input == "outputs":
                raise Invalid("applied_input", "outputs",
                              "commanded with motor_effectiveness on (the outputs the vehicle "
                              "reports already carry the motors' loss: the observer would see "
                              "no fault to estimate)")
        lm = self.lost_motor
        if lm is not None and lm.detect == "on" and (eff is None or eff.estimate != "on"):
            raise Invalid("lost_motor.detect", "on", "off without motor_effectiveness on (the "
                          "detector reads the motors' effectiveness estimate)")
        if lm is not None and lm.response == "spin" and self.spin is None:
            raise Invalid("lost_motor.response", "spin", "nmpc without a `spin:` section (the "
                          "spinning controller's parameters: see params/controller/"
                          "trq_nmpc_eso.yaml)")
        if lm is not None and lm.response == "spin" \
                and self.spin.control_rate_hz != self.control_rate_hz:
            raise Invalid("spin.control_rate_hz", self.spin.control_rate_hz,
                          f"{self.control_rate_hz} (control_rate_hz) with lost_motor.response "
                          "spin: the spinning controller steps in the controller's period")
        s = self.solver
        if s.hessian == "exact" and s.hpipm_mode == "speed_abs":
            raise Invalid("solver.hpipm_mode", "speed_abs",
                          "speed, balance, robust or auto with hessian exact (the exact Hessian "
                          "needs the QP's multipliers, which speed_abs does not compute to "
                          "tolerance)")
        est = self.estimator
        if est.kind == "fused" and est.dropout_s * self.control_rate_hz < 1.0 - 1e-9:
            raise Invalid("estimator.dropout_s", est.dropout_s,
                          f"at least one control period ({1.0 / self.control_rate_hz:g} s)")
        if est.kind == "fused" and est.position_source == "mocap" \
                and est.history * est.mocap_rate_hz < self.control_rate_hz:
            raise Invalid("estimator.history", est.history,
                          "at least one pose period of control periods (control_rate_hz / "
                          f"mocap_rate_hz = {self.control_rate_hz / est.mocap_rate_hz:g})")
        r = self.reference
        if 2.0 * r.ramp_s > r.duration_s:
            raise Invalid("reference.ramp_s", r.ramp_s,
                          f"at most half of duration_s ({r.duration_s:g})")
        period = 1.0 / self.control_rate_hz
        if self.horizon.step_s < period - 1e-12:
            raise Invalid("horizon.step_s", self.horizon.step_s,
                          f"at least one control period ({period:g} s)")
        if eff is not None and eff.estimate == "on" \
                and eff.bandwidth_rad_s > eff.substeps * self.control_rate_hz:
            raise Invalid("motor_effectiveness.bandwidth_rad_s", eff.bandwidth_rad_s,
                          f"at most substeps x control_rate_hz = {eff.substeps} x "
                          f"{self.control_rate_hz} = {eff.substeps * self.control_rate_hz:g} "
                          "rad/s (explicit Euler substeps; raise substeps for a faster observer)")
        return self


# --------------------------------------------------------------------------------------------
# fault script (sil_vehicle.faultscript: one model per kind of event)
# --------------------------------------------------------------------------------------------

class _Event(Strict):
    """An event of a fault script: when, in vehicle time."""
    at_s: Num(0.0, 1e6)


class TimeVarying(Strict):
    a: Num(0.0, 1.0)
    b: Num(0.0, 1.0)
    w: Num(0.0, 1000.0)
    phi: Num(-10.0, 10.0) = 0.0


class MotorEvent(_Event):
    motor: Int(1, 4)
    effectiveness: Optional[Num(0.0, 1.0)] = None
    time_varying: Optional[TimeVarying] = None
    stopped: Optional[Flag] = None      # (not "off": a bare off would read as a key or a string)

    @model_validator(mode="after")
    def _acts(self) -> "MotorEvent":
        if self.effectiveness is None and self.time_varying is None and self.stopped is None:
            raise Invalid("motor", self.motor, "with effectiveness, time_varying or stopped")
        return self


class ServoEvent(_Event):
    servo: Int(1, 4)
    # null frees the servo; the angle's range is the vehicle's tilt range (the validation's
    # context), the Range below when none is given
    stuck_deg: Annotated[Any, Range(-90.0, 90.0)]

    @field_validator("stuck_deg", mode="before")
    @classmethod
    def _angle(cls, value: Any, info: ValidationInfo) -> Any:
        lo, hi = info.context or (-90.0, 90.0)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not lo <= value <= hi):
            raise expect(f"null or an angle in [{lo:g}, {hi:g}] deg")
        return value


class EventWind(Strict):
    speed_m_s: Optional[Num(0.0, 40.0)] = None
    direction_deg: Optional[Num(-360.0, 360.0)] = None
    gusts: Optional[Flag] = None
    gust_sigma_m_s: Optional[Num(0.0, 20.0)] = None


class WindEvent(_Event):
    wind: EventWind

    @model_validator(mode="after")
    def _acts(self) -> "WindEvent":
        if not self.wind.model_fields_set:
            raise Invalid("wind", {}, "speed_m_s, direction_deg, gusts or gust_sigma_m_s")
        return self


# MAV_CMD_INJECT_FAILURE's sensor units (sil_vehicle.sensors.faults)
SENSOR_UNITS = ("gyro", "accel", "mag", "baro", "gnss", "mocap")


class SensorEvent(_Event):
    # MAV_CMD_INJECT_FAILURE's sensor units and types (sil_vehicle.sensors.faults)
    sensor: Choice(*SENSOR_UNITS)
    failure: Choice("ok", "off", "stuck", "garbage", "wrong")
    size: Optional[Num(-1e4, 1e4)] = None   # wrong: the error, in the unit's SI unit (or deg)

    @model_validator(mode="after")
    def _size(self) -> "SensorEvent":
        if self.size is not None and self.failure != "wrong":
            raise Invalid("size", self.size, "no size unless failure is wrong")
        return self


class ClearEvent(_Event):
    clear: Flag

    @model_validator(mode="after")
    def _true(self) -> "ClearEvent":
        if not self.clear:
            raise Invalid("clear", False, "true")
        return self


# --------------------------------------------------------------------------------------------
# scenario (trq_lab.scenario)
# --------------------------------------------------------------------------------------------

class ScenarioWind(Strict):
    speed_m_s: Num(0.0, 40.0)
    direction_deg: Num(-360.0, 360.0)
    gusts: Flag


class ScenarioLink(Strict):
    """The offboard link's seeded impairment (sil_vehicle's links.offboard.impair)."""
    loss: Optional[Num(0.0, 1.0)] = None
    delay_ms: Optional[Num(0.0, 10_000.0)] = None
    jitter_ms: Optional[Num(0.0, 10_000.0)] = None
    duplicate: Optional[Num(0.0, 1.0)] = None
    reorder: Optional[Num(0.0, 1.0)] = None


class ScenarioTargets(Strict):
    """What one controller must achieve: each metric at most its bound, crashed as given."""
    crashed: Optional[Flag] = None
    rmse_pos_m: Optional[Num(0.0, 1e6)] = None
    rmse_pos_after_fault_m: Optional[Num(0.0, 1e6)] = None
    max_pos_err_m: Optional[Num(0.0, 1e6)] = None
    max_yaw_err_deg: Optional[Num(0.0, 1e6)] = None
    rmse_yaw_deg: Optional[Num(0.0, 1e6)] = None
    recovery_s: Optional[Num(0.0, 1e6)] = None
    diagnosis_s: Optional[Num(0.0, 1e6)] = None
    # a whole motor lost (issue 40; trq_lab.metrics' lost-motor block)
    touchdown_speed_m_s: Optional[Num(0.0, 1e6)] = None
    drift_after_fault_m: Optional[Num(0.0, 1e6)] = None
    max_thrust_tilt_after_fault_deg: Optional[Num(0.0, 1e6)] = None
    detection_s: Optional[Num(0.0, 1e6)] = None


class ScenarioBetter(Strict):
    better: Text
    worse: Text
    # the bounded ones
    metric: Choice(*(k for k in ScenarioTargets.model_fields if k != "crashed"))


class ScenarioFile(Strict):
    """A scenario file (params/scenarios/*.yaml): wind, faults, reference, controllers, targets."""
    name: Text
    description: Text
    seed: Int(0, 2**31)
    wind: ScenarioWind
    faults: Optional[Text]                  # a built-in fault script name, a path, or null
    reference: dict[str, Any]               # checked by the controller's loader when flown
    controllers: list[Text]
    offboard_link: Optional[ScenarioLink] = None
    # the vehicle's sensing profile (params/sensing): a built-in name or a path; null (or left
    # out): mocap (trq_lab.scenario.SENSING_DEFAULT)
    sensing: Optional[NameOrPath] = None
    recovery_threshold_m: Num(0.001, 100.0)
    timeout_s: Num(1.0, 36000.0)
    targets: dict[str, ScenarioTargets] = {}
    better: list[ScenarioBetter] = []

    @model_validator(mode="after")
    def _names(self) -> "ScenarioFile":
        if not self.controllers:
            raise Invalid("controllers", [], "a non-empty list of controller names")
        for i, c in enumerate(self.controllers):
            if not exists("controller", c):
                raise Invalid(f"controllers[{i}]", c, "a built-in controller name or a "
                              "controller YAML path")
        for c in self.targets:
            if c not in self.controllers:
                raise Invalid(f"targets.{c}", self.targets[c].model_dump(exclude_none=True),
                              "targets of one of the controllers " + ", ".join(self.controllers))
        for i, b in enumerate(self.better):
            for key in ("better", "worse"):
                if getattr(b, key) not in self.controllers:
                    raise Invalid(f"better[{i}].{key}", getattr(b, key),
                                  "one of " + "|".join(self.controllers))
        return self


# --------------------------------------------------------------------------------------------
# campaign (trq_lab.campaign: the axes' keys are checked by trq_lab.campaign.spec)
# --------------------------------------------------------------------------------------------

AXES = ("fault", "wind", "trajectory", "link", "plant", "sensing", "outage")
CONTROLLER_MODELS = ("nominal", "plant")


class Plant(Strict):
    """A campaign's simulated airframe against its file (trq_lab.overlays.PLANT_PARAMS says what
    each key changes): factors, and an offset for idle; the defaults are the file itself, the
    ranges keep a plant physical (the vehicle schema then checks the airframe that results)."""
    mass_scale: Num(0.5, 2.0) = 1.0
    inertia_scale: Num(0.2, 5.0) = 1.0
    arm_length_scale: Num(0.5, 2.0) = 1.0
    thrust_scale: Num(0.5, 2.0) = 1.0
    torque_scale: Num(0.2, 5.0) = 1.0
    motor_lag_scale: Num(0.0, 10.0) = 1.0
    motor_rate_scale: Num(0.1, 10.0) = 1.0
    servo_lag_scale: Num(0.0, 10.0) = 1.0
    servo_rate_scale: Num(0.1, 10.0) = 1.0
    drag_scale: Num(0.0, 10.0) = 1.0
    idle_offset_pct: Num(-20.0, 20.0) = 0.0


class SensingAxis(Strict):
    """A campaign's sensing profile (params/sensing): what the sim file's `sensing` holds, a
    built-in name or a path; loaded against the physics rate by trq_lab.campaign.spec. A grid or
    a sample may write the profile, or a list of them, as the axis itself (`sensing: [truth,
    mocap]`)."""
    profile: NameOrPath = "truth"


class OutageAxis(Strict):
    """A campaign's sensor outage: `sensor` off (MAV_CMD_INJECT_FAILURE's OFF: it delivers
    nothing) from `at_s`, its own readings again (OK) from `at_s + duration_s`, in vehicle time.
    The two events join the flight's fault script beside its fault; a grid flies it under the
    sensing profiles that carry the sensor (trq_lab.campaign.spec checks that one does). A grid
    may write `none` for a flight without an outage."""
    sensor: Choice(*SENSOR_UNITS)
    at_s: Num(0.0, 1e6)
    duration_s: Num(0.0, 3600.0, open_lo=True)


# the models whose keys (dotted, `leaf_types`) each axis sets: a fault is a motor or a servo
# event, a wind a wind event's, a trajectory a controller's reference, a link the offboard link's
# impairment, a plant the simulated airframe's factors, a sensing the vehicle's sensing profile,
# an outage a sensor off for a while
AXIS_MODELS = {"fault": (MotorEvent, ServoEvent), "wind": (EventWind,),
               "trajectory": (ReferenceFile,), "link": (Impair,), "plant": (Plant,),
               "sensing": (SensingAxis,), "outage": (OutageAxis,)}


class CampaignGrid(Strict):
    """Every combination of the axes' values (each axis checked by trq_lab.campaign.spec)."""
    fault: Any = None
    wind: Any = None
    trajectory: Any = None
    link: Any = None
    plant: Any = None
    sensing: Any = None
    outage: Any = None


class CampaignSample(CampaignGrid):
    """n seeded random draws of the axes' distributions."""
    n: Int(1, 10_000_000)
    seed: Int(0, 2**31 - 1)


class CampaignPaired(Strict):
    """`controller` does better than `worse` (a lower RMSE after the fault, or it flies where
    the other crashes) on at least `share` of the flights both flew on the same plant."""
    worse: Text
    share: Num(0.0, 1.0)


class CampaignTargets(Strict):
    """A campaign's targets: among the flights of `controller` whose faulted trim keeps at least
    `min_margin_pct` of throttle margin on every motor, at least `share` stay within
    `rmse_after_fault_m`; and the paired comparisons."""
    controller: Text
    min_margin_pct: Num(0.0, 100.0)
    rmse_after_fault_m: Num(1e-5, 100.0)
    share: Num(0.0, 1.0)
    better: list[CampaignPaired] = []


# The metrics of a campaign's flight (trq_lab.metrics.RunMetrics; flights.csv's columns after
# the flight's inputs) a flight target may bound: the numbers, and `crashed` (0 or 1)
FLIGHT_METRICS = ("crashed", "flight_s", "rmse_pos_m", "max_pos_err_m", "rmse_pos_after_fault_m",
                  "rmse_vert_after_fault_m", "max_sink_after_fault_m", "rmse_yaw_deg",
                  "max_yaw_err_deg", "recovery_s", "solve_ms_p50", "solve_ms_p99",
                  "est_rmse_pos_m", "est_rmse_att_deg", "diagnosis_s", "max_pos_err_outage_m",
                  # a whole motor lost (issue 40; trq_lab.metrics' lost-motor block)
                  "touchdown_speed_m_s", "touchdown_tilt_deg", "drift_after_fault_m",
                  "max_thrust_tilt_after_fault_deg", "descent_rate_m_s", "detection_s",
                  # the estimator across a touchdown (issue 39; trq_lab.metrics)
                  "est_jump_touchdown_m")
# those a flight has only with a sensor outage (a campaign's `outage` axis): flights.csv carries
# them when the campaign has the axis
OUTAGE_METRICS = ("max_pos_err_outage_m",)


class FlightTarget(Strict):
    """A target on the distribution of a campaign's flights: among the flights of `controller`
    (only those flown under the sensing profile `sensing`, and with an outage of the sensor
    `outage`, when they are given), at least `share` have `metric` <= `max`, or, with `per`,
    `metric` <= `max` times the same flight's `per` (`rmse_pos_after_fault_m` within 1.5x its
    `est_rmse_pos_m`). A flight that failed, or whose metric (or `per`) is missing, does not
    meet it; nor does a crashed one, except on `crashed` itself (`metric: crashed, max: 0`: no
    crash). A target on an outage's metric (OUTAGE_METRICS) names the outage's sensor
    (checked by trq_lab.campaign.spec)."""
    controller: Text
    metric: Choice(*FLIGHT_METRICS)
    max: Num(0.0, 1e9)
    per: Optional[Choice(*FLIGHT_METRICS)] = None
    share: Num(0.0, 1.0) = 1.0
    sensing: Optional[NameOrPath] = None
    # only the flights with an outage of this sensor (`none`: those without an outage)
    outage: Optional[Choice(*SENSOR_UNITS, "none")] = None


class PairedTarget(Strict):
    """A target on two controllers' flights paired on the same conditions and seed (issue 34's
    kind): `controller`'s RMSE after the fault over `against`'s (the campaign's first controller
    when not given), the median of these ratios at most `max_median_ratio`, over the pairs
    flown under `sensing` and with an outage of `outage` (`none`: without) when given; with no
    more crashes than `against`, and, with `no_later_diagnosis`, no pair where it diagnoses the
    fault later."""
    controller: Text
    max_median_ratio: Num(0.0, 100.0)
    against: Optional[Text] = None
    sensing: Optional[NameOrPath] = None
    outage: Optional[Choice(*SENSOR_UNITS, "none")] = None
    no_later_diagnosis: Flag = True


class CampaignFile(Strict):
    """A campaign file (params/campaigns/*.yaml); the axes are checked key by key afterwards."""
    name: Text
    description: Text
    seed: Int(0, 2**31 - 1)
    controllers: list[Text]
    success_rmse_m: Num(0.001, 100.0)
    recovery_threshold_m: Num(0.001, 100.0)
    timeout_s: Num(1.0, 36000.0)
    repeats: Int(1, 1000) = 1
    controller_model: Any = "nominal"
    targets: CampaignTargets | None = None
    flight_targets: list[FlightTarget] = []
    paired_targets: list[PairedTarget] = []
    grid: CampaignGrid | None = None
    sample: CampaignSample | None = None

    @model_validator(mode="after")
    def _flights(self) -> "CampaignFile":
        if not self.controllers or len(set(self.controllers)) != len(self.controllers):
            raise Invalid("controllers", self.controllers,
                          "a non-empty list of distinct controller names")
        for i, c in enumerate(self.controllers):
            # a path is read against the campaign file's folder: trq_lab.campaign checks it
            if is_name(c) and not exists("controller", c):
                raise Invalid(f"controllers[{i}]", c, "a built-in controller name or a "
                              "controller YAML path")
        if self.grid is None and self.sample is None:
            raise Invalid("grid", None, "a grid (or a sample): a campaign needs flights")
        models = self.controller_model
        if not (models in CONTROLLER_MODELS or (
                isinstance(models, list) and models and len(set(models)) == len(models)
                and all(m in CONTROLLER_MODELS for m in models))):
            raise Invalid("controller_model", models, "one of " + "|".join(CONTROLLER_MODELS)
                          + " or a list of distinct ones")
        t = self.targets
        if t is not None:
            for key, name in [("targets.controller", t.controller)] + [
                    (f"targets.better[{i}].worse", b.worse) for i, b in enumerate(t.better)]:
                if name not in self.controllers:
                    raise Invalid(key, name, "one of the campaign's controllers ("
                                  + ", ".join(self.controllers) + ")")
        for i, ft in enumerate(self.flight_targets):
            if ft.controller not in self.controllers:
                raise Invalid(f"flight_targets[{i}].controller", ft.controller, "one of the "
                              "campaign's controllers (" + ", ".join(self.controllers) + ")")
        return self

# --------------------------------------------------------------------------------------------
# sensing profile (sil_vehicle.sensors.profile): which sensors the simulated vehicle carries
# and their error figures. A sensor set to `null` is absent; every section must be written.
# Checks that need the physics rate (a sensor rate divides it, a delay is a whole number of
# ticks) run when the loader passes `context={"physics_rate_hz": N}`; a delay beyond
# DELAY_BUFFER_MS is refused with or without it.
# --------------------------------------------------------------------------------------------

def _nonempty_list(value: Any) -> tuple[Any, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise expect("a non-empty list of mappings")
    return tuple(value)


DELAY_BUFFER_MS = 500
"""The longest delay (ms) a delayed measurement may have: the history the estimator keeps to
fuse it at its time of validity. Both daemons may read it from here."""

_SENSOR_RATE = Int(1, 10_000)        # Hz; then checked against the physics rate (context)
_SENSOR_DELAY = Int(0, 10_000)       # ms; then checked against DELAY_BUFFER_MS and the physics tick


class ImuHarmonic(Strict):
    """One vibration line per rotor: `times` the rotor's frequency (`of: rotor`) or its
    blade-pass frequency (`of: blade_pass`, the rotor's times its blade count); its amplitude
    per body axis (FRD) at full rotor speed, one rotor's, scaling with the speed squared."""
    of: Choice("rotor", "blade_pass")
    times: Int(1, 16)
    accel_m_s2: Vec(3, 0.0, 1000.0)
    gyro_rad_s: Vec(3, 0.0, 100.0)


class ImuVibration(Strict):
    """The rotors' vibration as the IMU sees it (sil_vehicle.sensors.imu states the model)."""
    harmonics: Annotated[tuple[ImuHarmonic, ...], BeforeValidator(_nonempty_list)]
    smear_hz: Num(0.0, 100.0)            # each rotor line's width (the rotor's speed jitter)


class Imu(Strict):
    """Gyro and accelerometer (sil_vehicle.sensors.imu states the model). `rate_hz` is the
    output rate: each reading integrates the physics ticks of its interval."""
    rate_hz: _SENSOR_RATE
    gyro_noise_density_rad_s_rthz: Num(0.0, 1.0)
    gyro_bias_random_walk_rad_s2_rthz: Num(0.0, 1.0)
    gyro_turn_on_bias_rad_s: Num(0.0, 1.0)
    accel_noise_density_m_s2_rthz: Num(0.0, 10.0)
    accel_bias_random_walk_m_s3_rthz: Num(0.0, 10.0)
    accel_turn_on_bias_m_s2: Num(0.0, 10.0)
    # what the vehicle's HIGHRES_IMU carries: the samples' mean over each integration interval
    # of this rate (PX4's IMU_INTEG_RATE, default 200 Hz: sensor_combined is the delta velocity
    # and angle over that interval, not one sample); at most the IMU's rate
    integration_rate_hz: Int(1, 10_000) = 200
    # the chip: its internal sample rate (a multiple of the physics rate) and its anti-alias
    # low-pass filter's cutoff; full scales (clipping); null vibration: none
    internal_rate_hz: Int(1, 1_000_000) = 8000
    anti_alias_cutoff_hz: Num(1.0, 100_000.0) = 585.0
    accel_full_scale_g: Num(0.5, 1000.0) = 16.0
    gyro_full_scale_deg_s: Num(10.0, 100_000.0) = 2000.0
    vibration: Optional[ImuVibration] = None
    # delivery: each output sample's stamp error (std, us) and the probability that one is
    # not delivered (the next one then covers both intervals)
    timestamp_jitter_us: Num(0.0, 100_000.0) = 0.0
    dropout_probability: Num(0.0, 0.99) = 0.0

    @model_validator(mode="after")
    def _integration(self) -> "Imu":
        if self.integration_rate_hz > self.rate_hz:
            raise Invalid("imu.integration_rate_hz", self.integration_rate_hz,
                          f"at most the IMU's rate_hz ({self.rate_hz})")
        if self.anti_alias_cutoff_hz >= self.internal_rate_hz / 2:
            raise Invalid("imu.anti_alias_cutoff_hz", self.anti_alias_cutoff_hz,
                          f"below the internal rate's Nyquist ({self.internal_rate_hz / 2:g} Hz)")
        return self


class Baro(Strict):
    rate_hz: _SENSOR_RATE
    noise_m: Num(0.0, 100.0)
    drift_sigma_m: Num(0.0, 100.0)
    drift_tau_s: Num(0.0, 1e6, open_lo=True)


class Mag(Strict):
    rate_hz: _SENSOR_RATE
    field_gauss: Num(0.0, 1.0, open_lo=True)
    declination_deg: Num(-180.0, 180.0)
    inclination_deg: Num(-90.0, 90.0)
    noise_density_gauss_rthz: Num(0.0, 1.0)
    bias_random_walk_gauss_s_rthz: Num(0.0, 1.0)
    turn_on_bias_gauss: Num(0.0, 1.0)


class Gnss(Strict):
    rate_hz: _SENSOR_RATE
    delay_ms: _SENSOR_DELAY
    fix_type: Int(3, 6)       # MAVLink GPS_FIX_TYPE: 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: Int(0, 64)
    position_white_h_m: Num(0.0, 100.0)
    position_white_v_m: Num(0.0, 100.0)
    position_markov_h_m: Num(0.0, 100.0)
    position_markov_v_m: Num(0.0, 100.0)
    position_markov_tau_s: Num(0.0, 1e6, open_lo=True)
    velocity_white_h_m_s: Num(0.0, 10.0)
    velocity_white_v_m_s: Num(0.0, 10.0)


class DropoutWindow(Strict):
    """[start_ms, end_ms): no pose arrives for a sample taken in this span."""
    start_ms: Int(0, 2**62)
    end_ms: Int(0, 2**62)

    @model_validator(mode="after")
    def _ordered(self) -> "DropoutWindow":
        if self.end_ms <= self.start_ms:
            raise expect(f"end_ms after start_ms ({self.start_ms})")
        return self


def _windows(value: Any) -> tuple[Any, ...]:
    if not isinstance(value, (list, tuple)):
        raise expect("a list of {start_ms, end_ms} mappings (empty for none)")
    return tuple(value)


class Mocap(Strict):
    """Motion capture: pose only."""
    rate_hz: _SENSOR_RATE
    latency_ms: _SENSOR_DELAY
    position_noise_m: Num(0.0, 1.0)
    attitude_noise_rad: Num(0.0, 1.0)
    dropout_probability: Num(0.0, 1.0)
    dropout_windows: Annotated[tuple[DropoutWindow, ...], BeforeValidator(_windows)]


class Ekf2(Strict):
    """The vehicle's estimator tuned as PX4 ships EKF2 (sil_vehicle.estimator.params reads it;
    docs/estimator.md). Every key is EKF2's parameter of that name, in its unit, with its
    range and its default from PX4's src/modules/ekf2 module.yaml and params_*.yaml (PX4-Autopilot
    main, 2024-2025; docs/decisions/2026-12-05-ekf2-defaults.md cites the files). `tuning:
    generator` instead matches the filter to the profile's own sensor figures (the simulator's
    noise, delays and drift: a study's option, the inverse crime, never a default); the EKF2_*
    keys are then unused. EKF2_RESET_TOUT is EKF2's reset_timeout_max (7 s, a constant there,
    not a parameter). IMU_GYRO_CUTOFF is not EKF2's but PX4's sensors module's: the low-pass of
    the body rates the autopilot publishes (vehicle_angular_velocity: ATTITUDE, ODOMETRY), 40 Hz
    by default as PX4 ships it; 0 publishes the raw sample."""
    tuning: Choice("ekf2", "generator") = "ekf2"
    EKF2_GYR_NOISE: Num(0.0001, 0.1) = 0.015         # rad/s, per sample at the filter's rate
    IMU_GYRO_CUTOFF: Num(0.0, 1000.0) = 40.0         # Hz, the published rates' low-pass
    EKF2_ACC_NOISE: Num(0.01, 1.0) = 0.35            # m/s^2, likewise
    EKF2_GYR_B_NOISE: Num(0.0, 0.01) = 0.001         # rad/s^2
    EKF2_ACC_B_NOISE: Num(0.0, 0.01) = 0.003         # m/s^3
    EKF2_GBIAS_INIT: Num(0.0, 0.2) = 0.1             # rad/s
    EKF2_ABIAS_INIT: Num(0.0, 0.5) = 0.2             # m/s^2
    EKF2_ANGERR_INIT: Num(0.0, 0.5) = 0.1            # rad
    EKF2_ABL_ACCLIM: Num(20.0, 200.0) = 25.0         # m/s^2
    EKF2_ABL_GYRLIM: Num(2.0, 20.0) = 3.0            # rad/s
    EKF2_ABL_TAU: Num(0.1, 1.0) = 0.5                # s
    EKF2_EV_CTRL: Int(0, 15) = 0                     # bits: 0 hpos, 1 vpos, 2 vel, 3 yaw
    EKF2_EV_DELAY: Num(0.0, 300.0) = 0.0             # ms
    EKF2_EVP_NOISE: Num(0.01, 10.0) = 0.1            # m
    EKF2_EVA_NOISE: Num(0.05, 10.0) = 0.1            # rad
    EKF2_EVP_GATE: Num(1.0, 100.0) = 5.0             # SD
    EKF2_GPS_DELAY: Num(0.0, 300.0) = 110.0          # ms
    EKF2_GPS_P_NOISE: Num(0.01, 10.0) = 0.5          # m
    EKF2_GPS_V_NOISE: Num(0.01, 5.0) = 0.3           # m/s
    EKF2_GPS_P_GATE: Num(1.0, 100.0) = 5.0           # SD
    EKF2_GPS_V_GATE: Num(1.0, 100.0) = 5.0           # SD
    EKF2_BARO_NOISE: Num(0.01, 15.0) = 3.5           # m
    EKF2_BARO_GATE: Num(1.0, 100.0) = 5.0            # SD
    EKF2_MAG_NOISE: Num(0.001, 1.0) = 0.05           # gauss
    EKF2_MAG_GATE: Num(1.0, 100.0) = 3.0             # SD
    EKF2_HGT_REF: Int(0, 3) = 1                      # 0 baro, 1 GNSS, 2 range (none here), 3 vision
    EKF2_NOAID_TOUT: Int(500_000, 10_000_000) = 5_000_000     # us
    EKF2_RESET_TOUT: Int(500_000, 30_000_000) = 7_000_000     # us
    EKF2_TAU_VEL: Num(0.01, 1.0) = 0.25              # s
    EKF2_TAU_POS: Num(0.1, 1.0) = 0.25               # s

    @model_validator(mode="after")
    def _delays(self) -> "Ekf2":
        for key in ("EKF2_EV_DELAY", "EKF2_GPS_DELAY"):
            if getattr(self, key) > DELAY_BUFFER_MS:
                raise Invalid(f"estimator.{key}", getattr(self, key),
                              f"a delay in [0, {DELAY_BUFFER_MS}] ms (the estimator's buffer)")
        if self.EKF2_HGT_REF == 2:
            raise Invalid("estimator.EKF2_HGT_REF", 2, "0 (baro), 1 (GNSS) or 3 (vision): this "
                                                       "vehicle carries no range sensor")
        return self


EKF2_KEYS = tuple(k for k in Ekf2.model_fields if k.startswith(("EKF2_", "IMU_")))
"""The parameters the vehicle's estimator takes (EKF2's, and the published rates' IMU_GYRO_CUTOFF),
in the schema's order."""


_SENSORS = ("imu", "baro", "mag", "gnss", "mocap")


class SensingFile(Strict):
    """A sensing profile: each sensor's section, or null when the vehicle does not carry it."""
    name: Text
    description: Text
    imu: Optional[Imu]
    baro: Optional[Baro]
    mag: Optional[Mag]
    gnss: Optional[Gnss]
    mocap: Optional[Mocap]
    # the vehicle's estimator: EKF2's parameters (PX4's defaults when left out)
    estimator: Ekf2 = Ekf2()

    @model_validator(mode="after")
    def _timing(self, info: ValidationInfo) -> "SensingFile":
        for key, delay in (("gnss.delay_ms", self.gnss and self.gnss.delay_ms),
                           ("mocap.latency_ms", self.mocap and self.mocap.latency_ms)):
            if delay and delay > DELAY_BUFFER_MS:
                raise Invalid(key, delay, f"a delay in [0, {DELAY_BUFFER_MS}] ms (the "
                                          "estimator's delayed-measurement buffer)")
        physics = (info.context or {}).get("physics_rate_hz") if info else None
        if physics is None:
            return self
        tick_us = 1_000_000 // physics
        for name in _SENSORS:
            section = getattr(self, name)
            if section is None:
                continue
            hz = section.rate_hz
            if hz > physics or physics % hz:
                raise Invalid(f"{name}.rate_hz", hz, f"a rate in Hz that divides the physics "
                                                     f"rate ({physics} Hz)")
        imu = self.imu
        if imu is not None and imu.internal_rate_hz % physics:
            raise Invalid("imu.internal_rate_hz", imu.internal_rate_hz,
                          f"a multiple of the physics rate ({physics} Hz)")
        for key, delay in (("gnss.delay_ms", self.gnss and self.gnss.delay_ms),
                           ("mocap.latency_ms", self.mocap and self.mocap.latency_ms)):
            if delay and (delay * 1000) % tick_us:
                raise Invalid(key, delay, f"a whole number of physics ticks ({tick_us} us)")
        return self
