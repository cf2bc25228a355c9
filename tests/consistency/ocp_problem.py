"""The NMPC test problem the solver-consistency tests share: a state off the reference, a
reference moving north at 0.3 m/s at 2 m altitude, a disturbance on every channel, and the hover
trim as the initial guess. Hand-picked numbers, so every solver sees the same NLP. Beside it,
the interpreted direct RTI solver that the compiled parts' twin tests attach their kernel to,
and those tests' marks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trq_params

from trq_offboard.allocation import Allocator
from trq_offboard.config import load_controller
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc import hpipm


def ocp_problem(cfg):
    """(model, u_trim, x0, x_ref, d, guess) for the controller config `cfg`."""
    model = PredictionModel(cfg.vehicle)
    alloc = Allocator(cfg.vehicle)
    u_trim = alloc.command_vector(alloc.hover())
    n = cfg.horizon_steps
    x0 = np.zeros(12)
    x0[0:3] = (0.3, -0.2, -1.8)
    x0[3:6] = (0.2, 0.1, 0.0)
    x0[6:9] = (0.05, -0.03, 0.1)
    x_ref = np.zeros((n + 1, 12))
    x_ref[:, 2] = -2.0
    x_ref[:, 3] = 0.3
    x_ref[:, 0] = 0.3 * cfg.step_s * np.arange(n + 1)
    d = np.array([0.5, -0.2, 0.3, 1.0, -2.0, 0.5])
    guess = (np.tile(u_trim, (n, 1)), np.tile(x0, (n + 1, 1)))
    return model, u_trim, x0, x_ref, d, guess


# a compiled part's twin tests: HPIPM called directly (else skipped), the part built into a
# temporary cache (tests/conftest.py's temporary_cache), never the user's
TWIN_MARKS = [pytest.mark.skipif(not hpipm.available()[0], reason="no libhpipm in casadi"),
              pytest.mark.usefixtures("temporary_cache")]


def interpreted_rti(name: str, hessian: str = "gauss_newton", actuator_states: str = "off",
                    part=None):
    """(cfg, RtiSolver, (u_trim, x0, x_ref, d, guess)) for the controller file `name` with the
    RTI on HPIPM's direct interface, interpreted (codegen off: no compiled part attached); the
    test skipped where the compiled `part` (a module with `available()`) cannot be built."""
    from trq_offboard.nmpc.rti import RtiSolver

    if part is not None and not part.available():
        pytest.skip(f"{part.__name__} cannot be built here (no C compiler)")
    cfg = load_controller(trq_params.DIR / "controller" / f"{name}.yaml")
    cfg = dataclasses.replace(cfg, actuator_states=actuator_states, solver=dataclasses.replace(
        cfg.solver, kind="rti", codegen="off", hpipm_interface="direct"))
    model, u_trim, x0, x_ref, d, guess = ocp_problem(cfg)
    return cfg, RtiSolver(cfg, model, u_trim, hessian), (u_trim, x0, x_ref, d, guess)
