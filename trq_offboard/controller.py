"""The controller core: observer + NMPC + allocation, one object per controller config.

    ctl = Controller.from_yaml("params/controller/trq_nmpc_eso.yaml")   # build once (~2 s)
    ctl.reset(t_s, state)                       # take over (ground or flying) without a jump
    cmd, info = ctl.step(t_s, state, applied, reference)   # once per control period
    ctl.prepare(reference)                      # after sending cmd: the RTI's preparation phase

`reference` is a reference.FlightReference (Reference, or ConstantReference for a fixed
target); the NMPC takes its grid at t_s + k h, k = 0..N.
`applied` is the ActuatorCommand the vehicle has been flying since the previous step (None:
the one this controller returned last).

The Controller composes, built once: the observer (eso.py), the delay predictor (predictor.py:
the commands sent, the actuators through their lags, the state when the command acts), the
motors' effectiveness (effectiveness.py's MotorEffectiveness: the motor effectiveness observer
with the model's deficit functions), the NMPC's solver (nmpc/) and the allocation. It keeps the
step, the preparation and the fallback.

Per step (`step`'s docstring has the order): the state estimate in; the observer (if any)
advanced one control period with the measurement and the commands in effect gives d; with
motor_effectiveness, d is read as one motor's output deficit and each motor's effectiveness e
estimated: the NMPC then plans the effective throttles (e x command, bounded by [e idle,
e 100]; the command sent is the plan / e), from the motors' estimated outputs, with d less the
motors' share; the NMPC is solved from the state predicted for when the command acts, with d
held over the horizon, warm-started from the previous plan shifted by the elapsed time (first
step: the allocation's hover trim, rolled out through the model); on a solver failure the
previous plan shifted in time is flown while it lasts, then the allocation's hover command; the
command is clipped to the actuator limits as a last line of defence (counted) and is always
finite. `step` never prints or sleeps, and reads no clock but the injected CPU clock `cpu_ns`
(default time.thread_time_ns) that times its parts for StepInfo.cpu (observer, effectiveness,
predictor, feedback) and `prepare` for `last_prepare_cpu_ns`: measurements only, never an input
of what is computed (the solver measures its own wall time).

A whole motor lost (lost_motor, with the effectiveness observer): the detector runs after step 4;
from a detection the failed configuration's NMPC flies (response nmpc), or, one motor lost, the
spinning controller of the file's `spin:` section (response spin: `_spin_step`, the NMPC no
longer solved; trq_offboard/spin.py). Two motors lost (lost_motor.pair_excess_m_s2): before any
loss the pair detector reads the observer's d against each motor's share of the model
(`_detect`); a pair declared flies the failed NMPC with both rotors out (`_detect_pair`).

`prepare` (for solvers with a preparation phase, `Solver.prepares`, such as the real-time
iteration; a no-op for the others): called after the command of `step` has been sent, it
linearises the NMPC at the plan expected one control period later, so that the next `step` only
embeds the measured state and solves a QP. Without it the solver prepares inside `step` (same
result, longer latency).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from trq_offboard.allocation import Allocator
from trq_offboard.config import ControllerConfig, load_controller
from trq_offboard.effectiveness import MotorEffectiveness, MotorEffectivenessObserver
from trq_offboard.eso import ExtendedStateObserver
from trq_offboard.fused_core import fused_filter
from trq_offboard.link.wire import HOME_GROUND_DOWN_M
from trq_offboard.lost_motor import (LostMotorDetector, PairLossDetector, failed_config,
                                      motor_contributions, pair_code)
from trq_offboard.model import PredictionModel
from trq_offboard.model.dynamics import NumpyFunction
from trq_offboard.nmpc.base import Solver
from trq_offboard.nmpc.cache import compiled_many
from trq_offboard.nmpc.factory import make_solver
from trq_offboard.observer_period import ObserverPeriod
from trq_offboard.predictor import DelayPredictor
from trq_offboard.rate_observer import RateObserver
from trq_offboard.records import (
    ActuatorCommand,
    CommandSource,
    EstimatorHealth,
    SensorSamples,
    SolveInfo,
    SolveStatus,
    StateEstimate,
    StepInfo,
    StepTimes,
)
from trq_offboard.reference import FlightReference
from trq_offboard.spin import SpinController, landing_reference, load_spin_config, spin_sense
from trq_wire.cache import built_once

# The time constant (s) of the low-pass of the observer's horizontal d (the accelerations the
# model misses, the motors' share taken out: the wind's drag) carried into the spinning
# controller's position loop at a switch, its integral's start: without it the loop starts from
# no wind and the wind pushes the vehicle downwind until the integral has learnt it again.
# Half a second: longer than the observer's noise, shorter than a gust (a choice; the record:
# docs/decisions/2026-12-05-lost-motor-axes.md)
SPIN_WIND_TAU_S = 0.5

__all__ = ["Controller", "sensor_streams_of"]

HOME_RATE_HZ = 1        # HOME_POSITION asked of the vehicle with a GNSS source (a moved home)
# with a GNSS source the filter starts from the autopilot's position with this 1 sigma: the
# fixes' own errors are the autopilot's too, give or take what it fused them with
GNSS_START_STD_M = 0.1

def _wrap(a):
    """Angle(s) (float or array) wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _on_microseconds(t_s: float) -> float:
    """t_s on the microsecond grid, as a time formed from MAVLink's integer microseconds:
    (stamp_us - t0_us) * 1e-6 (trq_offboard/loop.py)."""
    return round(t_s * 1e6) * 1e-6


def _interp_rows(x: np.ndarray, h: float, times: np.ndarray) -> np.ndarray:
    """Rows of x (n+1, m), sampled every h seconds from 0, linearly interpolated at `times`
    (clamped to [0, n h], as np.interp does), all columns at once: (len(times), m)."""
    return _interp_with(x, _interp_weights(x.shape[0] - 1, h, times))


def _interp_weights(n: int, h: float, times: np.ndarray):
    """`_interp_rows`' rows and weights for n + 1 rows: (i, i + 1, 1 - f, f)."""
    s = np.clip(times / h, 0.0, n)
    i = np.minimum(s.astype(int), n - 1)
    f = (s - i)[:, None]
    return i, i + 1, 1.0 - f, f


def _interp_with(x: np.ndarray, w) -> np.ndarray:
    i, i1, g, f = w
    return x[i] * g + x[i1] * f


def sensor_streams_of(cfg: ControllerConfig) -> dict[str, int]:
    """The raw sensor streams (MAVLink message name: Hz) a controller of this configuration
    needs from the vehicle: the fused filter's IMU and position source (the motion capture
    pose, or the GNSS fix and the home it is relative to), none on the autopilot's estimate."""
    f = cfg.fused
    if f is None:
        return {}
    if f.position_source == "gnss":
        return {"HIGHRES_IMU": f.imu_rate_hz, "GPS_RAW_INT": f.gnss_rate_hz,
                "HOME_POSITION": HOME_RATE_HZ}
    return {"HIGHRES_IMU": f.imu_rate_hz, "ATT_POS_MOCAP": f.mocap_rate_hz}


class Controller:
    """One controller file's controller (see the module docstring): its parts built once
    (`solver`: another Solver instead of the file's, e.g. a test's), then reset, step and
    prepare; `cpu_ns` the CPU clock that times the parts (a measurement only)."""

    def __init__(self, cfg: ControllerConfig, solver: Solver | None = None,
                 cpu_ns: Callable[[], int] = time.thread_time_ns) -> None:
        self.cfg = cfg
        self.cpu_ns = cpu_ns                 # the parts' CPU clock (a measurement only)
        # the preparation through the solver's compiled guess where it has one
        # (Solver.prepares_plans); False: the NumPy path, its specification (the twin tests)
        self.compiled_guess = True
        self.last_prepare_cpu_ns = 0
        vm = cfg.vehicle
        self.model = PredictionModel(vm)
        self.allocator = Allocator(vm)
        self.hover_command = self.allocator.hover()
        self.u_trim = self.allocator.command_vector(self.hover_command)
        self.solver = solver if solver is not None else make_solver(cfg, self.model, self.u_trim)
        self.eso = (ExtendedStateObserver(cfg.eso, cfg.control_dt_s,
                                          codegen=cfg.solver.codegen == "auto")
                    if cfg.eso is not None else None)
        # the body rates published through a low-pass (rates_lowpass_hz, the autopilot's
        # IMU_GYRO_CUTOFF): their observer carries the filter, so that its lag is not read as a
        # disturbance (rate_observer.py; the record: docs/decisions/2026-12-05-lossy-link-rates-
        # lowpass.md); the ESO's own body-rate channels are then not used
        rot = cfg.eso.rotational if cfg.eso is not None else None
        self.rate_observer = (RateObserver(cfg.rates_lowpass_hz, rot.omega_o_rad_s,
                                           cfg.control_dt_s, cfg.eso.substeps,
                                           cfg.eso.max_disturbance[1],
                                           codegen=cfg.solver.codegen == "auto")
                              if rot is not None and rot.output == "rates"
                              and cfg.rates_lowpass_hz > 0.0 else None)
        self.N, self.h = cfg.horizon_steps, cfg.step_s
        self._rollout = self.model.discrete(self.h, 1)
        # auto: predict, and through the actuator lags, once the delay reaches one control
        # period; below it the observer's delayed b0 alone does better (nmpc.yaml: measured)
        predict = cfg.predicts_delay
        self.delay_s = cfg.applied_delay_s if predict else 0.0
        # the motor effectiveness observer (motor_effectiveness): reads the observer's d as motor
        # outputs; it needs the actuators' lags (its motor model is the lag)
        effectiveness = (MotorEffectivenessObserver(cfg.effectiveness, vm.motor_time_constant_s,
                                                    cfg.control_dt_s,
                                                    codegen=cfg.solver.codegen == "auto")
                         if cfg.effectiveness is not None and self.eso is not None else None)
        self._nt = 4 if self.model.tilting else 0         # where the throttles start in u
        self._scale = np.ones(self.model.nu)              # plan (effective) = scale x command
        # auto: also whenever the NMPC carries the lag states, which must not meet an observer
        # whose b0 ignores the lags (measured: docs/decisions/2026-12-02-figures-from-comments.md);
        # always with the effectiveness observer
        lagged = effectiveness is not None or cfg.lagged_actuators == "on" or (
            cfg.lagged_actuators == "auto"
            and ((predict and self.delay_s > 0.0) or cfg.nmpc_actuator_states))
        self._shifts: dict[float, tuple] = {}     # _shift's, by elapsed time
        self._last_u = self.u_trim.copy()
        # the commands sent and the actuators through their lags (the observer's b0, the state
        # when the command acts), and the motors' effectiveness composed with them
        self.predictor = DelayPredictor(self.model, vm, cfg.applied_delay_s, cfg.control_dt_s,
                                        lagged, self._last_u)
        self.motors = (MotorEffectiveness(effectiveness, self.model, self.predictor)
                       if effectiveness is not None else None)
        # the observers' regular period as one compiled call (observer_period.py), with codegen
        self._period = (ObserverPeriod.of(self.eso, self.rate_observer, self.motors)
                        if cfg.solver.codegen == "auto" else None)
        # their functions, compiled (nmpc/cache.py; in parallel, one per core), once per process
        # for a configuration (they are functions of the file and `lagged` alone)
        def build() -> dict:
            fns = {**self.predictor.functions(),
                   **(self.motors.functions() if self.motors is not None else {}),
                   **({"observer_period": self._period.function()}
                      if self._period is not None else {})}
            return {name: fn for name, (fn, _) in
                    zip(fns, compiled_many(list(fns.values()), cfg.solver.codegen == "auto"))}

        functions, _ = built_once(("controller functions", cfg, lagged), build)
        built = {name: NumpyFunction(fn) for name, fn in functions.items()}
        self.predictor.bind(built)
        if self.motors is not None:
            self.motors.bind(built)
        if self._period is not None:
            self._period.bind(built["observer_period"])
        # the NMPC's stage carries the actuators' lag states (actuator_states): its plan starts
        # from the actuators' outputs predicted for t + delay (self._y_act)
        self._act_states = bool(self.solver.ocp.n_lag)
        self._y_act: np.ndarray | None = None
        self._u_lo = np.array(([vm.tilt_min_rad] * 4 if self.model.tilting else [])
                              + [vm.idle_pct] * 4)
        self._u_hi = np.array(([vm.tilt_max_rad] * 4 if self.model.tilting else []) + [100.0] * 4)
        self._plan: tuple[np.ndarray, np.ndarray] | None = None
        self._plan_t = 0.0
        self._last_t: float | None = None
        self._last_d = np.zeros(6)
        self._prev_u = self.u_trim.copy()
        self._grid_key: tuple | None = None     # (reference, t) of the last reference grid
        self._grid_val: tuple | None = None
        self.clip_count = 0
        self.failures = 0
        # the fused filter (estimator kind fused): position and velocity from the position
        # source, the IMU and the model with the motors' share of the observer's d; started at
        # the first position sample (`_fuse`)
        self.fused = (fused_filter(cfg.fused, vm.gravity_m_s2,
                                   codegen=cfg.solver.codegen == "auto")
                      if cfg.fused is not None else None)
        self._fused_on = False
        self._eso_d = np.zeros(6)                # the observer's d of the last step
        self._wind_acc = np.zeros(2)             # the low-pass of d's N, E (SPIN_WIND_TAU_S)
        self._motor_share = np.zeros(3)          # the motors' share of it (effectiveness)
        self._health: EstimatorHealth | None = None
        # a whole motor lost (lost_motor, with the effectiveness observer): the detector, and
        # the NMPC of the failed configuration built now (build once), flown once it detects
        self.detector = (LostMotorDetector(cfg.lost_motor)
                         if cfg.lost_motor is not None and self.motors is not None else None)
        self._nominal_solver = self.solver
        self._failed_solver = (make_solver(failed_config(cfg), self.model, self.u_trim)
                               if self.detector is not None and solver is None else None)
        # two motors lost (lost_motor.pair_excess_m_s2): the pair detector, before any loss
        self.pair_detector = (PairLossDetector(cfg.lost_motor)
                              if self.detector is not None
                              and cfg.lost_motor.pair_excess_m_s2 is not None else None)
        self.lost_motor = 0                   # the motor flown as lost (1..4; a pair 10 i + j)
        self._descent: tuple[float, np.ndarray] | None = None   # (t_s, position) at detection
        # the spinning response (lost_motor.response spin): the file's `spin:` controller for each
        # motor and each sense of the spin, built now (each its trim's IPOPT and its LQR), one of
        # them flown from a detection of one motor lost (`_detect`)
        self._spin_cfg = None
        self._spins: dict[tuple[int, int], SpinController] = {}
        if self.detector is not None and cfg.lost_motor.response == "spin":
            self._spin_cfg = load_spin_config(cfg.file)
            self._spins = {(m, d): SpinController(self._spin_cfg, vm, m,
                                                  delay_s=cfg.applied_delay_s, direction=d)
                           for m in (1, 2, 3, 4) for d in (1, -1)}
        self.spin: SpinController | None = None      # the spinning controller flying, if any
        self._spin_t0 = 0.0                            # when it took over (s)
        # the ground's NED down, for the spinning controller's landing: PROTOCOL.md's home, on
        # the ground (a caller that knows better may set it before the flight)
        self.ground_down_m = HOME_GROUND_DOWN_M
        # on the ground (the caller sets it before each step: the vehicle's land detector says
        # ON_GROUND, or TAKEOFF before the vehicle climbs, or the companion's own touchdown
        # test in a landing): the observers do not integrate, as PX4's rate controller does not
        # while landed. On the gear the ground's reaction and friction are no disturbance to
        # learn: learnt at a spool-up, they turn the vehicle on its gear and throw it at the
        # lift-off (docs/decisions/2026-12-06-observer-on-the-gear.md, and
        # docs/decisions/2026-12-06-observer-through-the-lift-off.md)
        self.landed = False

    @property
    def sensor_streams(self) -> dict[str, int]:
        """The raw sensor streams this controller needs from the vehicle (`sensor_streams_of`
        its configuration)."""
        return sensor_streams_of(self.cfg)

    @classmethod
    def from_yaml(cls, path: Path | str) -> "Controller":
        return cls(load_controller(path))

    def solver_line(self) -> str:
        """What solves this controller's NMPC, for the log's header: the solver's own account
        (its describe(): the QP path and the libhpipm)."""
        return self.solver.describe()

    # --- lifecycle ------------------------------------------------------------------------------
    def reset(self, t_s: float, state: StateEstimate,
              applied: ActuatorCommand | None = None) -> None:
        """Initialise observer and plan from the measured state (and the command being flown,
        default the hover trim), so the controller takes over without a jump."""
        x = state.as_vector()
        self._last_u = (self.allocator.command_vector(applied) if applied is not None
                        else self.u_trim.copy())
        self._last_u = np.clip(self._last_u, self._u_lo, self._u_hi)
        self._prev_u = self._last_u.copy()
        self.predictor.reset(t_s, self._last_u)
        self._reset_observers(x)
        self._scale = np.ones(self.model.nu)
        if self.motors is not None:
            self.motors.observer.reset(self._last_u[self._nt:])
            self.solver.ocp.set_throttle_scale(np.ones(4))
        self._plan = None
        self._y_act = None
        self._last_t = float(t_s)
        self._last_d = np.zeros(6)
        self.solver.discard()
        self.clip_count = 0
        self.failures = 0
        self._fused_on = False
        self._eso_d = np.zeros(6)
        self._wind_acc = np.zeros(2)
        self._motor_share = np.zeros(3)
        self._health = None
        if self.detector is not None:
            self.detector.reset()
            if self.pair_detector is not None:
                self.pair_detector.reset()
            self.solver = self._nominal_solver
            self._set_horizon(self.solver)
        self.lost_motor = 0
        self._descent = None
        self.spin = None

    @property
    def lost_motor_response(self) -> str:
        """What flies the lost motor: "spin" (the spinning controller) or "nmpc" (the failed
        NMPC; also before any loss)."""
        return "spin" if self.spin is not None else "nmpc"

    def _euler_rate(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.model.f(x, self._last_u, np.zeros(6))).ravel()[6:9]

    # --- one control step -----------------------------------------------------------------------
    def step(self, t_s: float, state: StateEstimate, applied: ActuatorCommand | None,
             reference: FlightReference, sensors: SensorSamples | None = None
             ) -> tuple[ActuatorCommand, StepInfo]:
        """One control period. In: t_s (s, the state's time on the flight's clock), `state` (the
        StateEstimate the command answers: the measured state, or a filter's estimate of it),
        `applied` (the ActuatorCommand the vehicle reports flying since the last step; None:
        the one this controller returned last), `reference`, `sensors` (the raw sensors received
        since the last step, for the fused filter; None: none). Out: the ActuatorCommand to send
        (clipped to the actuators' limits, finite) and its StepInfo. In order:

        1. the state estimate in (a non-finite one: the fallback, `_emergency`); with the
           fused filter and sensors, its position and velocity replace the state's (`_fuse`,
           after the actuators' walk, whose b0 it takes);
        2. the actuators walked through their lags from the last step to when this command
           acts, t_s + delay (`_walk`: one path for the observer and the predictor);
        3. the observer advanced to t_s under the commands in effect: d (`_observe`);
        4. the motors' effectiveness (motor_effectiveness): d less the motors' share, the
           walk after t_s in effective throttles and the plan's throttle scale;
        5. the state predicted for when the command acts (the delay predictor);
        6. the NMPC solved from it, warm-started from the previous plan;
        7. the command: the plan's first (or the fallback), clipped (`_finish`).
        The step's CPU is read between the parts (StepInfo.cpu: observer = 1-3,
        effectiveness = 4, predictor = 5, feedback = 6-7)."""
        clock = self.cpu_ns
        c0 = clock()
        if self._last_t is None:
            self.reset(t_s, state, applied)
        # 1. the state estimate in
        x = state.as_vector()
        if not np.isfinite(x).all():            # (the methods: no NumPy wrapper a period)
            return self._emergency(t_s, "non-finite state", c0)
        # the input that acted since the last step: the previous command, or what the vehicle
        # reports it produced (applied_input in the controller file)
        u_applied = (np.clip(self.allocator.command_vector(applied), self._u_lo, self._u_hi)
                     if applied is not None and self.cfg.applied_input == "outputs"
                     else self._last_u)
        # 2. the actuators until this command acts; 3. the observer
        t_act = t_s + self.delay_s
        t_prev = self._last_t
        path, y_act, y_now = self._walk(x, t_s, t_act)
        # the model's b0 over the period, once for the fused filter and the observer (at the
        # state as it came: the filter then replaces its position and velocity)
        b0 = self._b0(x, t_s, applied, u_applied, path) if t_s > self._last_t else None
        if self.fused is not None and sensors is not None:
            self._health = self._fuse(x, t_s, sensors, b0)
        d, d_obs, out_err, motored = self._observe(x, t_s, b0, y_now)
        self._eso_d = d_obs
        c1 = clock()
        # 4. the motors' effectiveness (its observer already advanced where `_observe` took the
        # composed period)
        if self.motors is not None:
            if motored:
                d, path, y_act, self._scale = self.motors.after_period(y_now, d, t_s, t_act,
                                                                       self.solver.ocp)
            else:
                d, path, y_act, self._scale = self.motors.step(x, d, y_now, t_prev, t_s, t_act,
                                                               self.solver.ocp)
            # the fused filter's: the motors' share of the observer's d, bounded as the observer
            # bounds d: at a spool-up on the ground (d is the ground's reaction) the deficit it
            # explains is not a motor's, and unbounded it would throw the filter off
            if self.fused is not None:
                share = d_obs[0:3] - d[0:3]
                norm = math.sqrt(share.dot(share))     # np.linalg.norm's figure, cheaper
                lim = self.cfg.eso.max_disturbance[0]
                self._motor_share = share if norm <= lim else share * (lim / norm)
            if self.detector is not None:
                self._detect(t_s, x, d_obs, y_now, d, path)
        c2 = clock()
        if self.detector is not None and self.spin is None and t_s > self._last_t:
            # only where a switch can read it (a lost-motor detector), not in every period
            k = 1.0 - math.exp(-(t_s - self._last_t) / SPIN_WIND_TAU_S)
            self._wind_acc = self._wind_acc + k * (np.asarray(d[0:2], float) - self._wind_acc)
        self._last_t = float(t_s)
        self._last_d = d
        if self.spin is not None:
            return self._spin_step(t_s, x, d_obs, out_err, (c0, c1, c2))
        # 5. the command computed now acts from t_act: plan from the state predicted for then
        x0 = self.predictor.predict(x, t_s, t_act, d, path) if self.delay_s > 0.0 else x
        c3 = clock()
        # 6. the NMPC
        x_ref = self._reference_states(t_act, x0, reference)

        def guess():           # a prepared real-time iteration needs it only to fail with
            return self._guess(t_act, x0, d)
        self._y_act = y_act
        u_plan, x_plan, info = self.solver.solve(x0, x_ref, d, u_applied, guess,
                                                 y0=y_act if self._act_states else None)
        # 7. the command
        if info.status is SolveStatus.OK and np.isfinite(u_plan).all() \
                and np.isfinite(x_plan).all():
            self._plan, self._plan_t = (u_plan, x_plan), t_act
            u, source = self._command_of_plan(u_plan[0]), CommandSource.NMPC
        else:
            self.failures += 1
            if info.status is SolveStatus.OK:      # finite-status but non-finite plan
                info = SolveInfo(SolveStatus.FAILED, info.iterations, info.solve_time_s,
                                 float("nan"), "non-finite plan")
            u, source = self._fallback(t_act)
        return self._finish(u, source, info, d_obs, out_err, (c0, c1, c2, c3))

    def _detect(self, t_s: float, x: np.ndarray, d_obs: np.ndarray | None = None,
                y_now=None, d: np.ndarray | None = None, path=None) -> None:
        """The lost-motor detector on this step's effectiveness and the commands in effect; on
        a detection (once) the failed configuration: its NMPC, the descent from here; then, every
        step, the dead rotor's effective throttle bounded to 0 (trq_offboard/lost_motor.py).
        Before any loss, the pair detector (when configured) on the observer's d and the
        motors' shares at their outputs y_now: a pair declared flies the failed NMPC with both
        rotors out (no spinning controller: it holds one motor lost)."""
        nt = self._nt
        if self.pair_detector is not None and (
                self.pair_detector.lost is not None or not self.lost_motor):
            pair = self.pair_detector.lost
            if pair is None and d_obs is not None and y_now is not None:
                contrib = motor_contributions(self.model.accel, x, y_now)
                pair = self.pair_detector.update(t_s, d_obs[2:6], contrib, self._last_u[nt:])
            if pair is not None:
                self._detect_pair(t_s, x, pair)
                return
        lost = self.detector.update(t_s, self._scale[nt:], self._last_u[nt:])
        if lost is None:
            return
        if not self.lost_motor:
            self.lost_motor = lost
            self._descent = (float(t_s), x[0:3].copy())
            others = np.delete(self._scale[nt:], lost - 1)
            if self._spins and np.all(others > self.cfg.lost_motor.below):
                # one motor lost (no other at the detector's threshold): the spinning
                # controller from here, holding where the loss was declared, its actuators
                # starting from the last command sent, spinning the way the body already yaws
                # (reversing a started spin passes through no spin at all, where nothing holds
                # the axis: the records; `spin_sense`) when its first command acts: over a
                # delayed link the yaw rate predicted for then (the NMPC's predictor, the loss in
                # its effectiveness), which the yaw torque of the rotors left can have turned
                # from the one measured (docs/decisions/2026-12-06-lost-motor-tilt-bound.md)
                x_act = (self.predictor.predict(x, t_s, t_s + self.delay_s, d, path)
                         if self.delay_s > 0.0 and d is not None else x)
                sense = spin_sense(x_act[9:12], self._spins[(lost, 1)].trim.axis_frd)
                self.spin = self._spins[(lost, sense)]
                self._spin_t0 = float(t_s)
                # the wind learnt before the switch: the position loop's integral starts from
                # it, or, with the observer's estimate fed forward, that estimate's low-pass
                wind = (self._wind_acc[0], self._wind_acc[1], 0.0)
                fed = self._spin_cfg.observer_lowpass_s is not None
                self.spin.reset(StateEstimate.from_vector(x),
                                command=self.allocator.command_of(self._last_u),
                                hold_pos_ned_m=tuple(x[0:3]), ground_down_m=self.ground_down_m,
                                integral_m_s2=None if fed else tuple(-w for w in wind),
                                disturbance_m_s2=wind if fed else None)
            self._to_failed_solver((lost,))
        self._scale[nt + lost - 1] = 0.0
        self.solver.ocp.set_throttle_scale(self._scale[nt:])

    def _to_failed_solver(self, dead: tuple[int, ...]) -> None:
        """The failed configuration's NMPC from here (when built), warm-started from the last
        plan with the dead rotors at 0 (another horizon: none, the trim rolled out)."""
        nt = self._nt
        if self._failed_solver is not None:
            self.solver.discard()
            self.solver = self._failed_solver
            self._set_horizon(self._failed_solver)
        if self._plan is not None and self.N == len(self._plan[0]):
            u_old = self._plan[0].copy()
            for m in dead:
                u_old[:, nt + m - 1] = 0.0
            self._plan = (u_old, self._plan[1])
        else:
            self._plan = None

    def _detect_pair(self, t_s: float, x: np.ndarray, pair: tuple[int, int]) -> None:
        """Two motors lost: once, the failed NMPC and the descent from here; every step, both
        rotors' effective throttles bounded to 0."""
        nt = self._nt
        if not self.lost_motor:
            self.lost_motor = pair_code(pair)
            self._descent = (float(t_s), x[0:3].copy())
            self._to_failed_solver(pair)
        for m in pair:
            self._scale[nt + m - 1] = 0.0
        self.solver.ocp.set_throttle_scale(self._scale[nt:])

    def _spin_step(self, t_s: float, x: np.ndarray, d_obs: np.ndarray, out_err: float,
                   marks) -> tuple[ActuatorCommand, StepInfo]:
        """A step of the spinning controller (a motor lost, response spin): its command for
        `x` (the estimate, the fused position in it) against its landing reference from the
        switch (hold, then land); the dead rotor, and every rotor once it has cut the motors at
        touchdown, commanded idle (the throttles' lower limit), as the NMPC's dead rotor is."""
        spin = self.spin
        ref = landing_reference(t_s - self._spin_t0, spin.hold_pos_ned_m, self._spin_cfg.landing,
                                self.ground_down_m)
        t0 = time.perf_counter()
        cmd = spin.step(StateEstimate.from_vector(x), ref, d_obs)
        solve_s = time.perf_counter() - t0          # a measurement, as the solvers' own
        c3 = self.cpu_ns()
        u = self.allocator.command_vector(cmd)
        nt = self._nt
        u[nt:] = np.maximum(u[nt:], self._u_lo[nt:])
        # the inner LQR solves nothing; the inner NMPC one QP (its iterations; a failed QP flew
        # the LQR's command that period: the message says so)
        qp = spin.info.qp_status
        info = SolveInfo(SolveStatus.OK, spin.info.qp_iterations, solve_s, float("nan"),
                         "spin" if qp in (-1, 0, 1, 2) else "spin: QP failed, LQR flown")
        return self._finish(u, CommandSource.SPIN, info, d_obs, out_err, (*marks, c3))

    def _set_horizon(self, solver: Solver) -> None:
        """The controller's horizon grid (N, h, the rollout, the shifts' cache) that of
        `solver`'s OCP (the failed configuration may have its own)."""
        N, h = solver.ocp.n_steps, solver.ocp.step_s
        if (N, h) != (self.N, self.h):
            self.N, self.h = N, h
            self._rollout = self.model.discrete(h, 1)
            self._shifts = {}
            self._grid_key = self._grid_val = None

    def _command_of_plan(self, u_row: np.ndarray) -> np.ndarray:
        """The command of a plan's row: the effective throttles divided by the motors' scale;
        a rotor flown as lost (scale 0) is commanded idle."""
        scale = self._scale
        if scale.min() > 0.0:             # no rotor flown as lost: the same quotient
            return np.asarray(u_row, float) / scale
        dead = scale <= 0.0
        u = np.asarray(u_row, float) / np.where(dead, 1.0, scale)
        u[dead] = self._u_lo[dead]
        return u

    def _walk(self, x: np.ndarray, t_s: float, t_act: float):
        """The actuators through their lags from the last step to t_act, when this step's
        command acts: (the path, for the observer before t_s and the predictor after it; their
        outputs at t_act; at t_s), each None where nothing needs it. With the effectiveness
        observer the predictor's part (after t_s) is walked in effective throttles by
        MotorEffectiveness.step: the healthy walk stops at t_s."""
        if self.predictor.lagged:
            t_end = t_s if self.motors is not None else t_act
            return self.predictor.actuator_walk(min(self._last_t, t_s), t_end, t_s, x)
        if self._act_states:
            return None, self.predictor.actuator_walk(t_act, t_act)[1], None
        return None, None, None

    def _reset_observers(self, x: np.ndarray) -> None:
        """The ESO and the rate observer started at the measured state x, no disturbance."""
        if self.eso is not None:
            eta_dot = np.asarray(self._euler_rate(x)).ravel()
            self.eso.reset(self.eso.measurement(x), np.concatenate([x[3:6], eta_dot]))
        if self.rate_observer is not None:
            self.rate_observer.reset(x[9:12])

    def _observe(self, x: np.ndarray, t_s: float, b0: np.ndarray | None,
                 y_nom: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, float, bool]:
        """The observer advanced from the last step to t_s with b0, the model's accelerations
        under the input that acted (`_b0`; None: no time has passed): (d, the observer's own
        estimate (logged), its output error, whether the motors' observer was advanced too);
        zeros without an observer. A regular period is one compiled call of the observers
        composed (observer_period.py), the motors' observer included (y_nom: the actuators'
        healthy outputs at t_s, the walk's), and d then less the motors' share."""
        if self.eso is None:
            d = np.zeros(6)
            return d, d, 0.0, False
        if self.landed:              # held at the measured state, no disturbance (`landed`)
            self._reset_observers(x)
            d = np.zeros(6)
            return d, d, 0.0, False
        if self._period is not None and t_s > self._last_t and b0 is not None:
            segs = (self.predictor.in_effect(self._last_t, t_s) if self.motors is not None
                    else None)
            got = self._period.run(x, b0, t_s - self._last_t, y_nom, segs)
            if got is not None:
                d_obs, d, out_err = got
                return d, d_obs, out_err, self.motors is not None
        y = self.eso.measurement(x)
        ro = self.rate_observer
        if t_s > self._last_t and b0 is not None:
            dt = t_s - self._last_t         # the true gap: samples can be lost or skipped
            b = self.eso.b0_of(b0)
            self.eso.update(y, b, dt)
            if ro is not None:
                ro.update(x[9:12], b[3:6], dt)
        d = self.eso.disturbance(x[6:9])
        if ro is not None:
            d[3:6] = ro.disturbance
        return d, d, self.eso.output_error(y), False

    def _b0(self, x: np.ndarray, t_s: float, applied: ActuatorCommand | None,
            u_applied: np.ndarray, path) -> np.ndarray:
        """The nominal model's accelerations (9) over the last step to t_s under the input that
        acted: the vehicle's reported outputs, or the commands in effect over the path."""
        if self.cfg.applied_input == "outputs" and applied is not None:
            return self.predictor.b0(x, u_applied)
        return self.predictor.b0_delayed(x, self._last_t, t_s, path)

    def _fuse(self, x: np.ndarray, t_s: float, sensors: SensorSamples,
              b0: np.ndarray | None) -> EstimatorHealth | None:
        """The fused filter advanced to this state's time on the samples received, its known
        input the model's acceleration over the period (the observer's b0) plus, by
        `disturbance_input`, the motors' share of the observer's d or its whole d (the last
        step's); x's position and velocity replaced (in place: the walk's b0 stays bound to x)
        by the filter's. Attitude and rates stay the autopilot's. The filter starts at the
        first position sample; before it (and under `truth`, which sends none) x is as it
        came and the health None."""
        f = self.fused
        gnss = f.cfg.position_source == "gnss"
        if not self._fused_on:
            # no position sample yet (none at all under truth): the state as it came
            if not (sensors.fixes if gnss else sensors.poses_ned_m):
                return None
            f.reset(sensors.stamp_us, x[0:3], x[3:6], GNSS_START_STD_M if gnss else None,
                    x[6:9])
            self._fused_on = True
        for t_us, acc in sensors.accel_frd_m_s2:      # each at its time of validity
            f.add_imu(t_us, acc)
        if gnss:
            h, v = f.cfg.gnss_std_m
            for fix in sensors.fixes:    # the configured noise, or (0) the fix's own
                sn, se, sd = fix.std_ned_m
                f.add_pose(fix.t_us, fix.pos_ned_m,
                           (h if h > 0.0 else sn, h if h > 0.0 else se, v if v > 0.0 else sd))
        else:
            for t_us, pos in sensors.poses_ned_m:
                f.add_pose(t_us, pos)
        if b0 is not None and sensors.stamp_us > f.t_us:
            a_known = b0[0:3]
            kind = self.cfg.fused.disturbance_input
            if kind == "observer":
                a_known = a_known + self._eso_d[0:3]
            elif kind == "motors":
                a_known = a_known + self._motor_share
            health = f.step(sensors.stamp_us, a_known, x[6:9], x[3:6])
        else:
            health = f.health(sensors.stamp_us)
        x[0:6] = f.x[0:6]
        return health

    def prepare(self, reference: FlightReference) -> None:
        """Preparation phase for the next step (t + one control period): the solver linearises
        at the current plan shifted by one period, with the current disturbance estimate. A
        no-op for solvers without one and before the first plan."""
        c0 = self.cpu_ns()
        try:
            self._prepare(reference)
        finally:
            self.last_prepare_cpu_ns = self.cpu_ns() - c0

    def _prepare(self, reference: FlightReference) -> None:
        if not self.solver.prepares or self._plan is None or self._last_t is None \
                or self.spin is not None:
            return
        # when the next step's command acts: the next state's time formed as the flight loop
        # forms a state's (whole microseconds times 1e-6), so that the next step, one period
        # on, finds this reference grid and this preparation's reference as its own
        t_next = _on_microseconds(self._last_t + self.cfg.control_dt_s) + self.delay_s
        elapsed = t_next - self._plan_t
        if elapsed >= self.N * self.h:
            return
        if self.solver.prepares_plans and self._descent is None and self.compiled_guess:
            # the same preparation in one compiled call (nmpc/guess_core.py): the plan shifted,
            # packed and clipped, the reference states beside it, from the grid kept below
            pv, yaw_ref = self._grid(t_next, reference)
            y0 = None
            if self._act_states and self._y_act is not None:
                y0 = self.predictor.lag(self._y_act, self._last_u * self._scale,
                                        self.cfg.control_dt_s)
            self.solver.prepare_plan(self._plan, elapsed, self.h, pv, yaw_ref, self._last_d,
                                     self._last_u, y0)
            return
        # the plan's states from t_next on: the guess's, its first row the predicted state
        xs = _interp_with(self._plan[1], self._shift(elapsed)[1])
        x_pred = xs[0].copy()
        x_ref = self._reference_states(t_next, x_pred, reference)
        guess = self._guess(t_next, x_pred, self._last_d, xs)
        if self._act_states and self._y_act is not None:
            # the actuators one period on, under the command just sent (it acts from t_act)
            y_next = self.predictor.lag(self._y_act, self._last_u * self._scale,
                                        self.cfg.control_dt_s)
            self.solver.prepare(x_ref, self._last_d, self._last_u, guess, y0=y_next)
        else:
            self.solver.prepare(x_ref, self._last_d, self._last_u, guess)

    # --- helpers --------------------------------------------------------------------------------
    def _reference_states(self, t_s: float, x: np.ndarray,
                          reference: FlightReference) -> np.ndarray:
        """The reference states of the horizon from t_s (N+1, 12), the yaw unwrapped next to
        x's. A reference's grid is a pure function of time: the same object asked for the same
        t gives the same grid."""
        xr = np.zeros((self.N + 1, 12))
        yaw = x[8]
        if self._descent is not None:
            # a motor lost: down at descent_speed_m_s from where it was detected, yaw free
            t0, p0 = self._descent
            v = self.cfg.lost_motor.descent_speed_m_s
            tk = t_s + self.h * np.arange(self.N + 1)
            xr[:, 0:2] = p0[0:2]
            xr[:, 2] = p0[2] + v * np.maximum(tk - t0, 0.0)
            xr[:, 5] = v
            xr[:, 8] = yaw
            # the spin's target (spin_weight), in the direction the vehicle spins
            xr[:, 11] = math.copysign(self.cfg.lost_motor.spin_rate_rad_s, x[11])
            return xr
        pv, yaw_ref = self._grid(t_s, reference)
        xr[:, 0:6] = pv
        xr[:, 8] = yaw + _wrap(yaw_ref - yaw)
        return xr

    def _grid(self, t_s: float, reference: FlightReference) -> tuple[np.ndarray, np.ndarray]:
        """The flight plan's grid of the horizon from t_s (reference.grid). The preparation
        samples the time the next step then asks for (when the two floats agree): the last
        grid kept."""
        key = self._grid_key
        if key is not None and key[0] is reference and key[1] == t_s:
            return self._grid_val
        got = reference.grid(t_s, self.h, self.N + 1)
        self._grid_key, self._grid_val = (reference, t_s), got
        return got

    def _guess(self, t_s: float, x: np.ndarray, d: np.ndarray, xs: np.ndarray | None = None):
        """The plan (u, x) shifted to t_s, x its first state (the yaw kept next to x's), or
        the hover trim rolled out from x without a plan (or past its end). `xs`: the plan's
        states interpolated at t_s + k h, when the caller has them."""
        N, h = self.N, self.h
        if self._plan is not None:
            u_old, x_old = self._plan
            elapsed = t_s - self._plan_t
            if elapsed < N * h:
                idx, weights = self._shift(elapsed)
                u = u_old[idx]
                xg = _interp_with(x_old, weights) if xs is None else xs
                xg[:, 8] += x[8] - xg[0, 8]          # keep yaw next to the measured one
                xg[0] = x
                return u, xg
        u = np.tile(self.u_trim, (N, 1))
        xs = [x]
        for k in range(N):
            nxt = np.asarray(self._rollout(xs[-1], u[k], d)).ravel()
            xs.append(nxt if np.all(np.isfinite(nxt)) else xs[-1])
        return u, np.array(xs)

    def _shift(self, elapsed: float):
        """The plan shifted by `elapsed` s: its input rows at elapsed + k h (k < N, held) and
        `_interp_rows`' weights of its states at elapsed + k h (k <= N). Cached: the same
        elapsed time (one control period, and the delay) comes back every period."""
        got = self._shifts.get(elapsed)
        if got is None:
            N, h = self.N, self.h
            times = elapsed + h * np.arange(N + 1)
            idx = np.minimum((times[:N] / h + 1e-9).astype(int), N - 1)
            got = (idx, _interp_weights(N, h, times))
            if len(self._shifts) < 256:
                self._shifts[elapsed] = got
        return got

    def _fallback(self, t_s: float) -> tuple[np.ndarray, CommandSource]:
        if self._plan is not None:
            elapsed = t_s - self._plan_t
            k = int(elapsed / self.h + 1e-9)
            if k < self.N:
                return self._command_of_plan(self._plan[0][k]), CommandSource.SHIFTED_PLAN
        return self.u_trim.copy(), CommandSource.HOVER

    def _finish(self, u, source, info, d, out_err, marks) -> tuple[ActuatorCommand, StepInfo]:
        """The command of the step (clipped, finite) and its StepInfo; `marks`: the CPU clock
        at the step's start and after its observer, effectiveness and predictor parts (any of
        them the same when a part did not run)."""
        u = np.array(u, float)
        bad = ~np.isfinite(u)
        n_bad = int(np.count_nonzero(bad))
        if n_bad:
            u[bad] = self.u_trim[bad]
        clipped_u = np.minimum(np.maximum(u, self._u_lo), self._u_hi)    # np.clip's values
        n_clip = n_bad + int(np.count_nonzero(np.abs(clipped_u - u) > 1e-9))
        self.clip_count += n_clip
        self._prev_u = self._last_u
        self._last_u = clipped_u
        self.predictor.sent_command(self._last_t, clipped_u)   # for the state at _last_t
        cmd = self.allocator.command_of(clipped_u)
        c0, c1, c2, c3 = marks
        cpu = StepTimes(c1 - c0, c2 - c1, c3 - c2, self.cpu_ns() - c3)
        info = StepInfo(source, info, tuple(d.tolist()), out_err, n_clip,
                        self.clip_count, self.failures, tuple(self._scale[self._nt:].tolist()),
                        cpu, self._health, self.lost_motor)
        return cmd, info

    def _emergency(self, t_s, why, c0) -> tuple[ActuatorCommand, StepInfo]:
        self.failures += 1
        u, source = self._fallback(t_s + self.delay_s)
        info = SolveInfo(SolveStatus.FAILED, 0, 0.0, float("nan"), why)
        return self._finish(u, source, info, np.zeros(6), 0.0, (c0, c0, c0, c0))
