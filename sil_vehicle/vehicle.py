"""The truth plant: one tilt-rotor (or fixed-rotor) vehicle advanced one physics tick at a time.

`Vehicle` composes the pure dynamics in a short fixed sequence per tick (after ArduPilot's
`Aircraft::update`): actuator targets -> faults -> motor and servo dynamics -> rotor wrench ->
wind -> RK4 (the ground's contact forces inside it: sil_vehicle.dynamics.contact) -> crash
checks -> ground events (touchdown, tip-over, resting: `_ground_events`, shared by both
cores). It holds no socket, clock or global random state: the random generator for gusts is
injected, time is an integer count of microseconds.

The tick runs either in Python (`_tick_python`, the reference, built from the pure functions of
`sil_vehicle.dynamics`) or compiled (`dynamics/tick.c` through `sil_vehicle.compiled`, the same
arithmetic in the same order: bit-identical, faster: docs/simulator.md), chosen by the simulation's
`physics_core` (auto: compiled when a C compiler is found). Gusts are drawn in Python in both, from
the same generator, so the random stream is the same too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sil_vehicle import compiled
from sil_vehicle.config import SimParams
from sil_vehicle.dynamics.actuators import first_order_step, lag_factor
from sil_vehicle.dynamics.contact import feet_ne_m, touching, update_anchors
from sil_vehicle.dynamics.environment import gust_coefficients, gust_step
from sil_vehicle.dynamics.rigid_body import rk4_step
from sil_vehicle.dynamics.rotors import body_wrench
from sil_vehicle.faults import Faults, MotorFault
from sil_vehicle.frames import quat_to_euler, tilt_from_vertical, wind_from_to_ned

# the centre of mass's down position when the vehicle rests level on its gear (the contact
# model's plane is placed so: sil_vehicle.dynamics.contact.resting_plane_down_m)
GROUND_DOWN_M = 0.0
# Ground events (docs/simulator.md, "Crashes"): a contact is a new touchdown once the centre of
# mass has been this far above its resting height since the last one (lower: a rebound of the
# last touchdown); a choice above the gear's rebound
TOUCHDOWN_REARM_M = 0.05
# resting on the gear (`landed`): touching, slower than this and turning slower than this; choices
RESTING_SPEED_M_S = 0.05
RESTING_RATE_RAD_S = 0.1
_NOISE_BLOCK = 1024


@dataclass(frozen=True)
class ActuatorCommand:
    """What the vehicle is told: throttle 0..100 % per motor, tilt (rad) per servo."""
    throttle_pct: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    tilt_rad: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class VehicleState:
    t_us: int
    x: tuple[float, ...]                      # rigid-body state, see dynamics.rigid_body
    motor_pct: tuple[float, ...]              # throttle the motors actually produce (%)
    tilt_rad: tuple[float, ...]               # servo angles actually reached (rad)
    wind_ned_m_s: tuple[float, float, float]  # mean wind plus gust
    armed: bool
    landed: bool
    crashed: bool
    crash_reason: str
    on_ground: bool = True                     # a contact point of the gear below the ground
    touchdown_speed_m_s: float = math.nan      # the last touchdown's down speed at contact
    touchdown_tilt_rad: float = math.nan       # and its tilt from vertical
    # the gear points' stick anchors, north and east per point (sil_vehicle.dynamics.contact);
    # empty out of the ground's reach (then taken where the points are)
    anchors_ne_m: tuple[float, ...] = ()

    @property
    def pos_ned_m(self) -> tuple[float, ...]:
        return self.x[0:3]

    @property
    def vel_ned_m_s(self) -> tuple[float, ...]:
        return self.x[3:6]

    @property
    def quat_wxyz(self) -> tuple[float, ...]:
        return self.x[6:10]

    @property
    def rates_frd_rad_s(self) -> tuple[float, ...]:
        return self.x[10:13]

    @property
    def euler_rad(self) -> tuple[float, float, float]:
        return quat_to_euler(*self.x[6:10])


def initial_state(yaw_rad: float = 0.0) -> tuple[float, ...]:
    return (0.0, 0.0, GROUND_DOWN_M, 0.0, 0.0, 0.0, math.cos(yaw_rad / 2), 0.0, 0.0,
            math.sin(yaw_rad / 2), 0.0, 0.0, 0.0)


def faults_from_params(sim: SimParams) -> Faults:
    return Faults(motors=tuple(
        MotorFault(a, b, w, phi) for a, b, w, phi in zip(
            sim.motor_effectiveness, sim.motor_tv_amplitude, sim.motor_tv_omega_rad_s,
            sim.motor_tv_phase_rad)))


class Vehicle:
    def __init__(self, sim: SimParams, rng: np.random.Generator) -> None:
        self.sim = sim
        self.vp = vp = sim.vehicle
        self._rng = rng
        self._dt_us = sim.dt_us
        self._dt = sim.dt_us * 1e-6
        self._motor_factor = lag_factor(vp.motor_time_constant_s, self._dt)
        self._motor_max = vp.motor_rate_limit_pct_s * self._dt
        self._servo_factor = lag_factor(vp.servo_time_constant_s, self._dt)
        self._servo_max = vp.servo_rate_limit_rad_s * self._dt
        self._rb = (vp.mass_kg, vp.inertia_kg_m2, vp.gravity_m_s2, vp.drag_N_s2_m2)
        self.faults = faults_from_params(sim)
        self.command = ActuatorCommand()
        self.armed = False
        self._noise = np.empty((0, 3))
        self._noise_i = 0
        self.set_wind(sim.wind_speed_m_s, sim.wind_from_deg, sim.gusts_enabled,
                      sim.gust_sigma_m_s, sim.gust_length_m)
        self._gust = (0.0, 0.0, 0.0)
        self._descending = True          # a contact now would be a touchdown (TOUCHDOWN_REARM_M)
        self._reach_down_m = self.vp.gear.reach_down_m
        self.state = VehicleState(0, initial_state(), (0.0,) * 4, (0.0,) * 4, self._wind_mean,
                                  False, True, False, "")
        self.core = self._load_core(sim.physics_core)
        if self.core is not None:
            self._p = self.core.params(vp, sim.crash_speed_m_s, sim.crash_tilt_rad, self._dt,
                                       self._motor_factor, self._motor_max, self._servo_factor,
                                       self._servo_max)
            self._s = self.core.new_state()
            # what the array holds: reloaded when the state, command or faults are replaced
            self._s_state: VehicleState | None = None
            self._s_command: ActuatorCommand | None = None
            self._s_faults: Faults | None = None
            self._s_anchors: tuple[float, ...] | None = None

    @staticmethod
    def _load_core(choice: str) -> compiled.CompiledCore | None:
        if choice == "python":
            return None
        core = compiled.load_core()
        if core is None and choice == "compiled":
            raise RuntimeError("physics_core: compiled was asked for, but the compiled tick is "
                               "unavailable (no C compiler, or its build failed: see the warning)")
        return core

    @property
    def core_name(self) -> str:
        return "python" if self.core is None else "compiled"

    # --- settings that change while flying -------------------------------------------------
    def set_wind(self, speed_m_s: float, from_deg: float, gusts: bool, sigma_m_s: float,
                 length_m: float) -> None:
        self.wind_speed_m_s, self.wind_from_deg = speed_m_s, from_deg
        self.gusts_enabled, self.gust_sigma_m_s, self.gust_length_m = gusts, sigma_m_s, length_m
        self._wind_mean = wind_from_to_ned(speed_m_s, from_deg)
        self._gust_a, self._gust_b = gust_coefficients(sigma_m_s, length_m, speed_m_s, self._dt)
        if not gusts:
            self._gust = (0.0, 0.0, 0.0)

    def set_armed(self, armed: bool) -> str | None:
        """Arm or disarm; returns the reason if refused."""
        if armed and self.state.crashed:
            return "crashed"
        if not armed and not self.state.landed and self.armed:
            return "flying"
        self.armed = armed
        return None

    def force_disarm(self) -> None:
        self.armed = False

    # --- one physics tick --------------------------------------------------------------------
    def step(self) -> VehicleState:
        if self.gusts_enabled:
            if self._noise_i >= len(self._noise):
                self._noise = self._rng.standard_normal((_NOISE_BLOCK, 3)).tolist()  # plain floats
                self._noise_i = 0
            self._gust = gust_step(self._gust, self._noise[self._noise_i], self._gust_a,
                                   self._gust_b)
            self._noise_i += 1
        g = self._gust
        m = self._wind_mean
        wind = (m[0] + g[0], m[1] + g[1], m[2] + g[2])
        if self.core is None:
            self.state = self._tick_python(wind)
        else:
            self.state = self._tick_compiled(wind)
        return self.state

    def _tick_compiled(self, wind: tuple[float, float, float]) -> VehicleState:
        """tick.c on the array `_s` (layout: sil_vehicle.compiled), reloaded from the Python
        objects only when one of them was replaced from outside (a fault, a new command, a
        state set by a test or a benchmark)."""
        c, st = compiled, self._s
        s = self.state
        if s is not self._s_state:
            st[c.S_X:c.S_X + 13] = s.x
            st[c.S_MOTOR:c.S_MOTOR + 4] = s.motor_pct
            st[c.S_TILT:c.S_TILT + 4] = s.tilt_rad
            st[c.S_LANDED] = float(s.landed)
            st[c.S_CRASHED] = float(s.crashed)
        if self.command is not self._s_command:
            self._s_command = cmd = self.command
            st[c.S_CMD_THROTTLE:c.S_CMD_THROTTLE + 4] = cmd.throttle_pct
            st[c.S_CMD_TILT:c.S_CMD_TILT + 4] = cmd.tilt_rad
        if self.faults is not self._s_faults:
            self._s_faults = faults = self.faults
            st[c.S_MOTOR_FAULT:c.S_MOTOR_FAULT + 20] = [
                v for f in faults.motors for v in (f.effectiveness, f.amplitude, f.omega_rad_s,
                                                   f.phase_rad, float(f.off))]
            st[c.S_SERVO_FAULT:c.S_SERVO_FAULT + 8] = [
                v for f in faults.servos for v in (float(f.stuck), f.angle_rad)]
        anchors = s.anchors_ne_m
        if not anchors and s.x[2] > self._reach_down_m:
            anchors = feet_ne_m(s.x, self.vp.gear)
        if anchors is not self._s_anchors:
            self._s_anchors = anchors
            if anchors:
                st[c.S_ANCHORS:c.S_ANCHORS + len(anchors)] = anchors
        st[c.S_RUNNING] = 1.0 if self.armed and not s.crashed else 0.0
        st[c.S_T] = s.t_us * 1e-6
        st[c.S_WIND] = wind[0]
        st[c.S_WIND + 1] = wind[1]
        st[c.S_WIND + 2] = wind[2]
        event = self.core.tick(self._p, st)
        reason = s.crash_reason
        if event == compiled.ATTITUDE:
            reason = "attitude past the crash limit"
        x = tuple(st[0:13])
        if x[2] > self._reach_down_m or s.on_ground or s.landed:
            new = self._ground_events(s, VehicleState(
                s.t_us + self._dt_us, x, tuple(st[13:17]), tuple(st[17:21]), wind, self.armed,
                s.landed, st[c.S_CRASHED] != 0.0, reason, s.on_ground, s.touchdown_speed_m_s,
                s.touchdown_tilt_rad, anchors))
            st[c.S_CRASHED] = float(new.crashed)
        else:                     # flying, out of the ground's reach: _ground_events' first case
            if x[2] < GROUND_DOWN_M - TOUCHDOWN_REARM_M:
                self._descending = True
            new = VehicleState(s.t_us + self._dt_us, x, tuple(st[13:17]), tuple(st[17:21]), wind,
                               self.armed, False, st[c.S_CRASHED] != 0.0, reason, False,
                               s.touchdown_speed_m_s, s.touchdown_tilt_rad, ())
        self._s_state = new
        return new

    def _tick_python(self, wind: tuple[float, float, float]) -> VehicleState:
        """The reference tick, from the pure functions of sil_vehicle.dynamics."""
        s = self.state
        vp = self.vp
        t_us = s.t_us + self._dt_us
        t_s = s.t_us * 1e-6
        running = self.armed and not s.crashed
        motors = []
        for zeta, cmd, fault in zip(s.motor_pct, self.command.throttle_pct, self.faults.motors):
            target = 0.0
            if running:
                target = min(max(cmd, vp.idle_pct), 100.0) * fault.factor(t_s)
            motors.append(first_order_step(zeta, target, self._motor_factor, self._motor_max,
                                           0.0, 100.0))
        tilts = []
        for alpha, cmd, fault in zip(s.tilt_rad, self.command.tilt_rad, self.faults.servos):
            if fault.stuck:
                tilts.append(fault.angle_rad)
                continue
            target = 0.0 if (vp.tilt_locked or not running) else cmd
            tilts.append(first_order_step(alpha, target, self._servo_factor, self._servo_max,
                                          vp.tilt_min_rad, vp.tilt_max_rad))
        if vp.tilt_locked:
            tilts = [0.0, 0.0, 0.0, 0.0]
        wrench = body_wrench(motors, tilts, vp)
        anchors = self._anchors(s)
        x = rk4_step(s.x, self._dt, wrench, wind, *self._rb, vp.gear, anchors)
        crashed, reason = s.crashed, s.crash_reason
        if not crashed and tilt_from_vertical(*x[6:10]) > self.sim.crash_tilt_rad:
            crashed, reason = True, "attitude past the crash limit"
        return self._ground_events(s, VehicleState(
            t_us, x, tuple(motors), tuple(tilts), wind, self.armed, s.landed, crashed, reason,
            s.on_ground, s.touchdown_speed_m_s, s.touchdown_tilt_rad, anchors))

    def _anchors(self, s: VehicleState) -> tuple[float, ...]:
        """The stick anchors this tick holds: the state's, or, within the ground's reach
        without any, the points' positions now (where they would first touch)."""
        if s.anchors_ne_m or not s.x[2] > self.vp.gear.reach_down_m:
            return s.anchors_ne_m
        return feet_ne_m(s.x, self.vp.gear)

    def _ground_events(self, before: VehicleState, s: VehicleState) -> VehicleState:
        """After a tick, from its state alone (both cores share this): which gear points touch;
        a touchdown (the first contact since the vehicle rose TOUCHDOWN_REARM_M) records its
        down speed just before contact and its tilt, and is a crash above `crash_speed_m_s`; a
        tilt past the gear's tip-over angle while touching is a crash; `landed` is resting on
        the gear."""
        x = s.x
        gear = self.vp.gear
        if not x[2] > gear.reach_down_m:                  # out of the ground's reach: flying
            if x[2] < GROUND_DOWN_M - TOUCHDOWN_REARM_M:
                self._descending = True
            if not s.landed and not s.on_ground and not s.anchors_ne_m:
                return s
            return VehicleState(s.t_us, x, s.motor_pct, s.tilt_rad, s.wind_ned_m_s, s.armed,
                                False, s.crashed, s.crash_reason, False, s.touchdown_speed_m_s,
                                s.touchdown_tilt_rad, ())
        on_ground = touching(x, gear) > 0
        crashed, reason = s.crashed, s.crash_reason
        speed, tilt_rad = s.touchdown_speed_m_s, s.touchdown_tilt_rad
        landed = False
        if on_ground:
            tilt = tilt_from_vertical(*x[6:10])
            if self._descending and not before.on_ground:
                self._descending = False
                speed, tilt_rad = before.x[5], tilt
                if not crashed and speed > self.sim.crash_speed_m_s:
                    crashed, reason = True, f"ground impact at {speed:.2f} m/s"
            if not crashed and tilt > self.vp.tip_over_rad:
                crashed, reason = True, f"tipped over on the ground ({math.degrees(tilt):.0f} deg)"
            landed = (x[3] * x[3] + x[4] * x[4] + x[5] * x[5] < RESTING_SPEED_M_S ** 2
                      and x[10] * x[10] + x[11] * x[11] + x[12] * x[12] < RESTING_RATE_RAD_S ** 2)
        elif x[2] < GROUND_DOWN_M - TOUCHDOWN_REARM_M:
            self._descending = True
        anchors = update_anchors(x, gear, s.anchors_ne_m)
        return VehicleState(s.t_us, x, s.motor_pct, s.tilt_rad, s.wind_ned_m_s, s.armed, landed,
                            crashed, reason, on_ground, speed, tilt_rad, anchors)
