"""NMPC of the TRQ: the optimal control problem built once, and the solvers behind one interface.

    ocp          the NLP of eq. 5 built once (`Ocp`), and its per-stage functions (`Stage`)
    base         the `Solver` base class every solver derives from (solve, prepare, discard,
                 describe, the OCP's shape), the plan types and the one casadi.conic QP builder
    rti          RtiSolver, the real-time default: one SQP step a period, a preparation and a
                 feedback phase on per-stage C compiled once
    feedback     the RTI's feedback phase as one compiled call (the NumPy one kept beside it)
    guess_core, guess_core.c  the RTI's next linearisation point as one compiled call: the
                 plan shifted, packed and clipped, and the reference states (the NumPy path kept)
    hpipm        HPIPM's OCP QP called directly through ctypes (the "direct" binding), and which
                 libhpipm is loaded
    hpipm_fetch  trq-hpipm-fetch: BLASFEO's tuned kernels from a well-kept wheel (opt-in)
    cache        generated C compiled once and cached, keyed by the functions' code
    nlp          SqpSolver and IpoptSolver on the whole-horizon NLP: the test oracles
    factory      `make_solver`: the solver a controller file names
"""

from trq_offboard.nmpc.base import Solver
from trq_offboard.nmpc.factory import make_solver
from trq_offboard.nmpc.ocp import Ocp, Stage
from trq_offboard.nmpc.rti import RtiSolver
from trq_offboard.nmpc.nlp import IpoptSolver, SqpSolver

__all__ = ["Ocp", "Stage", "Solver", "RtiSolver", "SqpSolver", "IpoptSolver", "make_solver"]
