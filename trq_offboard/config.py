"""Strictly validated parameters of the offboard controller, read from `params/` YAML files.

    load_vehicle_model(path)     params/vehicle/*.yaml  -> VehicleModel (what the controller knows
                                 about the airframe; the same files the simulator reads)
    load_controller(path)        params/controller/*.yaml -> ControllerConfig (names its vehicle
                                 file, its observer file, horizon, weights, solver, reference)
    load_eso(path)               params/controller/eso.yaml -> EsoConfig

Files are read and validated by `trq_params.loader` against `trq_params.schema` (one YAML dialect,
one `extends:` rule, the same vehicle schema the simulator reads): an unknown key, a missing key,
a wrong type or an out-of-range value raises `ConfigError` (the loader's) whose message names the
file, the dotted key, the value and what was expected. This module builds the records from the
validated models and checks what spans files; derived quantities (rotor geometry, hover
throttle) are computed once here.

This module is independent of `sil_vehicle` on purpose (the wire is the only coupling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from trq_params import loader, schema
from trq_params.loader import ConfigError
from trq_params.schema import throttle_curve

from trq_offboard.fused import FusedConfig

__all__ = ["ConfigError", "RotorGeometry", "Curve", "VehicleModel", "EsoChannelGains",
           "EsoConfig", "EffectivenessConfig", "LostMotorConfig", "Weights", "SolverConfig", "ReferenceConfig",
           "ControllerConfig", "load_vehicle_model", "load_eso", "load_controller", "PARAMS_DIR"]

from trq_params import DIR as PARAMS_DIR  # noqa: E402  (the shipped parameter files)


# --------------------------------------------------------------------------------------------
# vehicle
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Curve:
    """value(zeta) = c2 zeta^2 + c1 zeta + c0, zeta throttle in percent (not clamped here)."""
    c2: float
    c1: float
    c0: float

    def value(self, zeta_pct: float) -> float:
        return throttle_curve(self.c2, self.c1, self.c0, zeta_pct)

    def slope(self, zeta_pct: float) -> float:
        return 2.0 * self.c2 * zeta_pct + self.c1

    def solve(self, value: float) -> float:
        """Throttle (percent) on the rising branch with value(zeta) == value."""
        disc = self.c1 * self.c1 - 4.0 * self.c2 * (self.c0 - value)
        return (math.sqrt(max(disc, 0.0)) - self.c1) / (2.0 * self.c2)


@dataclass(frozen=True)
class RotorGeometry:
    name: str
    arm_frd: tuple[float, float, float]        # unit arm axis a_i (also the tilt axis)
    position_frd_m: tuple[float, float, float]
    spin: int                                  # +1 ccw seen from above, -1 cw


@dataclass(frozen=True)
class VehicleModel:
    """Airframe as the controller sees it. Rotor order is PX4 quad X (motor 1..4)."""
    name: str
    file: str
    mass_kg: float
    inertia_kg_m2: tuple[float, float, float]
    gravity_m_s2: float
    arm_length_m: float
    thrust_N: Curve
    torque_Nm: Curve
    rotors: tuple[RotorGeometry, ...]
    idle_pct: float
    tilt_locked: bool
    tilt_min_rad: float
    tilt_max_rad: float
    servo_rate_limit_rad_s: float
    drag_N_s2_m2: float
    # actuator lags: not in the NMPC's model; the delay predictor (controller.py) uses them
    motor_time_constant_s: float = 0.0
    motor_rate_limit_pct_s: float = math.inf
    servo_time_constant_s: float = 0.0
    # derived
    hover_throttle_pct: float = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "hover_throttle_pct",
                           self.thrust_N.solve(self.mass_kg * self.gravity_m_s2 / 4.0))

    @property
    def n_inputs(self) -> int:
        """4 throttles for a locked airframe, 4 tilts + 4 throttles otherwise."""
        return 4 if self.tilt_locked else 8


def _curve(c: schema.QuadraticCurve) -> Curve:
    return Curve(c.c2, c.c1, c.c0)


def vehicle_model(v: schema.VehicleFile, file: str) -> VehicleModel:
    """The record of a validated vehicle file."""
    arm = v.arm_length_m
    rotors = []
    for r in v.rotors:
        az = math.radians(r.azimuth_deg)
        a = (math.cos(az), math.sin(az), 0.0)
        rotors.append(RotorGeometry(r.name, a, (arm * a[0], arm * a[1], 0.0),
                                    1 if r.spin == "ccw" else -1))
    i = v.inertia_kg_m2
    return VehicleModel(v.name, file, v.mass_kg, (i.xx, i.yy, i.zz), v.gravity_m_s2, arm,
                        _curve(v.rotor_curves.thrust_N), _curve(v.rotor_curves.torque_Nm),
                        tuple(rotors), v.motor.idle_pct, v.tilt.locked,
                        math.radians(v.tilt.min_deg), math.radians(v.tilt.max_deg),
                        math.radians(v.tilt.servo_rate_limit_deg_s), v.drag.quadratic_N_s2_m2,
                        v.motor.time_constant_s, v.motor.rate_limit_pct_s,
                        v.tilt.servo_time_constant_s)


def load_vehicle_model(path: Path | str) -> VehicleModel:
    path = Path(path).resolve()
    return vehicle_model(loader.load(path, schema.VehicleFile), str(path))


# --------------------------------------------------------------------------------------------
# observer
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EsoChannelGains:
    """Gains of one group of channels (translational or rotational)."""
    # observer bandwidth: the group's, or one per axis (x, y, z; roll, pitch, yaw)
    omega_o_rad_s: float | tuple[float, float, float]
    delta: float                          # fal linear band (m or rad; m/s or rad/s on rates)
    # what the channels measure: the paper's third-order observer on the output (position,
    # angles), or one order lower on its measured rate (velocity, body rates)
    output: str


@dataclass(frozen=True)
class EffectivenessConfig:
    """The motor effectiveness observer (trq_offboard/effectiveness.py): controller key
    motor_effectiveness."""
    bandwidth_rad_s: float                # both poles of each motor's observer at -p
    min_effectiveness: float              # the estimate's floor (a motor the NMPC may still use)
    substeps: int                         # explicit Euler substeps per control period


@dataclass(frozen=True)
class LostMotorConfig:
    """A whole motor lost (trq_offboard/lost_motor.py): controller key lost_motor."""
    below: float                          # effectiveness at or below which a motor is lost
    hold_s: float                         # held this long (without a break, or within within_s)
    min_command_pct: float                # while commanded at least this (throttle %)
    yaw_weight: float                     # the failed NMPC's weight on yaw and yaw rate
    max_body_rate_rad_s: float            # the failed NMPC's body-rate bound
    descent_speed_m_s: float              # the descent to the ground once lost
    spin_weight: float | None = None      # the yaw rate's weight (None: yaw_weight, free spin)
    spin_rate_rad_s: float = 0.0          # the yaw rate's target's magnitude
    horizon_steps: int | None = None      # the failed NMPC's horizon (None: the controller's)
    horizon_step_s: float | None = None
    response: str = "nmpc"                # one motor lost: "nmpc" (the failed NMPC) or "spin"
    pair_excess_m_s2: float | None = None   # two motors lost: the vertical excess (None: off)
    pair_angular_scale_rad_s2: float = 5.0   # the angular parts' scale in the pair's fit
    within_s: float | None = None         # hold_s counted within this window (None: no break)


@dataclass(frozen=True)
class EsoConfig:
    file: str
    kind: str                             # "nonlinear" | "linear"
    alpha: tuple[float, float, float]     # fal exponents of the three corrections
    translational: EsoChannelGains
    rotational: EsoChannelGains
    substeps: int                         # explicit Euler substeps per control period
    max_disturbance: tuple[float, float]  # clamp of |d| (m/s^2, rad/s^2) handed to the NMPC


def eso_config(e: schema.EsoFile, file: str) -> EsoConfig:
    """The record of a validated observer file."""
    groups = [EsoChannelGains(g.omega_o_rad_s, g.delta, g.output)
              for g in (e.translational, e.rotational)]
    return EsoConfig(file, e.kind, e.alpha, groups[0], groups[1], e.substeps,
                     (e.max_disturbance.translational_m_s2, e.max_disturbance.rotational_rad_s2))


def load_eso(path: Path | str) -> EsoConfig:
    path = Path(path).resolve()
    return eso_config(loader.load(path, schema.EsoFile), str(path))


# --------------------------------------------------------------------------------------------
# controller
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Weights:
    """Diagonal weights. Inputs are weighted in scaled units: tilt in rad, throttle as a
    fraction (0..1) about the hover trim."""
    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    euler: tuple[float, float, float]
    rates: tuple[float, float, float]
    terminal_factor: float
    tilt: float
    throttle: float
    tilt_rate: float                      # on (alpha_{k+1} - alpha_k) / dt, (rad/s)^-2
    output_error: float                   # the paper's (y_hat - y)^T (y_hat - y) weight


@dataclass(frozen=True)
class SolverConfig:
    kind: str                             # "rti" (default) | "sqp" | "ipopt" (reference)
    hessian: str                          # rti, sqp: "gauss_newton" | "exact"
    max_iterations: int
    tolerance: float                      # stop when the step's inf-norm is below this
    qp_solver: str                        # casadi conic plugin for "sqp"
    regularization: float                 # Levenberg term added to the SQP Hessian
    ipopt_max_iterations: int
    codegen: str = "auto"                 # rti: "auto" (compile and cache C when a compiler is
                                          # found, else interpreted with a warning) | "off"
    hpipm_interface: str = "direct"       # rti with hpipm: "direct" (nmpc/hpipm.py) | "conic"
    hpipm_mode: str = "auto"              # direct: speed_abs | speed | balance | robust | auto
                                          # (speed_abs with gauss_newton, speed with exact)
    qp_max_iterations: int = 50           # rti, sqp: the QP solver's iteration limit
    hpipm_options: tuple[tuple[str, float], ...] = ()   # direct: further IPM arguments


@dataclass(frozen=True)
class ReferenceConfig:
    kind: str                             # hover | step | circle | helix | figure8
    altitude_m: float                     # take-off height above the start point
    climb_speed_m_s: float                # peak vertical speed of take-off and landing
    hold_s: float                         # hover before and after the manoeuvre
    duration_s: float                     # the manoeuvre itself (including its ramps)
    ramp_s: float                         # smooth start and stop of the phase speed
    radius_m: float                       # circle/helix radius, figure8 half-width
    period_s: float                       # one revolution / one figure of eight
    helix_climb_m: float                  # height gained per revolution (helix)
    step_ned_m: tuple[float, float, float]  # step: offset from the hover point
    land: bool                            # descend to the start point at the end


@dataclass(frozen=True)
class ControllerConfig:
    file: str
    name: str
    vehicle: VehicleModel
    observer: str                         # none | nonlinear | linear
    eso: EsoConfig | None
    control_rate_hz: int
    horizon_steps: int
    step_s: float
    weights: Weights
    max_tilt_deg: float                   # roll/pitch state bound
    max_rate_rad_s: float                 # body-rate state bound
    solver: SolverConfig
    reference: ReferenceConfig
    applied_input: str = "commanded"      # commanded | outputs: taken as the applied input
    applied_delay_s: float = 0.0          # how long a command takes to act (observer's b0)
    delay_compensation: str = "auto"      # predict | none | auto (predict from one control
                                          # period of delay): plan from the state at t + delay
    lagged_actuators: str = "auto"        # on | off | auto (on when predicting): the
                                          # observer's b0 and the predictor through the lags
    actuator_states: str = "auto"         # on | off | auto (on when predicting): the NMPC's
                                          # stage state carries the actuators' lag states
    effectiveness: EffectivenessConfig | None = None   # motor_effectiveness (None: off)
    fused: FusedConfig | None = None      # estimator kind fused (None: the autopilot's estimate)
    lost_motor: LostMotorConfig | None = None  # lost_motor (None: no detection)
    rates_lowpass_hz: float = 0.0         # the published rates' low-pass (IMU_GYRO_CUTOFF; 0: raw)

    @property
    def predicts_delay(self) -> bool:
        """Whether the controller plans from the state predicted at t + applied_delay_s:
        delay_compensation predict, or auto once the delay reaches one control period."""
        long_delay = self.applied_delay_s >= self.control_dt_s - 1e-12
        return self.delay_compensation == "predict" or (self.delay_compensation == "auto"
                                                        and long_delay)

    @property
    def nmpc_actuator_states(self) -> bool:
        """Whether the NMPC's stage state carries the actuators' first-order lag states
        (actuator_states on, or auto while the delay predictor is on with a delay)."""
        return self.actuator_states == "on" or (self.actuator_states == "auto"
                                                and self.predicts_delay
                                                and self.applied_delay_s > 0.0)

    @property
    def control_dt_s(self) -> float:
        return 1.0 / self.control_rate_hz


def controller_config(c: schema.ControllerFile, file: str) -> ControllerConfig:
    """The record of a validated controller file; reads the vehicle and observer files it names
    (their paths already absolute, resolved against the file that wrote them)."""
    vehicle = load_vehicle_model(c.vehicle)
    eso = None
    if c.observer.kind != "none":
        base = load_eso(c.observer.file)
        eso = EsoConfig(base.file, c.observer.kind, base.alpha, base.translational,
                        base.rotational, base.substeps, base.max_disturbance)
        # the observer's explicit Euler substeps: w h <= 1 keeps them stable with a margin (the
        # triple pole's discrete eigenvalue is 1 - w h; 2 is the edge)
        rate = c.control_rate_hz
        w_max = eso.substeps * rate
        for group, gains in (("translational", eso.translational), ("rotational", eso.rotational)):
            w = gains.omega_o_rad_s
            if (max(w) if isinstance(w, tuple) else w) > w_max:
                raise ConfigError(
                    f"{eso.file}: key '{group}.omega_o_rad_s': got {gains.omega_o_rad_s!r}, "
                    f"expected at most substeps x control_rate_hz = {eso.substeps} x {rate} = "
                    f"{w_max:g} rad/s (explicit Euler substeps of {1e3 / w_max:g} ms; raise "
                    f"substeps for a faster observer) for {file}")
        check_rates_lowpass(c.rates_lowpass_hz, eso, rate, file)
    w, s, r = c.weights, c.solver, c.reference
    weights = Weights(w.position, w.velocity, w.euler, w.rates, w.terminal_factor, w.tilt,
                      w.throttle, w.tilt_rate, w.output_error)
    solver = SolverConfig(s.kind, s.hessian, s.max_iterations, s.tolerance, s.qp_solver,
                          s.regularization, s.ipopt_max_iterations, s.codegen, s.hpipm_interface,
                          s.hpipm_mode, s.qp_max_iterations, s.hpipm_options.pairs())
    reference = ReferenceConfig(r.kind, r.altitude_m, r.climb_speed_m_s, r.hold_s, r.duration_s,
                                r.ramp_s, r.radius_m, r.period_s, r.helix_climb_m, r.step_ned_m,
                                r.land)
    e = c.motor_effectiveness
    effectiveness = None if e is None or e.estimate == "off" else EffectivenessConfig(
        e.bandwidth_rad_s, e.min, e.substeps)
    f = c.estimator
    # the history: the configured periods, or with a GNSS source enough to reach back to the
    # oldest fix fused (gnss_max_age_s) and the period before it
    history = f.history if f.position_source == "mocap" else max(
        f.history, math.ceil(f.gnss_max_age_s * c.control_rate_hz - 1e-9) + 2)
    fused = None if f.kind == "autopilot" else FusedConfig(
        mocap_std_m=f.mocap_std_m, accel_std_m_s2=f.accel_std_m_s2,
        model_acc_density=f.model_acc_density_m_s2_rthz,
        residual_walk_density=f.residual_walk_m_s3_rthz, accel_bias_std=f.accel_bias_std_m_s2,
        accel_bias_walk_density=f.accel_bias_walk_m_s3_rthz, pose_gate=f.pose_gate,
        dropout_s=f.dropout_s, imu_rate_hz=f.imu_rate_hz, mocap_rate_hz=f.mocap_rate_hz,
        history=history, disturbance_input=f.disturbance_input,
        autopilot_vel_std_m_s=f.autopilot_vel_std_m_s, position_source=f.position_source,
        gnss_rate_hz=f.gnss_rate_hz, gnss_std_m=tuple(f.gnss_std_m),
        accel_gate=f.accel_gate, accel_reject_max=f.accel_reject_max,
        regain_poses=f.regain_poses, gnss_delay_s=f.gnss_delay_s)
    lm = c.lost_motor
    lost_motor = None if lm is None or lm.detect == "off" else LostMotorConfig(
        lm.below, lm.hold_s, lm.min_command_pct, lm.yaw_weight, lm.max_body_rate_rad_s,
        lm.descent_speed_m_s, lm.spin_weight, lm.spin_rate_rad_s, lm.horizon_steps,
        lm.horizon_step_s, lm.response, lm.pair_excess_m_s2, lm.pair_angular_scale_rad_s2,
        lm.within_s)
    return ControllerConfig(file, c.name, vehicle, c.observer.kind, eso, c.control_rate_hz,
                            c.horizon.steps, c.horizon.step_s, weights,
                            c.constraints.max_roll_pitch_deg, c.constraints.max_body_rate_rad_s,
                            solver, reference, c.applied_input, c.applied_delay_s,
                            c.delay_compensation, c.lagged_actuators, c.actuator_states,
                            effectiveness, fused, lost_motor, c.rates_lowpass_hz)


def with_rates_lowpass(cfg: "ControllerConfig", cutoff_hz: float, where: str
                       ) -> "ControllerConfig":
    """`cfg` with the published rates' low-pass set to `cutoff_hz` (from the command line or
    the scenario's sensing profile), checked as the controller file's key is."""
    import dataclasses
    if not 0.0 <= cutoff_hz <= 1000.0:
        raise ConfigError(f"{where}: key 'rates_lowpass_hz': got {cutoff_hz!r}, expected a "
                          "cutoff in Hz in [0, 1000] (0: raw rates)")
    check_rates_lowpass(cutoff_hz, cfg.eso, cfg.control_rate_hz, where)
    return dataclasses.replace(cfg, rates_lowpass_hz=cutoff_hz)


def check_rates_lowpass(cutoff_hz: float, eso: EsoConfig | None, control_rate_hz: float,
                        where: str) -> None:
    """The body-rate observer integrates the published rates' low-pass with the observer's
    explicit Euler substeps: its bandwidth 2 pi cutoff_hz at most substeps x control_rate_hz
    (w h <= 1, as the observer's own). ConfigError naming `where`, the key and the bound."""
    if eso is None or cutoff_hz <= 0.0:
        return
    if eso.rotational.output == "rates" and not isinstance(eso.rotational.omega_o_rad_s, float):
        raise ConfigError(
            f"{eso.file}: key 'rotational.omega_o_rad_s': got "
            f"{list(eso.rotational.omega_o_rad_s)!r}, expected one number: the body-rate "
            f"observer of rates_lowpass_hz ({cutoff_hz:g} Hz, {where}) takes one bandwidth for "
            "the three rates")
    hz_max = eso.substeps * control_rate_hz / (2.0 * math.pi)
    if cutoff_hz > hz_max:
        raise ConfigError(
            f"{where}: key 'rates_lowpass_hz': got {cutoff_hz!r}, expected at most substeps x "
            f"control_rate_hz / 2 pi = {hz_max:.4g} Hz (the observer's substeps carry the "
            f"filter; raise {eso.file}'s substeps), or 0 for raw rates")


def load_controller(path: Path | str) -> ControllerConfig:
    path = Path(path).resolve()
    return controller_config(loader.load(path, schema.ControllerFile), str(path))
