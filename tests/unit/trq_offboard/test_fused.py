"""The fused filter (trq_offboard/fused.py): consistency against a known trajectory with
synthetic measurements, the delayed pose, dead reckoning through a dropout, the controller
file's `estimator` checks, and a closed-loop flight on it (slow)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from pymavlink.dialects.v20 import common as mavlink

from trq_offboard.config import ConfigError, load_controller
from trq_offboard.frames import rotation_ned_frd
from trq_offboard.fused import FusedConfig, HealthReport
from trq_offboard.fused_core import fused_filter
from trq_params.loader import read_yaml

from conftest import ROOT, feed_imu

G = 9.81
H_US = 10_000                 # the control period
CFG = FusedConfig(mocap_std_m=0.0005, accel_std_m_s2=0.3, model_acc_density=0.05,
                  residual_walk_density=0.5, accel_bias_std=0.2,
                  accel_bias_walk_density=0.01, pose_gate=25.0, dropout_s=0.05,
                  imu_rate_hz=125, mocap_rate_hz=100, history=8)


def _truth(t):
    """A smooth 3-D trajectory: (p, v, a) at t s (circle in NE, a slow bob in D)."""
    w, r = 1.5, 0.8
    p = np.array([r * math.cos(w * t), r * math.sin(w * t), -1.0 + 0.1 * math.sin(2 * t)])
    v = np.array([-r * w * math.sin(w * t), r * w * math.cos(w * t), 0.2 * math.cos(2 * t)])
    a = np.array([-r * w * w * math.cos(w * t), -r * w * w * math.sin(w * t),
                  -0.4 * math.sin(2 * t)])
    return p, v, a


def _fly(n_steps, *, seed=0, model_error=(0.3, -0.2, 0.1), bias_frd=(0.15, -0.1, 0.2),
         latency_us=10_000, stamp_arrival=False, drop=(), cfg=CFG, poses=True,
         vel_noise_m_s=0.0):
    """Run the filter over n_steps periods of the known trajectory: the known input the true
    acceleration less a constant model error (the residual a_r's to find), two accelerometer
    samples a period (biased, noisy, attitude level with a yaw), a pose each period
    `latency_us` after its time of validity (stamped with its arrival instead with
    stamp_arrival; none in the periods listed in `drop`), the autopilot's velocity (the truth
    with white noise of vel_noise_m_s). Returns (filter, rows of (t_us,
    error (12), P diagonal (12), health))."""
    rng = np.random.default_rng(seed)
    f = fused_filter(cfg, G)
    p0, v0, _ = _truth(0.0)
    euler = (0.0, 0.0, 0.4)
    f.reset(0, p0, v0, euler_rad=euler)
    rot = rotation_ned_frd(*euler)
    rows = []
    for k in range(1, n_steps + 1):
        t_us = k * H_US
        feed_imu(f, t_us, lambda t: _truth(t)[2], euler, bias_frd, rng, cfg.accel_std_m_s2, G)
        t_pose = t_us - latency_us
        if poses and t_pose >= 0 and k not in drop:
            p = _truth(t_pose * 1e-6)[0] + rng.normal(0.0, cfg.mocap_std_m, 3)
            f.add_pose(t_us if stamp_arrival else t_pose, p)
        # the known input over the period: the truth at its middle, less the model's error
        a_known = _truth((t_us - H_US / 2) * 1e-6)[2] - np.asarray(model_error)
        p, v, _ = _truth(t_us * 1e-6)
        health = f.step(t_us, a_known, euler, v + rng.normal(0.0, vel_noise_m_s or 1.0, 3))
        truth = np.concatenate([p, v, np.asarray(model_error), rot @ np.asarray(bias_frd)])
        rows.append((t_us, f.x - truth, np.diag(f.P).copy(), health))
    return f, rows


def test_errors_stay_within_the_filters_own_variance():
    f, rows = _fly(1500)
    settled = rows[300:]                       # after 3 s
    err = np.array([r[1] for r in settled])
    var = np.array([r[2] for r in settled])
    # position and velocity: the normalised squared errors average about one per state (a
    # consistent filter), and every error is inside five sigma
    for part in (slice(0, 3), slice(3, 6)):
        nees = err[:, part] ** 2 / var[:, part]
        assert 0.2 < nees.mean() < 3.0, nees.mean()
        assert np.all(np.abs(err[:, part]) < 5.0 * np.sqrt(var[:, part]))
    assert np.sqrt(np.mean(err[:, 0:3] ** 2)) < 0.001         # below the pose's 0.5 mm x 2
    # the model's error found in a_r
    assert np.all(np.abs(err[-100:, 6:9].mean(axis=0)) < 0.05)
    assert all(not r[3].dead_reckoning and r[3].test_ratio < 1.0 for r in settled)


def test_the_pose_fused_at_its_time_of_validity_matches_one_on_time():
    """A pose one period old, fused through the history, gives the estimate a filter gets
    when the same pose arrives at its own time (re-propagation is exact)."""
    a = fused_filter(CFG, G)
    b = fused_filter(CFG, G)
    for f in (a, b):
        f.reset(0, [0.0, 0.0, -1.0], [0.5, 0.0, 0.0])
    acc = np.array([0.2, -0.1, 0.05])
    pose = [0.006, 0.001, -0.999]
    a.add_pose(10_000, pose)                  # on time: at the step of its own time
    a.step(10_000, acc)
    b.step(10_000, acc)
    b.add_pose(10_000, pose)                  # one period late
    for f in (a, b):
        f.step(20_000, acc)
    assert np.allclose(a.x, b.x, atol=1e-12) and np.allclose(a.P, b.P, atol=1e-15)
    assert not np.allclose(b.x[0:3], [0.01, 0.0, -1.0])       # the pose moved it


def test_delayed_poses_stamped_at_arrival_bias_the_estimate():
    """Fusing the pose at its time of validity removes the lag a pose taken as new gives:
    on the circle (1.2 m/s) a 10 ms lag is about a centimetre."""
    _, on_time = _fly(600)
    _, late = _fly(600, stamp_arrival=True)
    rms = [np.sqrt(np.mean(np.array([r[1][0:3] for r in rows[200:]]) ** 2))
           for rows in (on_time, late)]
    assert rms[0] < 0.001 and rms[1] > 3.0 * rms[0], rms


def test_dead_reckoning_through_a_dropout_says_so_and_recovers():
    drop = set(range(401, 451))                # half a second without a pose (rows 400-449)
    f, rows = _fly(700, drop=drop)
    report = HealthReport()
    texts = []
    for _, _, _, h in rows:
        texts += [(m.severity, m.text) for m in report.messages(h)]
    flags = np.array([r[3].dead_reckoning for r in rows])
    # said once when it starts (dropout_s after the last pose) and once when the pose is back
    assert texts == [(mavlink.MAV_SEVERITY_WARNING, "fused filter: no pose, dead reckoning"),
                     (mavlink.MAV_SEVERITY_NOTICE, "fused filter: pose back")]
    assert flags[395:400].sum() == 0 and flags[410:450].all() and not flags[460:].any()
    var = np.array([r[3].pos_var_m2 for r in rows])
    assert var[449] > 20.0 * var[399]          # the position's variance grows meanwhile
    err = np.array([np.linalg.norm(r[1][0:3]) for r in rows])
    sig = np.sqrt(var)
    # through the dropout, on the model and the accelerometer: within its own 4 sigma, and
    # millimetres after half a second (the model's error found before)
    assert np.all(err[400:450] < 4.0 * math.sqrt(3.0) * sig[400:450])
    assert err[400:450].max() < 0.01
    assert err[500:].max() < 0.002            # back on the pose


def test_a_pose_far_off_is_rejected_by_the_gate():
    f = fused_filter(CFG, G)
    f.reset(0, [0.0, 0.0, -1.0], [0.0, 0.0, 0.0])
    for k in range(1, 20):
        f.add_pose(k * H_US - H_US, [0.0, 0.0, -1.0])
        f.step(k * H_US, np.zeros(3))
    report = HealthReport()
    assert report.messages(f.health(19 * H_US)) == []
    texts = []
    for k in (20, 21, 22, 24):                   # off two periods running, then once more
        f.add_pose(k * H_US - H_US, [0.5, 0.0, -1.0])      # half a metre off
        h = f.step(k * H_US, np.zeros(3))
        texts += [m.text for m in report.messages(h)]
        if k == 22:
            f.add_pose(22 * H_US, [0.0, 0.0, -1.0])
            texts += [m.text for m in report.messages(f.step(23 * H_US, np.zeros(3)))]
    assert h.rejected == 4 and h.test_ratio > 1.0 and abs(f.x[0]) < 1e-3
    # said once per run of rejections, with the innovation's size against the gate
    assert len(texts) == 2 and all(t.startswith("fused filter: pose rejected (")
                                   and t.endswith(" x gate)") for t in texts)
    assert float(texts[0].split("(")[1].split(" ")[0]) > 1.0
    assert all(len(t) <= 50 for t in texts)             # STATUSTEXT's text field


def test_the_autopilots_velocity_fused_as_a_measurement():
    """autopilot_vel_std_m_s > 0: the velocity handed to `step` is fused (a better velocity
    than the filter's own is taken); 0: it is ignored, whatever it says."""
    err = {}
    for std in (0.0, 0.005):
        cfg = FusedConfig(**{**CFG.__dict__, "autopilot_vel_std_m_s": std})
        _, rows = _fly(800, cfg=cfg, vel_noise_m_s=0.005)
        err[std] = np.sqrt(np.mean(np.array([r[1][3:6] for r in rows[300:]]) ** 2))
    _, ignored = _fly(800, vel_noise_m_s=5.0)         # a wild velocity: not fused by default
    _, plain = _fly(800)
    assert np.allclose([r[1] for r in ignored], [r[1] for r in plain], atol=0.0)
    assert err[0.005] < 0.7 * err[0.0], err


# --- the controller file's `estimator` ----------------------------------------------------------

def _controller(tmp_path, name, estimator):
    src = read_yaml(ROOT / "params/controller/trq_nmpc_eso.yaml")
    src["extends"] = str(ROOT / "params/controller/nmpc.yaml")
    src["vehicle"] = str(ROOT / "params/vehicle/trq.yaml")
    if estimator is not None:
        src["estimator"] = estimator
    path = tmp_path / name
    path.write_text(yaml.safe_dump(src))
    return path


def test_the_estimator_defaults_to_the_autopilot_and_loads_fused(tmp_path):
    assert load_controller(_controller(tmp_path, "a.yaml", None)).fused is None
    assert load_controller(_controller(tmp_path, "b.yaml", {"kind": "autopilot"})).fused is None
    cfg = load_controller(ROOT / "params/controller/trq_nmpc_eso_fused.yaml")
    assert cfg.fused is not None and cfg.fused.imu_rate_hz <= 200
    assert cfg.fused.disturbance_input
    assert load_controller(ROOT / "params/controller/trq_nmpc_eso.yaml").fused is None


@pytest.mark.parametrize("estimator, match", [
    ({"kind": "kalman"}, r"c\.yaml.*estimator\.kind.*kalman"),
    ({"kind": "fused", "imu_rate_hz": 250}, r"c\.yaml.*estimator\.imu_rate_hz.*250.*200"),
    ({"kind": "autopilot", "accel_std_m_s2": 0.3},
     r"c\.yaml.*estimator\.accel_std_m_s2.*kind: fused"),
    ({"kind": "fused", "dropout_s": 0.001}, r"c\.yaml.*estimator\.dropout_s.*control period"),
    ({"kind": "fused", "mocap_std_m": -1.0}, r"c\.yaml.*estimator\.mocap_std_m"),
    ({"kind": "fused", "history": 1}, r"c\.yaml.*estimator\.history"),
    ({"kind": "fused", "disturbance_input": "eso"}, r"c\.yaml.*estimator\.disturbance_input"),
    ({"kind": "fused", "gain": 1.0}, r"c\.yaml.*estimator\.gain"),
    ({"kind": "fused", "autopilot_vel_std_m_s": -0.1},
     r"c\.yaml.*estimator\.autopilot_vel_std_m_s"),
])
def test_estimator_errors_name_file_key_and_value(tmp_path, estimator, match):
    with pytest.raises(ConfigError, match=match):
        load_controller(_controller(tmp_path, "c.yaml", estimator))


# --- a closed-loop flight on the filter -----------------------------------------------------------

@pytest.mark.slow
def test_a_mocap_flight_on_the_fused_filter(tmp_path):
    """trq_nmpc_eso_fused flies a short hover under mocap in one process: the controller asks
    for the pose and the IMU, flies on the filter's estimate (near the truth), and logs its
    health."""
    from trq_lab import harness
    from trq_lab.metrics import read_csv
    reference = {"kind": "hover", "altitude_m": 1.0, "climb_speed_m_s": 0.8, "hold_s": 0.5,
                 "duration_s": 1.5, "ramp_s": 0.5}
    cfg = load_controller(harness.prepare_controller("trq_nmpc_eso_fused", reference, tmp_path))
    sim = harness.sim_params(cfg.vehicle.file, cfg.control_rate_hz, seed=3, sensing="mocap")
    res = harness.fly_inprocess(cfg, sim, out_dir=tmp_path / "fused", timeout_s=12.0)
    assert res.status in ("done", "not landed"), res.summary
    _, truth = read_csv(res.flight_csv)
    _, steps = read_csv(res.controller_csv)
    assert truth["pos_d_m"].min() < -0.5                       # it flew
    ratio, var = steps["est_test_ratio"], steps["est_pos_var_m2"]
    assert np.isfinite(var).all() and np.isfinite(ratio[10:]).all()   # poses from the start
    flying = (steps["phase"] != "takeoff") & (steps["phase"] != "land") & (steps["t_s"] > 1.0)
    assert not steps["est_dead_reckoning"][flying].any()
    # the estimate it flew on, against the truth, in the air: millimetres
    at = np.minimum(np.searchsorted(truth["t_us"], steps["stamp_us"]), len(truth["t_us"]) - 1)
    for a in "ned":
        err = steps[f"pos_{a}_m"][flying] - truth[f"pos_{a}_m"][at][flying]
        assert np.max(np.abs(err)) < 0.005, a



def test_without_a_pose_the_fused_controller_flies_the_state_as_it_came():
    """Before its first pose (and under `truth`, which sends no raw sensor) the fused filter has
    not started: the observer runs on the state as it came, as on the autopilot's estimate, bit
    for bit, IMU samples or not; the first pose starts the filter."""
    import dataclasses

    from trq_offboard.controller import Controller
    from trq_offboard.nmpc.base import Solver
    from trq_offboard.records import (ReferenceSample, SensorSamples, SolveInfo, SolveStatus,
                                      StateEstimate)
    from trq_offboard.reference import ConstantReference

    class Hold(Solver):                    # no NMPC (seconds to build): the plan holds u
        def __init__(self, u, n):
            self.u, self.n = np.asarray(u, float), n
            self.ocp = type("NoOcp", (), {"n_lag": 0, "set_throttle_scale": lambda s, e: None})()

        def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
            return (np.tile(self.u, (self.n, 1)), np.tile(x0, (self.n + 1, 1)),
                    SolveInfo(SolveStatus.OK, 1, 1e-4, 0.0))

    ref = ConstantReference(ReferenceSample((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), 0.0))
    ctls = []
    for name in ("trq_nmpc_eso.yaml", "trq_nmpc_eso_fused.yaml"):
        cfg = dataclasses.replace(load_controller(ROOT / "params" / "controller" / name),
                                  effectiveness=None)
        probe = Controller(cfg, solver=Hold(np.zeros(8), cfg.horizon_steps))
        ctls.append(Controller(cfg, solver=Hold(probe.u_trim, cfg.horizon_steps)))
    plain, fused = ctls
    for k in range(1, 30):
        state = StateEstimate((0.01 * k, 0.0, -2.0), (0.1 * math.sin(k), 0.05, 0.0),
                              (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        imu = SensorSamples(10_000 * k, ((10_000 * k, (0.0, 0.0, -9.81)),), ())
        plain.step(0.01 * k, state, None, ref)
        fused.step(0.01 * k, state, None, ref, imu)
        np.testing.assert_array_equal(fused.eso.z, plain.eso.z)
    assert fused._health is None and not fused._fused_on
    pose = SensorSamples(300_000, (), ((295_000, (0.3, 0.0, -2.0)),))
    fused.step(0.3, state, None, ref, pose)
    assert fused._fused_on and fused._health is not None


def test_the_motors_share_handed_to_the_filter_is_bounded_as_the_observers_d():
    """At a spool-up on the ground the effectiveness observer can read the ground's reaction as
    a motor deficit far beyond any motor's (docs/decisions/2026-12-05-fused-filter-motors.md,
    the addendum): the share the filter takes is bounded by the observer's own clamp, its
    direction kept."""
    from trq_offboard.controller import Controller
    from trq_offboard.nmpc.base import Solver
    from trq_offboard.records import ReferenceSample, SolveInfo, SolveStatus, StateEstimate
    from trq_offboard.reference import ConstantReference

    class Hold(Solver):
        def __init__(self, n):
            self.n = n
            self.ocp = type("NoOcp", (), {"n_lag": 0, "set_throttle_scale": lambda s, e: None})()

        def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
            return (np.tile(self.u, (self.n, 1)), np.tile(x0, (self.n + 1, 1)),
                    SolveInfo(SolveStatus.OK, 1, 1e-4, 0.0))

    cfg = load_controller(ROOT / "params" / "controller" / "trq_nmpc_eso_fused.yaml")
    ctl = Controller(cfg, solver=Hold(cfg.horizon_steps))
    ctl.solver.u = ctl.u_trim
    ctl._period = None               # the call-by-call period, whose motors.step is patched
    real = ctl.motors.step
    huge = np.array([-300.0, 400.0, -28000.0, 0.0, 0.0, 0.0])

    def step(x, d, *args):
        out = real(x, d, *args)
        return (out[0] - huge,) + tuple(out[1:])
    ctl.motors.step = step
    ref = ConstantReference(ReferenceSample((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), 0.0))
    state = StateEstimate((0.0, 0.0, -2.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    for k in range(1, 4):
        ctl.step(0.01 * k, state, None, ref)
        share = ctl._motor_share
        lim = cfg.eso.max_disturbance[0]
        assert np.linalg.norm(share) == pytest.approx(lim)
        assert np.dot(share, huge[0:3]) / (lim * np.linalg.norm(huge[0:3])) > 0.999
