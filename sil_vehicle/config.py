"""Parameters of the SIL vehicle: frozen, validated records loaded from `params/` YAML files.

`load_vehicle(path)` reads an airframe (`params/vehicle/*.yaml`), `load_sim(path)` the simulation
settings (`params/sim/*.yaml`, which names its airframe and its sensing profile,
`params/sensing/*.yaml`, loaded by `sensing_profile` against the physics rate). Files are read
and validated by `trq_params.loader` against `trq_params.schema` (the same vehicle schema the
controller reads); unknown, missing or out-of-range keys raise `ConfigError` (the loader's)
naming the file, the key, the value and the expected range. This module builds the records from
the validated models: derived quantities (rotor geometry, hover throttle) are computed once here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from pydantic_core import PydanticCustomError
from trq_params import loader, schema
from trq_params.loader import ConfigError
from trq_params.schema import STREAMS, throttle_curve

from sil_vehicle.dynamics.contact import Gear, resting_plane_down_m, tip_over_rad
from sil_vehicle.impair import ImpairParams
from sil_vehicle.sensors.profile import SensingProfile, load_sensing

__all__ = ["ConfigError", "VehicleParams", "SimParams", "RotorParams", "LinkParams",
           "SerialPort", "load_vehicle", "load_sim", "parse_serial", "sensing_profile",
           "STREAMS", "PARAMS_DIR"]

from trq_params import DIR as PARAMS_DIR  # noqa: E402  (the shipped parameter files)


@dataclass(frozen=True)
class Quadratic:
    """c2*zeta^2 + c1*zeta + c0 with zeta the throttle in percent, clamped at zero below."""
    c2: float
    c1: float
    c0: float

    def __call__(self, zeta_pct: float) -> float:
        value = throttle_curve(self.c2, self.c1, self.c0, zeta_pct)
        return value if value > 0.0 else 0.0

    def inverse(self, value: float) -> float:
        """The throttle (percent) that gives `value` (>= 0) on the rising branch."""
        disc = self.c1 * self.c1 - 4.0 * self.c2 * (self.c0 - value)
        return (-self.c1 + math.sqrt(disc)) / (2.0 * self.c2)


@dataclass(frozen=True)
class RotorParams:
    name: str
    azimuth_rad: float
    spin: int                                   # +1 ccw seen from above, -1 cw
    position_frd_m: tuple[float, float, float]
    tilt_axis_frd: tuple[float, float, float]   # unit vector along the arm


@dataclass(frozen=True)
class VehicleParams:
    name: str
    file: str
    mass_kg: float
    inertia_kg_m2: tuple[float, float, float]   # diagonal: xx, yy, zz (body FRD)
    gravity_m_s2: float
    arm_length_m: float
    thrust_N: Quadratic
    torque_Nm: Quadratic
    rotors: tuple[RotorParams, ...]
    idle_pct: float
    motor_time_constant_s: float
    motor_rate_limit_pct_s: float
    tilt_locked: bool
    tilt_min_rad: float
    tilt_max_rad: float
    servo_time_constant_s: float
    servo_rate_limit_rad_s: float
    drag_N_s2_m2: float
    gear_points_frd_m: tuple[tuple[float, float, float], ...]
    gear_stiffness_N_m: float          # per point
    gear_damping_N_s_m: float          # per point
    gear_friction: float
    gear_stick_stiffness_N_m: float    # per point
    gear_stick_damping_N_s_m: float    # per point
    # the rotors' speed at full throttle and blades per propeller (None: not given)
    rotor_max_rad_s: float | None = None
    rotor_blades: int | None = None
    # derived
    hover_throttle_pct: float = field(init=False)
    gear: Gear = field(init=False)                  # the contact model's record
    tip_over_rad: float = field(init=False)         # tilt on the ground past which it falls over

    def __post_init__(self) -> None:
        per_rotor = self.mass_kg * self.gravity_m_s2 / len(self.rotors)
        object.__setattr__(self, "hover_throttle_pct", self.thrust_N.inverse(per_rotor))
        pts = self.gear_points_frd_m
        ground = resting_plane_down_m(pts, self.gear_stiffness_N_m,
                                      self.mass_kg * self.gravity_m_s2)
        reach = max(math.sqrt(x * x + y * y + z * z) for x, y, z in pts)
        object.__setattr__(self, "gear", Gear(
            pts, self.gear_stiffness_N_m, self.gear_damping_N_s_m, self.gear_friction,
            self.gear_stick_stiffness_N_m, self.gear_stick_damping_N_s_m, ground, ground - reach))
        object.__setattr__(self, "tip_over_rad", tip_over_rad(pts))

    @property
    def tilt_limit_rad(self) -> float:
        """Half-range used to scale a normalised tilt command (-1..1)."""
        return max(abs(self.tilt_min_rad), abs(self.tilt_max_rad))


def _quadratic(c: schema.QuadraticCurve) -> Quadratic:
    return Quadratic(c.c2, c.c1, c.c0)


def vehicle_params(v: schema.VehicleFile, file: str) -> VehicleParams:
    """The record of a validated vehicle file (`file` as the caller named it)."""
    rotors = []
    for r in v.rotors:
        az = math.radians(r.azimuth_deg)
        axis = (math.cos(az), math.sin(az), 0.0)
        rotors.append(RotorParams(r.name, az, {"ccw": 1, "cw": -1}[r.spin],
                                  (v.arm_length_m * axis[0], v.arm_length_m * axis[1], 0.0),
                                  axis))
    return VehicleParams(
        name=v.name, file=file, mass_kg=v.mass_kg,
        inertia_kg_m2=(v.inertia_kg_m2.xx, v.inertia_kg_m2.yy, v.inertia_kg_m2.zz),
        gravity_m_s2=v.gravity_m_s2, arm_length_m=v.arm_length_m,
        thrust_N=_quadratic(v.rotor_curves.thrust_N),
        torque_Nm=_quadratic(v.rotor_curves.torque_Nm), rotors=tuple(rotors),
        idle_pct=v.motor.idle_pct, motor_time_constant_s=v.motor.time_constant_s,
        motor_rate_limit_pct_s=v.motor.rate_limit_pct_s, tilt_locked=v.tilt.locked,
        tilt_min_rad=math.radians(v.tilt.min_deg), tilt_max_rad=math.radians(v.tilt.max_deg),
        servo_time_constant_s=v.tilt.servo_time_constant_s,
        servo_rate_limit_rad_s=math.radians(v.tilt.servo_rate_limit_deg_s),
        drag_N_s2_m2=v.drag.quadratic_N_s2_m2,
        gear_points_frd_m=tuple((p.x_m, p.y_m, p.z_m) for p in v.landing_gear.points),
        gear_stiffness_N_m=v.landing_gear.stiffness_N_m,
        gear_damping_N_s_m=v.landing_gear.damping_N_s_m,
        gear_friction=v.landing_gear.friction,
        gear_stick_stiffness_N_m=v.landing_gear.stick_stiffness_N_m,
        gear_stick_damping_N_s_m=v.landing_gear.stick_damping_N_s_m,
        rotor_max_rad_s=v.rotor_speed.max_rad_s if v.rotor_speed else None,
        rotor_blades=v.rotor_speed.blades if v.rotor_speed else None)


def load_vehicle(path: Path | str) -> VehicleParams:
    path = Path(path)
    return vehicle_params(loader.load(path, schema.VehicleFile), str(path))


@dataclass(frozen=True)
class Endpoint:
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.host}:{self.port}"


@dataclass(frozen=True)
class SerialPort:
    device: str
    baud: int                    # 8N1: the line carries baud / 10 bytes a second


@dataclass(frozen=True)
class LinkParams:
    name: str
    bind: Endpoint
    target: Endpoint
    rates_hz: tuple[tuple[str, int], ...]    # (stream, Hz), Hz divides the physics rate or is 0
    impair: ImpairParams = ImpairParams()    # a bad link on purpose (tests, lossy scenarios)
    # the link on a byte stream instead of UDP (bind and target then unused): a serial device,
    # or a TCP server on this endpoint (one client at a time)
    serial: SerialPort | None = None
    tcp: Endpoint | None = None

    @property
    def transport(self) -> str:
        return "serial" if self.serial else "tcp" if self.tcp else "udp"

    def rate(self, stream: str) -> int:
        return dict(self.rates_hz)[stream]


@dataclass(frozen=True)
class SimParams:
    file: str
    vehicle: VehicleParams
    physics_rate_hz: int
    control_rate_hz: int
    seed: int
    clock_mode: str              # "lockstep" | "realtime"
    speed_up: float
    resend_s: float
    free_run_after_s: float
    links: tuple[LinkParams, ...]
    wind_speed_m_s: float
    wind_from_deg: float
    gusts_enabled: bool
    gust_sigma_m_s: float
    gust_length_m: float
    noise_position_m: float
    noise_velocity_m_s: float
    noise_attitude_rad: float
    noise_rates_rad_s: float
    motor_effectiveness: tuple[float, ...]
    motor_tv_amplitude: tuple[float, ...]
    motor_tv_omega_rad_s: tuple[float, ...]
    motor_tv_phase_rad: tuple[float, ...]
    crash_speed_m_s: float
    crash_tilt_rad: float
    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float
    log_dir: str
    log_rate_hz: int
    physics_core: str = "auto"   # "auto" | "compiled" | "python" (sil_vehicle/compiled.py)
    # the sensing profile, loaded for physics_rate_hz: always a profile, `truth` included (its
    # `is_truth` says that it carries no sensor); None only for a record built by hand, read
    # as truth
    sensing: SensingProfile | None = None
    mocap_wiring: str = "autopilot"     # trq_wire.mocap.WIRINGS: where the mocap pose enters

    @property
    def dt_us(self) -> int:
        return 1_000_000 // self.physics_rate_hz

    @property
    def ticks_per_control(self) -> int:
        return self.physics_rate_hz // self.control_rate_hz

    @property
    def senses(self) -> bool:
        """Does the profile carry any sensor (false under `truth`)?"""
        return self.sensing is not None and not self.sensing.is_truth

    def link(self, name: str) -> LinkParams:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)

    def with_changes(self, **changes) -> "SimParams":
        return replace(self, **changes)


def parse_endpoint(text: str, where: str) -> Endpoint:
    """`HOST:PORT` given outside a file (`where`, e.g. a command-line option)."""
    try:
        return Endpoint(*schema.parse_endpoint(text))
    except PydanticCustomError as exc:
        raise ConfigError(f"{where}: got {text!r}, expected {exc.context['expected']}") from None


def parse_serial(text: str, where: str) -> SerialPort:
    """`DEVICE[:BAUD]` (baud 921600 if left out), read as trq_wire.connection reads
    `serial://DEVICE:BAUD`."""
    from trq_wire.connection import Connection

    try:
        c = Connection.parse(f"serial://{text}")
    except ValueError:
        raise ConfigError(f"{where}: got {text!r}, expected DEVICE or DEVICE:BAUD (a device "
                          "path such as /dev/ttyUSB0, BAUD a positive integer, 921600 if "
                          "left out)") from None
    return SerialPort(c.device, c.baud)


def sensing_profile(name_or_path: str | Path, physics_rate_hz: int, where: str,
                    key: str = "sensing") -> SensingProfile:
    """The sensing profile `name_or_path` (a built-in name or a path) for `physics_rate_hz`.
    Any error, an unknown name or a bad file (whose own message names its key), is a
    ConfigError naming `where` (a file or the command line), `key` and the value."""
    try:
        return load_sensing(name_or_path, physics_rate_hz)
    except (ConfigError, OSError) as exc:
        raise ConfigError(f"{where}: key '{key}': got {str(name_or_path)!r}: {exc}") from None


def load_sim(path: Path | str, vehicle: Path | str | None = None) -> SimParams:
    """Load simulation settings; `vehicle` overrides the airframe file the settings name."""
    path = Path(path)
    sim = loader.load(path, schema.SimFile)
    sensing = sensing_profile(sim.sensing, sim.physics_rate_hz, str(path))
    vparams = load_vehicle(Path(vehicle) if vehicle is not None else path.parent / sim.vehicle)
    links = []
    for name in ("gcs", "offboard"):
        streams = getattr(sim.telemetry, name)
        rates = tuple((stream, getattr(streams, stream)) for stream in STREAMS)
        link = getattr(sim.links, name)
        imp = link.impair
        impair = ImpairParams() if imp is None else ImpairParams(
            imp.loss, imp.delay_ms, imp.jitter_ms, imp.duplicate, imp.reorder)
        links.append(LinkParams(name, Endpoint(*schema.parse_endpoint(link.bind)),
                                Endpoint(*schema.parse_endpoint(link.target)), rates, impair))
    faults = sim.faults
    return SimParams(
        file=str(path), vehicle=vparams, physics_rate_hz=sim.physics_rate_hz,
        control_rate_hz=sim.control_rate_hz, seed=sim.seed, clock_mode=sim.clock.mode,
        speed_up=sim.clock.speed_up, resend_s=sim.clock.resend_s,
        free_run_after_s=sim.clock.free_run_after_s, links=tuple(links),
        wind_speed_m_s=sim.wind.speed_m_s, wind_from_deg=sim.wind.direction_deg,
        gusts_enabled=sim.wind.gusts.enabled, gust_sigma_m_s=sim.wind.gusts.sigma_m_s,
        gust_length_m=sim.wind.gusts.length_m, noise_position_m=sim.noise.position_m,
        noise_velocity_m_s=sim.noise.velocity_m_s, noise_attitude_rad=sim.noise.attitude_rad,
        noise_rates_rad_s=sim.noise.rates_rad_s, motor_effectiveness=faults.motor_effectiveness,
        motor_tv_amplitude=faults.motor_tv_amplitude,
        motor_tv_omega_rad_s=faults.motor_tv_omega_rad_s,
        motor_tv_phase_rad=faults.motor_tv_phase_rad,
        crash_speed_m_s=sim.ground.crash_speed_m_s,
        crash_tilt_rad=math.radians(sim.ground.crash_tilt_deg), home_lat_deg=sim.home.lat_deg,
        home_lon_deg=sim.home.lon_deg, home_alt_m=sim.home.alt_m, log_dir=sim.log.dir,
        log_rate_hz=sim.log.rate_hz, physics_core=sim.physics_core, sensing=sensing,
        mocap_wiring=sim.mocap_wiring)
