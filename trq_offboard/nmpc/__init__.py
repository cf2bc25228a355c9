"""NMPC of the TRQ: `ocp` builds the NLP once (and its per-stage functions, `Stage`), `solver`
solves it behind the `Solver` protocol: RtiSolver (`rti`: the real-time default, per-stage C
compiled once and cached by `cache`, its QP solved by HPIPM through the direct binding `hpipm`),
SqpSolver (interpreted SQP), IpoptSolver (converged reference)."""

from trq_offboard.nmpc.ocp import Ocp, Stage
from trq_offboard.nmpc.rti import RtiSolver
from trq_offboard.nmpc.solver import IpoptSolver, Solver, SqpSolver, make_solver

__all__ = ["Ocp", "Stage", "Solver", "RtiSolver", "SqpSolver", "IpoptSolver", "make_solver"]
