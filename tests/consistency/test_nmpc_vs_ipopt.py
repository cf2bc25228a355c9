"""The fast SQP solver, run to convergence, against the IPOPT reference on the same NLP; and
the real-time budget (3 iterations, warm-started) close to it along a short closed loop."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trq_params
from ocp_problem import ocp_problem

from trq_offboard.config import load_controller
from trq_offboard.nmpc.nlp import IpoptSolver, SqpSolver
from trq_offboard.records import SolveStatus


def _problem(name):
    cfg = load_controller(trq_params.builtin("controller", name))
    return (cfg, *ocp_problem(cfg))


@pytest.mark.parametrize("name,hessian", [("trq_nmpc_eso", "gauss_newton"),
                                          pytest.param("trq_nmpc_eso", "exact",
                                                       marks=pytest.mark.slow),
                                          ("quad_nmpc", "gauss_newton")])
def test_sqp_converges_to_ipopt(name, hessian):
    cfg, model, u_trim, x0, x_ref, d, guess = _problem(name)
    ref = IpoptSolver(cfg, model, u_trim)
    u_r, x_r, info_r = ref.solve(x0, x_ref, d, u_trim, guess)
    assert info_r.status is SolveStatus.OK
    cfg_long = dataclasses.replace(cfg, solver=dataclasses.replace(
        cfg.solver, max_iterations=60, tolerance=1e-10))
    fast = SqpSolver(cfg_long, model, u_trim, hessian)
    u, x, info = fast.solve(x0, x_ref, d, u_trim, guess)
    assert info.status is SolveStatus.OK and info.message == "converged"
    assert info.cost == pytest.approx(info_r.cost, rel=1e-7)
    # what each says solved it (controller.csv's solver line)
    assert ref.describe() == "ipopt"
    assert fast.describe() == f"sqp {hessian}, {cfg.solver.qp_solver} conic" + (
        ", libhpipm CasADi's" if cfg.solver.qp_solver == "hpipm" else "")
    np.testing.assert_allclose(u, u_r, atol=1e-4)        # rad and %
    np.testing.assert_allclose(x, x_r, atol=1e-5)
    # constraints of the plan: tilt rate and limits
    if model.tilting:
        rate = cfg.vehicle.servo_rate_limit_rad_s
        assert np.all(np.abs(np.diff(u[:, 0:4], axis=0)) <= rate * cfg.step_s + 1e-7)
        assert np.all(np.abs(u[0, 0:4] - u_trim[0:4]) <= rate * cfg.control_dt_s + 1e-7)
    thr = u[:, -4:]
    assert np.all(thr >= cfg.vehicle.idle_pct - 1e-6) and np.all(thr <= 100 + 1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("iterations,settle", [(3, 5), (1, 35)])
def test_realtime_budget_tracks_reference_solution(iterations, settle):
    """Along a 1 s closed loop on the model, the warm-started SQP's first input is within
    0.5 % throttle / 0.005 rad of IPOPT's converged one: from step 5 on with 3 iterations a step,
    and once the loop has settled (the last 15 steps) with 1 (the real-time iteration)."""
    cfg, model, u_trim, x0, x_ref, d, guess = _problem("trq_nmpc_eso")
    cfg = dataclasses.replace(cfg, solver=dataclasses.replace(cfg.solver,
                                                              max_iterations=iterations))
    ref = IpoptSolver(cfg, model, u_trim)
    fast = SqpSolver(cfg, model, u_trim, cfg.solver.hessian)
    F = model.discrete(cfg.control_dt_s, 2)
    x, u_prev, plan = x0, u_trim, guess
    worst = np.zeros(8)
    for k in range(50):
        u, xp, info = fast.solve(x, x_ref, d, u_prev, plan)
        assert info.status is SolveStatus.OK
        if k >= settle:     # after the warm start has caught up
            u_r, _, info_r = ref.solve(x, x_ref, d, u_prev, plan)
            worst = np.maximum(worst, np.abs(u[0] - u_r[0]))
        plan = (np.vstack([u[1:], u[-1:]]), np.vstack([xp[1:], xp[-1:]]))  # crude shift
        u_prev = u[0]
        x = np.asarray(F(x, u[0], d)).ravel()
    assert np.all(worst[0:4] < 5e-3) and np.all(worst[4:8] < 0.5), worst
