"""trq-latency-bound: the optimal flight after a fault, given a reaction latency (the lower
bound quoted for the lossy-link scenario), on a synthetic onset: a hover with no wind."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from conftest import PARAMS, cli

from trq_lab.analysis import latency_bound as lb
from trq_offboard.allocation import Allocator
from trq_offboard.config import load_vehicle_model

TRQ = PARAMS / "vehicle" / "trq.yaml"


QUAD = PARAMS / "vehicle" / "quad.yaml"


def hover_onset(factors, vehicle=TRQ) -> lb.Onset:
    vm = load_vehicle_model(vehicle)
    trim = Allocator(vm).command_vector(Allocator(vm).hover())
    if vm.tilt_locked:                      # the onset carries tilts (all zero) and throttles
        trim = np.concatenate([np.zeros(4), trim])
    x0 = np.zeros(12)
    x0[2] = -2.0
    t = np.arange(0, 201) * 0.01
    flown = np.tile(np.concatenate([x0, trim]), (2, 1))
    return lb.Onset(t0_us=12_000_000, x0=x0, y0=trim.copy(), cmd0=trim.copy(),
                    factors=np.asarray(factors, float), wind=np.zeros(3), ref_t=t,
                    ref_pos=np.tile(x0[0:3], (len(t), 1)), ref_yaw=np.zeros(len(t)),
                    flown_t=np.array([0.0, 10.0]), flown_x=flown,
                    flown_err=np.zeros(len(t) - 1))


def run(onset, latency_s, horizon_s=0.6):
    return lb.bound(onset, TRQ, latency_s, horizon_s, math.radians(5.0))


@pytest.mark.slow
def test_no_fault_the_hover_trim_holds():
    r = run(hover_onset([1.0, 1.0, 1.0, 1.0]), 0.0)
    assert r["status"] == "optimal"
    assert r["rmse_lower_bound_m"] < 1e-3, r


@pytest.fixture(scope="module")
def half_motor():
    onset = hover_onset([0.5, 1.0, 1.0, 1.0])
    return {L: run(onset, L) for L in (0.0, 0.06)}


@pytest.mark.slow
def test_a_fault_seen_at_once_costs_little(half_motor):
    r = half_motor[0.0]
    assert r["status"] == "optimal"
    assert r["rmse_lower_bound_m"] < 5e-3, r
    # the yaw constraint holds: the plan keeps its heading
    X = r["states"]
    assert np.all(np.abs(X[8]) <= math.radians(5.0) + 1e-6)


@pytest.mark.slow
def test_latency_costs_position(half_motor):
    now, late = half_motor[0.0], half_motor[0.06]
    assert late["status"] == "optimal"
    # frozen for 60 ms, the weak motor tips the vehicle before any answer
    assert late["max_tilt_deg"] > 3.0
    assert late["rmse_lower_bound_m"] > 2.0 * now["rmse_lower_bound_m"]
    assert late["max_err_m"] > now["max_err_m"]


@pytest.mark.slow
def test_the_fixed_rotor_quad_cannot_hold_yaw_on_half_a_motor(half_motor):
    """As trq-envelope finds (no trim): with yaw held, the quad's best answer tips over."""
    onset = hover_onset([0.5, 1.0, 1.0, 1.0], QUAD)
    r = lb.bound(onset, QUAD, 0.0, 0.6, math.radians(5.0))
    assert np.allclose(r["states"][12:16], 0.0)                     # its tilts stay at zero
    assert r["max_tilt_deg"] > 30.0
    assert r["rmse_lower_bound_m"] > 100.0 * half_motor[0.0]["rmse_lower_bound_m"]
    assert r["rmse_lower_bound_m"] > 0.01


@pytest.mark.slow
def test_frozen_outputs_follow_the_plants_lag(half_motor):
    """During the latency the faulted motor's output decays towards factor x command with the
    motor's time constant (rate limited), as the plant's does."""
    vm = load_vehicle_model(TRQ)
    onset = hover_onset([0.5, 1.0, 1.0, 1.0])
    r = lb.bound(onset, TRQ, 0.5, 0.52, math.radians(5.0))     # frozen for 50 steps
    y1 = r["frozen"][:, 16]
    target = 0.5 * onset.cmd0[4]
    tau = vm.motor_time_constant_s
    expect = target + (onset.y0[4] - target) * np.exp(-np.arange(len(y1)) * 0.01 / tau)
    # the plant's exact lag at every sample (its rate limit, 1500 %/s, is not reached:
    # (77 - 38) / 0.03 = 1300 %/s)
    assert np.max(np.abs(y1 - expect)) < 1e-6
    assert abs(y1[-1] - target) < 0.01


def test_bad_latency_is_a_usage_error(tmp_path, capsys):
    """In the command's own process (its main: the exit code and stderr the installed command
    gives; the subprocess path is the next test's)."""
    assert lb.main([str(tmp_path), "--latency-ms", "10,abc"]) == 2
    assert "--latency-ms" in capsys.readouterr().err
    assert lb.main([str(tmp_path), "--latency-ms", "5000", "--horizon-s", "2"]) == 2
    assert "[0, 2000) ms" in capsys.readouterr().err
    assert lb.main([str(tmp_path), "--step-ms", "3"]) == 2
    err = capsys.readouterr().err
    assert "--step-ms 3" in err and "divisor" in err


def test_a_flight_without_fault_is_refused(tmp_path):
    r = subprocess.run([*cli("trq-latency-bound"), str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "flight.csv" in r.stderr


def test_frozen_flight_matches_the_plant():
    """The optimiser's model (10 ms RK4, outputs linear within a step) flown with the frozen
    commands against the plant's own 1 ms update (lags, rate limits, RK4, drag on the airspeed),
    with the fault and an 8 m/s wind, for 0.15 s: the weak motor tips the vehicle."""
    from sil_vehicle.config import load_vehicle
    from sil_vehicle.dynamics.actuators import first_order_step, lag_factor
    from sil_vehicle.dynamics.rigid_body import rk4_step
    from sil_vehicle.dynamics.rotors import body_wrench
    from sil_vehicle.frames import euler_to_quat, quat_to_euler

    vp = load_vehicle(TRQ)
    onset = hover_onset([0.5, 1.0, 1.0, 1.0])
    onset = lb.Onset(**{**onset.__dict__, "wind": np.array([-8.0, 0.0, 0.0])})
    r = lb.bound(onset, TRQ, 0.15, 0.17, math.radians(5.0))
    frozen = r["frozen"]                       # 16 samples, 10 ms apart
    x = (*onset.x0[0:6], *euler_to_quat(*onset.x0[6:9]), *onset.x0[9:12])
    y = list(onset.y0)
    target = list(onset.cmd0[0:4]) + [c * f for c, f in zip(onset.cmd0[4:], onset.factors)]
    fm, fs = lag_factor(vp.motor_time_constant_s, 1e-3), lag_factor(vp.servo_time_constant_s, 1e-3)
    for _ in range(150):
        y = ([first_order_step(a, t, fs, vp.servo_rate_limit_rad_s * 1e-3, vp.tilt_min_rad,
                               vp.tilt_max_rad) for a, t in zip(y[0:4], target[0:4])]
             + [first_order_step(z, t, fm, vp.motor_rate_limit_pct_s * 1e-3, 0.0, 100.0)
                for z, t in zip(y[4:8], target[4:8])])
        x = rk4_step(x, 1e-3, body_wrench(y[4:8], y[0:4], vp), (-8.0, 0.0, 0.0), vp.mass_kg,
                     vp.inertia_kg_m2, vp.gravity_m_s2, vp.drag_N_s2_m2)
    euler = np.array(quat_to_euler(*x[6:10]))
    end = frozen[-1]
    assert np.degrees(np.abs(euler[0:2])).max() > 10.0          # it did tip
    np.testing.assert_allclose(end[0:3], x[0:3], atol=5e-3)     # m
    np.testing.assert_allclose(end[3:6], x[3:6], atol=2e-2)     # m/s
    np.testing.assert_allclose(end[6:9], euler, atol=math.radians(0.5))
    np.testing.assert_allclose(end[12:20], y, atol=1e-6)


def write_logs(d, factors, stuck_servo=None):
    """A minimal pair of logs (every column the bound reads): 2 s of hover, 100 Hz."""
    from sil_vehicle.sitl import LOG_COLUMNS
    n = len(factors)
    cols = {c: np.zeros(n) for c in LOG_COLUMNS}
    cols["t_us"] = np.arange(n) * 10_000 + 10_000
    cols["pos_d_m"][:] = -2.0
    for i in range(4):
        cols[f"motor{i + 1}_factor"] = np.asarray(factors, float)[:, i]
        cols[f"out_throttle{i + 1}_pct"][:] = cols[f"cmd_throttle{i + 1}_pct"][:] = 77.0
    if stuck_servo is not None:
        cols[f"servo{stuck_servo}_stuck"][n // 2:] = 1.0
    with open(d / "flight.csv", "w", encoding="ascii") as f:
        f.write(f"# vehicle_file: {TRQ}\n# physics_rate_hz: 1000\n")
        f.write(",".join(LOG_COLUMNS) + "\n")
        for k in range(n):
            f.write(",".join(str(int(cols[c][k])) if c == "t_us" else repr(float(cols[c][k]))
                             for c in LOG_COLUMNS) + "\n")
    with open(d / "controller.csv", "w", encoding="ascii") as f:
        f.write("stamp_us,phase,ref_pos_n_m,ref_pos_e_m,ref_pos_d_m,ref_yaw_rad,solve_ms\n")
        for k in range(n):
            f.write(f"{int(cols['t_us'][k])},hold,0.0,0.0,-2.0,0.0,1.0\n")


def test_logs_of_a_constant_motor_fault_are_read(tmp_path):
    fac = [[1.0] * 4] * 100 + [[0.5, 1.0, 1.0, 1.0]] * 100
    write_logs(tmp_path, fac)
    onset = lb.read_onset(tmp_path)
    assert onset.t0_us == 1_000_000 and onset.n_after == 101
    np.testing.assert_allclose(onset.factors, [0.5, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(onset.x0[2], -2.0)


@pytest.mark.parametrize("case, words", [
    ("varying", "change after the onset"),
    ("stuck", "servo3_stuck"),
    ("none", "no motor fault"),
])
def test_logs_the_bound_cannot_take_are_refused(tmp_path, case, words):
    healthy = [[1.0] * 4] * 100
    if case == "varying":
        fac = healthy + [[0.5, 1.0, 1.0, 1.0]] * 50 + [[0.7, 1.0, 1.0, 1.0]] * 50
    else:
        fac = healthy + ([[0.5, 1.0, 1.0, 1.0]] * 100 if case == "stuck" else healthy)
    write_logs(tmp_path, fac, stuck_servo=3 if case == "stuck" else None)
    with pytest.raises(lb.LogError, match=words):
        lb.read_onset(tmp_path)
    r = subprocess.run([*cli("trq-latency-bound"), str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and words in r.stderr


# ------------------------------------------------------------------------------------------
# --objective tilt: a motor lost whole


@pytest.fixture(scope="module")
def lost_motor():
    onset = hover_onset([0.0, 1.0, 1.0, 1.0])
    return onset, {L: lb.tilt_bound(onset, TRQ, L, 0.5) for L in (0.0, 0.03, 0.06)}


@pytest.mark.slow
def test_a_lost_motor_seen_at_once_is_answered_nearly_level(lost_motor):
    _, r = lost_motor
    assert r[0.0]["status"] == "optimal"
    assert r[0.0]["max_tilt_deg"] < 10.0, r[0.0]["max_tilt_deg"]
    # the thrust tilt it reports is the one of its own attitudes
    X = r[0.0]["states"]
    np.testing.assert_allclose(r[0.0]["tilt_deg"][1:], lb.euler_tilt_deg(X[6, 1:], X[7, 1:]))


@pytest.mark.slow
def test_each_millisecond_of_latency_tips_a_lost_motor_further(lost_motor):
    _, r = lost_motor
    tilts = [r[L]["max_tilt_deg"] for L in (0.0, 0.03, 0.06)]
    assert all(r[L]["status"] == "optimal" for L in r)
    assert tilts[0] < tilts[1] < tilts[2], tilts
    assert tilts[2] > 3.0 * tilts[0] + 20.0, tilts
    # the answer cannot act before the latency: the peak comes after it
    assert r[0.06]["peak_s"] > 0.06


@pytest.mark.slow
def test_the_dead_motors_output_runs_down_as_the_plants(lost_motor):
    """A motor at 0 % is no decision: its output in the free part follows the plant's own
    update from where the frozen part left it (rate limited, then the lag), whatever the
    optimiser would prefer."""
    onset, r = lost_motor
    vm = load_vehicle_model(TRQ)
    X = r[0.0]["states"]
    y = [float(onset.y0[4])]
    f = lb.lag_factor(vm.motor_time_constant_s, 1e-3)
    for _ in range(X.shape[1] - 1):
        v = y[-1]
        for _ in range(10):
            v = lb.first_order_step(v, 0.0, f, vm.motor_rate_limit_pct_s * 1e-3, 0.0, 100.0)
        y.append(v)
    np.testing.assert_allclose(X[16], y, atol=1e-6)
    assert X[16, 3] < onset.y0[4] - 20.0        # it fell at the rate limit, not at once


@pytest.mark.slow
def test_no_fault_no_tilt():
    r = lb.tilt_bound(hover_onset([1.0, 1.0, 1.0, 1.0]), TRQ, 0.0, 0.3)
    assert r["status"] == "optimal" and r["max_tilt_deg"] < 0.5


@pytest.mark.slow
def test_the_tilt_objective_from_the_command_line(tmp_path):
    write_logs(tmp_path, [[1.0] * 4] * 100 + [[0.0, 1.0, 1.0, 1.0]] * 100)
    r = subprocess.run([*cli("trq-latency-bound"), str(tmp_path), "--objective", "tilt",
                        "--latency-ms", "0,40", "--horizon-s", "0.4"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rows = [ln for ln in r.stdout.splitlines() if ln.startswith("| 0 ") or ln.startswith("| 40 ")]
    assert len(rows) == 2, r.stdout
    bound = [float(ln.split("|")[2]) for ln in rows]
    assert bound[0] < bound[1], r.stdout
    assert "largest tilt of the thrust axis in the first 0.4 s" in r.stdout
