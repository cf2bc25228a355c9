"""The autopilot side of the SIL vehicle, without sockets: it advances the plant tick by tick,
decides which telemetry is due, answers commands and parameters, and applies actuator targets.

The daemon moves bytes; everything that decides what the vehicle does or says is here, so that a
test (or a campaign in one process) can drive it with messages and read back messages.

Sensors: under a sensing profile that carries any (not `truth`), the Sitl owns a `SensorSuite`
with its own generator (seeded from the simulation's seed, apart from the gusts', the noise's
and the links'), sampled once per physics tick by `_sense`, the seam where an estimator plugs
in: its readings are `readings` (the tick's) and `latest` (each sensor's newest), read by the
raw-sensor telemetry (HIGHRES_IMU, GPS_RAW_INT, ATT_POS_MOCAP) and the flight log. Under
`truth` no suite is built and nothing of this runs. With the motion capture wired to the
companion (`mocap_wiring: companion`), the Sitl also hosts the simulated mocap PC (its poses
leave from their own system, `Outgoing.source`) and its estimator takes the poses the companion
forwards (`vision`) instead of the mocap's own.
"""

from __future__ import annotations

import dataclasses

import math
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sil_vehicle.config import STREAMS, SimParams
from sil_vehicle.estimator.eskf import Eskf, Estimate
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.faultscript import Event, ParamAction
from sil_vehicle.frames import euler_to_quat, quat_to_euler
from sil_vehicle.mavlink import codec
from sil_vehicle.mavlink.codec import Measured, RxCounters
from sil_vehicle.failsafe import FailsafeLander
from sil_vehicle import land_detector
from sil_vehicle.land_detector import LandDetector
from sil_vehicle.impair import Impairment
from sil_vehicle.mavlink.params import Param, ParamTable, ekf2_params
from sil_vehicle.sensors import baro, gnss, imu, mag, mocap
from sil_vehicle.sensors import faults as sensor_faults
from sil_vehicle.sensors.faults import SensorFaults
from sil_vehicle.sensors.suite import Reading, SensorSuite
from sil_vehicle.sensors.truth import Truth, imu_truth
from sil_vehicle.vehicle import ActuatorCommand, Vehicle, VehicleState
from trq_wire.mocap import MOCAP_COMPONENT_ID, MOCAP_SYSTEM_ID, VISION_ESTIMATOR_TYPE

LINKS = ("gcs", "offboard")

# Modes, with PX4's custom_mode encoding so that ground stations name them (main << 16 | sub << 24)
MODE_OFFBOARD = 6 << 16
MODE_AUTO_LAND = (4 << 16) | (6 << 24)
MODE_NAMES = {MODE_OFFBOARD: "OFFBOARD", MODE_AUTO_LAND: "AUTO.LAND (failsafe)"}
FORCE_DISARM_MAGIC = 21196
ANNOUNCE_EVERY_US = 1_000_000       # rejected-target STATUSTEXT at most once a simulated second

_MSG_IDS = {name: getattr(mavlink, f"MAVLINK_MSG_ID_{name}") for name in STREAMS}
_MSG_NAMES = {v: k for k, v in _MSG_IDS.items()}

SENSOR_SEED_KEY = 33            # the sensors' generator: default_rng([seed, SENSOR_SEED_KEY])
SENSOR_FAULT_SEED_KEY = 34      # the sensor faults' (garbage) generator, apart from the sensors'
# no IMU reading for this long: the attitude estimate is lost (a choice: ten filter periods;
# PX4's sensors module flags a silent IMU within a comparable time)
IMU_TIMEOUT_US = 100_000
# SYS_STATUS's health report (Sitl.sensor_bits): a sensor silent this long is unhealthy (a
# choice: one second, PX4's GPS_RAW_INT reports NO_GPS after a second without a fix)
SENSOR_TIMEOUT_US = 1_000_000
# GPS_RAW_INT with fix type NO_GPS every second once the receiver has been silent a second (as
# PX4's stream does: kNoGpsSendInterval)
NO_GPS_EVERY_US = 1_000_000
# each sensor's SYS_STATUS bit (MAV_SYS_STATUS_SENSOR): the IMU's are two
SENSOR_BITS = {"imu": mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL,
               "mag": mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG,
               "baro": mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE,
               "gnss": mavlink.MAV_SYS_STATUS_SENSOR_GPS,
               "mocap": mavlink.MAV_SYS_STATUS_SENSOR_VISION_POSITION}
# the estimator's (PX4's health report: attitude_estimate -> AHRS and ATTITUDE_STABILIZATION,
# local_position_estimate -> XY_POSITION_CONTROL)
ATTITUDE_BITS = mavlink.MAV_SYS_STATUS_AHRS | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
POSITION_BITS = mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
# each reading type's sensor, as the suite and the profile name them
SENSOR_OF = {imu.ImuReading: "imu", baro.BaroReading: "baro", mag.MagReading: "mag",
             gnss.GnssReading: "gnss", mocap.MocapReading: "mocap"}
# the raw-sensor messages sent at a reading's arrival (at most at the link's rate)
ON_ARRIVAL = {"gnss": "GPS_RAW_INT", "mocap": "ATT_POS_MOCAP"}
ARRIVING = frozenset(cls for cls, name in SENSOR_OF.items() if name in ON_ARRIVAL)


@dataclass(frozen=True)
class Outgoing:
    link: str                                  # "gcs" or "offboard"
    msg: mavlink.MAVLink_message
    to: tuple[str, int] | None = None          # None: the link's target and every known peer
    # the sender's (system, component) when not the autopilot's: the simulated mocap PC's
    # poses (trq_wire.mocap), which share the offboard link's port in the simulation
    source: tuple[int, int] | None = None


MOCAP_SOURCE = (MOCAP_SYSTEM_ID, MOCAP_COMPONENT_ID)


# flight.csv's columns for a position source of the sensing profile (only when it has one): its
# latest sample arrived by the row's time, with that sample's time of validity
SOURCE_LOG_COLUMNS = {name: (f"{name}_t_us",) + tuple(f"{name}_pos_{a}_m" for a in "ned")
                      for name in ("mocap", "gnss")}
# under a sensing profile: what the vehicle reports (its estimator's estimate), beside the truth
ESTIMATE_LOG_COLUMNS = (tuple(f"est_pos_{a}_m" for a in "ned")
                        + tuple(f"est_vel_{a}_m_s" for a in "ned")
                        + ("est_roll_rad", "est_pitch_rad", "est_yaw_rad", "est_aligned",
                           "est_position_valid", "sensor_fault_mask", "nav_failure"))
# flight.csv's nav_failure: what the vehicle lost (Sitl._navigation)
NAV_FAILURES = {"": 0, "position": 1, "attitude": 2}
LAND_DETECTOR_HZ = 50

LOG_COLUMNS = (
    ["t_us"] + [f"pos_{a}_m" for a in "ned"] + [f"vel_{a}_m_s" for a in "ned"]
    + [f"q{a}" for a in "wxyz"] + ["roll_rad", "pitch_rad", "yaw_rad"]
    + [f"rate_{a}_rad_s" for a in "pqr"]
    + [f"cmd_throttle{i}_pct" for i in range(1, 5)] + [f"cmd_tilt{i}_rad" for i in range(1, 5)]
    + [f"out_throttle{i}_pct" for i in range(1, 5)] + [f"out_tilt{i}_rad" for i in range(1, 5)]
    + [f"motor{i}_factor" for i in range(1, 5)] + [f"servo{i}_stuck" for i in range(1, 5)]
    + [f"wind_{a}_m_s" for a in "ned"] + ["armed", "landed", "crashed"]
    # the gear touching; the last touchdown's down speed and tilt (NaN before the first)
    + ["on_ground", "touchdown_speed_m_s", "touchdown_tilt_deg"])


class Sitl:
    def __init__(self, sim: SimParams, log_sink: Callable[[tuple], None] | None = None) -> None:
        self.sim = sim
        gust_seq, noise_seq, link_seq = np.random.SeedSequence(sim.seed).spawn(3)
        self.vehicle = Vehicle(sim, np.random.default_rng(gust_seq))
        self._noise_rng = np.random.default_rng(noise_seq)
        self.offboard_loss_s = 0.5
        self.params = ParamTable(self.vehicle, (
            Param("COM_OF_LOSS_T", 0.05, 10.0, "s", "offboard loss time before the failsafe",
                  lambda v: self.offboard_loss_s,
                  lambda v, value: setattr(self, "offboard_loss_s", value)),))
        self.mode = MODE_OFFBOARD
        self.lander = FailsafeLander(sim.vehicle)
        # EXTENDED_SYS_STATE's landed_state, updated at LAND_DETECTOR_HZ (PX4 runs its at 50 Hz)
        self.land_detector = LandDetector()
        self._land_every = max(1, sim.physics_rate_hz // LAND_DETECTOR_HZ)
        # targets silent for longer than three control periods: the vehicle's own hold bridges
        self._bridge_after_us = 3 * 1_000_000 // sim.control_rate_hz
        self._last_target_us = 0
        self._newest_target_us = -1
        self.counters = {name: RxCounters() for name in LINKS}
        # a bad link on purpose: per link, one impairment each way (seeded, simulated time)
        link_seqs = iter(link_seq.spawn(2 * len(LINKS)))
        self._down: dict[str, Impairment] = {}
        self._up: dict[str, Impairment] = {}
        for link in sim.links:
            down_seq, up_seq = next(link_seqs), next(link_seqs)
            if link.impair.active:
                self._down[link.name] = Impairment(link.impair, down_seq)
                self._up[link.name] = Impairment(link.impair, up_seq)
        self.periods = {link.name: {s: (sim.physics_rate_hz // hz if hz else 0)
                                    for s, hz in link.rates_hz} for link in sim.links}
        self.default_periods = {k: dict(v) for k, v in self.periods.items()}
        self.home = (sim.home_lat_deg, sim.home_lon_deg, sim.home_alt_m)
        self.tick = 0
        self.log_sink = log_sink
        self._log_period = sim.physics_rate_hz // sim.log_rate_hz if sim.log_rate_hz else 0
        self._limit = sim.vehicle.tilt_limit_rad
        self.lockstep_stamp_us: int | None = None   # latest ODOMETRY stamp on the offboard link
        # has the target for that stamp arrived? True until a stamp has left: on a delayed link
        # the first ODOMETRY (and HEARTBEAT) leave only once time has advanced by the delay
        self.answered = True
        self.targets_applied = 0
        self.targets_ignored = 0
        self.failsafes = 0
        self.bridges = 0
        self._last_announce_us = -ANNOUNCE_EVERY_US
        self._measured: Measured | None = None
        self._was_crashed = False
        self._events: list[Event] = []
        self._gcd_key: tuple | None = None
        self._gcd = 1
        self.events_played: list[tuple[int, str]] = []
        # sensors: none under truth (no suite, no draw, no message)
        profile = sim.sensing if sim.senses else None
        self.suite: SensorSuite | None = None
        self.estimator: Eskf | None = None          # the autopilot's filter on the readings
        self.sensor_faults: SensorFaults | None = None     # injected sensor faults
        self.nav_failure = ""                      # "position" or "attitude" once one was lost
        self._had_position = False                 # a valid position seen in flight (to lose)
        self._estimate: Estimate | None = None     # its output at this tick, once made
        self.readings: list[Reading] = []          # the latest tick's, in the suite's order
        self.latest: dict[str, Reading] = {}       # each sensor's newest reading arrived
        has = set() if profile is None else {
            name for name in SENSOR_OF.values() if getattr(profile, name) is not None}
        # the motion capture wired to the companion (trq_wire.mocap): the vehicle sends no
        # ATT_POS_MOCAP of its own and its estimator takes the companion's forwarded copies
        self.mocap_to_companion = "mocap" in has and sim.mocap_wiring == "companion"
        self._visions: list[mocap.MocapReading] = []      # forwarded, for the next tick
        self._mocap_sent: dict[int, int] = {}     # a pose's stamp -> when the mocap PC sent it
        self._last_vision_us: int | None = None
        # streams the tick loop never sends (not carried, or sent at a reading's arrival)
        self._not_periodic = frozenset(
            {"ATT_POS_MOCAP"} | ({"HIGHRES_IMU"} if "imu" not in has else set())
            | ({"GPS_RAW_INT"} if profile is not None else set())
            | ({"ESTIMATOR_STATUS"} if profile is None else set()))
        self._on_arrival = {ON_ARRIVAL[n]: n for n in ON_ARRIVAL if n in has
                            and not (n == "mocap" and self.mocap_to_companion)}
        self._arrival_sent: dict[tuple[str, str], int] = {}     # (link, stream) -> arrival_us
        self._imu_sent: dict[str, dict[str, int]] = {link: {} for link in LINKS}
        # per link, the IMU's samples summed since its last HIGHRES_IMU (gyro xyz, accel xyz,
        # count, the last sample's time): each message carries the mean since the one before
        self._imu_pending: dict[str, list] = {link: [0.0] * 6 + [0, 0] for link in LINKS}
        # HIGHRES_IMU's accelerometer and gyro: the mean over the last integration interval
        self.imu_mean: imu.ImuReading | None = None
        self._imu_sum = [0.0] * 6
        self._imu_count = 0
        self._imu_interval_us = (profile.imu.samples_per_interval * profile.imu.period_us
                                 if profile is not None and profile.imu is not None else 1)
        self._sources = tuple(n for n in ("mocap", "gnss") if n in has)
        self.log_columns = list(LOG_COLUMNS) + [c for n in self._sources
                                                for c in SOURCE_LOG_COLUMNS[n]]
        if profile is not None:
            self.log_columns += ESTIMATE_LOG_COLUMNS
            self.sensor_faults = SensorFaults(
                np.random.default_rng([sim.seed, SENSOR_FAULT_SEED_KEY]))
            self.suite = SensorSuite(profile,
                                     np.random.default_rng([sim.seed, SENSOR_SEED_KEY]),
                                     home_alt_m=sim.home_alt_m, vehicle=sim.vehicle)
            self._dt_s = sim.dt_us * 1e-6
            self._gravity = sim.vehicle.gravity_m_s2
            self._sensed_vel = self.vehicle.state.x[3:6]    # at rest before the first tick
            self._sensed_q = self.vehicle.state.x[6:10]
            self.readings = self._sense(self.vehicle.state)
            self.estimator = Eskf(self._estimator_params(profile))
            self.estimator.step(self.t_us, self._estimator_readings())
            self._ekf2 = profile.estimator     # the estimator's EKF2 parameters in force
            self.params.extend(ekf2_params(lambda: self._ekf2, self._retune))

    def _estimator_params(self, profile) -> EstimatorParams:
        """The estimator's parameters for `profile`; with the motion capture wired through the
        companion, its delayed horizon reaching a control period further back (the forwarded
        pose comes up to a control period after the mocap's latency)."""
        params = EstimatorParams.from_profile(profile)
        if self.mocap_to_companion:
            sim = self.sim
            extra = -(-sim.dt_us * sim.ticks_per_control // params.filter_period_us)
            params = EstimatorParams.from_profile(
                profile, horizon_us=params.horizon_us + extra * params.filter_period_us)
        return params

    def _retune(self, tuning) -> None:
        """The estimator's EKF2 parameters set from a ground station (PARAM_SET): the filter
        retuned in flight, its state kept (Eskf.retune refuses what needs a restart)."""
        profile = dataclasses.replace(self.sim.sensing, estimator=tuning)
        self.estimator.retune(self._estimator_params(profile))
        self._ekf2 = tuning

    # --- time ------------------------------------------------------------------------------
    @property
    def state(self) -> VehicleState:
        return self.vehicle.state

    @property
    def t_us(self) -> int:
        return self.vehicle.state.t_us

    def step(self) -> list[Outgoing]:
        """Advance one physics tick; return the events and the telemetry due at the new time."""
        out: list[Outgoing] = self._play_events() if self._events else []
        out += self._failsafe()
        state = self.vehicle.step()
        self.tick += 1
        if self.tick % self._land_every == 0:
            self._detect_landing(state)
        self._measured = None
        if self.suite is not None:
            # the tick's readings into the estimator, before the log and the telemetry
            self.readings = self._sense(state)
            self.estimator.set_at_rest(state.landed)     # its zero-velocity update's condition
            self.estimator.step(state.t_us, self._estimator_readings())
            self._estimate = None
        if state.crashed and not self._was_crashed:
            self._was_crashed = True
            self.vehicle.force_disarm()
            out += self.announce(mavlink.MAV_SEVERITY_CRITICAL, f"CRASH: {state.crash_reason}")
        if self._log_period and self.tick % self._log_period == 0 and self.log_sink:
            self.log_sink(self.log_row())
        replies: list[Outgoing] = []
        for link, up in self._up.items():            # what arrived late is handled now
            for msg, sender in up.due(self.t_us):
                replies += self._handle(link, msg, sender)
        return self._deliver(out + replies + self._due_streams())

    def _sense(self, state: VehicleState) -> list[Reading]:
        """The sensors at this tick: the readings that arrive now (each with its time of
        validity), kept as the latest of each sensor. The truth they read: the tick's state,
        and the rates and specific force an integrating IMU reads over the tick, from the
        attitude's and the velocity's change (sensors.truth.imu_truth). An estimator takes the
        readings from here (`readings`, `latest`)."""
        x = state.x
        v0, v = self._sensed_vel, x[3:6]
        q0, q = self._sensed_q, x[6:10]
        self._sensed_vel, self._sensed_q = v, q
        rates, f = imu_truth(q0, q, v0, v, self._dt_s, self._gravity)
        t_us = state.t_us
        readings = self.suite.sample(t_us, Truth(t_us, x[0:3], v, q, rates, f, state.motor_pct))
        if self.sensor_faults.active:
            readings = self.sensor_faults.apply(readings)
        latest = self.latest
        for r in readings:
            latest[SENSOR_OF[type(r)]] = r
            if type(r) is imu.ImuReading:
                self._integrate_imu(r)
        return readings

    def _estimator_readings(self) -> list[Reading]:
        """What the estimator takes at this tick: the tick's readings; with the motion capture
        wired to the companion, not the mocap's own but the poses the companion forwarded
        (`vision`) since the last tick."""
        if not self.mocap_to_companion:
            return self.readings
        fed = [r for r in self.readings if type(r) is not mocap.MocapReading]
        if self._visions:
            fed += self._visions
            self._visions = []
        return fed

    def vision(self, arrival_us: int, t_us: int, pos_ned_m, quat_wxyz,
               pose_cov: tuple[float, ...] | None = None) -> None:
        """A vision (motion-capture) pose arrived from the companion at `arrival_us`, stamped
        `t_us` (its time of validity as the mocap system stamped it), with its pose covariance
        (ODOMETRY's 21 upper-triangle entries; NaN: unknown, the estimator's own figures then).
        The estimator takes it at the next tick, as a reading that arrived at `arrival_us`.
        The EKF2-like estimator takes it at arrival_us - EKF2_EV_DELAY, its variances floored by
        EKF2_EVP_NOISE / EKF2_EVA_NOISE (sil_vehicle.estimator.eskf)."""
        self._last_vision_us = arrival_us
        pos_var = att_var = None
        if pose_cov is not None:
            # the diagonal of the upper triangle (x, y, z, roll, pitch, yaw): the largest of
            # each triple, as EKF2 takes one variance per vision position and one for its yaw
            pv = [pose_cov[i] for i in (0, 6, 11)]
            av = [pose_cov[i] for i in (15, 18, 20)]
            pos_var = max(pv) if all(math.isfinite(v) for v in pv) else None
            att_var = max(av) if all(math.isfinite(v) for v in av) else None
        self._visions.append(mocap.MocapReading(
            int(t_us), int(arrival_us), np.array(pos_ned_m, dtype=float),
            np.array(quat_wxyz, dtype=float), pos_var, att_var))

    def _mocap_poses(self) -> list[Outgoing]:
        """The simulated mocap PC: each pose that arrived at this tick, as ATT_POS_MOCAP from
        its own system to the companion (the offboard link's peer)."""
        out = []
        for r in self.readings:
            if type(r) is mocap.MocapReading:
                self._mocap_sent[r.t_us] = self.t_us
                out.append(Outgoing("offboard", codec.att_pos_mocap(r), source=MOCAP_SOURCE))
        return out

    def _integrate_imu(self, r: imu.ImuReading) -> None:
        """The IMU's samples summed over each integration interval (the profile's
        imu.integration_rate_hz, PX4's IMU_INTEG_RATE; intervals end on its multiples of the
        clock); at its end their mean is `imu_mean`, and each link with HIGHRES_IMU on adds the
        interval's sums to what its next HIGHRES_IMU carries (`_highres_imu`)."""
        acc = self._imu_sum
        g, a = r.gyro, r.accel
        for i in range(3):
            acc[i] += g[i]
            acc[3 + i] += a[i]
        self._imu_count += 1
        if r.t_us % self._imu_interval_us == 0:
            n = self._imu_count
            self.imu_mean = imu.ImuReading(r.t_us, tuple(acc[i] / n for i in range(3)),
                                           tuple(acc[3 + i] / n for i in range(3)))
            for link in LINKS:
                if self.periods[link]["HIGHRES_IMU"]:
                    pending = self._imu_pending[link]
                    for i in range(6):
                        pending[i] += acc[i]
                    pending[6] += n
                    pending[7] = r.t_us
            self._imu_sum = [0.0] * 6
            self._imu_count = 0

    def _arrivals(self) -> list[Outgoing]:
        """GPS_RAW_INT and ATT_POS_MOCAP of the readings that arrived at this tick, on each
        link whose rate for the message is not 0, at most at that rate."""
        out = []
        for r in self.readings:
            stream = ON_ARRIVAL.get(SENSOR_OF[type(r)])
            if stream is None or stream not in self._on_arrival:
                continue
            msg = None
            for link in LINKS:
                period = self.periods[link][stream]
                last = self._arrival_sent.get((link, stream))
                if not period or (last is not None
                                  and r.arrival_us - last < period * self.sim.dt_us):
                    continue
                self._arrival_sent[(link, stream)] = r.arrival_us
                if msg is None:
                    msg = self._sensor_message(stream, r)
                out.append(Outgoing(link, msg))
        return out

    def _sensor_message(self, stream: str, r: Reading) -> mavlink.MAVLink_message:
        if stream == "GPS_RAW_INT":
            return codec.gnss_raw_int(r, self.home)
        return codec.att_pos_mocap(r)

    def _highres_imu(self, link: str | None) -> mavlink.MAVLink_message | None:
        """HIGHRES_IMU on `link`: the mean of the IMU's samples over the integration intervals
        completed since the link's last HIGHRES_IMU (so that no interval is lost at any rate;
        None when none completed: PX4 sends only on a new vehicle_imu), stamped with the last
        sample's time, less the estimator's current gyro and accelerometer bias estimates (as
        PX4's stream subtracts EKF2's estimator_sensor_bias); with the latest barometer and
        magnetometer readings, fields_updated marking those not yet sent on this link. `link`
        None (a MAV_CMD_REQUEST_MESSAGE): the last interval's mean, all fields marked."""
        if link is None:
            mean, sent = self.imu_mean, {}
        else:
            pending = self._imu_pending[link]
            n = pending[6]
            if not n:
                return None
            mean = imu.ImuReading(pending[7], tuple(pending[i] / n for i in range(3)),
                                  tuple(pending[3 + i] / n for i in range(3)))
            self._imu_pending[link] = [0.0] * 6 + [0, 0]
            sent = self._imu_sent[link]
        if self.estimator is not None:
            e = self.estimate()
            bg, ba = e.gyro_bias_frd_rad_s, e.accel_bias_frd_m_s2
            mean = imu.ImuReading(mean.t_us, tuple(float(mean.gyro[i] - bg[i]) for i in range(3)),
                                  tuple(float(mean.accel[i] - ba[i]) for i in range(3)))
        bits = codec.IMU_FIELDS
        for name, fields in (("baro", codec.BARO_FIELDS), ("mag", codec.MAG_FIELDS)):
            r = self.latest.get(name)
            if r is not None and sent.get(name) != r.t_us:
                bits |= fields
                sent[name] = r.t_us
        return codec.highres_imu(mean, self.latest.get("baro"), self.latest.get("mag"), bits)

    def _no_gps(self) -> list[Outgoing]:
        """GPS_RAW_INT NO_GPS on each link that has sent a fix and none for NO_GPS_EVERY_US
        (called on whole seconds of the clock)."""
        out = []
        t = self.t_us
        for link in LINKS:
            last = self._arrival_sent.get((link, "GPS_RAW_INT"))
            if self.periods[link]["GPS_RAW_INT"] and last is not None \
                    and t - last >= NO_GPS_EVERY_US:
                out.append(Outgoing(link, codec.gnss_raw_int_no_gps(t)))
        return out

    def sensor_bits(self) -> codec.SensorBits | None:
        """SYS_STATUS's present / enabled / health bits as PX4's health report sets them (None
        under `truth`: codec.TRUTH_SENSORS). Present and enabled: each sensor the profile
        carries, the estimator's attitude and position. Healthy: a sensor heard from within
        SENSOR_TIMEOUT_US (the IMU within IMU_TIMEOUT_US) and, for GNSS, with a 3D fix or
        better; the IMU's gyro and accelerometer also while the estimator has not diverged; the
        attitude while aligned and not diverged; the position while the estimator's position
        is valid (its no-aid timeout)."""
        if self.suite is None:
            return None
        present = mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | ATTITUDE_BITS | POSITION_BITS
        health = mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        t = self.t_us
        e = self.estimate()
        for name in self.suite.sensors:
            bit = SENSOR_BITS.get(name)
            if bit is None:
                continue
            present |= bit
            r = self.latest.get(name)
            timeout = IMU_TIMEOUT_US if name == "imu" else SENSOR_TIMEOUT_US
            last = r.arrival_us if r is not None else None
            if name == "mocap" and self.mocap_to_companion:
                last = self._last_vision_us       # what the autopilot gets: the forwarded
            ok = last is not None and t - last <= timeout
            if name == "gnss":
                ok = ok and r.fix_type >= mavlink.GPS_FIX_TYPE_3D_FIX
            elif name == "imu":
                ok = ok and not e.diverged
            if ok:
                health |= bit
        if e.attitude_aligned and not e.diverged:
            health |= ATTITUDE_BITS
        if e.position_valid and not e.diverged:
            health |= POSITION_BITS
        return codec.SensorBits(present, present, health)

    def _deliver(self, out: list[Outgoing], impaired: bool = True) -> list[Outgoing]:
        """Pass outgoing messages through the impaired links (unless `impaired` is False), and
        note the lockstep stamp of each offboard ODOMETRY that actually leaves."""
        if self._down and impaired:
            kept = []
            for item in out:
                down = self._down.get(item.link)
                if down is None:
                    kept.append(item)
                else:
                    down.offer(self.t_us, item, item.msg.get_type())
            for down in self._down.values():
                kept += down.due(self.t_us)
            out = kept
        for item in out:
            if item.link == "offboard" and item.msg.get_type() == "ODOMETRY":
                stamp = int(item.msg.time_usec)
                if stamp != self.lockstep_stamp_us:
                    self.lockstep_stamp_us = stamp
                    self.answered = False
        return out

    def _failsafe(self) -> list[Outgoing]:
        """Offboard loss. A target stream that stops for more than a few control periods is
        bridged at once by the vehicle's own controller (it holds attitude and altitude, as an
        autopilot's inner loops would), so that nothing flies open loop; a fresh target ends
        the bridge. No valid target for COM_OF_LOSS_T while armed: mode AUTO.LAND, the same
        controller holds, lands and disarms (PX4's offboard failsafe)."""
        v, s = self.vehicle, self.vehicle.state
        if not v.armed or s.crashed:
            self.lander.active = False
            return []
        out: list[Outgoing] = []
        if self.estimator is not None and not s.landed:
            out += self._navigation(s)
            if not v.armed:
                return out
        if self.mode == MODE_OFFBOARD:
            silence_us = s.t_us - self._last_target_us
            if s.landed or silence_us <= self._bridge_after_us:
                self.lander.active = False
                return []
            if not self.lander.active:
                self.lander.engage(self._nav_state(s))
                self.bridges += 1
            if silence_us > self.offboard_loss_s * 1e6:
                self.mode = MODE_AUTO_LAND
                self.failsafes += 1
                out += self.announce(mavlink.MAV_SEVERITY_CRITICAL,
                                     "offboard lost: failsafe, holding then landing")
        elif s.landed and s.t_us - self.lander.engaged_us > 1_000_000:
            v.force_disarm()
            self.lander.active = False
            return self.announce(mavlink.MAV_SEVERITY_WARNING, "failsafe: landed, disarmed")
        v.command = self.lander.update(self._nav_state(s), self.sim.dt_us * 1e-6)
        if self.mode == MODE_AUTO_LAND and self.land_detector.ground_contact(s.t_us * 1e-6):
            # landing, the land detector's ground contact held: thrust off, as PX4's position
            # controller does on it (otherwise the wind slides a vehicle that its thrust keeps
            # light). Not while the bridge holds a vehicle in the air between two targets: a
            # hover on less than 0.9 of the weight reads as contact at once
            v.command = ActuatorCommand()
        return out

    def _detect_landing(self, s: VehicleState) -> None:
        """The land detector on what the autopilot knows: its estimate (the plant's state under
        `truth`) and the rotors' thrust over the weight."""
        vp = self.sim.vehicle
        nav = self._nav_state(s) if self.estimator is not None else s
        thrust = sum(vp.thrust_N(m) for m in s.motor_pct) / (vp.mass_kg * vp.gravity_m_s2)
        self.land_detector.update(s.t_us * 1e-6, self.vehicle.armed, nav.x[3:6], nav.x[10:13],
                                  thrust)

    def _navigation(self, s: VehicleState) -> list[Outgoing]:
        """The estimator's health in flight, as an autopilot's failsafe reads it. No attitude
        (the IMU silent for IMU_TIMEOUT_US, or the filter diverged): nothing can fly the
        vehicle, so it terminates the flight (PX4's mode fallback ends there when even Descend
        cannot run) and says so. No position (no position aid fused for the estimator's
        no-aid timeout) while offboard: the companion's commands assume one, so the vehicle
        takes over, holding attitude and height on its estimate, then descends and lands
        (PX4's Descend, reported as AUTO.LAND), and says so; only a position it had is lost
        (arming asks for one; a vehicle armed past that check is left alone until it has one)."""
        imu_r = self.latest.get("imu")
        silent = imu_r is None or s.t_us - imu_r.t_us > IMU_TIMEOUT_US
        if silent or self.estimator.diverged:
            self.nav_failure = "attitude"
            self.vehicle.force_disarm()
            self.lander.active = False
            why = "IMU silent" if silent else "estimator diverged"
            return self.announce(mavlink.MAV_SEVERITY_EMERGENCY,
                                 f"no attitude ({why}): flight termination")
        if self.estimator.position_valid():
            self._had_position = True
            return []
        # never had one (armed past the preflight check: a bench, a test), or not offboard
        if not self._had_position or self.mode != MODE_OFFBOARD:
            return []
        self.nav_failure = "position"
        self.mode = MODE_AUTO_LAND
        self.failsafes += 1
        if not self.lander.active:
            self.lander.engage(self._nav_state(s))
        return self.announce(mavlink.MAV_SEVERITY_CRITICAL,
                             "position estimate lost: failsafe, descending")

    def _nav_state(self, s: VehicleState) -> VehicleState:
        """What the vehicle's own controller flies on: under a sensing profile its estimate
        (position, velocity, attitude, rates), under `truth` the plant's state."""
        if self.estimator is None:
            return s
        e = self.estimate()
        x = (tuple(float(c) for c in e.pos_ned_m) + tuple(float(c) for c in e.vel_ned_m_s)
             + tuple(float(c) for c in e.quat_wxyz) + tuple(float(c) for c in e.rates_frd_rad_s))
        return VehicleState(s.t_us, x + tuple(s.x[13:]), s.motor_pct, s.tilt_rad,
                            s.wind_ned_m_s, s.armed, s.landed, s.crashed, s.crash_reason)

    def telemetry_due(self, everything: bool = False, resend: bool = False) -> list[Outgoing]:
        """The telemetry due now (or one of each enabled stream), through the link: what the
        daemon sends first (t = 0). `resend`: what it sends again when a lockstep answer is
        late in wall-clock time; that is the daemon's recovery from a real network's loss, not
        part of the simulated link, so it bypasses an impairment (whose delays run in
        simulated time, which stands still while the vehicle waits)."""
        return self._deliver(self._due_streams(everything), impaired=not resend)

    def _due_streams(self, everything: bool = False) -> list[Outgoing]:
        """Streams whose period divides the current tick (or one of each enabled stream), and
        the raw sensors' messages of the readings that arrived at this tick."""
        # the suite lists the delayed sensors' readings last: none arrived unless the last
        # reading is one (most ticks hold the IMU's alone)
        readings = self.readings
        out = (self._arrivals() if self._on_arrival and readings
               and type(readings[-1]) in ARRIVING else [])
        if self.mocap_to_companion and readings and type(readings[-1]) is mocap.MocapReading:
            out += self._mocap_poses()
        if self.t_us % NO_GPS_EVERY_US == 0 and "GPS_RAW_INT" in self._on_arrival:
            out += self._no_gps()
        if not everything and self.tick % self._period_gcd():
            return out                  # most ticks: nothing is due (cheap test first)
        skip = self._not_periodic
        for link in LINKS:
            for stream, period in self.periods[link].items():
                if period and (everything or self.tick % period == 0) and stream not in skip:
                    msg = self.build(stream, link)
                    if msg is not None:         # a stream PX4 would not send now
                        out.append(Outgoing(link, msg))
        return out


    def _period_gcd(self) -> int:
        if self._gcd_key is None:           # recomputed only after a rate change
            self._gcd_key = ()
            self._gcd = math.gcd(*(p for link in LINKS for s, p in self.periods[link].items()
                                   if p and s not in self._not_periodic)) or 1
        return self._gcd

    @property
    def had_offboard(self) -> bool:
        """Has any valid actuator target arrived yet?"""
        return self._newest_target_us >= 0

    def lockstep_ticks(self) -> int:
        """Physics ticks in one lockstep period (the offboard ODOMETRY period)."""
        return self.periods["offboard"]["ODOMETRY"]

    # --- telemetry -------------------------------------------------------------------------
    def measured(self) -> Measured:
        """What the vehicle reports of its state this tick: under a sensing profile its
        estimator's estimate (with its covariances), under `truth` the true state plus the sim
        file's white noise."""
        if self._measured is None and self.estimator is not None:
            self._measured = codec.measured_of(self.estimate())
        if self._measured is None:
            s, sim = self.vehicle.state, self.sim
            n = self._noise_rng.standard_normal(12)
            x = s.x
            roll, pitch, yaw = quat_to_euler(*x[6:10])
            q = euler_to_quat(roll + sim.noise_attitude_rad * n[6],
                              pitch + sim.noise_attitude_rad * n[7],
                              yaw + sim.noise_attitude_rad * n[8])
            self._measured = Measured(
                s.t_us,
                tuple(x[i] + sim.noise_position_m * n[i] for i in range(3)),
                tuple(x[3 + i] + sim.noise_velocity_m_s * n[3 + i] for i in range(3)),
                q, tuple(x[10 + i] + sim.noise_rates_rad_s * n[9 + i] for i in range(3)))
        return self._measured

    def available(self, stream: str) -> bool:
        """Can `build` make the message now? Not a raw sensor's the profile does not carry,
        nor one whose sensor has not reported yet."""
        if stream == "HIGHRES_IMU":
            return "HIGHRES_IMU" not in self._not_periodic and self.imu_mean is not None
        if stream == "ESTIMATOR_STATUS":
            return self.estimator is not None
        if stream in self._on_arrival:
            return self._on_arrival[stream] in self.latest
        if stream in ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT") and self.estimator is not None:
            return self._position_sendable(stream)
        return stream not in self._not_periodic

    def _position_sendable(self, stream: str) -> bool:
        """As PX4's streams under EKF2: LOCAL_POSITION_NED only while the horizontal position
        and velocity are valid; GLOBAL_POSITION_INT once the estimator is aligned (EKF2
        publishes vehicle_global_position while its origin is valid and its yaw aligned: a
        dead-reckoned position keeps coming; its validity is SYS_STATUS's)."""
        e = self.estimate()
        if stream == "LOCAL_POSITION_NED":
            return e.position_valid and not e.diverged
        return e.attitude_aligned

    def build(self, stream: str, link: str | None = None) -> mavlink.MAVLink_message | None:
        """The message of `stream` now (`link`: the link it goes to, for what HIGHRES_IMU
        carries and marks as updated). Raw sensors' messages: only when `available`. None: a
        message PX4 would not send now (HIGHRES_IMU with no new interval on `link`;
        LOCAL_POSITION_NED / GLOBAL_POSITION_INT while the estimate is not valid for it)."""
        if stream == "HIGHRES_IMU":
            return self._highres_imu(link)
        if stream == "ESTIMATOR_STATUS":
            return codec.estimator_status(self.estimate())
        if stream in self._on_arrival:
            return self._sensor_message(stream, self.latest[self._on_arrival[stream]])
        s = self.vehicle.state
        if stream == "EXTENDED_SYS_STATE":
            return mavlink.MAVLink_extended_sys_state_message(
                mavlink.MAV_VTOL_STATE_UNDEFINED, self.land_detector.state)
        if stream == "HEARTBEAT":
            return codec.heartbeat(self.vehicle.armed, s.crashed, not s.landed, self.mode,
                                   failsafe=self.mode != MODE_OFFBOARD)
        if stream == "SYS_STATUS":
            total = RxCounters()
            for c in self.counters.values():
                for k, v in vars(c).items():
                    setattr(total, k, getattr(total, k) + v)
            rate = int(1000 * total.dropped / max(total.datagrams, 1))
            return codec.sys_status(0, rate * 10, total.dropped,
                                    (total.bad_frames, total.unknown_ids, total.other_system,
                                     total.rejected_targets + total.stale_targets),
                                    self.sensor_bits())
        if stream == "HOME_POSITION":
            return codec.home_position(self.home, s.t_us)
        if stream in ("SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS"):
            fn = codec.servo_output_raw if stream == "SERVO_OUTPUT_RAW" else codec.actuator_output_status
            return fn(s.t_us, s.motor_pct, s.tilt_rad, self._limit)
        if stream in ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT") \
                and self.estimator is not None and not self._position_sendable(stream):
            return None
        m = self.measured()
        if stream == "ODOMETRY":
            return codec.odometry(m, self.estimator.state_resets if self.estimator else 0)
        if stream == "ATTITUDE":
            return codec.attitude(m)
        if stream == "LOCAL_POSITION_NED":
            return codec.local_position_ned(m)
        if stream == "GLOBAL_POSITION_INT":
            return codec.global_position_int(m, self.home)
        if stream == "GPS_RAW_INT":
            return codec.gps_raw_int(m, self.home)
        raise KeyError(stream)

    def estimate(self) -> Estimate:
        """The estimator's output at this tick, made once a tick (telemetry, the log and the
        arming check read the same one)."""
        if self._estimate is None:
            self._estimate = self.estimator.output()
        return self._estimate

    def estimator_ready(self) -> bool:
        """No estimator (truth), or one with its attitude aligned and a valid position."""
        if self.estimator is None:
            return True
        e = self.estimate()
        return e.attitude_aligned and e.position_valid and not e.diverged

    def announce(self, severity: int, text: str) -> list[Outgoing]:
        msg = codec.statustext(severity, text)
        return [Outgoing(link, msg) for link in LINKS]

    # --- incoming --------------------------------------------------------------------------
    def handle(self, link: str, msg: mavlink.MAVLink_message,
               sender: tuple[str, int] | None = None) -> list[Outgoing]:
        """React to one decoded message; return the replies. On an impaired link the message
        may be lost or handled later; an answer to the lockstep stamp counts as an answer
        either way (the vehicle knows what its own link did to it)."""
        up = self._up.get(link)
        if up is None:
            return self._deliver(self._handle(link, msg, sender))
        if msg.get_type() == "SET_ACTUATOR_CONTROL_TARGET" \
                and int(msg.time_usec) == self.lockstep_stamp_us:
            self.answered = True
        if up.offer(self.t_us, (msg, sender), msg.get_type()):
            return self._deliver([r for m, s in up.due(self.t_us)
                                  for r in self._handle(link, m, s)])
        self.counters[link].impaired_lost += 1
        return []

    def _handle(self, link: str, msg: mavlink.MAVLink_message,
                sender: tuple[str, int] | None = None) -> list[Outgoing]:
        counters = self.counters[link]
        target = getattr(msg, "target_system", None)
        if target not in (None, 0, codec.SYSTEM_ID):
            counters.other_system += 1
            return []
        kind = msg.get_type()
        if kind == "SET_ACTUATOR_CONTROL_TARGET":
            return self._target(link, msg)
        if kind == "ODOMETRY":
            self._external_vision(msg)
            return []
        if kind == "COMMAND_LONG":
            return self._command(link, msg, sender)
        if kind == "COMMAND_INT":
            return [Outgoing(link, codec.command_ack(msg.command, mavlink.MAV_RESULT_UNSUPPORTED,
                                                     msg.get_srcSystem(), msg.get_srcComponent()),
                             sender)]
        if kind == "PARAM_REQUEST_LIST":
            n = len(self.params)
            return [Outgoing(link, codec.param_value(p.name, self.params.value(i), n, i), sender)
                    for i, p in enumerate(self.params.params)]
        if kind == "PARAM_REQUEST_READ":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            i = self.params.index(name) if msg.param_index < 0 else msg.param_index
            if i is None or not 0 <= i < len(self.params):
                return []
            return [Outgoing(link, codec.param_value(self.params.params[i].name,
                                                     self.params.value(i), len(self.params), i),
                             sender)]
        if kind == "PARAM_SET":
            return self._param_set(link, msg, sender)
        if kind == "TIMESYNC":
            # as PX4 answers: a request (tc1 = 0) gets tc1 = the vehicle's time in ns (here the
            # simulated clock) and its own ts1 back; an answer (tc1 != 0) is not ours to answer
            if msg.tc1 != 0:
                return []
            return [Outgoing(link, mavlink.MAVLink_timesync_message(self.t_us * 1000, msg.ts1),
                             sender)]
        if kind == "MISSION_REQUEST_LIST":
            return [Outgoing(link, codec.mission_count(msg.get_srcSystem(), msg.get_srcComponent()),
                             sender)]
        return []

    def _external_vision(self, msg) -> None:
        """ODOMETRY from the companion: external vision (estimator_type MOCAP or VISION, pose
        in LOCAL_NED), taken as a vision reading arriving now when the motion capture is wired
        to the companion; anything else is ignored."""
        if not self.mocap_to_companion or msg.estimator_type not in (
                VISION_ESTIMATOR_TYPE, mavlink.MAV_ESTIMATOR_TYPE_VISION) \
                or msg.frame_id != mavlink.MAV_FRAME_LOCAL_NED:
            return
        pos, q = (msg.x, msg.y, msg.z), tuple(msg.q)
        if not all(math.isfinite(v) for v in pos + q):
            return
        self.vision(self._vision_arrival_us(int(msg.time_usec)), int(msg.time_usec), pos, q,
                    tuple(msg.pose_covariance))

    def _vision_arrival_us(self, t_us: int) -> int:
        """When a forwarded pose stamped t_us counts as arrived. In lockstep over a clean
        offboard link: the first control tick at or after the simulated mocap PC sent it, the
        earliest the companion can have answered it, whatever tick the datagram is read at (the
        companion forwards as it reads, which the vehicle's free-running ticks between two control
        ticks may see early or late): the same flight replays bit for bit over UDP. Otherwise
        (real time, or an impaired link, whose delay is the vehicle's own, in vehicle time): now."""
        sent = self._mocap_sent.pop(t_us, None)
        for stale in [k for k in self._mocap_sent if k < t_us]:
            del self._mocap_sent[stale]             # poses the companion never forwarded
        if self.sim.clock_mode != "lockstep" or sent is None or "offboard" in self._up:
            return self.t_us
        period = self.sim.dt_us * self.sim.ticks_per_control
        return -(-sent // period) * period

    def _target(self, link: str, msg: mavlink.MAVLink_message) -> list[Outgoing]:
        counters = self.counters[link]
        target = codec.decode_target(msg, self._limit)
        if target is None:
            counters.rejected_targets += 1
            t = self.t_us
            if t - self._last_announce_us >= ANNOUNCE_EVERY_US:
                self._last_announce_us = t
                return self.announce(mavlink.MAV_SEVERITY_WARNING,
                                     f"actuator target rejected ({counters.rejected_targets})")
            return []
        if target.stamp_us < self._newest_target_us:
            counters.stale_targets += 1          # older than one already applied
            return []
        if self.sim.clock_mode == "lockstep" and link not in self._up \
                and target.stamp_us != self.lockstep_stamp_us:
            counters.stale_targets += 1
            return []
        self._newest_target_us = target.stamp_us
        self._last_target_us = self.t_us
        if target.stamp_us == self.lockstep_stamp_us:
            self.answered = True
        if self.mode != MODE_OFFBOARD:
            self.targets_ignored += 1        # the failsafe flies until offboard is asked back
            return []
        self.vehicle.command = ActuatorCommand(target.throttle_pct, target.tilt_rad)
        self.targets_applied += 1
        return []

    def _ack(self, link: str, msg, result: int, sender) -> Outgoing:
        return Outgoing(link, codec.command_ack(msg.command, result, msg.get_srcSystem(),
                                                msg.get_srcComponent()), sender)

    def _command(self, link: str, msg, sender) -> list[Outgoing]:
        cmd = msg.command
        ok, denied = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            arm = msg.param1 == 1.0
            if not arm and msg.param2 == FORCE_DISARM_MAGIC:
                self.vehicle.force_disarm()
                reason = None
            elif arm and not self.estimator_ready():
                # PX4's preflight check: no arming before the estimator has its attitude and a
                # position; the companion retries (MAV_RESULT_TEMPORARILY_REJECTED)
                return [self._ack(link, msg, mavlink.MAV_RESULT_TEMPORARILY_REJECTED, sender)] \
                    + self.announce(mavlink.MAV_SEVERITY_WARNING,
                                    "arming denied: estimator not ready")
            else:
                reason = self.vehicle.set_armed(arm)
                if arm and reason is None:
                    self._last_target_us = self.t_us      # the stream has its grace time
                    self.mode = MODE_OFFBOARD
            if reason:
                return [self._ack(link, msg, denied, sender)] + self.announce(
                    mavlink.MAV_SEVERITY_WARNING, f"{'arming' if arm else 'disarming'} denied: {reason}")
            return [self._ack(link, msg, ok, sender)] + self.announce(
                mavlink.MAV_SEVERITY_INFO, "armed" if arm else "disarmed")
        if cmd == mavlink.MAV_CMD_INJECT_FAILURE:
            return self._inject(link, msg, sender)
        if cmd == mavlink.MAV_CMD_DO_SET_MODE:
            return self._set_mode(link, msg, sender)
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _MSG_NAMES.get(int(msg.param1)) if math.isfinite(msg.param1) else None
            interval = msg.param2
            if name is None or not math.isfinite(interval):
                return [self._ack(link, msg, mavlink.MAV_RESULT_UNSUPPORTED if name is None
                                  else denied, sender)]
            if name == "ODOMETRY" and link == "offboard" and self.sim.clock_mode == "lockstep":
                return [self._ack(link, msg, denied, sender)]   # it is the lockstep period
            if interval == -1:
                period = 0
            elif interval == 0:
                period = self.default_periods[link][name]
            elif interval > 0:
                period = max(1, int(round(interval / self.sim.dt_us)))
            else:
                return [self._ack(link, msg, denied, sender)]
            self.periods[link][name] = period
            self._gcd_key = None
            return [self._ack(link, msg, ok, sender)]
        if cmd in (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
            wanted = (int(msg.param1) if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE and
                      math.isfinite(msg.param1) else mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            if wanted == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                reply = codec.autopilot_version()
            elif wanted in _MSG_NAMES and self.available(_MSG_NAMES[wanted]):
                reply = self.build(_MSG_NAMES[wanted])
            else:
                return [self._ack(link, msg, mavlink.MAV_RESULT_UNSUPPORTED, sender)]
            return [self._ack(link, msg, ok, sender), Outgoing(link, reply, sender)]
        return [self._ack(link, msg, mavlink.MAV_RESULT_UNSUPPORTED, sender)]

    def _set_mode(self, link: str, msg, sender) -> list[Outgoing]:
        """MAV_CMD_DO_SET_MODE, p1 base mode (CUSTOM_MODE_ENABLED), p2 PX4 main mode: 6
        OFFBOARD, 4 AUTO (p3 sub mode 6: LAND). Offboard is granted only while a valid target
        stream is arriving (as PX4 asks), so control returns after a failsafe only on request."""
        main = int(msg.param2) if math.isfinite(msg.param2) else -1
        sub = int(msg.param3) if math.isfinite(msg.param3) else -1
        if main == 6:
            fresh = self.t_us - self._last_target_us <= self.offboard_loss_s * 1e6
            if not fresh or not self.estimator_ready():
                return [self._ack(link, msg, mavlink.MAV_RESULT_TEMPORARILY_REJECTED, sender)]
            changed = self.mode != MODE_OFFBOARD
            self.mode = MODE_OFFBOARD
            out = [self._ack(link, msg, mavlink.MAV_RESULT_ACCEPTED, sender)]
            if changed:
                out += self.announce(mavlink.MAV_SEVERITY_INFO, "mode OFFBOARD: offboard control")
            return out
        if main == 4 and sub == 6:
            if self.mode != MODE_AUTO_LAND and self.vehicle.armed:
                self.mode = MODE_AUTO_LAND
                if not self.lander.active:
                    self.lander.engage(self.vehicle.state)
            return [self._ack(link, msg, mavlink.MAV_RESULT_ACCEPTED, sender)] + self.announce(
                mavlink.MAV_SEVERITY_INFO, "mode AUTO.LAND")
        return [self._ack(link, msg, mavlink.MAV_RESULT_UNSUPPORTED, sender)]

    def _inject(self, link: str, msg, sender) -> list[Outgoing]:
        result = self.inject(msg.param1, msg.param2, msg.param3, msg.param4)
        out = [self._ack(link, msg, result, sender)]
        if result == mavlink.MAV_RESULT_ACCEPTED:
            # (STATUSTEXT holds 50 characters: the kind of fault injected alone)
            text = (f"sensor faults: {self.sensor_faults.describe()}"
                    if msg.param1 in sensor_faults.UNITS and self.sensor_faults is not None
                    else f"faults: {self.vehicle.faults.describe()}")
            out += self.announce(mavlink.MAV_SEVERITY_WARNING, text)
        return out

    def inject(self, unit: float, kind: float, instance: float, param4: float) -> int:
        """MAV_CMD_INJECT_FAILURE: unit motor (101) / servo (102), type OK (0), OFF (1, motors),
        STUCK (2, servos), instance 1..4 (0 = all), param4 the stuck angle in degrees (NaN:
        where it is); or a sensor unit (`inject_sensor`). Returns the MAV_RESULT; nothing
        changes unless it is ACCEPTED."""
        denied = mavlink.MAV_RESULT_DENIED
        if not all(math.isfinite(v) for v in (unit, kind, instance)) or not 0 <= instance <= 4 \
                or instance != int(instance):
            return denied
        if unit in sensor_faults.UNITS:
            return self.inject_sensor(int(unit), kind, int(instance), param4)
        angle_deg = param4
        instances = range(4) if instance == 0 else [int(instance) - 1]
        faults = self.vehicle.faults
        if unit == mavlink.FAILURE_UNIT_SYSTEM_MOTOR and kind in (mavlink.FAILURE_TYPE_OK,
                                                                 mavlink.FAILURE_TYPE_OFF):
            for i in instances:
                faults = faults.with_motor(i, off=(kind == mavlink.FAILURE_TYPE_OFF))
        elif unit == mavlink.FAILURE_UNIT_SYSTEM_SERVO and kind in (mavlink.FAILURE_TYPE_OK,
                                                                   mavlink.FAILURE_TYPE_STUCK):
            vp = self.sim.vehicle
            for i in instances:
                if kind == mavlink.FAILURE_TYPE_OK:
                    faults = faults.with_servo(i, stuck=False)
                    continue
                angle = self.vehicle.state.tilt_rad[i]
                if math.isfinite(angle_deg):
                    angle = math.radians(angle_deg)
                    if not vp.tilt_min_rad <= angle <= vp.tilt_max_rad:
                        return denied
                faults = faults.with_servo(i, stuck=True, angle_rad=angle)
        else:
            return mavlink.MAV_RESULT_UNSUPPORTED
        self.vehicle.faults = faults
        return mavlink.MAV_RESULT_ACCEPTED

    def inject_sensor(self, unit: int, kind: float, instance: int, size: float) -> int:
        """A sensor unit of MAV_CMD_INJECT_FAILURE (sil_vehicle.sensors.faults): type OK, OFF,
        STUCK, GARBAGE or WRONG (size: param4, NaN for the default), instance 0 or 1 (each
        sensor has one). OK on a sensor the profile does not carry is accepted (it is healthy);
        any other type on one is DENIED, as is an instance above 1 or a size not finite."""
        name = sensor_faults.UNITS[unit]
        sensor = sensor_faults.SENSOR[name]
        if kind not in sensor_faults.KIND_NAMES or kind != int(kind):
            return mavlink.MAV_RESULT_UNSUPPORTED
        kind = int(kind)
        carried = self.suite is not None and sensor in self.suite.sensors
        if kind == sensor_faults.OK and not carried:
            return mavlink.MAV_RESULT_ACCEPTED
        if not carried or instance > 1 or math.isinf(size):
            return mavlink.MAV_RESULT_DENIED
        self.sensor_faults.set(name, kind, size if kind == sensor_faults.WRONG else math.nan,
                               self.latest.get(sensor))
        return mavlink.MAV_RESULT_ACCEPTED

    # --- fault scripts played by the vehicle itself (deterministic timing) ----------------
    def schedule(self, events: Iterable[Event]) -> None:
        self._events = sorted(self._events + list(events), key=lambda e: e.at_us)

    def _play_events(self) -> list[Outgoing]:
        out: list[Outgoing] = []
        while self._events and self._events[0].at_us <= self.t_us:
            event = self._events.pop(0)
            for action in event.actions:
                if isinstance(action, ParamAction):
                    _, error = self.params.set(action.name, action.value)
                else:
                    result = self.inject(action.unit, action.kind, action.instance,
                                         action.param4)
                    error = None if result == mavlink.MAV_RESULT_ACCEPTED else f"result {result}"
                if error:
                    out += self.announce(mavlink.MAV_SEVERITY_ERROR, f"script: {error}")
            self.events_played.append((self.t_us, event.text))
            out += self.announce(mavlink.MAV_SEVERITY_WARNING, f"script: {event.text}")
        return out

    def _param_set(self, link: str, msg, sender) -> list[Outgoing]:
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        i, error = self.params.set(name, float(msg.param_value))
        out = []
        if error:
            out += self.announce(mavlink.MAV_SEVERITY_ERROR, f"param: {error}")
        else:
            out += self.announce(mavlink.MAV_SEVERITY_INFO,
                                 f"{name} = {self.params.value(i):g}; faults: "
                                 f"{self.vehicle.faults.describe()}")
        if i is not None:
            # the value now in force (unchanged after an error), as the protocol asks
            out.insert(0, Outgoing(link, codec.param_value(name, self.params.value(i),
                                                           len(self.params), i)))
        return out

    # --- log -------------------------------------------------------------------------------
    def log_row(self) -> tuple:
        """A row of `log_columns`: the truth, then (with a position source) its latest
        sample (NaN before the first), then (under a sensing profile) the estimate."""
        s = self.vehicle.state
        t_s = s.t_us * 1e-6
        cmd = self.vehicle.command
        extra: tuple = ()
        for name in self._sources:
            r = self.latest.get(name)
            extra += ((r.t_us, *(float(v) for v in r.pos_ned_m)) if r is not None
                      else (math.nan,) * 4)
        if self.estimator is not None:
            e = self.estimate()
            extra += (tuple(float(v) for v in e.pos_ned_m) + tuple(float(v) for v in e.vel_ned_m_s)
                      + tuple(quat_to_euler(*e.quat_wxyz))
                      + (int(e.attitude_aligned), int(e.position_valid),
                         sum(1 << sensor_faults.UNIT_OF[u] for u in self.sensor_faults.active),
                         NAV_FAILURES[self.nav_failure]))
        return ((s.t_us,) + s.x[0:10] + tuple(quat_to_euler(*s.x[6:10])) + s.x[10:13]
                + tuple(cmd.throttle_pct) + tuple(cmd.tilt_rad) + s.motor_pct + s.tilt_rad
                + tuple(m.factor(t_s) for m in self.vehicle.faults.motors)
                + tuple(float(sv.stuck) for sv in self.vehicle.faults.servos)
                + s.wind_ned_m_s + (int(s.armed), int(s.landed), int(s.crashed))
                + (int(s.on_ground), s.touchdown_speed_m_s, math.degrees(s.touchdown_tilt_rad))
                + extra)
