"""Control allocation (trq_offboard.allocation) against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trq_offboard.allocation import Allocator, rotor_wrench
from trq_offboard.config import load_vehicle_model

from conftest import ROOT

VEH = ROOT / "params" / "vehicle"


@pytest.fixture(scope="module", params=["trq", "quad"])
def alloc(request):
    return Allocator(load_vehicle_model(VEH / f"{request.param}.yaml"))


def test_hover_trim_by_hand(alloc):
    # F = m g / 4 = 2.1 * 9.80665 / 4 = 5.14849 N per rotor;
    # 0.0007 z^2 + 0.0157 z - 0.1891 = 5.14849 -> z = (-0.0157 + sqrt(0.0157^2 + 4 * 0.0007 *
    # 5.33759)) / 0.0014 = 76.82 %
    by_hand = (-0.0157 + math.sqrt(0.0157 ** 2 + 4 * 0.0007 * (0.1891 + 2.1 * 9.80665 / 4))) \
        / 0.0014
    assert by_hand == pytest.approx(76.82, abs=0.01)
    cmd = alloc.hover()
    np.testing.assert_allclose(cmd.throttle_pct, [by_hand] * 4, atol=1e-9)
    np.testing.assert_allclose(cmd.tilt_rad, [0.0] * 4, atol=1e-12)
    w = rotor_wrench(alloc.vehicle, cmd.throttle_pct, cmd.tilt_rad)
    np.testing.assert_allclose(w, [0, 0, -2.1 * 9.80665, 0, 0, 0], atol=1e-9)


def test_effectiveness_columns_by_hand():
    vm = load_vehicle_model(VEH / "trq.yaml")
    a = Allocator(vm)
    B = a.effectiveness(0.01)
    s = math.sqrt(0.5)
    l = 0.23
    # rotor 1: front right (ccw), arm (s, s): c_1 -> F (0,0,-1), M (-l s, l s, +kappa)
    np.testing.assert_allclose(B[:, 0], [0, 0, -1, -l * s, l * s, 0.01], atol=1e-15)
    # s_1 -> F (-s, s, 0), M (kappa s, -kappa s, l)
    np.testing.assert_allclose(B[:, 4], [-s, s, 0, 0.01 * s, -0.01 * s, l], atol=1e-15)
    # rotor 3: front left (cw), arm (s, -s): c_3 -> M (l s, l s, -kappa)
    np.testing.assert_allclose(B[:, 2], [0, 0, -1, l * s, l * s, -0.01], atol=1e-15)
    assert np.linalg.matrix_rank(B) == 6
    q = Allocator(load_vehicle_model(VEH / "quad.yaml")).effectiveness(0.01)
    assert q.shape == (4, 4) and np.linalg.matrix_rank(q) == 4


def test_feasible_wrench_reproduced_exactly(alloc):
    """Wrenches made by in-limit commands are reproduced after the fixed-point refinement."""
    vm = alloc.vehicle
    rng = np.random.default_rng(3)
    rows = slice(0, 6) if not vm.tilt_locked else [2, 3, 4, 5]
    worst_refined = worst_raw = 0.0
    raw = Allocator(vm, refine_iterations=0)
    for _ in range(50):
        zeta = rng.uniform(60.0, 90.0, 4)
        alpha = np.zeros(4) if vm.tilt_locked else rng.uniform(-0.2, 0.2, 4)
        w = rotor_wrench(vm, zeta, alpha)
        res = alloc.allocate(w)
        got = rotor_wrench(vm, res.command.throttle_pct, res.command.tilt_rad)
        assert not res.saturated
        worst_refined = max(worst_refined, np.max(np.abs(got - w)[rows]))
        r0 = raw.allocate(w)
        got0 = rotor_wrench(vm, r0.command.throttle_pct, r0.command.tilt_rad)
        worst_raw = max(worst_raw, np.max(np.abs(got0 - w)[rows]))
    assert worst_refined < 1e-6
    assert worst_raw > 10 * worst_refined          # the refinement is what makes it exact


def test_limits_respected_on_infeasible_wrench(alloc):
    vm = alloc.vehicle
    for w in ([5.0, -5.0, -40.0, 1.0, -1.0, 0.5], [0, 0, 5.0, 0, 0, 0], [0, 0, -1, 0, 0, 2.0]):
        res = alloc.allocate(w)
        assert res.saturated
        t = np.array(res.command.throttle_pct)
        a = np.array(res.command.tilt_rad)
        assert np.all(t >= vm.idle_pct - 1e-12) and np.all(t <= 100.0 + 1e-12)
        assert np.all(a >= vm.tilt_min_rad - 1e-12) and np.all(a <= vm.tilt_max_rad + 1e-12)
        assert np.all(np.isfinite(t)) and np.all(np.isfinite(a))


def test_command_vector_roundtrip(alloc):
    cmd = alloc.hover(0.1, -0.05)
    u = alloc.command_vector(cmd)
    assert u.size == alloc.vehicle.n_inputs
    assert alloc.command_of(u) == cmd
