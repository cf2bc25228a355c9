"""Parameters of the SIL vehicle: frozen, validated records loaded from `params/` YAML files.

`load_vehicle(path)` reads an airframe (`params/vehicle/*.yaml`), `load_sim(path)` the simulation
settings (`params/sim/*.yaml`, which names its airframe). Unknown, missing or out-of-range keys
raise `ConfigError` naming the file, the key, the value and the expected range. Derived quantities
(rotor geometry, hover throttle) are computed once here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from sil_vehicle.impair import ImpairParams
from sil_vehicle.yamlcheck import ConfigError, Section, load_with_extends

__all__ = ["ConfigError", "VehicleParams", "SimParams", "RotorParams", "load_vehicle", "load_sim",
           "STREAMS", "PARAMS_DIR"]

from trq_params import DIR as PARAMS_DIR  # noqa: E402  (the shipped parameter files)

# Telemetry streams the vehicle can send, by MAVLink message name.
STREAMS = ("HEARTBEAT", "SYS_STATUS", "ODOMETRY", "ATTITUDE", "LOCAL_POSITION_NED",
           "SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS", "GLOBAL_POSITION_INT", "GPS_RAW_INT",
           "HOME_POSITION")


@dataclass(frozen=True)
class Quadratic:
    """c2*zeta^2 + c1*zeta + c0 with zeta the throttle in percent, clamped at zero below."""
    c2: float
    c1: float
    c0: float

    def __call__(self, zeta_pct: float) -> float:
        value = (self.c2 * zeta_pct + self.c1) * zeta_pct + self.c0
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
    # derived
    hover_throttle_pct: float = field(init=False)

    def __post_init__(self) -> None:
        per_rotor = self.mass_kg * self.gravity_m_s2 / len(self.rotors)
        object.__setattr__(self, "hover_throttle_pct", self.thrust_N.inverse(per_rotor))

    @property
    def tilt_limit_rad(self) -> float:
        """Half-range used to scale a normalised tilt command (-1..1)."""
        return max(abs(self.tilt_min_rad), abs(self.tilt_max_rad))


def _quadratic(sec: Section) -> Quadratic:
    q = Quadratic(sec.float("c2", 0.0, 1.0, lo_open=True), sec.float("c1", -10.0, 10.0),
                  sec.float("c0", -10.0, 10.0))
    sec.done()
    return q


def load_vehicle(path: Path | str) -> VehicleParams:
    path = Path(path)
    top = Section(load_with_extends(path), path)
    name = top.str("name")
    mass = top.float("mass_kg", 0.05, 100.0)
    inertia = top.section("inertia_kg_m2")
    inertia_t = (inertia.float("xx", 1e-6, 100.0), inertia.float("yy", 1e-6, 100.0),
                 inertia.float("zz", 1e-6, 100.0))
    inertia.done()
    gravity = top.float("gravity_m_s2", 9.7, 9.9)
    arm = top.float("arm_length_m", 0.01, 5.0)
    curves = top.section("rotor_curves")
    thrust = _quadratic(curves.section("thrust_N"))
    torque = _quadratic(curves.section("torque_Nm"))
    curves.done()
    rotors = []
    for sec in top.sections("rotors", 4):
        rname = sec.str("name")
        az = math.radians(sec.float("azimuth_deg", -180.0, 180.0))
        spin = {"ccw": 1, "cw": -1}[sec.str("spin", ("ccw", "cw"))]
        sec.done()
        axis = (math.cos(az), math.sin(az), 0.0)
        rotors.append(RotorParams(rname, az, spin, (arm * axis[0], arm * axis[1], 0.0), axis))
    motor = top.section("motor")
    idle = motor.float("idle_pct", 0.0, 50.0)
    motor_tc = motor.float("time_constant_s", 0.0, 1.0)
    motor_rate = motor.float("rate_limit_pct_s", 1.0, 1e6)
    motor.done()
    tilt = top.section("tilt")
    locked = tilt.bool("locked")
    tmin = tilt.float("min_deg", -90.0, 0.0)
    tmax = tilt.float("max_deg", 0.0, 90.0)
    servo_tc = tilt.float("servo_time_constant_s", 0.0, 1.0)
    servo_rate = tilt.float("servo_rate_limit_deg_s", 1.0, 1e5)
    tilt.done()
    drag = top.section("drag")
    k = drag.float("quadratic_N_s2_m2", 0.0, 10.0)
    drag.done()
    top.done()
    params = VehicleParams(
        name=name, file=str(path), mass_kg=mass, inertia_kg_m2=inertia_t, gravity_m_s2=gravity,
        arm_length_m=arm, thrust_N=thrust, torque_Nm=torque, rotors=tuple(rotors), idle_pct=idle,
        motor_time_constant_s=motor_tc, motor_rate_limit_pct_s=motor_rate, tilt_locked=locked,
        tilt_min_rad=math.radians(tmin), tilt_max_rad=math.radians(tmax),
        servo_time_constant_s=servo_tc, servo_rate_limit_rad_s=math.radians(servo_rate),
        drag_N_s2_m2=k)
    if thrust(100.0) * 4 <= mass * gravity:
        raise ConfigError(f"{path}: key 'rotor_curves.thrust_N': full throttle gives "
                          f"{4 * thrust(100.0):.2f} N, not more than the weight "
                          f"{mass * gravity:.2f} N: the vehicle cannot fly")
    return params


@dataclass(frozen=True)
class Endpoint:
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.host}:{self.port}"


@dataclass(frozen=True)
class LinkParams:
    name: str
    bind: Endpoint
    target: Endpoint
    rates_hz: tuple[tuple[str, int], ...]    # (stream, Hz), Hz divides the physics rate or is 0
    impair: ImpairParams = ImpairParams()    # a bad link on purpose (tests, lossy scenarios)

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

    @property
    def dt_us(self) -> int:
        return 1_000_000 // self.physics_rate_hz

    @property
    def ticks_per_control(self) -> int:
        return self.physics_rate_hz // self.control_rate_hz

    def link(self, name: str) -> LinkParams:
        for link in self.links:
            if link.name == name:
                return link
        raise KeyError(name)

    def with_changes(self, **changes) -> "SimParams":
        return replace(self, **changes)


def parse_endpoint(text: str, sec: Section, key: str) -> Endpoint:
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise sec.fail(key, text, "HOST:PORT with a port in [0, 65535]")
    return Endpoint(host, int(port))


def _rate(sec: Section, key: str, physics_hz: int) -> int:
    hz = sec.int(key, 0, physics_hz)
    if hz and physics_hz % hz:
        raise sec.fail(key, hz, f"0 or a rate in Hz that divides physics_rate_hz ({physics_hz})")
    return hz


def load_sim(path: Path | str, vehicle: Path | str | None = None) -> SimParams:
    """Load simulation settings; `vehicle` overrides the airframe file the settings name."""
    path = Path(path)
    top = Section(load_with_extends(path, path_keys=("vehicle",)), path)
    vehicle_ref = top.str("vehicle")
    vehicle_path = Path(vehicle) if vehicle is not None else (path.parent / vehicle_ref)
    vparams = load_vehicle(vehicle_path)
    physics = top.int("physics_rate_hz", 500, 10_000)
    if 1_000_000 % physics:
        raise top.fail("physics_rate_hz", physics, "a rate whose period is a whole microsecond")
    control = _rate(top, "control_rate_hz", physics)
    if control == 0:
        raise top.fail("control_rate_hz", 0, "a rate > 0")
    seed = top.int("seed", 0, 2**63 - 1)
    core = top.str("physics_core", ("auto", "compiled", "python"), default="auto")
    clock = top.section("clock")
    mode = clock.str("mode", ("lockstep", "realtime"))
    speed_up = clock.float("speed_up", 0.01, 1000.0)
    resend = clock.float("resend_s", 0.01, 60.0)
    free_run = clock.float("free_run_after_s", 0.05, 3600.0)
    clock.done()
    telemetry = top.section("telemetry")
    link_secs = top.section("links")
    links = []
    for name in ("gcs", "offboard"):
        rates_sec = telemetry.section(name)
        rates = tuple((stream, _rate(rates_sec, stream, physics)) for stream in STREAMS)
        if name == "offboard" and dict(rates)["ODOMETRY"] != control:
            raise rates_sec.fail("ODOMETRY", dict(rates)["ODOMETRY"],
                                 f"control_rate_hz ({control}): the offboard state stream "
                                 "paces the control loop and the lockstep")
        rates_sec.done()
        lsec = link_secs.section(name)
        bind = parse_endpoint(lsec.str("bind"), lsec, "bind")
        target = parse_endpoint(lsec.str("target"), lsec, "target")
        impair = ImpairParams()
        if lsec.has("impair"):
            isec = lsec.section("impair")
            impair = ImpairParams(
                isec.float("loss", 0.0, 1.0, default=0.0),
                isec.float("delay_ms", 0.0, 10_000.0, default=0.0),
                isec.float("jitter_ms", 0.0, 10_000.0, default=0.0),
                isec.float("duplicate", 0.0, 1.0, default=0.0),
                isec.float("reorder", 0.0, 1.0, default=0.0))
            isec.done()
        lsec.done()
        links.append(LinkParams(name, bind, target, rates, impair))
    telemetry.done()
    link_secs.done()
    wind = top.section("wind")
    wspeed = wind.float("speed_m_s", 0.0, 40.0)
    wdir = wind.float("direction_deg", -360.0, 360.0)
    gusts = wind.section("gusts")
    genabled = gusts.bool("enabled")
    gsigma = gusts.float("sigma_m_s", 0.0, 20.0)
    glength = gusts.float("length_m", 1.0, 2000.0)
    gusts.done()
    wind.done()
    noise = top.section("noise")
    n_pos = noise.float("position_m", 0.0, 10.0)
    n_vel = noise.float("velocity_m_s", 0.0, 10.0)
    n_att = noise.float("attitude_rad", 0.0, 1.0)
    n_rate = noise.float("rates_rad_s", 0.0, 10.0)
    noise.done()
    faults = top.section("faults")
    eff = faults.floats("motor_effectiveness", 4, 0.0, 1.0)
    tv_b = faults.floats("motor_tv_amplitude", 4, 0.0, 1.0)
    tv_w = faults.floats("motor_tv_omega_rad_s", 4, 0.0, 1000.0)
    tv_phi = faults.floats("motor_tv_phase_rad", 4, -10.0, 10.0)
    faults.done()
    ground = top.section("ground")
    crash_speed = ground.float("crash_speed_m_s", 0.1, 100.0)
    crash_tilt = ground.float("crash_tilt_deg", 10.0, 180.0)
    ground.done()
    home = top.section("home")
    lat = home.float("lat_deg", -90.0, 90.0)
    lon = home.float("lon_deg", -180.0, 180.0)
    alt = home.float("alt_m", -500.0, 9000.0)
    home.done()
    log = top.section("log")
    log_dir = log.str("dir")
    log_rate = _rate(log, "rate_hz", physics)
    log.done()
    top.done()
    return SimParams(
        file=str(path), vehicle=vparams, physics_rate_hz=physics, control_rate_hz=control,
        seed=seed, clock_mode=mode, speed_up=speed_up, resend_s=resend,
        free_run_after_s=free_run, links=tuple(links),
        wind_speed_m_s=wspeed, wind_from_deg=wdir, gusts_enabled=genabled,
        gust_sigma_m_s=gsigma, gust_length_m=glength, noise_position_m=n_pos,
        noise_velocity_m_s=n_vel, noise_attitude_rad=n_att, noise_rates_rad_s=n_rate,
        motor_effectiveness=eff, motor_tv_amplitude=tv_b, motor_tv_omega_rad_s=tv_w,
        motor_tv_phase_rad=tv_phi, crash_speed_m_s=crash_speed,
        crash_tilt_rad=math.radians(crash_tilt), home_lat_deg=lat, home_lon_deg=lon,
        home_alt_m=alt, log_dir=log_dir, log_rate_hz=log_rate, physics_core=core)
