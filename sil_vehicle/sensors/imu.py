"""The IMU: a 3-axis gyro and a 3-axis accelerometer in body FRD, integrating over its own
output interval (`rate_hz`, a divisor of the physics rate), with the rotors' vibration as
harmonic lines behind the chip's anti-alias filter, full scales and clipping.

Model, per physics tick k (dt the tick, per axis; w.[k] independent standard normals):

    gyro[k]  = clip_G(omega[k] + bg[k] + sigma_g w_g[k] + vib_g[k])
    accel[k] = clip_A(f[k]     + ba[k] + sigma_a w_a[k] + vib_a[k])
    bg[k+1]  = bg[k] + rw_g sqrt(dt) w_bg[k],     bg[0] ~ N(0, turn_on_g^2)
    ba[k+1]  = ba[k] + rw_a sqrt(dt) w_ba[k],     ba[0] ~ N(0, turn_on_a^2)

with omega, f the body rates and specific force the plant's tick gives (sensors.truth.imu_truth:
what an integrating IMU reads over the tick), sigma = noise density * sqrt(physics rate) (white
over the tick; averaged over an output interval of N ticks it is density * sqrt(rate_hz), the
Kalibr / PX4 gazebo discretisation), rw the bias random walk density, clip_X(v) = v held to
[-X, X] (the full scale; a tick that reaches it is flagged on that axis and counted).
A reading is the mean of its interval's ticks: its rates and specific force are the delta angle
and delta velocity over its interval `dt_us` divided by it (`delta_angle_frd_rad`,
`delta_velocity_frd_m_s` give the deltas), stamped `t_us`, the interval's end.

Vibration. Each rotor m turns at omega_m = max_rad_s sqrt(T(z_m) / T(100)) (the vehicle file's
rotor_speed and thrust curve, thrust proportional to speed squared; z_m the motor's actual
output), its phase phi_m wandering around that speed's integral by the rotor's speed jitter
(`smear_walk`): the jitter a first-order Gauss-Markov process with the rotor's time constant
tau (the vehicle file's motor.time_constant_s: the rotor cannot change speed faster), its
phase diffusion 2 pi smear_hz rad^2/s over times longer than tau, so that the line is about
smear_hz wide at its centre (n^2 that at its n-th multiple) and its skirts fall as 1/df^4
beyond 1/(2 pi tau) from it. (White speed jitter, a pure phase random walk, gives a Lorentzian
whose 1/df^2 skirts reach 0 Hz: a 125 Hz line then leaks a sub-hertz acceleration of a few
hundredths of a m/s^2 that the estimator integrates into millimetres of position,
docs/decisions/2026-12-06-vibration-line-skirts.md; tau = 0 keeps that walk.) Each
harmonic h of the profile, at n_h times the rotor frequency (n_h = times, or times * blades for
blade-pass lines), adds per axis i

    vib_i = sum_h a_hi Im( e^{j theta_i} sum_m (T(z_m) / T(100)) G(n_h omega_m / 2 pi) e^{j n_h phi_m} )

a_hi the profile's amplitude at full speed (it scales with speed squared), theta_i a fixed phase
per axis (AXIS_PHASE_RAD, a choice: the axes not in step), and G the chip's response: the
sinusoid sampled at `internal_rate_hz`, through its anti-alias filter (a 2nd-order Butterworth
low-pass at `anti_alias_cutoff_hz`, digital, at the internal rate) and averaged over the physics
tick's internal samples, in steady state:

    G(f) = H(e^{j w}) (1/M) sum_{i<M} e^{-j w i},  w = 2 pi f / internal_rate,  M = internal / physics

so that a line above the output rate's Nyquist frequency shows at its alias, attenuated by the
filter and the averaging, as on a real IMU. The rotor speeds are read once per vibration block
of VIBRATION_BLOCK_US (a choice: 50 ms, for speed: the cost per tick falls with the block,
docs/decisions/2026-12-05-imu-vibration.md) and held over it; the
phase runs on continuously.

Delivery: with `timestamp_jitter_us` each stamp is off by a normal error of that std (dt_us
follows the stamps); with `dropout_probability` an output sample is not delivered and the next
one covers both intervals (its dt_us twice the period), as an integrating driver does.

Speed: the IMU works every physics tick, so its arithmetic is split: `noise_block` turns a
block's standard normals (a (K, NOISE) draw, the same stream as K draws of NOISE) into each
tick's bias plus white noise with NumPy; `vibration_block` computes a vibration block with NumPy;
the suite adds the two and walks the rows in plain floats (NumPy costs more per call than the
arithmetic on 3-vectors), building the reading with `reading` (no dataclass __init__ per tick).
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import accumulate

import numpy as np

from sil_vehicle.sensors.noise import random_walk_std, white_std
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2, Truth

__all__ = ["ImuParams", "ImuHarmonic", "ImuVibration", "RotorModel", "ImuState", "ImuReading",
           "ImuClips", "NOISE", "VIBRATION_BLOCK_US", "AXIS_PHASE_RAD", "initial", "draw",
           "noise_block", "vibration_block", "response", "harmonic_multiples",
           "check_vibration", "response_table", "smear_walk", "smear_lines", "reading", "clip3",
           "step"]

NOISE = 12      # standard normals per tick: w_g, w_a, w_bg, w_ba (3 each)
VIBRATION_BLOCK_US = 50_000     # rotor speeds read once per block (a choice)
# each axis's phase in the vibration lines (x, y, z of gyro, then of accel): a choice, so that
# the axes are not in step (a rotating imbalance moves x and y a quarter turn apart)
AXIS_PHASE_RAD = (0.0, 0.5 * math.pi, 0.25 * math.pi, 0.0, 0.5 * math.pi, 0.25 * math.pi)
NO_CLIP = (False, False, False)


@dataclass(frozen=True)
class ImuHarmonic:
    of: str                                     # "rotor" or "blade_pass"
    times: int
    accel_m_s2: tuple[float, float, float]      # per axis, one rotor's, at full speed
    gyro_rad_s: tuple[float, float, float]


@dataclass(frozen=True)
class ImuVibration:
    harmonics: tuple[ImuHarmonic, ...]
    smear_hz: float


@dataclass(frozen=True)
class RotorModel:
    """The rotors' speed from the motor outputs: omega = max_rad_s sqrt(T(z) / T(100)), T the
    thrust curve c2 z^2 + c1 z + c0 (z in percent) clamped at zero."""
    max_rad_s: float
    blades: int
    c2: float
    c1: float
    c0: float
    time_constant_s: float = 0.0        # the rotor's speed lag (the speed jitter's band limit)

    def thrust_fraction(self, motor_pct: Sequence[float]) -> np.ndarray:
        z = np.asarray(motor_pct, float)
        full = (self.c2 * 100.0 + self.c1) * 100.0 + self.c0
        return np.maximum((self.c2 * z + self.c1) * z + self.c0, 0.0) / full

    @classmethod
    def of_vehicle(cls, v) -> "RotorModel":
        """From a sil_vehicle.config.VehicleParams (which must carry rotor_speed)."""
        if v.rotor_max_rad_s is None or v.rotor_blades is None:
            raise ValueError(f"{v.file}: rotor_speed: missing; the IMU's vibration needs the "
                             "rotors' max_rad_s and blades")
        t = v.thrust_N
        return cls(v.rotor_max_rad_s, v.rotor_blades, t.c2, t.c1, t.c0,
                   v.motor_time_constant_s)


@dataclass(frozen=True)
class ImuParams:
    rate_hz: int                                # output rate
    gyro_noise_density_rad_s_rthz: float
    gyro_bias_random_walk_rad_s2_rthz: float
    gyro_turn_on_bias_rad_s: float
    accel_noise_density_m_s2_rthz: float
    accel_bias_random_walk_m_s3_rthz: float
    accel_turn_on_bias_m_s2: float
    integration_rate_hz: int = 200      # HIGHRES_IMU's interval (PX4's IMU_INTEG_RATE)
    physics_rate_hz: int = 0            # the tick it integrates; 0: rate_hz
    internal_rate_hz: int = 8000
    anti_alias_cutoff_hz: float = 585.0
    accel_full_scale_g: float = 16.0
    gyro_full_scale_deg_s: float = 2000.0
    vibration: ImuVibration | None = None
    timestamp_jitter_us: float = 0.0
    dropout_probability: float = 0.0

    # derived once
    period_us: int = field(init=False)
    tick_us: int = field(init=False)
    ticks_per_sample: int = field(init=False)          # physics ticks per output sample
    samples_per_interval: int = field(init=False)      # the integration interval, in samples
    gyro_white_rad_s: float = field(init=False)        # per tick
    accel_white_m_s2: float = field(init=False)
    gyro_bias_step_rad_s: float = field(init=False)
    accel_bias_step_m_s2: float = field(init=False)
    accel_full_scale_m_s2: float = field(init=False)
    gyro_full_scale_rad_s: float = field(init=False)

    def __post_init__(self) -> None:
        physics = self.physics_rate_hz or self.rate_hz
        if physics % self.rate_hz:
            raise ValueError(f"imu.rate_hz: got {self.rate_hz}, expected a divisor of the "
                             f"physics rate ({physics} Hz)")
        dt = 1.0 / physics
        for name, value in (
                ("physics_rate_hz", physics),
                ("period_us", 1_000_000 // self.rate_hz),
                ("tick_us", 1_000_000 // physics),
                ("ticks_per_sample", physics // self.rate_hz),
                ("samples_per_interval", max(1, round(self.rate_hz / self.integration_rate_hz))),
                ("gyro_white_rad_s", white_std(self.gyro_noise_density_rad_s_rthz, physics)),
                ("accel_white_m_s2", white_std(self.accel_noise_density_m_s2_rthz, physics)),
                ("gyro_bias_step_rad_s",
                 random_walk_std(self.gyro_bias_random_walk_rad_s2_rthz, dt)),
                ("accel_bias_step_m_s2",
                 random_walk_std(self.accel_bias_random_walk_m_s3_rthz, dt)),
                ("accel_full_scale_m_s2", self.accel_full_scale_g * STANDARD_GRAVITY_M_S2),
                ("gyro_full_scale_rad_s", math.radians(self.gyro_full_scale_deg_s))):
            object.__setattr__(self, name, value)

    # the vibration's size as one figure per sensor: the RMS per axis (the largest axis) of
    # four rotors' lines at full speed, before the chip's filter. What a filter tuned from the
    # generator (estimator.params, generator-matched) reads in place of the old white term.
    @property
    def gyro_vibration_rad_s(self) -> float:
        return self._vibration_rms(lambda h: h.gyro_rad_s)

    @property
    def accel_vibration_m_s2(self) -> float:
        return self._vibration_rms(lambda h: h.accel_m_s2)

    def _vibration_rms(self, amp) -> float:
        if self.vibration is None:
            return 0.0
        return max(math.sqrt(sum(4 * amp(h)[i] ** 2 / 2 for h in self.vibration.harmonics))
                   for i in range(3))


@dataclass(frozen=True)
class ImuState:
    gyro_bias_frd_rad_s: np.ndarray     # (3,)
    accel_bias_frd_m_s2: np.ndarray     # (3,)


@dataclass(frozen=True)
class ImuReading:
    """One IMU output sample: the mean rates and specific force over its interval (the delta
    angle and delta velocity over `dt_us`, divided by it), held as plain floats (built every
    physics tick); the arrays and the deltas are built on access."""
    t_us: int                           # time of validity: its interval's end (no delay)
    gyro: Sequence[float]               # (3,) body FRD rates, rad/s
    accel: Sequence[float]              # (3,) specific force, body FRD, m/s^2
    dt_us: int = 0                      # its interval (0: not given, a record built by hand: the
                                        # IMU's nominal period to the estimator)
    accel_clipped: tuple[bool, bool, bool] = NO_CLIP    # per axis: full scale reached in it
    gyro_clipped: tuple[bool, bool, bool] = NO_CLIP

    @property
    def arrival_us(self) -> int:
        return self.t_us

    @property
    def gyro_frd_rad_s(self) -> np.ndarray:     # (3,), a new array per access
        return np.array(self.gyro, dtype=float)

    @property
    def accel_frd_m_s2(self) -> np.ndarray:     # (3,), a new array per access
        return np.array(self.accel, dtype=float)

    @property
    def delta_angle_frd_rad(self) -> np.ndarray:        # (3,)
        return np.array(self.gyro, dtype=float) * (self.dt_us * 1e-6)

    @property
    def delta_velocity_frd_m_s(self) -> np.ndarray:     # (3,)
        return np.array(self.accel, dtype=float) * (self.dt_us * 1e-6)


@dataclass(frozen=True)
class ImuClips:
    """The running clip counts per axis: physics ticks at which the axis was at full scale."""
    accel: tuple[int, int, int]
    gyro: tuple[int, int, int]


_new = object.__new__


def reading(t_us: int, gyro, accel, dt_us: int, accel_clipped=NO_CLIP,
            gyro_clipped=NO_CLIP) -> ImuReading:
    """An ImuReading built without its __init__ (whose per-field setattr on a frozen record
    costs more than the IMU's arithmetic): the same fields, the same record."""
    r = _new(ImuReading)
    r.__dict__.update(t_us=t_us, gyro=gyro, accel=accel, dt_us=dt_us,
                      accel_clipped=accel_clipped, gyro_clipped=gyro_clipped)
    return r


def initial(params: ImuParams, rng: np.random.Generator) -> ImuState:
    """The turn-on biases, drawn once."""
    w = rng.standard_normal(6)
    return ImuState(params.gyro_turn_on_bias_rad_s * w[:3], params.accel_turn_on_bias_m_s2 * w[3:])


def draw(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(NOISE)


def noise_block(p: ImuParams, s: ImuState, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What each of K ticks adds, from their standard normals `w` (K, NOISE) and the state before
    the first: (adds (K, 6): per tick bias plus white noise, gyro then accel; biases (K + 1, 6):
    the bias at each tick and, last, the state after the K-th)."""
    k = len(w)
    steps = np.empty((k + 1, 6))
    steps[0, :3], steps[0, 3:] = s.gyro_bias_frd_rad_s, s.accel_bias_frd_m_s2
    steps[1:, :3] = p.gyro_bias_step_rad_s * w[:, 6:9]
    steps[1:, 3:] = p.accel_bias_step_m_s2 * w[:, 9:12]
    bias = np.add.accumulate(steps, axis=0)         # b[j] = b[j-1] + step_j, in order
    white = np.concatenate((p.gyro_white_rad_s * w[:, 0:3], p.accel_white_m_s2 * w[:, 3:6]),
                           axis=1)
    return bias[:k] + white, bias


def harmonic_multiples(p: ImuParams, blades: int) -> np.ndarray:
    """Each harmonic's multiple of the rotor frequency, (H,)."""
    return np.array([h.times * (blades if h.of == "blade_pass" else 1)
                     for h in p.vibration.harmonics], float)


def response(p: ImuParams, f_hz) -> np.ndarray:
    """G(f): the chip's complex response to a line at f_hz (any shape), sampled at its internal
    rate, through its anti-alias filter (2nd-order Butterworth, bilinear with prewarping) and
    averaged over a physics tick's internal samples."""
    fs = float(p.internal_rate_hz)
    m = p.internal_rate_hz // p.physics_rate_hz
    k = math.tan(math.pi * p.anti_alias_cutoff_hz / fs)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * norm
    a1, a2 = 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm
    w = 2.0 * math.pi * np.asarray(f_hz, float) / fs
    z1 = np.exp(-1j * w)
    h = b0 * (1.0 + z1) ** 2 / (1.0 + a1 * z1 + a2 * z1 * z1)
    # the mean of e^{-j w i} over i < m (1 at w = 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        avg = np.where(np.abs(1.0 - z1) > 1e-12, (1.0 - z1 ** m) / (m * (1.0 - z1)), 1.0)
    return h * avg


def check_vibration(p: ImuParams, rotor: RotorModel, file: str) -> None:
    """Every harmonic at the rotors' full speed below the internal rate's Nyquist frequency (the
    chip cannot represent a line above it), or a ValueError naming the file and the key."""
    if p.vibration is None:
        return
    nyquist = p.internal_rate_hz / 2
    for i, n in enumerate(harmonic_multiples(p, rotor.blades)):
        f = n * rotor.max_rad_s / (2 * math.pi)
        if f >= nyquist:
            raise ValueError(
                f"{file}: imu.vibration.harmonics[{i}]: {f:.0f} Hz at the rotors' full speed "
                f"({rotor.max_rad_s:g} rad/s, {rotor.blades} blades), expected below the "
                f"internal rate's Nyquist frequency ({nyquist:g} Hz, imu.internal_rate_hz "
                f"{p.internal_rate_hz})")


def vibration_coefficients(p: ImuParams, n_rotors: int = 1) -> np.ndarray:
    """(H * n_rotors, 6) complex: each harmonic's amplitude per axis (gyro x y z, accel x y z)
    with the axis's phase, repeated for each rotor (harmonic-major)."""
    amp = np.array([tuple(h.gyro_rad_s) + tuple(h.accel_m_s2) for h in p.vibration.harmonics])
    return np.repeat(amp * np.exp(1j * np.array(AXIS_PHASE_RAD)), n_rotors, axis=0)


RESPONSE_STEP_HZ = 0.05        # the response table's frequency step (see `response_table`)


def response_table(p: ImuParams, max_hz: float) -> np.ndarray:
    """`response` on a grid of RESPONSE_STEP_HZ from 0 to max_hz (looked up to the nearest
    point: the filter's response moves by far less than a part in a thousand over a step)."""
    return response(p, np.arange(0.0, max_hz + 2 * RESPONSE_STEP_HZ, RESPONSE_STEP_HZ))


def smear_walk(w: np.ndarray, walk: np.ndarray, jitter: np.ndarray, smear_hz: float,
               tau_s: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The rotors' phase wander over a block from its standard normals w (n_motors, K): the
    speed jitter nu (rad/s) first-order Gauss-Markov with time constant tau_s and std
    sqrt(pi smear_hz / tau_s) (so that the phase diffuses at 2 pi smear_hz rad^2/s over times
    longer than tau_s), nu[k] = a nu[k-1] + sqrt(1 - a^2) std w[k] with a = exp(-dt / tau_s),
    and the phase W[k] = W[k-1] + nu[k] dt; from the block's start values `walk` and `jitter`
    (n_motors,). Returns (W (n_motors, K), nu at the block's end). tau_s = 0: white jitter, the
    phase a random walk of step sqrt(2 pi smear_hz dt)."""
    if tau_s <= 0.0:
        return np.cumsum(math.sqrt(2.0 * math.pi * smear_hz * dt_s) * w, axis=1) \
            + walk[:, None], jitter
    a = math.exp(-dt_s / tau_s)
    kick = math.sqrt((1.0 - a * a) * math.pi * smear_hz / tau_s)
    nu = np.empty_like(w)
    for m, (row, u) in enumerate(zip((kick * w).tolist(), jitter.tolist())):
        nu[m] = list(accumulate(row, lambda prev, x: a * prev + x, initial=u))[1:]
    return np.cumsum(nu * dt_s, axis=1) + walk[:, None], nu[:, -1].copy()


def smear_lines(multiples: np.ndarray, walk: np.ndarray) -> np.ndarray:
    """e^{j n_h W_m(k)}: the smear's phase walk W (n_motors, K) on each harmonic's line,
    (H * n_motors, K), harmonic-major (computed once per noise block): e^{j W} once, raised to
    each whole multiple (NumPy's integer power: repeated products), for speed."""
    z = np.exp(1j * walk)
    return np.concatenate([z ** int(n) if n == int(n) else np.exp(1j * n * walk)
                           for n in multiples.tolist()])


def vibration_block(p: ImuParams, rotor: RotorModel, multiples: Sequence[float],
                    coefficients: np.ndarray, table: Sequence[complex], phases: Sequence[float],
                    motor_pct: Sequence[float], smear: np.ndarray
                    ) -> tuple[np.ndarray, list[float]]:
    """The vibration over B ticks with the rotor speeds of `motor_pct` held: from each line's
    multiple of the rotor frequency (H,), the rotors' deterministic phases at the block's start
    (n_motors,: the speed's integral, without the smear), the smear's factor on each line at each
    of the block's ticks (`smear_lines`' columns, (H * n_motors, B)), `coefficients`
    (`vibration_coefficients` repeated per rotor, (H * M, 6)) and the chip's response table
    (`response_table`, as a list): (vib (B, 6), gyro then accel; the deterministic phases at its
    end). Each line at tick b of the block is e^{j n (phase + (b + 1) step)} times its smear
    factor: the start's e^{j n phase} times the running product of e^{j n step} (a product of B
    unit complex numbers, exact to rounding). The per-line factors (a dozen numbers) in plain
    Python, the block in four NumPy operations: fewer calls cost less in the vehicle's loop."""
    dt = 1.0 / p.physics_rate_hz
    c2, c1, c0 = rotor.c2, rotor.c1, rotor.c0
    full = (c2 * 100.0 + c1) * 100.0 + c0
    frac = [max((c2 * z + c1) * z + c0, 0.0) / full for z in motor_pct]   # amplitude scale
    step = [rotor.max_rad_s * math.sqrt(x) * dt for x in frac]           # rad per tick
    b = smear.shape[1]
    k = 1.0 / (2.0 * math.pi * RESPONSE_STEP_HZ * dt)
    exp = cmath.exp
    gains, rots = [], []
    for h in multiples:
        for x, st, f in zip(phases, step, frac):
            gains.append(table[int(h * st * k + 0.5)] * f * exp(1j * h * x))
            rots.append(exp(1j * h * st))
    lines = np.cumprod(np.array(rots)[:, None].repeat(b, axis=1), axis=1)
    lines *= smear
    vib = (lines.T @ (np.array(gains)[:, None] * coefficients)).imag        # (B, 6)
    return vib, [x + b * st for x, st in zip(phases, step)]


def clip3(v, fs: float) -> tuple[tuple[float, ...], tuple[bool, ...]]:
    """A 3-vector held to [-fs, fs], and per axis whether it was beyond."""
    out = tuple(fs if x > fs else -fs if x < -fs else x for x in v)
    return out, tuple(x > fs or x < -fs for x in v)


def step(p: ImuParams, s: ImuState, truth: Truth, w: np.ndarray,
         vib: Sequence[float] = (0.0,) * 6) -> tuple[ImuState, ImuReading]:
    """One tick as one output sample (rate_hz the physics rate), for tests: the reading of
    `truth` with the normals `w` (NOISE,) and the tick's vibration `vib` (6,)."""
    adds, bias = noise_block(p, s, np.asarray(w, float).reshape(1, NOISE))
    a = adds[0] + np.asarray(vib, float)
    g, gc = clip3([truth.rates[i] + a[i] for i in range(3)], p.gyro_full_scale_rad_s)
    f, ac = clip3([truth.force[i] + a[3 + i] for i in range(3)], p.accel_full_scale_m_s2)
    nxt = ImuState(bias[1, :3].copy(), bias[1, 3:].copy())
    return nxt, reading(truth.t_us, g, f, p.period_us, ac, gc)
