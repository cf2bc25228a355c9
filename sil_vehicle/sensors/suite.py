"""The sensor suite: the sensors of a sensing profile, sampled in lockstep with the physics.

    suite = SensorSuite(load_sensing("rtk", 1000), rng, home_alt_m=30.0)
    for each physics tick:  readings = suite.sample(t_us, truth)

`sample` must be called once per physics tick, in order (t_us = k * dt_us). It returns the
readings that arrive at t_us, in a fixed order: IMU, barometer, magnetometer, GNSS, motion
capture (a delayed reading arrives at t + delay and carries its time of validity `t_us` and its
`arrival_us`). A sensor samples on the ticks where t_us is a multiple of its period; the IMU
works every tick (it integrates over its output interval) and its reading arrives at the
interval's end. `imu_clips` holds the IMU's running clip counts per axis. The IMU's vibration
needs the rotors' speed: `vehicle` (a sil_vehicle.config.VehicleParams with rotor_speed; the
Sitl passes its own), or without one the built-in `trq` airframe's. Each of the
five sensor slots draws its noise from its own child of the injected generator
(`rng.spawn(5)`, in that order, whether the profile carries the sensor or not), so the same seed
and the same truths give the same readings bit for bit, a sensor's noise does not change when
another sensor is added or removed, and nothing else (no clock, no global random state) enters.

The `truth` profile has no sensor: the suite returns nothing, and the vehicle keeps its
truth-plus-noise state stream (today's ODOMETRY) for debugging.

The state of every sensor is in `states` (frozen records, for logs and replays; assigning one
sets the sensor's state from its next sample on).

Speed: `sample` runs every physics tick, so the suite spends as little as it can per tick. A
sensor's standard normals are drawn a block of samples at a time (one second's worth): NumPy's
Generator fills a (K, n) draw in the order of K draws of n, so each sensor sees the same stream
as one draw per sample, and its readings are the same bit for bit. The motion capture draws a
uniform between its normals, which a block would reorder: it draws per sample (at its own,
lower rate). The IMU, stepped every tick, precomputes what each tick of a block adds
(`imu.noise_block`, a second's worth; `imu.vibration_block`, one vibration block's) and keeps
its state as the position in that block; its record is built when `states` is read. The IMU's
vibration, jitter and dropouts draw from their own children of the IMU's generator
(`spawn(3)`), so its white noise and biases do not change when they are switched on or off. The other sensors step their frozen records at their own rates, and a
delayed sensor's line is only released when its first reading is due.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, MutableMapping
from dataclasses import replace
from typing import Any, Union

import numpy as np

from sil_vehicle.sensors import baro, gnss, imu, mag, mocap
from sil_vehicle.sensors.profile import SensingProfile
from sil_vehicle.sensors.truth import Truth

__all__ = ["SensorSuite", "Reading"]

Reading = Union[imu.ImuReading, baro.BaroReading, mag.MagReading, gnss.GnssReading,
                mocap.MocapReading]

_IMMEDIATE = (("imu", imu), ("baro", baro), ("mag", mag))


N_ROTORS = 4       # the airframe's rotors (VehicleFile's four)


def _rotor(vehicle: Any, p: imu.ImuParams) -> imu.RotorModel | None:
    """The rotors' speed model for the IMU's vibration: the vehicle's (its rotor_speed and thrust
    curve); without a vehicle, the built-in airframe the sim files fly (trq)."""
    if p.vibration is None:
        return None
    if vehicle is None:
        from sil_vehicle.config import PARAMS_DIR, load_vehicle
        vehicle = load_vehicle(PARAMS_DIR / "vehicle" / "trq.yaml")
    return imu.RotorModel.of_vehicle(vehicle)
_DELAYED = (("gnss", gnss), ("mocap", mocap))
_PER_SAMPLE = frozenset({"mocap"})      # draws that mix normals and uniforms: not in blocks
_NEVER = float("inf")                   # no reading in a delay line
_NO_CLIP = imu.NO_CLIP
_new = object.__new__                   # an ImuReading built as imu.reading builds it


class _Normals:
    """A sensor's standard normals, `n` per sample, drawn `k` samples at a time."""

    __slots__ = ("_i", "_k", "_n", "_rng", "_w")

    def __init__(self, rng: np.random.Generator, n: int, k: int) -> None:
        self._rng, self._n, self._k = rng, n, k
        self._w = np.empty((0, n))
        self._i = 0

    def __call__(self) -> np.ndarray:
        if self._i == len(self._w):
            self._w, self._i = self._rng.standard_normal((self._k, self._n)), 0
        self._i += 1
        return self._w[self._i - 1]


class _Slot:
    """A sensor other than the IMU: its frozen state, stepped by its module at its rate; for a
    delayed sensor, `due_us` the arrival time of the first reading in its line."""

    __slots__ = ("draw", "due_us", "module", "params", "state")

    def __init__(self, name: str, module: Any, params: Any, rng: np.random.Generator) -> None:
        self.module, self.params = module, params
        self.state = module.initial(params, rng)
        self.draw = ((lambda: module.draw(rng)) if name in _PER_SAMPLE
                     else _Normals(rng, module.NOISE, max(1, params.rate_hz)))
        self.due_us = _NEVER

    def step(self, truth: Truth) -> Reading:
        self.state, reading = self.module.step(self.params, self.state, truth, self.draw())
        return reading

    def sample(self, truth: Truth) -> None:
        self.state = self.module.sample(self.params, self.state, truth, self.draw())
        self._due()

    def release(self, t_us: int) -> tuple[Reading, ...]:
        self.state, arrived = self.module.release(self.state, t_us)
        self._due()
        return arrived

    def _due(self) -> None:
        pending = getattr(self.state, "pending", ())
        self.due_us = pending[0].arrival_us if pending else _NEVER

    def set_state(self, s: Any) -> None:
        self.state = s
        self._due()


class _Imu:
    """The IMU, stepped every physics tick: a second's noise (`imu.noise_block`) and a vibration
    block's lines (`imu.vibration_block`) added into per-tick rows, consumed one row per tick;
    the ticks summed over each output interval; the clip counts kept."""

    def __init__(self, params: imu.ImuParams, rng: np.random.Generator,
                 rotor: imu.RotorModel | None, file: str) -> None:
        p = self.params = params
        self._rng, self._k = rng, p.physics_rate_hz
        # the vibration block, in ticks (dividing the noise block)
        b = max(1, imu.VIBRATION_BLOCK_US // p.tick_us)
        self._b = b if self._k % b == 0 else 1
        self._after = imu.initial(p, rng)              # the state after the noise block
        # the vibration's, the stamps' and the dropouts' own streams (children of the IMU's)
        vib_rng, self._jitter_rng, self._drop_rng = rng.spawn(3)
        self._vib = None
        if p.vibration is not None:
            if rotor is None:
                raise ValueError(f"{file}: imu.vibration: needs the vehicle's rotor_speed")
            imu.check_vibration(p, rotor, file)
            mult = imu.harmonic_multiples(p, rotor.blades)
            self._vib = (rotor, mult, imu.vibration_coefficients(p, N_ROTORS),
                         imu.response_table(p, float(mult.max()) * rotor.max_rad_s
                                            / (2 * math.pi)).tolist(), mult.tolist())
            self._vib_rng = vib_rng
            self._phases = vib_rng.uniform(0.0, 2.0 * math.pi, N_ROTORS).tolist()
            # the smear's phase walk per rotor over the noise block (drawn per block), the
            # speed jitter it carries across blocks, and its factor on each line
            self._walk = np.zeros(N_ROTORS)
            self._jitter = np.zeros(N_ROTORS)
            self._lines = np.ones((0, 0), complex)
        self._w = np.empty((0, imu.NOISE))             # the noise block's standard normals
        self._adds = np.empty((0, 6))                  # its bias plus white noise, per tick
        self._bias = np.empty((1, 6))                  # its biases (and the state after it)
        self._i = 0                                    # the noise block's next tick
        self._rows: list[list[float]] = []             # the vibration block's rows to use
        self._vib_rows = np.zeros((0, 6))
        self._gfs, self._afs = p.gyro_full_scale_rad_s, p.accel_full_scale_m_s2
        self._tick_us = p.tick_us
        self.accel_clips = [0, 0, 0]
        self.gyro_clips = [0, 0, 0]
        # one tick per output sample, every one delivered on time: the short path
        self._simple = (p.ticks_per_sample == 1 and not p.timestamp_jitter_us
                        and not p.dropout_probability)
        self._sum = [0.0] * 6
        self._count = 0
        self._ac, self._gc = imu.NO_CLIP, imu.NO_CLIP
        self._jitter_prev = 0
        self._uniform: list[float] = []
        self._normal: list[float] = []

    def _block(self, truth: Truth) -> list[list[float]]:
        if self._i == len(self._adds):
            self._w = self._rng.standard_normal((self._k, imu.NOISE))
            self._adds, self._bias = imu.noise_block(self.params, self._after, self._w)
            self._after = imu.ImuState(self._bias[-1, :3].copy(), self._bias[-1, 3:].copy())
            self._i = 0
            if self._vib is not None:
                walk, self._jitter = imu.smear_walk(
                    self._vib_rng.standard_normal((N_ROTORS, self._k)), self._walk,
                    self._jitter, self.params.vibration.smear_hz, self._vib[0].time_constant_s,
                    1.0 / self._k)
                self._walk = np.mod(walk[:, -1], 2.0 * math.pi)      # carried to the next
                self._lines = imu.smear_lines(self._vib[1], walk)
                self._phases = [x % (2.0 * math.pi) for x in self._phases]
        i, b = self._i, self._b
        adds = self._adds[i:i + b]
        if self._vib is not None:
            rotor, _, coef, table, mult = self._vib
            motors = truth.motors
            if len(motors) != N_ROTORS:
                raise ValueError(f"imu.vibration: {len(motors)} motors, the model has "
                                 f"{N_ROTORS}")
            self._vib_rows, self._phases = imu.vibration_block(
                self.params, rotor, mult, coef, table, self._phases, motors,
                self._lines[:, i:i + b])
            adds = adds + self._vib_rows
        else:
            self._vib_rows = np.zeros((b, 6))
        self._i = i + b
        rows = adds.tolist()
        rows.reverse()
        self._rows = rows
        return rows

    def _clip(self, g, a):
        g, gc = imu.clip3(g, self._gfs)
        a, ac = imu.clip3(a, self._afs)
        for j in range(3):
            self.gyro_clips[j] += gc[j]
            self.accel_clips[j] += ac[j]
        return g, a, gc, ac

    def step(self, truth: Truth) -> imu.ImuReading | None:
        row = (self._rows or self._block(truth)).pop()
        r0, r1, r2 = truth.rates
        f0, f1, f2 = truth.force
        g0, g1, g2 = r0 + row[0], r1 + row[1], r2 + row[2]
        a0, a1, a2 = f0 + row[3], f1 + row[4], f2 + row[5]
        G, A = self._gfs, self._afs
        if (-G <= g0 <= G and -G <= g1 <= G and -G <= g2 <= G
                and -A <= a0 <= A and -A <= a1 <= A and -A <= a2 <= A):
            if self._simple:
                r = _new(imu.ImuReading)
                r.__dict__.update(t_us=truth.t_us, gyro=(g0, g1, g2), accel=(a0, a1, a2),
                                  dt_us=self._tick_us, accel_clipped=_NO_CLIP,
                                  gyro_clipped=_NO_CLIP)
                return r
            g, a, gc, ac = (g0, g1, g2), (a0, a1, a2), _NO_CLIP, _NO_CLIP
        else:
            g, a, gc, ac = self._clip((g0, g1, g2), (a0, a1, a2))
        p = self.params
        if self._simple:
            return imu.reading(truth.t_us, g, a, p.tick_us, ac, gc)
        acc = self._sum
        acc[0] += g[0]; acc[1] += g[1]; acc[2] += g[2]          # noqa: E702
        acc[3] += a[0]; acc[4] += a[1]; acc[5] += a[2]          # noqa: E702
        self._count += 1
        if gc is not imu.NO_CLIP:
            self._gc = tuple(x or y for x, y in zip(self._gc, gc))
            self._ac = tuple(x or y for x, y in zip(self._ac, ac))
        t_us = truth.t_us
        if t_us % p.period_us:
            return None
        if p.dropout_probability and self._draw(self._uniform, self._drop_rng, False) \
                < p.dropout_probability:
            return None                     # not delivered: the next sample covers both
        n = self._count
        dt_us = n * p.tick_us
        if p.timestamp_jitter_us:
            jitter = round(p.timestamp_jitter_us * self._draw(self._normal, self._jitter_rng,
                                                               True))
            t_us += jitter
            dt_us += jitter - self._jitter_prev
            self._jitter_prev = jitter
        out = imu.reading(t_us, (acc[0] / n, acc[1] / n, acc[2] / n),
                          (acc[3] / n, acc[4] / n, acc[5] / n), dt_us, self._ac, self._gc)
        self._sum = [0.0] * 6
        self._count = 0
        self._ac = self._gc = imu.NO_CLIP
        return out

    def _draw(self, pool: list[float], rng: np.random.Generator, normal: bool) -> float:
        """One uniform (or standard normal) from a second's block of its own stream."""
        if not pool:
            k = max(1, self.params.rate_hz)
            pool.extend((rng.standard_normal(k) if normal else rng.random(k)).tolist()[::-1])
        return pool.pop()

    @property
    def clips(self) -> imu.ImuClips:
        return imu.ImuClips(tuple(self.accel_clips), tuple(self.gyro_clips))

    @property
    def state(self) -> imu.ImuState:
        """The state before the next tick."""
        if not self._rows and self._i == len(self._adds):
            return self._after
        j = self._i - len(self._rows)
        return imu.ImuState(self._bias[j, :3].copy(), self._bias[j, 3:].copy())

    def set_state(self, s: imu.ImuState) -> None:
        # the noise block's remaining normals, from s on, in place (the block's positions and
        # the vibration's stay aligned); the vibration block's lines kept
        if not self._rows and self._i == len(self._adds):
            self._after = s
            return
        j = self._i - len(self._rows)
        adds, bias = imu.noise_block(self.params, s, self._w[j:])
        self._adds = np.concatenate((self._adds[:j], adds))
        self._bias = np.concatenate((self._bias[:j], bias))
        self._after = imu.ImuState(bias[-1, :3].copy(), bias[-1, 3:].copy())
        rest = len(self._rows)
        vib = self._vib_rows[len(self._vib_rows) - rest:]
        rows = (self._adds[j:self._i] + vib).tolist()
        rows.reverse()
        self._rows = rows


class _States(MutableMapping):
    """Each sensor's state by name: read as a frozen record, assigned to set it."""

    def __init__(self, slots: dict[str, Any]) -> None:
        self._slots = slots

    def __getitem__(self, name: str) -> Any:
        return self._slots[name].state

    def __setitem__(self, name: str, state: Any) -> None:
        self._slots[name].set_state(state)

    def __delitem__(self, name: str) -> None:
        raise TypeError("a sensor's state cannot be removed")

    def __iter__(self) -> Iterator[str]:
        return iter(self._slots)

    def __len__(self) -> int:
        return len(self._slots)


class SensorSuite:
    def __init__(self, profile: SensingProfile, rng: np.random.Generator, *,
                 home_alt_m: float = 0.0, vehicle: Any = None) -> None:
        self.profile = profile
        slots = _IMMEDIATE + _DELAYED
        rngs = dict(zip((name for name, _ in slots), rng.spawn(len(slots))))
        self.params: dict[str, Any] = {}
        for name, _ in slots:
            p = getattr(profile, name)
            if p is not None:
                self.params[name] = replace(p, home_alt_m=home_alt_m) if name == "baro" else p
        # turn-on biases and stationary starts, drawn once, in the fixed order
        self._slots: dict[str, Any] = {
            name: (_Imu(self.params[name], rngs[name], _rotor(vehicle, self.params[name]),
                        profile.file) if name == "imu"
                   else _Slot(name, module, self.params[name], rngs[name]))
            for name, module in slots if name in self.params}
        self.states = _States(self._slots)
        # per tick: (period, the sensor's sample) in the readings' order
        self._imu = self._slots.get("imu")
        self._imu_step = self._imu.step if self._imu is not None else None
        self._immediate = tuple((self.params[n].period_us, self._slots[n].step)
                                for n, _ in _IMMEDIATE if n in self._slots and n != "imu")
        self._delayed = tuple((self.params[n].period_us, self._slots[n])
                              for n, _ in _DELAYED if n in self._slots)
        self._dt_us = profile.dt_us

    @property
    def imu_clips(self) -> imu.ImuClips | None:
        """The IMU's running clip counts per axis (None without an IMU)."""
        return self._imu.clips if self._imu is not None else None

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.params)

    def sample(self, t_us: int, truth: Truth) -> list[Reading]:
        """The readings that arrive at `t_us` (a physics tick; `truth` is the plant then)."""
        if t_us != truth.t_us or t_us % self._dt_us:
            raise ValueError(f"sample: t_us {t_us} must be a physics tick (a multiple of "
                             f"{self._dt_us} us) and equal truth.t_us ({truth.t_us})")
        out: list[Reading] = []
        if self._imu_step is not None:
            r = self._imu_step(truth)
            if r is not None:
                out.append(r)
        for period, step in self._immediate:
            if not t_us % period:
                out.append(step(truth))
        for period, slot in self._delayed:
            if not t_us % period:
                slot.sample(truth)
            if slot.due_us <= t_us:
                out.extend(slot.release(t_us))
        return out
