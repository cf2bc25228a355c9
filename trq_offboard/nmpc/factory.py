"""The solver a controller file asks for (solver.kind): rti (the real-time default), sqp, ipopt."""

from __future__ import annotations

import numpy as np

from trq_offboard.config import ControllerConfig
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc.base import Solver
from trq_offboard.nmpc.rti import RtiSolver
from trq_offboard.nmpc.nlp import IpoptSolver, SqpSolver

__all__ = ["make_solver"]


def make_solver(cfg: ControllerConfig, model: PredictionModel, u_trim: np.ndarray) -> Solver:
    if cfg.solver.kind == "ipopt":
        return IpoptSolver(cfg, model, u_trim)
    if cfg.solver.kind == "rti":
        return RtiSolver(cfg, model, u_trim, cfg.solver.hessian)
    return SqpSolver(cfg, model, u_trim, cfg.solver.hessian)
