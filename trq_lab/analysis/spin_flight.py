"""The lost-motor controller (trq_offboard/spin.py) flown in the plant, in one process.

The plant is sil_vehicle's `Vehicle` (1 kHz); the controller steps at its own rate on the truth
state (an oracle: no estimator, no link) or on the truth with the body rates through a gyro's full
scale. Scenarios:

    orbit   started on the relaxed hover at `altitude_m` (the envelope's periodic orbit), with a
            seeded perturbation of the rates and the position
    hover   level hover at `altitude_m` on the hover commands, motor `motor` off at t = 0, the
            hover commands held `switch_delay_s` (the detection's delay), then the controller
    Both with `land`: the position held landing.hold_s, then the descent of
    spin.landing_reference to the ground, the motors off at touchdown.

`fly` returns a `SpinFlight` of the figures the record reports. Used by tests/integration/
test_spin_flight.py and by docs/decisions/2026-12-05-lost-motor-spin-controller.md's runs.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np

import trq_params
from trq_offboard.config import load_vehicle_model
from trq_offboard.records import ActuatorCommand as OffboardCommand
from trq_offboard.records import ReferenceSample, StateEstimate
from trq_offboard.spin import SpinController, landing_reference, load_spin_config

CONTROLLER_FILE = trq_params.DIR / "controller" / "trq_nmpc_eso.yaml"
SIM_FILE = trq_params.DIR / "sim" / "default.yaml"
# the gyro's full scale the report checks against: +-2000 deg/s per axis (the envelope record's
# choice, the common MEMS range)
GYRO_FULL_SCALE_RAD_S = math.radians(2000.0)


@dataclass(frozen=True)
class SpinFlight:
    scenario: str
    seed: int
    seconds: float
    crashed: bool
    crash_reason: str
    landed: bool
    motors_off: bool                  # the controller saw the touchdown and cut the motors
    max_axis_lean_deg: float          # the flown trim's primary axis (body) from the vertical
    max_body_tilt_deg: float          # body -z from the world vertical
    max_lean_first_s_deg: float       # the axis' largest lean in the first second after the switch
    max_drift_m: float                # horizontal distance from the failure point, largest
    hold_drift_m: float               # the same over the hold's last second (1-period mean)
    touchdown_drift_m: float          # horizontal distance at touchdown (nan: no touchdown)
    touchdown_speed_m_s: float        # vertical speed at the gear's first contact (the plant's)
    touchdown_tilt_deg: float         # body -z from the vertical then (the cone + lean)
    max_descent_m_s: float            # the largest downward speed
    spin_mean_rad_s: float            # |omega| over the hold's last second
    max_rate_axis_rad_s: float        # the largest |omega_i| of any body axis (the gyro reads)
    gyro_ok: bool                     # max_rate_axis_rad_s below the full scale
    saturated_fraction: float         # share of the steps with a live command clipped
    step_us_mean: float               # the controller's step, the thread's CPU (a measurement)


def _start_on_orbit(sim, motor: int, spin_rad_s: float, altitude_m: float):
    from trq_lab.analysis import spin_envelope
    factors = [0.0 if i == motor - 1 else 1.0 for i in range(4)]
    eq = spin_envelope.solve(sim.vehicle, factors, spin_rad_s=spin_rad_s)
    return eq, list(spin_envelope.initial_state(sim.vehicle, eq, down_m=-altitude_m))


def fly(scenario: str = "orbit", *, seed: int = 0, seconds: float = 2.0, motor: int = 1,
        altitude_m: float = 5.0, land: bool = False, switch_delay_s: float = 0.0,
        perturb_rates_rad_s: float = 0.1, perturb_pos_m: float = 0.1,
        gyro_clip: bool = False, controller: SpinController | None = None,
        physics_core: str = "auto", command_delay_s: float = 0.0, measured: bool = False,
        wind_m_s: float = 0.0, gusts: bool = False, nmpc_before_s: float = 0.0,
        plant: dict[str, float] | None = None, trace=None) -> SpinFlight:
    """One flight (the module docstring). `measured`: the controller flies on the autopilot's
    estimate (sil_vehicle's ESKF on the `mocap` sensing profile's IMU, barometer, magnetometer and
    pose, aligned on a still hover for `_ALIGN_S` before the flight) instead of the truth; hover
    scenario only. `wind_m_s`: a mean wind from the north (with `gusts`, the simulation file's
    turbulence); the controller knows nothing of it (its trim is calm air's). `nmpc_before_s` > 0
    (hover, on the truth): the project's NMPC (trq_nmpc_eso.yaml's Controller) flies the hover
    that long before the failure and on until the switch, instead of the held hover commands.
    `plant`: the airframe perturbed as a campaign's plant (trq_lab.overlays: mass_scale,
    thrust_scale, ...), the controller's model left nominal. `trace`: a list the control steps
    append (t_s, plant state, command, SpinInfo) to."""
    from sil_vehicle.config import load_sim
    from sil_vehicle.faults import Faults
    from sil_vehicle.frames import quat_to_dcm, quat_to_euler
    from sil_vehicle.vehicle import ActuatorCommand, Vehicle, VehicleState

    if scenario not in ("orbit", "hover"):
        raise ValueError(f"spin_flight: scenario {scenario!r}, expected 'orbit' or 'hover'")
    rng = np.random.default_rng(seed)
    vehicle_file = None
    if plant:
        import tempfile
        from pathlib import Path

        from trq_lab.overlays import write_vehicle_overlay
        vehicle_file = write_vehicle_overlay(trq_params.DIR / "vehicle" / "trq.yaml", plant,
                                             Path(tempfile.mkdtemp(prefix="spin_plant_")))
    sim = load_sim(SIM_FILE, vehicle_file).with_changes(
        physics_core=physics_core, wind_speed_m_s=wind_m_s, gusts_enabled=gusts)
    vp = sim.vehicle
    if controller is None:
        cfg = load_spin_config(CONTROLLER_FILE)
        controller = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), motor)
    cfg = controller.config
    veh = Vehicle(sim, np.random.default_rng(seed))
    veh.faults = Faults().with_motor(motor - 1, off=True)
    veh.armed = True
    if scenario == "orbit":
        eq, x0 = _start_on_orbit(sim, motor, cfg.spin_rate_rad_s, altitude_m)
        x0[10:13] = (np.asarray(x0[10:13]) + rng.normal(0.0, perturb_rates_rad_s, 3)).tolist()
        x0[0:3] = (np.asarray(x0[0:3]) + rng.normal(0.0, perturb_pos_m, 3)).tolist()
        held = ActuatorCommand(tuple(eq.throttle_pct), tuple(eq.tilt_rad))
        motors = tuple(min(max(z, vp.idle_pct), 100.0) * (0.0 if i == motor - 1 else 1.0)
                       for i, z in enumerate(eq.throttle_pct))
        tilts = tuple(eq.tilt_rad)
        switch_delay_s = 0.0
    else:
        yaw = float(rng.uniform(-math.pi, math.pi))
        hover = vp.thrust_N.inverse(vp.mass_kg * vp.gravity_m_s2 / 4.0)
        v0 = rng.normal(0.0, perturb_pos_m * 0.5, 3)
        x0 = [0.0, 0.0, -altitude_m, *v0.tolist(), math.cos(yaw / 2), 0.0, 0.0,
              math.sin(yaw / 2), *rng.normal(0.0, perturb_rates_rad_s, 3).tolist()]
        held = ActuatorCommand((hover,) * 4, (0.0,) * 4)
        # every motor at hover: the dead one's output decays through the plant's motor lag and
        # rate limit from the failure on, as the plant's own fault does
        motors, tilts = (hover,) * 4, (0.0,) * 4
    veh.command = held
    sensing = None
    t_start_us = 0
    if measured:
        if scenario != "hover":
            raise ValueError("spin_flight: measured flights start from a hover (the estimator "
                             "aligns on it)")
        x0[3:6] = [0.0, 0.0, 0.0]
        x0[10:13] = [0.0, 0.0, 0.0]
        sensing = _Sensing(sim, seed, x0, motors)
        t_start_us = sensing.t_us
    veh.state = VehicleState(t_start_us, tuple(x0), motors, tilts, (0.0, 0.0, 0.0), True, False,
                             False, "")
    failure_pos = np.array([0.0, 0.0, -altitude_m])        # the point to hold (unperturbed)
    dt = sim.dt_us * 1e-6
    nmpc = None
    if nmpc_before_s > 0.0:
        if scenario != "hover" or measured:
            raise ValueError("spin_flight: nmpc_before_s with the hover scenario on the truth")
        from trq_offboard.controller import Controller
        from trq_offboard.reference import ConstantReference
        nmpc = Controller.from_yaml(CONTROLLER_FILE)
        nmpc_ref = ConstantReference(ReferenceSample(tuple(failure_pos), (0.0, 0.0, 0.0), 0.0))
        faults, veh.faults = veh.faults, Faults()

        def nmpc_step(state):
            est_n = StateEstimate(tuple(state.x[0:3]), tuple(state.x[3:6]),
                                  tuple(quat_to_euler(*state.x[6:10])), tuple(state.x[10:13]))
            c, _ = nmpc.step(state.t_us * 1e-6, est_n, None, nmpc_ref)
            return ActuatorCommand(c.throttle_pct, c.tilt_rad)

        for k in range(int(round(nmpc_before_s / dt))):
            if k % int(round(1.0 / (cfg.control_rate_hz * dt))) == 0:
                veh.command = nmpc_step(veh.state)
            veh.step()
        veh.faults = faults
        t_start_us = veh.state.t_us
    ticks_per = int(round(1.0 / (cfg.control_rate_hz * dt)))
    switch_tick = int(round(switch_delay_s / dt))
    switch_tick -= switch_tick % ticks_per
    n_ticks = int(round(seconds / dt))
    axis = np.asarray(controller.trim.axis_frd)
    started = False
    step_ns, steps, sat = 0, 0, 0
    lean = tilt = lean_first = drift = max_down = rate_axis = 0.0
    touchdown_speed = touchdown_drift = touchdown_tilt = tilt_now = math.nan
    spins, hold_pos = [], []
    last_vz = 0.0
    touchdown_tick = n_ticks
    pending: list = []           # (tick, command): the link's delay
    hold_end = switch_delay_s + (cfg.landing.hold_s if land else seconds)
    for k in range(n_ticks):
        s = veh.state
        t = k * dt
        if nmpc is not None and k < switch_tick and k % ticks_per == 0:
            held = nmpc_step(s)
            veh.command = held
        if k >= switch_tick and k % ticks_per == 0:
            if sensing is not None:
                e = sensing.eskf.output()
                pos_e, vel_e, q_e, rates = e.pos_ned_m, e.vel_ned_m_s, e.quat_wxyz, \
                    np.asarray(e.rates_frd_rad_s)
            else:
                pos_e, vel_e, q_e, rates = s.x[0:3], s.x[3:6], s.x[6:10], np.asarray(s.x[10:13])
            if gyro_clip:
                rates = np.clip(rates, -GYRO_FULL_SCALE_RAD_S, GYRO_FULL_SCALE_RAD_S)
            est = StateEstimate(tuple(map(float, pos_e)), tuple(map(float, vel_e)),
                                tuple(quat_to_euler(*q_e)), tuple(rates.tolist()))
            if not started:
                controller.reset(est, command=OffboardCommand(held.throttle_pct, held.tilt_rad),
                                 hold_pos_ned_m=tuple(failure_pos), ground_down_m=0.0)
                started = True
            t_sw = t - switch_tick * dt
            if land:
                ref = landing_reference(t_sw, failure_pos, cfg.landing, 0.0)
            else:
                ref = ReferenceSample(tuple(failure_pos), (0.0, 0.0, 0.0), 0.0, "hold")
            t0 = time.thread_time_ns()
            cmd = controller.step(est, ref)
            step_ns += time.thread_time_ns() - t0
            steps += 1
            sat += controller.info.saturated > 0
            axis = np.asarray(controller.trim.axis_frd)     # the stage flown (final spin: its own)
            pending.append((k + int(round(command_delay_s / dt)),
                            ActuatorCommand(cmd.throttle_pct, cmd.tilt_rad)))
            if trace is not None:
                trace.append((t, s.x, cmd, controller.info))
        while pending and pending[0][0] <= k:
            veh.command = pending.pop(0)[1]
        last_vz = s.x[5]
        prev = s
        s = veh.step()
        if sensing is not None:
            sensing.tick(prev, s)
        if s.crashed:
            break
        if s.on_ground or s.landed:
            # the gear's contact (the plant's ground: the body settles on its gear over tens of
            # ms, `landed` once at rest): the plant's own impact speed and tilt at the contact
            if math.isnan(touchdown_speed):
                touchdown_speed = (s.touchdown_speed_m_s if math.isfinite(s.touchdown_speed_m_s)
                                   else last_vz)
                touchdown_tilt = (math.degrees(s.touchdown_tilt_rad)
                                  if math.isfinite(s.touchdown_tilt_rad) else tilt_now)
                touchdown_drift = float(np.linalg.norm(np.asarray(s.x[0:2]) - failure_pos[0:2]))
                touchdown_tick = k
            if s.landed and k - touchdown_tick > int(round(0.5 / dt)):
                break
            continue
        r = np.array(quat_to_dcm(*s.x[6:10]))
        up = -r[2, :]                                  # world up in body: r^T (0,0,-1)
        a_lean = math.degrees(math.acos(max(-1.0, min(1.0, float(up @ axis)))))
        b_tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(r[2, 2])))))
        lean, tilt = max(lean, a_lean), max(tilt, b_tilt)
        tilt_now = b_tilt
        if t < switch_delay_s + 1.0:
            lean_first = max(lean_first, a_lean)
        drift = max(drift, float(np.linalg.norm(np.asarray(s.x[0:2]) - failure_pos[0:2])))
        max_down = max(max_down, s.x[5])
        rate_axis = max(rate_axis, float(np.max(np.abs(s.x[10:13]))))
        if hold_end - 1.0 <= t < hold_end:
            spins.append(float(np.linalg.norm(s.x[10:13])))
            hold_pos.append(s.x[0:2])
    s = veh.state
    if s.landed and math.isnan(touchdown_speed):
        touchdown_speed = last_vz
    hold_drift = (float(np.linalg.norm(np.mean(hold_pos, axis=0) - failure_pos[0:2]))
                  if hold_pos else math.nan)
    return SpinFlight(
        scenario=scenario, seed=seed, seconds=round((veh.state.t_us - t_start_us) * 1e-6, 3),
        crashed=s.crashed, crash_reason=s.crash_reason, landed=s.landed,
        motors_off=controller.info.landed and max(veh.command.throttle_pct) == 0.0,
        max_axis_lean_deg=lean, max_body_tilt_deg=tilt, max_lean_first_s_deg=lean_first,
        max_drift_m=drift, hold_drift_m=hold_drift, touchdown_drift_m=touchdown_drift,
        touchdown_speed_m_s=touchdown_speed, touchdown_tilt_deg=touchdown_tilt,
        max_descent_m_s=max_down,
        spin_mean_rad_s=float(np.mean(spins)) if spins else math.nan,
        max_rate_axis_rad_s=rate_axis, gyro_ok=rate_axis < GYRO_FULL_SCALE_RAD_S,
        saturated_fraction=sat / max(1, steps), step_us_mean=step_ns / max(1, steps) / 1e3)


def main() -> None:       # a manual run: python -m trq_lab.analysis.spin_flight
    import json
    import sys
    args = sys.argv[1:]
    scenario = args[0] if args else "orbit"
    seeds = range(int(args[1])) if len(args) > 1 else range(3)
    land = "land" in args
    for seed in seeds:
        r = fly(scenario, seed=seed, seconds=16.0 if land else 3.0, land=land,
                switch_delay_s=0.05 if scenario == "hover" else 0.0)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v)
                          for k, v in asdict(r).items()}))


if __name__ == "__main__":
    main()


_ALIGN_S = 10.0       # the estimator's still hover before a measured flight (a choice)


class _Sensing:
    """The autopilot's sensors and estimator as sil_vehicle.sitl.Sitl wires them (its _sense),
    on the `mocap` profile, first on `_ALIGN_S` of a still hover at the start's pose."""

    def __init__(self, sim, seed: int, x0, motors) -> None:
        from sil_vehicle.estimator.eskf import Eskf
        from sil_vehicle.estimator.params import EstimatorParams
        from sil_vehicle.sensors.profile import load_sensing
        from sil_vehicle.sensors.suite import SensorSuite
        from sil_vehicle.sensors.truth import Truth, specific_force_frd

        self.dt_us, self.g = sim.dt_us, sim.vehicle.gravity_m_s2
        profile = load_sensing("mocap", sim.physics_rate_hz)
        self.suite = SensorSuite(profile, np.random.default_rng([seed, 7]),
                                 home_alt_m=sim.home_alt_m)
        self.eskf = Eskf(EstimatorParams.from_profile(profile))
        q = np.asarray(x0[6:10], float)
        f = specific_force_frd(q, np.zeros(3), self.g)
        t = 0
        for _ in range(int(round(_ALIGN_S * 1e6 / self.dt_us))):
            truth = Truth.of(t, x0[0:3], (0.0, 0.0, 0.0), q, (0.0, 0.0, 0.0), f, motors)
            self.eskf.step(t, self.suite.sample(t, truth))
            t += self.dt_us
        e = self.eskf.output()
        if not (e.attitude_aligned and e.position_valid) or e.diverged:
            raise RuntimeError("spin_flight: the estimator did not align on the still hover")
        self.t_us = t

    def tick(self, s0, s1) -> None:
        from sil_vehicle.sensors.truth import Truth, imu_truth
        rates, f = imu_truth(s0.x[6:10], s1.x[6:10], s0.x[3:6], s1.x[3:6], self.dt_us * 1e-6,
                             self.g)
        truth = Truth(s1.t_us, s1.x[0:3], s1.x[3:6], s1.x[6:10], rates, f, s1.motor_pct)
        self.eskf.step(s1.t_us, self.suite.sample(s1.t_us, truth))


def step_time_ratio(steps: int = 200, seed: int = 0,
                    controller: SpinController | None = None) -> dict:
    """The CPU time per step of the spin controller (`controller`, else the shipped one) against
    the existing NMPC controller (trq_nmpc_eso.yaml's Controller), both stepped in this process
    on the plant's truth: the NMPC in a level hover at 5 m (no fault), the spin controller on
    the orbit. Thread CPU time (a measurement: it depends on the machine and its load; the ratio
    is what is reported)."""
    from sil_vehicle.config import load_sim
    from sil_vehicle.frames import quat_to_euler
    from sil_vehicle.vehicle import ActuatorCommand, Vehicle, VehicleState
    from trq_offboard.controller import Controller
    from trq_offboard.reference import ConstantReference

    sim = load_sim(SIM_FILE).with_changes(wind_speed_m_s=0.0, gusts_enabled=False)
    nmpc = Controller.from_yaml(CONTROLLER_FILE)
    veh = Vehicle(sim, np.random.default_rng(seed))
    veh.armed = True
    hover = sim.vehicle.thrust_N.inverse(sim.vehicle.mass_kg * sim.vehicle.gravity_m_s2 / 4.0)
    x0 = (0.0, 0.0, -5.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    veh.state = VehicleState(0, x0, (hover,) * 4, (0.0,) * 4, (0.0, 0.0, 0.0), True, False,
                             False, "")
    ref = ConstantReference(ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0))
    ticks = int(round(nmpc.cfg.control_dt_s / (sim.dt_us * 1e-6)))    # physics ticks a step
    ns = []
    for k in range(steps):
        s = veh.state
        est = StateEstimate(tuple(s.x[0:3]), tuple(s.x[3:6]), tuple(quat_to_euler(*s.x[6:10])),
                            tuple(s.x[10:13]))
        t0 = time.thread_time_ns()
        cmd, _ = nmpc.step(k * nmpc.cfg.control_dt_s, est, None, ref)
        ns.append(time.thread_time_ns() - t0)
        veh.command = ActuatorCommand(cmd.throttle_pct, cmd.tilt_rad)
        for _ in range(ticks):
            veh.step()
    nmpc_us = float(np.median(ns[20:])) / 1e3
    flight = fly("orbit", seed=seed, seconds=steps / 100.0, controller=controller)
    return {"nmpc_step_us_median": nmpc_us, "nmpc_control_rate_hz": 1.0 / nmpc.cfg.control_dt_s,
            "spin_step_us_mean": flight.step_us_mean,
            "ratio_spin_over_nmpc": flight.step_us_mean / nmpc_us}
