"""Reference trajectories: continuity, velocity = d position / dt, phases and done(t)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from trq_offboard.config import load_controller
from trq_offboard.reference import CRAWL_RAMP_S, LAND_BELOW_M, LAND_CRAWL_M_S, Reference

from conftest import ROOT

CFG = load_controller(ROOT / "params/controller/trq_nmpc.yaml")


@pytest.mark.parametrize("kind", ["hover", "circle", "helix", "figure8", "step"])
def test_plan_is_smooth_and_consistent(kind):
    rc = replace(CFG.reference, kind=kind)
    start = np.array([1.0, -2.0, 0.0])
    ref = Reference(rc, start, 0.3, t0_s=5.0)
    s0 = ref.sample(5.0)
    np.testing.assert_allclose(s0.pos_ned_m, start, atol=1e-12)
    assert s0.phase == "takeoff" and s0.yaw_rad == 0.3
    np.testing.assert_allclose(ref.sample(ref.t1).pos_ned_m, start + [0, 0, -rc.altitude_m],
                               atol=1e-12)
    ts = np.arange(5.0, ref.end_time_s + 2.0, 0.01)
    pos = np.array([ref.sample(t).pos_ned_m for t in ts])
    vel = np.array([ref.sample(t).vel_ned_m_s for t in ts])
    fd = np.gradient(pos, ts, axis=0)
    jumps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    if kind != "step":
        assert jumps.max() < 0.02                                  # continuous
        np.testing.assert_allclose(vel[1:-1], fd[1:-1], atol=2e-3)  # velocity consistent
    speed = np.linalg.norm(vel, axis=1)
    assert speed.max() < 1.0                                       # gentle
    acc = np.gradient(vel, ts, axis=0)
    assert np.linalg.norm(acc, axis=1).max() < 1.0
    # landing ends below the start point, then goes on down at a crawl until the ground stops it
    end = ref.sample(ref.end_time_s)
    np.testing.assert_allclose(end.pos_ned_m, [pos[-1][0], pos[-1][1], start[2] + LAND_BELOW_M])
    assert not ref.done(ref.end_time_s - 0.01) and ref.done(ref.end_time_s)
    later = ref.sample(ref.end_time_s + CRAWL_RAMP_S + 1.0)
    assert later.phase == "landed" and later.vel_ned_m_s[2] == pytest.approx(LAND_CRAWL_M_S)
    assert later.pos_ned_m[2] == pytest.approx(
        start[2] + LAND_BELOW_M + LAND_CRAWL_M_S * (CRAWL_RAMP_S / 2 + 1.0))


def test_no_landing_holds_forever():
    ref = Reference(replace(CFG.reference, kind="circle", land=False), [0, 0, 0])
    end = ref.sample(ref.t4 + 100.0)
    assert end.phase == "hold" and ref.done(ref.t4) and not ref.done(ref.t4 - 0.01)
    np.testing.assert_allclose(end.vel_ned_m_s, 0.0)


def test_pure_function_of_time():
    ref = Reference(CFG.reference, [0, 0, 0])
    a = [ref.sample(t) for t in (3.0, 12.5, 20.0)]
    b = [ref.sample(t) for t in (20.0, 12.5, 3.0)][::-1]
    assert a == b


@pytest.mark.parametrize("kind", ["hover", "circle", "helix", "figure8", "step"])
def test_grid_equals_samples(kind):
    """grid() (what the controller samples twice a step) gives what sample() gives, on a grid
    across every phase, and a ConstantReference's grid is its one sample."""
    from trq_offboard.reference import ConstantReference
    ref = Reference(replace(CFG.reference, kind=kind), [1.0, -2.0, 0.0], 0.3, t0_s=5.0)
    for t0 in np.arange(4.0, ref.end_time_s + 1.0, 0.37):
        pv, yaw = ref.grid(t0, 0.05, 21)
        for k in range(21):
            s = ref.sample(t0 + k * 0.05)
            assert tuple(pv[k]) == s.pos_ned_m + s.vel_ned_m_s and yaw[k] == s.yaw_rad
            assert all(type(v) is float for v in s.pos_ned_m + s.vel_ned_m_s)
    for t in (ref.t1, ref.t2, ref.t3, ref.t4, ref.t5):              # at the phase boundaries
        pv, _ = ref.grid(t - 0.05, 0.05, 3)
        for k in range(3):
            s = ref.sample(t - 0.05 + k * 0.05)
            assert pv[k].tobytes() == np.array(s.pos_ned_m + s.vel_ned_m_s).tobytes()
    const = ConstantReference(ref.sample(7.0))
    pv, yaw = const.grid(0.0, 0.05, 3)
    assert pv.shape == (3, 6) and tuple(pv[2]) == ref.sample(7.0).pos_ned_m + \
        ref.sample(7.0).vel_ned_m_s and yaw[1] == 0.3


@pytest.mark.parametrize("kind", ["circle", "helix", "figure8", "step"])
@pytest.mark.parametrize("shape", [dict(), dict(ramp_s=0.0), dict(duration_s=3.0, ramp_s=2.0),
                                   dict(land=False), dict(hold_s=0.0)])
def test_grid_is_the_samples_to_the_bit(kind, shape):
    """The vectorised grid against sample() byte for byte (signed zeros too) on random times
    over every phase, for ramps longer than half the manoeuvre, no ramp, no landing, no hold
    and a vehicle taken over in flight."""
    rng = np.random.default_rng(hash((kind, tuple(shape))) % 2**32)
    for airborne in (False, True):
        ref = Reference(replace(CFG.reference, kind=kind, **shape), [0.5, 1.5, -0.3], -1.0,
                        t0_s=2.0, airborne=airborne, ground_down_m=0.0)
        for t0 in rng.uniform(0.0, ref.end_time_s + 3.0, 60):
            step = float(rng.choice([0.05, 0.01, 0.0123]))
            pv, yaw = ref.grid(t0, step, 21)
            want = [ref.sample(t0 + k * step) for k in range(21)]
            assert pv.tobytes() == np.array([w.pos_ned_m + w.vel_ned_m_s for w in want]).tobytes()
            assert yaw.tobytes() == np.array([w.yaw_rad for w in want]).tobytes()


@pytest.mark.parametrize("kind", ["hover", "circle", "helix", "figure8", "step"])
def test_compiled_grid_is_the_python_grid(kind):
    """reference_core.c's grid (where a C compiler is found: the one a controller flies) against
    `_pv` point by point (compiled=False), byte for byte, on a dense sweep through every phase
    and the crawl after the landing, with steps that land on the phases' edges and steps that
    do not; a grid's points at arbitrary offsets (a lost period: t not on the control grid)."""
    from trq_offboard import reference_core
    from trq_offboard.nmpc.cache import find_compiler

    if find_compiler() is None:
        pytest.skip("no C compiler: the grid is the Python one")
    assert reference_core.grid_kernel() is not None
    rc = replace(CFG.reference, kind=kind, helix_climb_m=-0.4, step_ned_m=(0.3, -0.2, -0.1))
    for airborne in (False, True):
        args = (rc, [0.25, -1.5, -0.02], 0.7)
        kw = dict(t0_s=1.5, airborne=airborne, ground_down_m=0.1)
        fast, slow = Reference(*args, **kw), Reference(*args, compiled=False, **kw)
        for t0 in np.arange(0.0, fast.end_time_s + 3.0, 0.0137):
            for step in (0.05, 0.01):
                a, ya = fast.grid(t0, step, 21)
                b, yb = slow.grid(t0, step, 21)
                assert a.tobytes() == b.tobytes() and ya.tobytes() == yb.tobytes(), (t0, step)
        assert fast._kernel and slow._kernel is False
