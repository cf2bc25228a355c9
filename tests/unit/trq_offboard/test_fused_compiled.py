"""The fused filter's compiled kernels held to its NumPy path (trq_offboard/fused.py): the same
sequence of samples through both, every period's x and P equal to a stated tolerance, every
decision (gate, drop, dead reckoning) the same.

The tolerance: each difference at most 1e-9 of the filter's own standard deviation (x_i against
sqrt(P_ii), P_ij against sqrt(P_ii P_jj)). The two paths do the same arithmetic in a different
order: NumPy's matrix products go through BLAS (its own summation order, over the structural
zeros too) and its inverse and solve through LAPACK's LU, the generated C sums each entry in the
SX expression's order, skips the zeros of F and of the measurement matrices and inverts S by
CasADi's own formula. Each period's results then differ in their last bits, which the filter (a
stable one) carries on without growing: the differences seen stay orders of magnitude inside
the tolerance, and a wrong term in either path (a missing dt, a wrong block of Q) moves the
estimate by much more than a standard deviation's billionth."""

from __future__ import annotations

import numpy as np
import pytest

from trq_offboard import fused
from trq_offboard.frames import rotation_ned_frd
from trq_offboard.fused import FusedConfig, FusedFilter
from trq_offboard.nmpc import cache

G = 9.81
CFG = FusedConfig(mocap_std_m=0.0005, accel_std_m_s2=0.3, model_acc_density=0.05,
                  residual_walk_density=0.5, accel_bias_std=0.2,
                  accel_bias_walk_density=0.01, pose_gate=25.0, dropout_s=0.05,
                  imu_rate_hz=125, mocap_rate_hz=100, history=8)
TOL = 1e-9                     # of the filter's own standard deviation (module docstring)

needs_compiler = pytest.mark.skipif(cache.find_compiler() is None, reason="no C compiler")


def _position(t: float) -> np.ndarray:
    return np.array([0.4 * np.cos(1.5 * t), 0.4 * np.sin(1.5 * t), -1.0 + 0.1 * np.sin(2 * t)])


def _sequence(n_periods: int, seed: int = 7):
    """A recorded-like stream, period by period: (t_us, IMU samples [(f_frd, euler)], poses
    [(t_us, pos)], a_known). Mostly 10 ms periods, some lost (20 or 30 ms) or jittered; 0 to 3
    IMU samples a period; poses in order, 0 to 47 ms late (at a period's end or between two),
    sometimes two at once, one older than the history; a pose half a metre off at period 150
    (rejected);
    no pose in periods 300-339 (dead reckoning), then one 10 cm off (past the gate: held,
    after a dropout)."""
    rng = np.random.default_rng(seed)
    t_us, last_pose, rows = 0, 0, []
    for k in range(1, n_periods + 1):
        t_us += int(rng.choice([10_000] * 12 + [20_000, 30_000, 9_000, 11_000]))
        t = t_us * 1e-6
        acc = np.array([-0.9 * np.cos(1.5 * t), -0.9 * np.sin(1.5 * t), -0.4 * np.sin(2 * t)])
        pos = _position(t)
        euler = (0.02 * np.sin(t), -0.03 * np.cos(t), 0.4 + 0.1 * t)
        stamps = sorted(set(int(v) for v in t_us - rng.integers(0, 12_000, int(rng.integers(0, 4)))))
        imu = [(s, rotation_ned_frd(*euler).T @ (acc - [0.0, 0.0, G])
                + [0.15, -0.1, 0.2] + rng.normal(0.0, 0.3, 3)) for s in stamps]
        poses = []
        if not 300 <= k < 340:
            for _ in range(1 if rng.random() < 0.9 else 2):     # in order of their time
                late = int(rng.choice([0, 10_000, 10_000, 10_000, 13_000, 25_000, 47_000]))
                t_pose = max(t_us - late, last_pose + 1000)
                if t_pose <= t_us:
                    poses.append((t_pose, _position(t_pose * 1e-6) + rng.normal(0.0, 5e-4, 3)))
                    last_pose = t_pose
        if k == 150:
            poses.append((t_us - 10_000, pos + [0.5, 0.0, 0.0]))
        if k == 340:
            poses = [(t_us - 10_000, _position(t - 0.01) + [0.1, 0.0, 0.0])]
        if k == 200:
            poses.append((t_us - 200_000, pos))             # older than the history
        a_known = acc - [0.3, -0.2, 0.1] + rng.normal(0.0, 0.05, 3)
        rows.append((t_us, imu, poses, a_known, euler))
    return rows


def _start(codegen: bool) -> FusedFilter:
    f = FusedFilter(CFG, G, codegen=codegen)
    f.reset(0, [0.4, 0.0, -1.0], [0.0, 0.6, 0.2])
    return f


def _fed_in_step(filters, sequence):
    """Each step of the sequence given to every filter (its IMU samples, its poses, then the
    step): (t_us, the filters' health records) a step."""
    for t_us, imu, poses, a_known, euler in sequence:
        health = []
        for f in filters:
            for t_imu, f_frd in imu:
                f.add_imu(t_imu, f_frd)
            for pose in poses:
                f.add_pose(*pose)
            health.append(f.step(t_us, a_known, euler))
        yield t_us, health


@needs_compiler
def test_the_compiled_kernels_equal_the_numpy_path_over_a_sequence():
    c, p = _start(True), _start(False)
    assert c.compiled and not p.compiled
    flags = []
    for t_us, (hc, hp) in _fed_in_step((c, p), _sequence(500)):
        assert (hc.dead_reckoning, hc.rejected, c.dropped, c.last_pose_us) == \
            (hp.dead_reckoning, hp.rejected, p.dropped, p.last_pose_us), t_us
        assert hc.test_ratio == pytest.approx(hp.test_ratio, rel=1e-9, abs=1e-12)
        sd = np.sqrt(np.diag(p.P))
        assert np.all(np.abs(c.x - p.x) <= TOL * sd), (t_us, (c.x - p.x) / sd)
        assert np.all(np.abs(c.P - p.P) <= TOL * np.outer(sd, sd)), t_us
        # every kept period's posterior, which the next delayed pose starts from
        for a, b in zip(c._periods, p._periods):
            assert a.t_us == b.t_us
            sd = np.sqrt(np.diag(b.P))
            assert np.all(np.abs(a.x - b.x) <= TOL * sd)
            assert np.all(np.abs(a.P - b.P) <= TOL * np.outer(sd, sd))
        flags.append((hp.rejected, hp.dead_reckoning, p.dropped, hp.test_ratio))
    # the sequence did what it says: a rejected pose, a dropout with dead reckoning and the pose
    # 10 cm off taken after it, a pose dropped as too old
    rejected, dead, dropped, ratio = (np.array(v) for v in zip(*flags))
    assert rejected[149] - rejected[148] == 1 and rejected[148] == 0
    assert dead[310:339].all() and not dead[345:].any()
    assert ratio[339] > 1.0 and rejected[339] == rejected[338] + 1     # held, not taken
    assert dropped[199] > dropped[198]


@needs_compiler
def test_the_two_period_kernel_gives_two_single_calls_figures_to_the_bit():
    """The usual step (the period before run again, then the new one) in one call of the
    two-period kernel: every period's x and P, and every decision, exactly those of the same
    filter running each period by itself, over the sequence (which takes both paths, and the
    way back when a new pose is past its gate)."""
    two, one = _start(True), _start(True)
    one._fn2 = None                      # each period by itself
    calls = {"two": 0, "taken": 0}
    inner = two._run_two

    def counted(k):
        calls["two"] += 1
        done = inner(k)
        calls["taken"] += done
        return done
    two._run_two = counted
    for t_us, health in _fed_in_step((two, one), _sequence(500)):
        assert health[0] == health[1] or (np.isnan(health[0].test_ratio)
                                          and np.isnan(health[1].test_ratio)), t_us
        assert two.accel_rejected == one.accel_rejected and two.dropped == one.dropped
        for a, b in zip(two._periods, one._periods):
            assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P), t_us
            assert a.acc_taken == b.acc_taken
    assert calls["taken"] > 100 and calls["two"] > calls["taken"], calls


@needs_compiler
def test_the_kernels_do_not_change_a_period_without_samples():
    """A period with neither IMU nor pose is the prediction alone, in both paths; a step to
    the same time changes nothing."""
    c, p = _start(True), _start(False)
    for f in (c, p):
        f.step(10_000, np.array([0.1, 0.0, -0.2]))
        x, P = f.x.copy(), f.P.copy()
        f.step(10_000, np.array([5.0, 5.0, 5.0]))
        assert np.array_equal(f.x, x) and np.array_equal(f.P, P)
    sd = np.sqrt(np.diag(p.P))
    assert np.all(np.abs(c.x - p.x) <= TOL * sd)
    assert np.all(np.abs(c.P - p.P) <= TOL * np.outer(sd, sd))


def test_codegen_off_or_no_compiler_runs_the_numpy_path(monkeypatch):
    assert not FusedFilter(CFG, G, codegen=False).compiled
    monkeypatch.setattr(cache, "find_compiler", lambda: None)
    other = FusedConfig(**{**CFG.__dict__, "pose_gate": 24.0})   # not built yet in this process
    f = FusedFilter(other, G)
    assert not f.compiled
    f.reset(0, [0.0, 0.0, -1.0], [0.0, 0.0, 0.0])
    f.add_pose(0, [0.001, 0.0, -1.0])
    assert np.isfinite(f.step(10_000, np.zeros(3)).test_ratio)
