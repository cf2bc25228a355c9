"""The fused filter's C core (trq_offboard/fused_core.c) held to FusedFilter's compiled path
(trq_offboard/fused.py) to the bit: every call given to both, after every step each kept
period's time, x, P and accelerometer decision equal, and the health and every counter equal.
The sequences take every branch of the bookkeeping: late, lost, jittered and repeated samples,
poses older than the history, rejected poses, dead reckoning, held candidates and a position
reset after a dropout, the autopilot's velocity, the queues' limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trq_offboard.fused import (IMU_PENDING_MAX, POSES_MAX, POSES_PENDING_MAX, FusedConfig,
                                FusedFilter)
from trq_offboard.fused_core import FusedCore, fused_filter
from trq_offboard.nmpc import cache

from unit.trq_offboard import test_fused_compiled as sequences
from unit.trq_offboard import test_fused_gnss as gnss

pytestmark = pytest.mark.skipif(cache.find_compiler() is None, reason="no C compiler")


class Twin:
    """A FusedCore and a FusedFilter (compiled kernels) given the same calls; `step` checks
    them equal and returns the reference's health. Attributes read from the reference."""

    def __init__(self, cfg: FusedConfig, g: float, codegen: bool = True) -> None:
        self.core = fused_filter(cfg, g)
        assert isinstance(self.core, FusedCore)
        self.ref = FusedFilter(cfg, g, codegen=True)
        assert self.ref.compiled
        self.steps = 0

    def __getattr__(self, name):
        return getattr(self.ref, name)

    def reset(self, *args, **kwargs) -> None:
        self.core.reset(*args, **kwargs)
        self.ref.reset(*args, **kwargs)
        check_same(self.core, self.ref)

    def add_imu(self, *args) -> None:
        self.core.add_imu(*args)
        self.ref.add_imu(*args)

    def add_pose(self, *args) -> None:
        self.core.add_pose(*args)
        self.ref.add_pose(*args)

    def step(self, *args):
        hc, hr = self.core.step(*args), self.ref.step(*args)
        check_same(self.core, self.ref, hc, hr)
        self.steps += 1
        return hr


def check_same(core: FusedCore, ref: FusedFilter, hc=None, hr=None) -> None:
    if hc is not None:
        assert (math.isnan(hc.test_ratio) and math.isnan(hr.test_ratio)) \
            or hc.test_ratio == hr.test_ratio
        assert (hc.pos_ned_m, hc.vel_ned_m_s, hc.pos_var_m2, hc.dead_reckoning, hc.rejected,
                hc.resets, hc.accel_rejected) == \
               (hr.pos_ned_m, hr.vel_ned_m_s, hr.pos_var_m2, hr.dead_reckoning, hr.rejected,
                hr.resets, hr.accel_rejected)
    assert (core.dropped, core.imu_dropped, core.last_pose_us, core.t_us) == \
           (ref.dropped, ref.imu_dropped, ref.last_pose_us, ref.t_us)
    kept_core, kept_ref = core._periods, ref._periods
    assert len(kept_core) == len(kept_ref)
    for a, b in zip(kept_core, kept_ref):
        assert a.t_us == b.t_us
        assert np.array_equal(a.x, b.x), (a.t_us, a.x - b.x)
        assert np.array_equal(a.P, b.P), a.t_us
        assert a.acc_taken == b.acc_taken and a.covered_s == b.covered_s


def test_the_core_gives_the_compiled_paths_figures_over_the_sequence():
    """The sequence of test_fused_compiled (lost and jittered periods, 0 to 3 IMU messages a
    period, poses late by up to 47 ms, two at once, one rejected, one older than the history,
    a dropout and a pose held after it)."""
    twin = Twin(sequences.CFG, sequences.G)
    twin.reset(0, [0.4, 0.0, -1.0], [0.0, 0.6, 0.2])
    seen = set()
    for t_us, imu, poses, a_known, euler in sequences._sequence(500):
        for t_imu, f_frd in imu:
            twin.add_imu(t_imu, f_frd)
        for pose in poses:
            twin.add_pose(*pose)
        h = twin.step(t_us, a_known, euler)
        seen.add((h.rejected > 0, h.dead_reckoning))
    assert seen >= {(False, False), (True, False), (True, True)}
    assert twin.dropped > 0


def test_the_core_gives_the_compiled_paths_figures_through_a_reset():
    """A second without poses or IMU on a model 4 m/s^2 wrong: the estimate drifts past the
    gate, the poses after it are held as candidates (one a glitch off their line), and
    regain_poses on a line reset the position."""
    twin = Twin(sequences.CFG, sequences.G)
    twin.reset(0, [0.0, 0.0, -1.0], [0.5, 0.0, 0.0])
    rng = np.random.default_rng(11)
    level = np.array([0.0, 0.0, -sequences.G])
    for k in range(1, 301):
        t_us = k * 10_000
        dark = 100 <= k < 200
        if not dark:
            twin.add_imu(t_us - 4000, level + rng.normal(0.0, 0.3, 3))
            twin.add_imu(t_us, level + rng.normal(0.0, 0.3, 3))
            glitch = [0.0, 0.3, 0.0] if k == 201 else [0.0, 0.0, 0.0]
            twin.add_pose(t_us - 10_000, [0.5 * (t_us - 10_000) * 1e-6, 0.0, -1.0]
                          + rng.normal(0.0, 5e-4, 3) + glitch)
        twin.step(t_us, np.array([4.0 if dark else 0.0, 0.0, 0.0]), (0.0, 0.0, 0.1))
    assert twin.resets >= 1 and twin.rejected >= 3


@pytest.mark.parametrize("case", ["outage", "wander", "short history"])
def test_the_core_gives_the_compiled_paths_figures_on_gnss_flights(monkeypatch, case):
    """test_fused_gnss's flights: fixes 110 ms late through a 27-period history, a 4.5 s
    outage (dead reckoning, the fix taken back), the autopilot's
    wandering velocity fused every period, and a history too short for the delay (every fix
    dropped)."""
    monkeypatch.setattr(gnss, "fused_filter", Twin)
    if case == "outage":
        f, rows = gnss._fly(2000, outage=set(range(1001, 1451)))
        assert any(r[2].dead_reckoning for r in rows)
    elif case == "wander":
        wander = gnss._wander(600, seed=3)
        cfg = FusedConfig(**{**gnss.CFG.__dict__, "autopilot_vel_std_m_s": 0.05})
        f, rows = gnss._fly(600, cfg=cfg, vel_error=lambda k: wander[k])
    else:
        cfg = FusedConfig(**{**gnss.CFG.__dict__, "history": 8})
        f, rows = gnss._fly(300, cfg=cfg)
        assert f.dropped > 0
    assert f.steps == len(rows)


def test_the_queues_limits_count_what_they_drop_alike():
    """More IMU messages and poses between two steps than the queues hold, and more poses in
    one period than it holds: the same ones dropped, counted alike."""
    cfg = sequences.CFG
    twin = Twin(cfg, sequences.G)
    twin.reset(0, [0.0, 0.0, -1.0], [0.0, 0.0, 0.0])
    rng = np.random.default_rng(5)
    for t in range(IMU_PENDING_MAX + 6):
        twin.add_imu(100 * (t + 1), rng.normal(0.0, 0.3, 3) + [0.0, 0.0, -sequences.G])
    for t in range(POSES_PENDING_MAX + 3):
        twin.add_pose(100 * (t + 1), rng.normal(0.0, 5e-4, 3) + [0.0, 0.0, -1.0])
    twin.step(10_000, np.zeros(3))
    assert twin.imu_dropped >= 6 and twin.dropped >= 3 + POSES_PENDING_MAX - POSES_MAX
    for t in range(POSES_MAX + 2):
        twin.add_pose(10_000 + 100 * (t + 1), rng.normal(0.0, 5e-4, 3) + [0.0, 0.0, -1.0])
    twin.step(20_000, np.zeros(3))


def test_a_history_past_the_cores_limit_is_refused_by_name():
    with pytest.raises(ValueError, match=r"FusedConfig.history = 300: .*<= 256"):
        FusedConfig(**{**sequences.CFG.__dict__, "history": 300})


def test_without_codegen_the_factory_gives_the_numpy_path():
    f = fused_filter(sequences.CFG, sequences.G, codegen=False)
    assert isinstance(f, FusedFilter) and not f.compiled


def test_a_step_or_health_before_the_first_reset_is_refused_by_name():
    f = fused_filter(sequences.CFG, sequences.G)
    assert f.last_pose_us is None
    with pytest.raises(RuntimeError, match=r"FusedCore\.step before reset"):
        f.step(10_000, np.zeros(3))
    with pytest.raises(RuntimeError, match=r"FusedCore\.health before reset"):
        f.health(0)
