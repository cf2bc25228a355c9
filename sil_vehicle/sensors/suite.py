"""The sensor suite: the sensors of a sensing profile, sampled in lockstep with the physics.

    suite = SensorSuite(load_sensing("rtk", 1000), rng, home_alt_m=30.0)
    for each physics tick:  readings = suite.sample(t_us, truth)

`sample` must be called once per physics tick, in order (t_us = k * dt_us). It returns the
readings that arrive at t_us, in a fixed order: IMU, barometer, magnetometer, GNSS, motion
capture (a delayed reading arrives at t + delay and carries its time of validity `t_us` and its
`arrival_us`). A sensor samples on the ticks where t_us is a multiple of its period. Each of the
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
lower rate). The IMU, sampled every tick, precomputes what each sample of a block adds
(`imu.noise_block`) and keeps its state as the position in that block; its record is built
when `states` is read. The other sensors step their frozen records at their own rates, and a
delayed sensor's line is only released when its first reading is due.
"""

from __future__ import annotations

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
_DELAYED = (("gnss", gnss), ("mocap", mocap))
_PER_SAMPLE = frozenset({"mocap"})      # draws that mix normals and uniforms: not in blocks
_NEVER = float("inf")                   # no reading in a delay line


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
    """The IMU: a block of samples' noise (`imu.noise_block`) consumed one row per sample."""

    __slots__ = ("_after", "_k", "_rng", "_rows", "_w", "params")

    def __init__(self, params: imu.ImuParams, rng: np.random.Generator) -> None:
        self.params, self._rng, self._k = params, rng, max(1, params.rate_hz)
        self._after = imu.initial(params, rng)         # the state after the block
        self._w = np.empty((0, imu.NOISE))             # the block's standard normals
        self._rows: list[list[float]] = []             # its rows still to use, the next last

    def _fill(self, s: imu.ImuState, w: np.ndarray) -> list[list[float]]:
        self._w = w
        rows, self._after = imu.noise_block(self.params, s, w)
        rows.reverse()
        self._rows = rows
        return rows

    def step(self, truth: Truth) -> imu.ImuReading:
        rows = self._rows or self._fill(self._after,
                                        self._rng.standard_normal((self._k, imu.NOISE)))
        return imu.measure(self.params, truth, rows.pop())

    @property
    def state(self) -> imu.ImuState:
        """The state before the next sample."""
        if not self._rows:
            return self._after
        row = self._rows[-1]
        return imu.ImuState(np.array(row[0:3]), np.array(row[3:6]))

    def set_state(self, s: imu.ImuState) -> None:
        # the block's remaining normals, from s on
        self._fill(s, self._w[len(self._w) - len(self._rows):])


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
                 home_alt_m: float = 0.0) -> None:
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
            name: (_Imu(self.params[name], rngs[name]) if name == "imu"
                   else _Slot(name, module, self.params[name], rngs[name]))
            for name, module in slots if name in self.params}
        self.states = _States(self._slots)
        # per tick: (period, the sensor's sample) in the readings' order
        self._immediate = tuple((self.params[n].period_us, self._slots[n].step)
                                for n, _ in _IMMEDIATE if n in self._slots)
        self._delayed = tuple((self.params[n].period_us, self._slots[n])
                              for n, _ in _DELAYED if n in self._slots)
        self._dt_us = profile.dt_us

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.params)

    def sample(self, t_us: int, truth: Truth) -> list[Reading]:
        """The readings that arrive at `t_us` (a physics tick; `truth` is the plant then)."""
        if t_us != truth.t_us or t_us % self._dt_us:
            raise ValueError(f"sample: t_us {t_us} must be a physics tick (a multiple of "
                             f"{self._dt_us} us) and equal truth.t_us ({truth.t_us})")
        out: list[Reading] = []
        for period, step in self._immediate:
            if not t_us % period:
                out.append(step(truth))
        for period, slot in self._delayed:
            if not t_us % period:
                slot.sample(truth)
            if slot.due_us <= t_us:
                out.extend(slot.release(t_us))
        return out
