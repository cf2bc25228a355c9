"""NMPC of the TRQ: `ocp` builds the NLP once (and its per-stage functions, `Stage`); `base` holds
the `Solver` base class every solver derives from (solve, prepare, discard, describe), the plan
types and the one casadi.conic QP builder; `rti` the real-time default, RtiSolver (per-stage C
compiled once and cached by `cache`, its QP solved by HPIPM through the direct binding `hpipm`,
its feedback one compiled call, `feedback`); `solver` the NLP solvers SqpSolver (interpreted
SQP) and IpoptSolver (converged reference), the test oracles; `factory.make_solver` the one a
controller file names."""

from trq_offboard.nmpc.base import Solver
from trq_offboard.nmpc.factory import make_solver
from trq_offboard.nmpc.ocp import Ocp, Stage
from trq_offboard.nmpc.rti import RtiSolver
from trq_offboard.nmpc.solver import IpoptSolver, SqpSolver

__all__ = ["Ocp", "Stage", "Solver", "RtiSolver", "SqpSolver", "IpoptSolver", "make_solver"]
