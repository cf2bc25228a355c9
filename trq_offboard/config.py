"""Strictly validated parameters of the offboard controller, read from `params/` YAML files.

    load_vehicle_model(path)     params/vehicle/*.yaml  -> VehicleModel (what the controller knows
                                 about the airframe; the same files the simulator reads)
    load_controller(path)        params/controller/*.yaml -> ControllerConfig (names its vehicle
                                 file, its observer file, horizon, weights, solver, reference)
    load_eso(path)               params/controller/eso.yaml -> EsoConfig

Every file may start with `extends: OTHER.yaml` (relative to the file): the other file supplies
defaults, mappings are merged key by key. Every key must be read exactly once: an unknown key, a
missing key, a wrong type or an out-of-range value raises `ConfigError` whose message names the
file, the dotted key, the value and what was expected. Derived quantities (rotor geometry, hover
throttle) are computed once here.

This module is independent of `sil_vehicle` on purpose (the wire is the only coupling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import yaml

__all__ = ["ConfigError", "RotorGeometry", "Curve", "VehicleModel", "EsoChannelGains",
           "EsoConfig", "EffectivenessConfig", "Weights", "SolverConfig", "ReferenceConfig",
           "ControllerConfig", "load_vehicle_model", "load_eso", "load_controller", "PARAMS_DIR"]

from trq_params import DIR as PARAMS_DIR  # noqa: E402  (the shipped parameter files)


class ConfigError(ValueError):
    """A parameter file is wrong; the message names file, key, value and expectation."""


# --------------------------------------------------------------------------------------------
# reading files
# --------------------------------------------------------------------------------------------

def _read_mapping(path: Path) -> dict[str, Any]:
    try:
        raw = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror})") from exc
    try:
        doc = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: invalid YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: the top level must be a mapping, found {type(doc).__name__}")
    return doc


def _deep_update(defaults: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    result = {k: v for k, v in defaults.items()}
    for key, val in overrides.items():
        old = result.get(key)
        result[key] = _deep_update(old, val) if isinstance(old, dict) and isinstance(val, dict) \
            else val
    return result


def read_with_extends(path: Path | str) -> dict[str, Any]:
    """The mapping of `path` with its `extends:` chain resolved (children override parents)."""
    path = Path(path).resolve()
    chain = [path]
    layers = [_read_mapping(path)]
    while "extends" in layers[-1]:
        ref = layers[-1].pop("extends")
        if not isinstance(ref, str) or not ref:
            raise ConfigError(f"{chain[-1]}: key 'extends': got {ref!r}, expected a file name")
        parent = (chain[-1].parent / ref).resolve()
        if parent in chain:
            raise ConfigError(f"{chain[-1]}: key 'extends': got {ref!r}, which closes a cycle")
        chain.append(parent)
        layers.append(_read_mapping(parent))
    merged: dict[str, Any] = {}
    for layer in reversed(layers):
        merged = _deep_update(merged, layer)
    return merged


class _Keys:
    """Consumes the keys of one mapping; `close()` rejects whatever was not consumed."""

    def __init__(self, mapping: Any, file: Path | str, where: str = "") -> None:
        self.file, self.where = str(file), where
        if not isinstance(mapping, dict):
            raise ConfigError(f"{self.file}: key '{where.rstrip('.') or '<top>'}': got "
                              f"{mapping!r}, expected a mapping")
        self._left = dict(mapping)

    def error(self, key: str, value: Any, expected: str) -> ConfigError:
        return ConfigError(f"{self.file}: key '{self.where}{key}': got {value!r}, "
                           f"expected {expected}")

    def _pop(self, key: str, default: Any) -> Any:
        if key in self._left:
            return self._left.pop(key)
        if default is _MISSING:
            raise ConfigError(f"{self.file}: key '{self.where}{key}' is missing")
        return default

    def number(self, key: str, lo: float, hi: float, default: Any = None, *,
               open_lo: bool = False) -> float:
        val = self._pop(key, _MISSING if default is None else default)
        want = f"a number in {'(' if open_lo else '['}{lo:g}, {hi:g}]"
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            raise self.error(key, val, want)
        x = float(val)
        if not (math.isfinite(x) and lo <= x <= hi) or (open_lo and x == lo):
            raise self.error(key, val, want)
        return x

    def integer(self, key: str, lo: int, hi: int, default: Any = None) -> int:
        val = self._pop(key, _MISSING if default is None else default)
        if isinstance(val, bool) or not isinstance(val, int) or not lo <= val <= hi:
            raise self.error(key, val, f"an integer in [{lo}, {hi}]")
        return val

    def flag(self, key: str, default: Any = None) -> bool:
        val = self._pop(key, _MISSING if default is None else default)
        if not isinstance(val, bool):
            raise self.error(key, val, "true or false")
        return val

    def text(self, key: str, choices: tuple[str, ...] | None = None, default: Any = None) -> str:
        val = self._pop(key, _MISSING if default is None else default)
        if isinstance(val, bool) and choices and {"on", "off"} <= set(choices):
            val = "on" if val else "off"      # YAML 1.1 reads a bare on / off as a boolean
        if not isinstance(val, str) or (choices and val not in choices):
            raise self.error(key, val, ("one of " + "|".join(choices)) if choices else "a string")
        return val

    def vector(self, key: str, n: int, lo: float, hi: float) -> tuple[float, ...]:
        val = self._pop(key, _MISSING)
        want = f"a list of {n} numbers in [{lo:g}, {hi:g}]"
        if not isinstance(val, list) or len(val) != n or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                or not lo <= v <= hi for v in val):
            raise self.error(key, val, want)
        return tuple(float(v) for v in val)

    def sub(self, key: str) -> "_Keys":
        return _Keys(self._pop(key, _MISSING), self.file, f"{self.where}{key}.")

    def items(self, key: str, n: int) -> list["_Keys"]:
        val = self._pop(key, _MISSING)
        if not isinstance(val, list) or len(val) != n:
            raise self.error(key, val, f"a list of {n} mappings")
        return [_Keys(v, self.file, f"{self.where}{key}[{i}].") for i, v in enumerate(val)]

    def close(self) -> None:
        if self._left:
            key = sorted(self._left)[0]
            raise ConfigError(f"{self.file}: key '{self.where}{key}' is unknown "
                              f"(value {self._left[key]!r})")


_MISSING = object()


def _read(path: Path | str, build: Callable[[_Keys, Path], Any]) -> Any:
    path = Path(path).resolve()
    keys = _Keys(read_with_extends(path), path)
    out = build(keys, path)
    keys.close()
    return out


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
        return (self.c2 * zeta_pct + self.c1) * zeta_pct + self.c0

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


def _curve(k: _Keys) -> Curve:
    c = Curve(k.number("c2", 0.0, 1.0, open_lo=True), k.number("c1", -10.0, 10.0),
              k.number("c0", -10.0, 10.0))
    k.close()
    return c


def _vehicle(k: _Keys, path: Path) -> VehicleModel:
    name = k.text("name")
    mass = k.number("mass_kg", 0.05, 100.0)
    ik = k.sub("inertia_kg_m2")
    inertia = tuple(ik.number(a, 1e-6, 100.0) for a in ("xx", "yy", "zz"))
    ik.close()
    g = k.number("gravity_m_s2", 9.7, 9.9)
    arm = k.number("arm_length_m", 0.01, 5.0)
    ck = k.sub("rotor_curves")
    thrust, torque = _curve(ck.sub("thrust_N")), _curve(ck.sub("torque_Nm"))
    ck.close()
    rotors = []
    for rk in k.items("rotors", 4):
        rname = rk.text("name")
        az = math.radians(rk.number("azimuth_deg", -180.0, 180.0))
        spin = 1 if rk.text("spin", ("ccw", "cw")) == "ccw" else -1
        rk.close()
        a = (math.cos(az), math.sin(az), 0.0)
        rotors.append(RotorGeometry(rname, a, (arm * a[0], arm * a[1], 0.0), spin))
    mk = k.sub("motor")
    idle = mk.number("idle_pct", 0.0, 50.0)
    motor_tau = mk.number("time_constant_s", 0.0, 1.0)
    motor_rate = mk.number("rate_limit_pct_s", 1.0, 1e6)
    mk.close()
    tk = k.sub("tilt")
    locked = tk.flag("locked")
    tmin = tk.number("min_deg", -90.0, 0.0)
    tmax = tk.number("max_deg", 0.0, 90.0)
    servo_tau = tk.number("servo_time_constant_s", 0.0, 1.0)
    srate = tk.number("servo_rate_limit_deg_s", 1.0, 1e5)
    tk.close()
    dk = k.sub("drag")
    drag = dk.number("quadratic_N_s2_m2", 0.0, 10.0)
    dk.close()
    if thrust.value(idle) <= 0.0:
        raise k.error("motor.idle_pct", idle, "a throttle where rotor_curves.thrust_N > 0 "
                      f"(above {thrust.solve(0.0):.2f} %)")
    if 4.0 * thrust.value(100.0) <= mass * g:
        raise k.error("rotor_curves.thrust_N", thrust,
                      f"full throttle to lift the weight {mass * g:.2f} N")
    return VehicleModel(name, str(path), mass, inertia, g, arm, thrust, torque, tuple(rotors),
                        idle, locked, math.radians(tmin), math.radians(tmax),
                        math.radians(srate), drag, motor_tau, motor_rate, servo_tau)


def load_vehicle_model(path: Path | str) -> VehicleModel:
    return _read(path, _vehicle)


# --------------------------------------------------------------------------------------------
# observer
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class EsoChannelGains:
    """Gains of one group of channels (translational or rotational)."""
    omega_o_rad_s: float                  # observer bandwidth
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
class EsoConfig:
    file: str
    kind: str                             # "nonlinear" | "linear"
    alpha: tuple[float, float, float]     # fal exponents of the three corrections
    translational: EsoChannelGains
    rotational: EsoChannelGains
    substeps: int                         # explicit Euler substeps per control period
    max_disturbance: tuple[float, float]  # clamp of |d| (m/s^2, rad/s^2) handed to the NMPC


def _eso(k: _Keys, path: Path) -> EsoConfig:
    kind = k.text("kind", ("nonlinear", "linear"))
    alpha = k.vector("alpha", 3, 0.05, 1.0)
    groups = []
    for name, outputs in (("translational", ("position", "velocity")),
                          ("rotational", ("angles", "rates"))):
        gk = k.sub(name)
        groups.append(EsoChannelGains(gk.number("omega_o_rad_s", 0.1, 500.0),
                                      gk.number("delta", 1e-6, 10.0),
                                      gk.text("output", outputs, default=outputs[0])))
        gk.close()
    sub = k.integer("substeps", 1, 1000)
    lim = k.sub("max_disturbance")
    max_d = (lim.number("translational_m_s2", 0.0, 100.0),
             lim.number("rotational_rad_s2", 0.0, 1000.0))
    lim.close()
    return EsoConfig(str(path), kind, alpha, groups[0], groups[1], sub, max_d)


def load_eso(path: Path | str) -> EsoConfig:
    return _read(path, _eso)


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
    applied_input: str = "commanded"      # commanded | outputs: what the controller takes as applied
    applied_delay_s: float = 0.0          # how long a command takes to act (observer's b0)
    delay_compensation: str = "auto"      # predict | none | auto (predict from one control
                                          # period of delay): plan from the state at t + delay
    lagged_actuators: str = "auto"        # on | off | auto (on when predicting): the
                                          # observer's b0 and the predictor through the lags
    actuator_states: str = "auto"         # on | off | auto (on when predicting): the NMPC's
                                          # stage state carries the actuators' lag states
    tilt_rate_limit: str = "horizon"      # horizon | first_step: where the NMPC enforces the
                                          # servos' rate limit (nmpc/ocp.py)
    effectiveness: EffectivenessConfig | None = None   # motor_effectiveness (None: off)

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


def _weights(k: _Keys) -> Weights:
    w = Weights(k.vector("position", 3, 0.0, 1e6), k.vector("velocity", 3, 0.0, 1e6),
                k.vector("euler", 3, 0.0, 1e6), k.vector("rates", 3, 0.0, 1e6),
                k.number("terminal_factor", 0.0, 1e4), k.number("tilt", 0.0, 1e6),
                k.number("throttle", 0.0, 1e6), k.number("tilt_rate", 0.0, 1e6),
                k.number("output_error", 0.0, 1e6))
    k.close()
    return w


# HPIPM's further IPM arguments (d_ocp_qp_ipm_arg_set_<name>) a solver file may set: range, integer
_HPIPM_OPTIONS = {"mu0": (1e-8, 1e8, False), "tol_stat": (1e-14, 1.0, False),
                  "tol_eq": (1e-14, 1.0, False), "tol_ineq": (1e-14, 1.0, False),
                  "tol_comp": (1e-14, 1.0, False), "reg_prim": (0.0, 1.0, False),
                  "ric_alg": (0, 1, True), "pred_corr": (0, 1, True), "split_step": (0, 1, True)}


def _hpipm_options(k: _Keys) -> tuple[tuple[str, float], ...]:
    if "hpipm_options" not in k._left:
        return ()
    ok = k.sub("hpipm_options")
    out = []
    for name in list(ok._left):
        if name not in _HPIPM_OPTIONS:
            raise ok.error(name, ok._left[name], "no such key: hpipm_options are "
                           + ", ".join(_HPIPM_OPTIONS))
        lo, hi, integer = _HPIPM_OPTIONS[name]
        out.append((name, ok.integer(name, lo, hi) if integer else ok.number(name, lo, hi)))
    ok.close()
    return tuple(out)


def _solver(k: _Keys) -> SolverConfig:
    s = SolverConfig(k.text("kind", ("rti", "sqp", "ipopt")),
                     k.text("hessian", ("gauss_newton", "exact")),
                     k.integer("max_iterations", 1, 100),
                     k.number("tolerance", 0.0, 1.0),
                     k.text("qp_solver", ("qrqp", "osqp", "qpoases", "hpipm", "daqp", "proxqp")),
                     k.number("regularization", 0.0, 1e3),
                     k.integer("ipopt_max_iterations", 1, 10_000),
                     k.text("codegen", ("auto", "off"), default="auto"),
                     k.text("hpipm_interface", ("direct", "conic"), default="direct"),
                     k.text("hpipm_mode", ("auto", "speed_abs", "speed", "balance", "robust"),
                            default="auto"),
                     k.integer("qp_max_iterations", 1, 1000, default=50),
                     _hpipm_options(k))
    k.close()
    if s.hessian == "exact" and s.hpipm_mode == "speed_abs":
        raise ConfigError(f"{k.file}: key '{k.where}hpipm_mode': got 'speed_abs', expected speed, "
                          "balance, robust or auto with hessian exact (the exact Hessian needs the "
                          "QP's multipliers, which speed_abs does not compute to tolerance)")
    return s


def _reference(k: _Keys) -> ReferenceConfig:
    r = ReferenceConfig(
        k.text("kind", ("hover", "step", "circle", "helix", "figure8")),
        k.number("altitude_m", 0.2, 100.0), k.number("climb_speed_m_s", 0.05, 5.0),
        k.number("hold_s", 0.0, 600.0), k.number("duration_s", 0.0, 3600.0),
        k.number("ramp_s", 0.0, 60.0), k.number("radius_m", 0.0, 50.0),
        k.number("period_s", 1.0, 600.0), k.number("helix_climb_m", -20.0, 20.0),
        k.vector("step_ned_m", 3, -20.0, 20.0), k.flag("land"))
    k.close()
    if 2.0 * r.ramp_s > r.duration_s:
        raise ConfigError(f"{k.file}: key '{k.where}ramp_s': got {r.ramp_s!r}, expected at most "
                          f"half of duration_s ({r.duration_s:g})")
    return r


def _effectiveness(k: _Keys, observer: str) -> EffectivenessConfig | None:
    """motor_effectiveness: {estimate: on | off, bandwidth_rad_s (250), min (0.1), substeps
    (10)}; it reads the observer's disturbance, so it needs one."""
    if "motor_effectiveness" not in k._left:
        return None
    ek = k.sub("motor_effectiveness")
    on = ek.text("estimate", ("on", "off")) == "on"
    cfg = EffectivenessConfig(ek.number("bandwidth_rad_s", 1.0, 2000.0, default=250.0),
                              ek.number("min", 0.01, 1.0, default=0.1),
                              ek.integer("substeps", 1, 1000, default=10))
    ek.close()
    if on and observer == "none":
        raise ek.error("estimate", "on", "off with observer.kind none (the motor effectiveness "
                       "observer reads the extended state observer's disturbance)")
    return cfg if on else None


def _controller(k: _Keys, path: Path) -> ControllerConfig:
    name = k.text("name")
    vehicle = load_vehicle_model(path.parent / k.text("vehicle"))
    ok = k.sub("observer")
    observer = ok.text("kind", ("none", "nonlinear", "linear"))
    eso_file = ok.text("file")
    ok.close()
    applied_input = k.text("applied_input", ("commanded", "outputs"))
    applied_delay = k.number("applied_delay_s", 0.0, 1.0)
    delay_comp = k.text("delay_compensation", ("predict", "none", "auto"), default="auto")
    lagged = k.text("lagged_actuators", ("on", "off", "auto"), default="auto")
    act_states = k.text("actuator_states", ("on", "off", "auto"), default="auto")
    tilt_rate_limit = k.text("tilt_rate_limit", ("horizon", "first_step"), default="horizon")
    effectiveness = _effectiveness(k, observer)
    if effectiveness is not None and applied_input == "outputs":
        raise k.error("applied_input", applied_input, "commanded with motor_effectiveness on (the "
                      "outputs the vehicle reports already carry the motors' loss: the observer "
                      "would see no fault to estimate)")
    eso = None
    if observer != "none":
        base = load_eso(path.parent / eso_file)
        eso = EsoConfig(base.file, observer, base.alpha, base.translational, base.rotational,
                        base.substeps, base.max_disturbance)
    rate = k.integer("control_rate_hz", 1, 1000)
    hk = k.sub("horizon")
    steps = hk.integer("steps", 2, 200)
    step_s = hk.number("step_s", 1e-3, 1.0)
    hk.close()
    weights = _weights(k.sub("weights"))
    ck = k.sub("constraints")
    max_tilt = ck.number("max_roll_pitch_deg", 1.0, 89.0)
    max_rate = ck.number("max_body_rate_rad_s", 0.1, 50.0)
    ck.close()
    solver = _solver(k.sub("solver"))
    reference = _reference(k.sub("reference"))
    if step_s < 1.0 / rate - 1e-12:
        raise k.error("horizon.step_s", step_s, f"at least one control period ({1.0 / rate:g} s)")
    if eso is not None:
        # the observer's explicit Euler substeps: w h <= 1 keeps them stable with a margin (the
        # triple pole's discrete eigenvalue is 1 - w h; 2 is the edge)
        w_max = eso.substeps * rate
        for group, gains in (("translational", eso.translational), ("rotational", eso.rotational)):
            if gains.omega_o_rad_s > w_max:
                raise ConfigError(
                    f"{eso.file}: key '{group}.omega_o_rad_s': got {gains.omega_o_rad_s!r}, "
                    f"expected at most substeps x control_rate_hz = {eso.substeps} x {rate} = "
                    f"{w_max:g} rad/s (explicit Euler substeps of {1e3 / w_max:g} ms; raise "
                    f"substeps for a faster observer) for {path}")
    if effectiveness is not None and effectiveness.bandwidth_rad_s > effectiveness.substeps * rate:
        raise ConfigError(
            f"{path}: key 'motor_effectiveness.bandwidth_rad_s': got "
            f"{effectiveness.bandwidth_rad_s!r}, expected at most substeps x control_rate_hz = "
            f"{effectiveness.substeps} x {rate} = {effectiveness.substeps * rate:g} rad/s "
            "(explicit Euler substeps; raise substeps for a faster observer)")
    return ControllerConfig(str(path), name, vehicle, observer, eso, rate, steps, step_s,
                            weights, max_tilt, max_rate, solver, reference, applied_input,
                            applied_delay, delay_comp, lagged, act_states, tilt_rate_limit,
                            effectiveness)


def load_controller(path: Path | str) -> ControllerConfig:
    return _read(path, _controller)
