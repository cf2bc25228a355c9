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
    done(t)              true from t5 (from t4 when not landing: the plan then holds forever)

Everything is a pure function of t (float seconds since the same origin as t0_s): no state.
Keep within what the vehicle can do: the defaults fly at 0.63 m/s with 0.4 m/s^2.
"""

from __future__ import annotations

import math

import numpy as np

from trq_offboard.config import ReferenceConfig
from trq_offboard.records import ReferenceSample

__all__ = ["Reference", "LAND_BELOW_M"]

LAND_BELOW_M = 0.2


def _smoothstep5(s: float) -> tuple[float, float]:
    """(value, derivative) of 10 s^3 - 15 s^4 + 6 s^5 on [0, 1], clamped outside."""
    if s <= 0.0:
        return 0.0, 0.0
    if s >= 1.0:
        return 1.0, 0.0
    return s ** 3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2


class Reference:
    """The flight plan of one run (see the module docstring)."""

    def __init__(self, cfg: ReferenceConfig, start_ned_m, start_yaw_rad: float = 0.0,
                 t0_s: float = 0.0, *, airborne: bool = False,
                 ground_down_m: float | None = None) -> None:
        """`airborne`: the controller takes over a flying vehicle: no take-off, the plan starts
        by holding where the vehicle is; it lands on `ground_down_m` (NED down of the ground,
        default the start point's)."""
        self.cfg = cfg
        self.start = np.asarray(start_ned_m, float).reshape(3)
        self.yaw = float(start_yaw_rad)
        self.t0 = float(t0_s)
        self.airborne = airborne
        self.ground = float(self.start[2] if ground_down_m is None else ground_down_m)
        self.hover_point = self.start + np.array([0.0, 0.0, 0.0 if airborne else -cfg.altitude_m])
        rise = self.hover_point[2] - self.start[2]
        self.t_takeoff = abs(rise) * 1.875 / cfg.climb_speed_m_s
        self.t1 = self.t0 + self.t_takeoff
        self.t2 = self.t1 + cfg.hold_s
        self.t3 = self.t2 + cfg.duration_s
        self.t4 = self.t3 + cfg.hold_s
        self.end_point = self._manoeuvre(cfg.duration_s)[0]
        drop = (self.ground + LAND_BELOW_M) - self.end_point[2]
        self.t_land = abs(drop) * 1.875 / cfg.climb_speed_m_s if cfg.land else 0.0
        self.t5 = self.t4 + self.t_land

    # --- phase of the periodic manoeuvres -------------------------------------------------
    def _phase(self, tau: float) -> tuple[float, float]:
        """(phi, dphi/dt) at tau seconds into the manoeuvre; rate ramps 0 -> w -> 0."""
        cfg = self.cfg
        w = 2.0 * math.pi / cfg.period_s
        T, r = cfg.duration_s, cfg.ramp_s
        tau = min(max(tau, 0.0), T)

        def ramp_integral(s: float) -> float:      # integral of (1 - cos(pi x / r)) / 2
            return 0.5 * (s - r / math.pi * math.sin(math.pi * s / r)) if r > 0 else s

        full_ramp = ramp_integral(r)
        if tau < r:
            return w * ramp_integral(tau), w * 0.5 * (1 - math.cos(math.pi * tau / r))
        if tau <= T - r:
            return w * (full_ramp + tau - r), w
        back = T - tau
        phi_end = w * (2 * full_ramp + T - 2 * r)
        return phi_end - w * ramp_integral(back), w * 0.5 * (1 - math.cos(math.pi * back / r))

    def _manoeuvre(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.cfg
        c = self.hover_point
        if cfg.kind == "hover":
            return c.copy(), np.zeros(3)
        if cfg.kind == "step":
            on = 0.0 <= tau < cfg.duration_s
            return c + (np.asarray(cfg.step_ned_m) if on else 0.0), np.zeros(3)
        phi, dphi = self._phase(tau)
        R = cfg.radius_m
        if cfg.kind in ("circle", "helix"):
            climb = cfg.helix_climb_m / (2 * math.pi) if cfg.kind == "helix" else 0.0
            pos = c + np.array([R * (math.cos(phi) - 1.0), R * math.sin(phi), climb * phi])
            vel = dphi * np.array([-R * math.sin(phi), R * math.cos(phi), climb])
            return pos, vel
        # figure8: x = R sin(phi), y = R/2 sin(2 phi)
        pos = c + np.array([R * math.sin(phi), 0.5 * R * math.sin(2 * phi), 0.0])
        vel = dphi * np.array([R * math.cos(phi), R * math.cos(2 * phi), 0.0])
        return pos, vel

    # --- public -------------------------------------------------------------------------------
    def sample(self, t_s: float) -> ReferenceSample:
        t = float(t_s)
        if t < self.t1:
            s, ds = _smoothstep5((t - self.t0) / self.t_takeoff if self.t_takeoff > 0 else 1.0)
            dz = self.hover_point[2] - self.start[2]
            pos = self.start + np.array([0.0, 0.0, s * dz])
            vel = np.array([0.0, 0.0, ds * dz / self.t_takeoff if self.t_takeoff > 0 else 0.0])
            return _sample(pos, vel, self.yaw, "takeoff")
        if t < self.t2:
            return _sample(self.hover_point, np.zeros(3), self.yaw, "hold")
        if t < self.t3:
            pos, vel = self._manoeuvre(t - self.t2)
            return _sample(pos, vel, self.yaw, self.cfg.kind)
        if t < self.t4 or not self.cfg.land:
            return _sample(self.end_point, np.zeros(3), self.yaw, "hold")
        z_ground = self.ground + LAND_BELOW_M
        dz = z_ground - self.end_point[2]
        s, ds = _smoothstep5((t - self.t4) / self.t_land if self.t_land > 0 else 1.0)
        pos = self.end_point + np.array([0.0, 0.0, s * dz])
        vel = np.array([0.0, 0.0, ds * dz / self.t_land if self.t_land > 0 else 0.0])
        return _sample(pos, vel, self.yaw, "land" if t < self.t5 else "landed")

    def done(self, t_s: float) -> bool:
        """The plan is over: landed (or, without landing, the final hold has started)."""
        return float(t_s) >= (self.t5 if self.cfg.land else self.t4)

    @property
    def end_time_s(self) -> float:
        return self.t5 if self.cfg.land else self.t4


class ConstantReference:
    """Hold one sample forever (e.g. a position-hold target set by the daemon)."""

    def __init__(self, sample: ReferenceSample) -> None:
        self._s = sample

    def sample(self, t_s: float) -> ReferenceSample:
        return self._s

    def done(self, t_s: float) -> bool:
        return False


def _sample(pos, vel, yaw, phase) -> ReferenceSample:
    return ReferenceSample(tuple(float(v) for v in pos), tuple(float(v) for v in vel),
                           float(yaw), phase)
