"""Reference trajectories: pure functions of time giving position NED, velocity NED and yaw.

`Reference(cfg, start_ned_m, start_yaw_rad, t0_s)` is the flight plan of one run, relative to
where the controller takes over (the vehicle on the ground, or already flying):

    takeoff   [t0, t1)   straight up from the start point to the hover point (altitude_m above
                         it), quintic smooth-step, peak vertical speed climb_speed_m_s
    hold      [t1, t2)   hover for hold_s
    manoeuvre [t2, t3)   `kind` for duration_s (ramps of ramp_s at both ends):
                           hover    stay at the hover point
                           step     jump by step_ned_m at the start of the manoeuvre, back at its end
                           circle   horizontal circle of radius_m through the hover point
                           helix    circle plus helix_climb_m (NED) per revolution
                           figure8  lemniscate of Gerono, half-width radius_m, through the point
                         circle, helix and figure8 advance a phase phi(t) whose rate rises and
                         falls smoothly (cosine ramps), so velocity is continuous everywhere
    hold      [t3, t4)   hover at the manoeuvre's end point for hold_s
    land      [t4, t5)   straight down to the start altitude plus 0.2 m (below the start point: the
                         vehicle touches down gently and stays down), if `land`
    landed    [t5, ...)  on down at LAND_CRAWL_M_S (a vehicle not down by then is over a ground
                         its estimate puts too low), until the flight loop sees the ground
    done(t)              true from t5 (from t4 when not landing: the plan then holds forever)

Everything is a pure function of t (float seconds since the same origin as t0_s): no state.
Keep within what the vehicle can do: the defaults fly at 0.63 m/s with 0.4 m/s^2.
"""

from __future__ import annotations

import ctypes
import math
from typing import Protocol

import numpy as np

from trq_offboard import reference_core
from trq_offboard.config import ReferenceConfig
from trq_offboard.records import ReferenceSample

__all__ = ["Reference", "LAND_BELOW_M", "LAND_CRAWL_M_S"]

LAND_BELOW_M = 0.2
# after the landing's plan, down on at PX4's MPC_LAND_CRWL until the ground stops it: PX4 lands
# on a speed, not on a height, so that a height estimate tenths of a metre off still reaches the
# ground (docs/decisions/2026-12-05-landing-on-a-wrong-height.md)
LAND_CRAWL_M_S = 0.3
# a choice: the crawl reached over a second, at most 1.875 LAND_CRAWL_M_S / CRAWL_RAMP_S of
# acceleration (the quintic's steepest slope)
CRAWL_RAMP_S = 1.0


def _smoothstep5(s: float) -> tuple[float, float]:
    """(value, derivative) of 10 s^3 - 15 s^4 + 6 s^5 on [0, 1], clamped outside."""
    if s <= 0.0:
        return 0.0, 0.0
    if s >= 1.0:
        return 1.0, 0.0
    return s ** 3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2


class FlightReference(Protocol):
    """What the flight loop and the controller use of a reference (Reference,
    ConstantReference)."""

    @property
    def land(self) -> bool: ...   # the plan ends on the ground (else: in the air, held)

    def sample(self, t_s: float) -> ReferenceSample: ...

    def grid(self, t_s: float, step_s: float, n: int) -> tuple[np.ndarray, np.ndarray]: ...

    def done(self, t_s: float) -> bool: ...


class Reference:
    """The flight plan of one run (see the module docstring)."""

    def __init__(self, cfg: ReferenceConfig, start_ned_m, start_yaw_rad: float = 0.0,
                 t0_s: float = 0.0, *, airborne: bool = False,
                 ground_down_m: float | None = None, compiled: bool = True) -> None:
        """`airborne`: the controller takes over a flying vehicle: no take-off, the plan starts
        by holding where the vehicle is; it lands on `ground_down_m` (NED down of the ground,
        default the start point's). `compiled`: `grid` in C (reference_core.py) where a C
        compiler is found, else `_pv` point by point: the same figures."""
        self.cfg = cfg
        self.start = np.asarray(start_ned_m, float).reshape(3)
        self.yaw = float(start_yaw_rad)
        self.t0 = float(t0_s)
        self.airborne = airborne
        self.ground = float(self.start[2] if ground_down_m is None else ground_down_m)
        self.hover_point = self.start + np.array([0.0, 0.0, 0.0 if airborne else -cfg.altitude_m])
        self._w = 2.0 * math.pi / cfg.period_s          # the phase's constants (_phase)
        self._T, self._r = cfg.duration_s, cfg.ramp_s
        self._full_ramp = self._ramp_integral(self._r)
        self._phi_end = self._w * (2 * self._full_ramp + self._T - 2 * self._r)
        self._start = tuple(float(v) for v in self.start)
        self._hover = tuple(float(v) for v in self.hover_point)
        rise = self.hover_point[2] - self.start[2]
        self.t_takeoff = float(abs(rise) * 1.875 / cfg.climb_speed_m_s)
        self.t1 = self.t0 + self.t_takeoff
        self.t2 = self.t1 + cfg.hold_s
        self.t3 = self.t2 + cfg.duration_s
        self.t4 = self.t3 + cfg.hold_s
        self._end = self._manoeuvre_pv(cfg.duration_s)[0:3]
        self.end_point = np.array(self._end)
        drop = (self.ground + LAND_BELOW_M) - self.end_point[2]
        self.t_land = float(abs(drop) * 1.875 / cfg.climb_speed_m_s) if cfg.land else 0.0
        self.t5 = self.t4 + self.t_land
        self._kernel = None if compiled else False      # reference_core's, on the first grid
        self._params = np.array(
            [self.t0, self.t1, self.t2, self.t3, self.t4, self.t5, self.t_takeoff, self.t_land,
             *self._start, *self._hover, *self._end, self.ground, self._w, self._T, self._r,
             self._full_ramp, self._phi_end, cfg.radius_m, cfg.helix_climb_m,
             *(float(v) for v in cfg.step_ned_m), cfg.duration_s,
             reference_core.KINDS.index(cfg.kind) if cfg.kind in reference_core.KINDS else -1,
             1.0 if cfg.land else 0.0, LAND_BELOW_M, LAND_CRAWL_M_S, CRAWL_RAMP_S], float)
        self._params_at = self._params.ctypes.data       # (the array is kept: its address)

    # --- phase of the periodic manoeuvres -------------------------------------------------
    def _phase(self, tau: float) -> tuple[float, float]:
        """(phi, dphi/dt) at tau seconds into the manoeuvre; rate ramps 0 -> w -> 0."""
        w, T, r = self._w, self._T, self._r
        tau = min(max(tau, 0.0), T)
        if tau < r:
            return w * self._ramp_integral(tau), w * 0.5 * (1 - math.cos(math.pi * tau / r))
        if tau <= T - r:
            return w * (self._full_ramp + tau - r), w
        back = T - tau
        return (self._phi_end - w * self._ramp_integral(back),
                w * 0.5 * (1 - math.cos(math.pi * back / r)))

    def _ramp_integral(self, s: float) -> float:
        """The integral of (1 - cos(pi x / r)) / 2 over [0, s]."""
        r = self._r
        return 0.5 * (s - r / math.pi * math.sin(math.pi * s / r)) if r > 0 else s

    def _manoeuvre_pv(self, tau: float) -> tuple[float, ...]:
        """(north, east, down, vn, ve, vd) at tau seconds into the manoeuvre (plain floats: the
        controller samples 21 points twice a step)."""
        cfg = self.cfg
        cn, ce, cd = self._hover
        if cfg.kind == "hover":
            return cn, ce, cd, 0.0, 0.0, 0.0
        if cfg.kind == "step":
            if 0.0 <= tau < cfg.duration_s:
                sn, se, sd = cfg.step_ned_m
                return cn + float(sn), ce + float(se), cd + float(sd), 0.0, 0.0, 0.0
            return cn, ce, cd, 0.0, 0.0, 0.0
        phi, dphi = self._phase(tau)
        R = cfg.radius_m
        c, s = math.cos(phi), math.sin(phi)
        if cfg.kind in ("circle", "helix"):
            climb = cfg.helix_climb_m / (2 * math.pi) if cfg.kind == "helix" else 0.0
            return (cn + R * (c - 1.0), ce + R * s, cd + climb * phi,
                    -dphi * R * s, dphi * R * c, dphi * climb)
        # figure8: x = R sin(phi), y = R/2 sin(2 phi)
        return (cn + R * s, ce + 0.5 * R * math.sin(2 * phi), cd,
                dphi * R * c, dphi * R * math.cos(2 * phi), 0.0)

    def _pv(self, t: float) -> tuple[tuple[float, ...], str]:
        """(north, east, down, vn, ve, vd) and the phase at time t."""
        if t < self.t1:
            s, ds = _smoothstep5((t - self.t0) / self.t_takeoff if self.t_takeoff > 0 else 1.0)
            sn, se, sd = self._start
            dz = self._hover[2] - sd
            vz = ds * dz / self.t_takeoff if self.t_takeoff > 0 else 0.0
            return (sn, se, sd + s * dz, 0.0, 0.0, vz), "takeoff"
        if t < self.t2:
            return (*self._hover, 0.0, 0.0, 0.0), "hold"
        if t < self.t3:
            return self._manoeuvre_pv(t - self.t2), self.cfg.kind
        en, ee, ed = self._end
        if t < self.t4 or not self.cfg.land:
            return (en, ee, ed, 0.0, 0.0, 0.0), "hold"
        dz = self.ground + LAND_BELOW_M - ed
        if t >= self.t5:
            # the vehicle not down yet (an estimate whose height is wrong): on down at a crawl,
            # reached smoothly over CRAWL_RAMP_S
            x = (t - self.t5) / CRAWL_RAMP_S
            s, _ = _smoothstep5(x)
            rise = x ** 4 * (2.5 - 3.0 * x + x * x) if x < 1.0 else x - 0.5   # the integral of s
            return (en, ee, ed + dz + LAND_CRAWL_M_S * CRAWL_RAMP_S * rise, 0.0, 0.0,
                    LAND_CRAWL_M_S * s), "landed"
        s, ds = _smoothstep5((t - self.t4) / self.t_land if self.t_land > 0 else 1.0)
        vz = ds * dz / self.t_land if self.t_land > 0 else 0.0
        return (en, ee, ed + s * dz, 0.0, 0.0, vz), "land"

    # --- public -------------------------------------------------------------------------------
    def sample(self, t_s: float) -> ReferenceSample:
        pv, phase = self._pv(float(t_s))
        return ReferenceSample(pv[0:3], pv[3:6], self.yaw, phase)

    def grid(self, t_s: float, step_s: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The plan at t_s + k step_s, k = 0..n-1: (pos_vel (n, 6) NED [m, m/s], yaw (n,) rad);
        the same values as `sample`, without a record per point."""
        t0 = float(t_s)
        kernel = self._kernel
        if kernel is None:
            kernel = self._kernel = reference_core.grid_kernel() or False
        if kernel:
            # a ctypes buffer the array is made over: its address without NumPy's ctypes
            # helper, a few microseconds a call on the controller's period
            out = (ctypes.c_double * (6 * n))()
            kernel(self._params_at, t0, float(step_s), n, ctypes.addressof(out))
            return np.frombuffer(out).reshape(n, 6), np.full(n, self.yaw)
        pv = self._pv
        return np.array([pv(t0 + k * step_s)[0] for k in range(n)]), np.full(n, self.yaw)

    def done(self, t_s: float) -> bool:
        """The plan is over: landed (or, without landing, the final hold has started)."""
        return float(t_s) >= (self.t5 if self.cfg.land else self.t4)

    @property
    def end_time_s(self) -> float:
        return self.t5 if self.cfg.land else self.t4

    @property
    def land(self) -> bool:
        """The plan ends on the ground (else it ends holding in the air)."""
        return self.cfg.land


class ConstantReference:
    """Hold one sample forever (e.g. a position-hold target set by the daemon)."""

    def __init__(self, sample: ReferenceSample) -> None:
        self._s = sample

    def sample(self, t_s: float) -> ReferenceSample:
        return self._s

    def grid(self, t_s: float, step_s: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        row = np.array([*self._s.pos_ned_m, *self._s.vel_ned_m_s], float)
        return np.tile(row, (n, 1)), np.full(n, float(self._s.yaw_rad))

    def done(self, t_s: float) -> bool:
        return False

    @property
    def land(self) -> bool:
        return True

