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

The state of every sensor is in `states` (frozen records), for logs and replays.
"""

from __future__ import annotations

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


class SensorSuite:
    def __init__(self, profile: SensingProfile, rng: np.random.Generator, *,
                 home_alt_m: float = 0.0) -> None:
        self.profile = profile
        slots = _IMMEDIATE + _DELAYED
        self._rngs = dict(zip((name for name, _ in slots), rng.spawn(len(slots))))
        self.params: dict[str, Any] = {}
        for name, _ in _IMMEDIATE + _DELAYED:
            p = getattr(profile, name)
            if p is not None:
                self.params[name] = replace(p, home_alt_m=home_alt_m) if name == "baro" else p
        # turn-on biases and stationary starts, drawn once, in the fixed order
        self.states: dict[str, Any] = {name: module.initial(self.params[name], self._rngs[name])
                                       for name, module in _IMMEDIATE + _DELAYED
                                       if name in self.params}
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
        for name, module in _IMMEDIATE:
            p = self.params.get(name)
            if p is not None and t_us % p.period_us == 0:
                self.states[name], reading = module.step(p, self.states[name], truth,
                                                         module.draw(self._rngs[name]))
                out.append(reading)
        for name, module in _DELAYED:
            p = self.params.get(name)
            if p is None:
                continue
            state = self.states[name]
            if t_us % p.period_us == 0:
                state = module.sample(p, state, truth, module.draw(self._rngs[name]))
            self.states[name], arrived = module.release(state, t_us)
            out.extend(arrived)
        return out
