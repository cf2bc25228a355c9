"""The real-time iteration (trq_offboard/nmpc/rti.py) against the converged reference, and its
compiled-function cache (trq_offboard/nmpc/cache.py, building through trq_wire/cache.py): reuse,
invalidation, no-compiler fallback.

Every test builds into a temporary cache directory ($TRQ_CACHE_DIR), never the user's."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
import trq_params
from ocp_problem import ocp_problem

import trq_wire.cache
from trq_offboard.config import load_controller
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc import cache
from trq_offboard.nmpc.rti import RtiSolver
from trq_offboard.nmpc.nlp import IpoptSolver
from trq_offboard.records import SolveStatus

CTRL = trq_params.DIR / "controller"


@pytest.fixture(scope="module")
def cache_root(tmp_path_factory):
    return tmp_path_factory.mktemp("trq-cache")


@pytest.fixture
def cache_env(cache_root, monkeypatch):
    monkeypatch.setenv("TRQ_CACHE_DIR", str(cache_root))
    return cache_root


def _cfg(name="trq_nmpc_eso", **solver):
    cfg = load_controller(CTRL / f"{name}.yaml")
    return dataclasses.replace(cfg, solver=dataclasses.replace(
        cfg.solver, kind="rti", **solver))




def _has_compiler() -> bool:
    return cache.find_compiler() is not None


@pytest.mark.parametrize("hessian,codegen,interface", [
    ("gauss_newton", "auto", "direct"), ("exact", "off", "direct"),
    ("gauss_newton", "auto", "conic"), ("exact", "off", "conic")])
def test_rti_steps_at_fixed_state_converge_to_ipopt(cache_env, hessian, codegen, interface):
    """Repeated real-time iterations at a fixed x0, each warm-started from the previous plan,
    converge to IPOPT's solution of the same NLP (exact-Hessian case interpreted: its C takes
    tens of seconds to compile, the algorithm is the same), with HPIPM called directly or
    through casadi.conic."""
    cfg = _cfg(hessian=hessian, codegen=codegen, hpipm_interface=interface)
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    u_r, x_r, info_r = IpoptSolver(cfg, model, u_trim).solve(x0, x_ref, d, u_trim, guess)
    assert info_r.status is SolveStatus.OK
    rti = RtiSolver(cfg, model, u_trim, hessian)
    assert rti.qp_interface == interface
    plan = guess
    for _ in range(25):
        u, x, info = rti.solve(x0, x_ref, d, u_trim, plan)
        assert info.status is SolveStatus.OK and info.iterations == 1
        assert 0 < rti.qp_iterations < 50          # the QP converges, not at its limit
        plan = (u, x)
    np.testing.assert_allclose(u, u_r, atol=1e-4)        # rad and %
    np.testing.assert_allclose(x, x_r, atol=1e-5)
    assert info.cost == pytest.approx(info_r.cost, rel=1e-6)
    # the split: prepare at the plan, then feedback with the same data: the same step
    rti.prepare(x_ref, d, u_trim, plan)
    u2, x2, info2 = rti.solve(x0, x_ref, d, u_trim, plan)
    np.testing.assert_allclose(u2, u, atol=1e-5)
    # feedback corrects for a reference and a disturbance that changed after the preparation
    x_ref2 = x_ref.copy()
    x_ref2[:, 0] += 0.02
    d2 = d + 0.01
    rti.prepare(x_ref, d, u_trim, plan)
    u_split, _, _ = rti.solve(x0, x_ref2, d2, u_trim, plan)
    u_full, _, _ = rti.solve(x0, x_ref2, d2, u_trim, plan)     # prepared with the new data
    np.testing.assert_allclose(u_split[:, 0:4], u_full[:, 0:4], atol=2e-3)    # rad
    np.testing.assert_allclose(u_split[:, 4:8], u_full[:, 4:8], atol=0.1)     # %


@pytest.mark.parametrize("hessian", ["gauss_newton", "exact"])
def test_direct_hpipm_step_equals_the_conic_one(cache_env, hessian):
    """One RTI step from the same guess: HPIPM called directly (initial state eliminated, only
    finite bounds, with the compiled shim and with the ctypes loop) and through casadi.conic
    give the same plan; and the same multipliers, which the exact Hessian's next step uses."""
    plans = {}
    for interface, shim in (("conic", True), ("direct", True), ("direct", False)):
        cfg = _cfg(hessian=hessian, codegen="off", hpipm_interface=interface)
        model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
        rti = RtiSolver(cfg, model, u_trim, hessian)
        if interface == "direct" and not shim:
            rti._hqp._shim = None
        u, x, info = rti.solve(x0, x_ref, d, u_trim, guess)
        assert info.status is SolveStatus.OK
        u2, x2, _ = rti.solve(x0, x_ref, d, u_trim, (u, x))     # uses the multipliers (exact)
        plans[interface, shim] = (u, x, u2, x2)
    ref = plans["conic", True]      # both solve to HPIPM's tolerance: about 1e-4 % of throttle
    for key in (("direct", True), ("direct", False)):
        for a, b, atol in zip(plans[key], ref, (None, 2e-5, None, 2e-5)):
            if atol is None:                                        # u: rad and %
                np.testing.assert_allclose(a[:, 0:4], b[:, 0:4], atol=2e-5)
                np.testing.assert_allclose(a[:, 4:8], b[:, 4:8], atol=2e-3)
            else:
                np.testing.assert_allclose(a, b, atol=atol)


@pytest.mark.parametrize("name", ["trq_nmpc_eso", "quad_nmpc"])
def test_the_logged_cost_is_the_nlps(cache_env, name):
    """The cost an RTI step reports (its compiled function) is the NLP's objective (Ocp.cost_fn,
    interpreted) at the returned plan, to rounding; at random points too."""
    cfg = _cfg(name=name, hessian="gauss_newton")
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    rti = RtiSolver(cfg, model, u_trim)
    o = rti.ocp
    u, x, info = rti.solve(x0, x_ref, d, u_trim, guess)
    p = o.params(x_ref, u_trim, d)
    a_prev = u_trim[0:4] if o.tilting else None
    w = np.clip(o.pack(x, u, a_prev), o.lbw, o.ubw)
    assert info.cost == pytest.approx(float(o.cost_fn(w, p)), rel=1e-9)
    rng = np.random.default_rng(3)
    for _ in range(20):
        w, xr = rng.normal(size=o.lbw.size), rng.normal(size=x_ref.shape)
        assert rti._cost(w, xr) == pytest.approx(float(o.cost_fn(w, o.params(xr, u_trim, d))),
                                                 rel=1e-12)


def _built_warned_and_solved(cfg, match):
    """An RTI built under a RuntimeWarning matching `match`, and its first solve from the test
    problem (its status OK): (the solver, the plan's inputs, its states)."""
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    with pytest.warns(RuntimeWarning, match=match):
        rti = RtiSolver(cfg, model, u_trim)
    u, x, info = rti.solve(x0, x_ref, d, u_trim, guess)
    assert info.status is SolveStatus.OK
    return rti, u, x


def test_direct_hpipm_missing_falls_back_to_conic(cache_env, monkeypatch):
    """No usable libhpipm (an exotic casadi build): the RTI says so and uses casadi.conic."""
    from trq_offboard.nmpc import hpipm
    monkeypatch.setattr(hpipm, "available", lambda: (False, "libhpipm not found (test)"))
    rti, _, _ = _built_warned_and_solved(_cfg(codegen="off"), "libhpipm not found")
    assert rti.qp_interface == "conic"


@pytest.mark.skipif(not _has_compiler(), reason="no C compiler")
def test_cache_is_reused_and_invalidated(cache_env, monkeypatch):
    calls = []
    real_run = trq_wire.cache.subprocess.run

    def spy(*a, **k):
        calls.append(a[0][0])
        return real_run(*a, **k)

    monkeypatch.setattr(trq_wire.cache.subprocess, "run", spy)
    cfg = _cfg(hessian="gauss_newton")
    model, u_trim, *_ = ocp_problem(cfg)
    libs_before = set(cache_env.glob("rti_prep_*.so"))
    first = RtiSolver(cfg, model, u_trim)
    n_first = len(calls)       # 0 if an earlier test of this module already compiled it
    second = RtiSolver(cfg, model, u_trim)
    assert second.build_mode == "cached" and len(calls) == n_first      # no compiler call
    if n_first:
        assert first.build_mode == "compiled"
    # the preparation is compiled whole for its horizon (no CasADi virtual machine around the
    # stage functions a period): another N is another library
    cfg_n = dataclasses.replace(cfg, horizon_steps=10)
    assert RtiSolver(cfg_n, model, u_trim).build_mode == "compiled"
    assert RtiSolver(cfg_n, model, u_trim).build_mode == "cached"
    # a parameter of the formulation changes: a new library is compiled
    heavy = dataclasses.replace(cfg, vehicle=dataclasses.replace(
        cfg.vehicle, mass_kg=cfg.vehicle.mass_kg * 1.1))
    before = len(calls)
    s = RtiSolver(heavy, PredictionModel(heavy.vehicle), u_trim)
    assert s.build_mode == "compiled" and len(calls) == before + 1
    # and the prediction step h too
    cfg_h = dataclasses.replace(cfg, step_s=0.04)
    assert RtiSolver(cfg_h, model, u_trim).build_mode == "compiled"
    new = set(cache_env.glob("rti_prep_*.so")) - libs_before
    assert len(new) == (1 if n_first else 0) + 3, new


def test_pure_python_fallback_without_compiler(cache_env, monkeypatch):
    """No compiler on PATH (and none in $CC): the RTI runs interpreted and says so."""
    monkeypatch.setenv("PATH", "")
    monkeypatch.delenv("CC", raising=False)
    assert cache.find_compiler() is None
    rti, u, x = _built_warned_and_solved(_cfg(name="quad_nmpc", hessian="gauss_newton"),
                                         "no C compiler")
    assert rti.build_mode == "interpreted"
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(x))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["trq_nmpc_eso", "quad_nmpc"])
def test_rti_and_sqp_with_actuator_lag_states_converge_to_ipopt(cache_env, name):
    """actuator_states on (the actuators start behind the applied command): repeated real-time
    iterations and the SQP converge to IPOPT on the same NLP (they share ocp.Stage); the plan
    is the commands, which lead the lagged outputs."""
    from trq_offboard.nmpc.nlp import SqpSolver

    cfg = dataclasses.replace(_cfg(name=name, hessian="gauss_newton"), actuator_states="on")
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    y0 = u_trim.copy()
    y0[-4:] -= 4.0                                   # throttles 4 % below the command
    if model.tilting:
        y0[0:4] += (0.03, -0.02, 0.0, 0.01)
    ref = IpoptSolver(cfg, model, u_trim)
    assert ref.ocp.n_lag == model.nu
    u_r, x_r, info_r = ref.solve(x0, x_ref, d, u_trim, guess, y0=y0)
    assert info_r.status is SolveStatus.OK
    rti = RtiSolver(cfg, model, u_trim)
    plan = guess
    for _ in range(25):
        u, x, info = rti.solve(x0, x_ref, d, u_trim, plan, y0=y0)
        assert info.status is SolveStatus.OK
        plan = (u, x)
    np.testing.assert_allclose(u, u_r, atol=1e-4)
    np.testing.assert_allclose(x, x_r, atol=1e-5)
    assert info.cost == pytest.approx(info_r.cost, rel=1e-6)
    sqp = SqpSolver(dataclasses.replace(cfg, solver=dataclasses.replace(
        cfg.solver, max_iterations=60, tolerance=1e-10)), model, u_trim)
    u_s, x_s, info_s = sqp.solve(x0, x_ref, d, u_trim, guess, y0=y0)
    assert info_s.status is SolveStatus.OK
    np.testing.assert_allclose(u_s, u_r, atol=1e-4)
    # the lag matters: without it (actuators settled at the command) the plan differs
    u_settled, _, _ = ref.solve(x0, x_ref, d, u_trim, guess, y0=u_trim)
    assert np.max(np.abs(u_settled - u_r)) > 0.1


@pytest.mark.skipif(not _has_compiler(), reason="no C compiler")
def test_unwritable_cache_runs_interpreted(tmp_path, monkeypatch):
    """A cache directory that cannot be created: the RTI says so and runs interpreted."""
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the cache directory should be")
    monkeypatch.setenv("TRQ_CACHE_DIR", str(blocker / "cache"))
    cfg = _cfg()
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rti = RtiSolver(cfg, model, u_trim)
    assert any("interpreter" in str(w.message) for w in caught), [str(w.message) for w in caught]
    assert rti.build_mode == "interpreted"
    u, x, info = rti.solve(x0, x_ref, d, u_trim, guess)
    assert info.status is SolveStatus.OK
