"""NMPC of the TRQ: `ocp` builds the NLP once, `solver` solves it (SqpSolver: real time,
IpoptSolver: converged reference) behind the `Solver` protocol."""

from trq_offboard.nmpc.ocp import Ocp
from trq_offboard.nmpc.solver import IpoptSolver, Solver, SqpSolver, make_solver

__all__ = ["Ocp", "Solver", "SqpSolver", "IpoptSolver", "make_solver"]
