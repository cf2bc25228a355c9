"""What every NMPC solver is: the `Solver` base class, the plan types it takes and returns, and
the one casadi.conic QP that the solvers going through CasADi's QP interface build.

    u, x, info = solver.solve(x0, x_ref, d, u_prev, guess, y0=None)   # the plan and SolveInfo
    solver.prepare(x_ref, d, u_prev, guess, y0=None)     # `prepares`: the RTI's preparation
    solver.discard()                                     # forget a pending preparation
    solver.describe()                                    # what solves it, for logs

A solver never returns NaN: on a failure it returns the guess (finite) with
`SolveInfo.status == FAILED`; the caller decides what to fly. Each solve measures its wall time
with time.perf_counter (a measurement, returned in SolveInfo).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from typing import Callable, Union

import casadi as ca
import numpy as np

from trq_offboard.nmpc import hpipm
from trq_offboard.nmpc.ocp import Ocp
from trq_offboard.records import SolveInfo, SolveStatus

__all__ = ["Solver", "Plan", "Guess", "plan_of", "conic_line", "conic_qp"]

Plan = tuple[np.ndarray, np.ndarray]      # (u (N, nu) physical, x (N+1, 12))
# a plan, or a function making one: called only if the solver needs it (a real-time iteration
# that was prepared needs it only to fail with)
Guess = Union[Plan, Callable[[], Plan]]


def plan_of(guess: Guess) -> Plan:
    """The plan of a Guess (calling it if it is a function)."""
    return guess() if callable(guess) else guess


class Solver(ABC):
    """An NMPC solver on `ocp` (its shape: n_steps, nx, nu, n_lag, tilting; its throttle bounds
    follow the motors' effectiveness through set_throttle_scale)."""

    ocp: Ocp
    prepares: bool = False           # has a preparation phase (`prepare` does something)
    prepares_plans: bool = False     # `prepare_plan` prepares at a plan shifted in one call
    qp_iterations: int = 0           # the last solve's QP iterations (0: not counted)
    build_mode: str = "interpreted"  # its functions: compiled | cached | interpreted

    @abstractmethod
    def solve(self, x0: np.ndarray, x_ref: np.ndarray, d: np.ndarray, u_prev: np.ndarray,
              guess: Guess, y0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray,
                                                                 SolveInfo]:
        """x0 (12) measured state, x_ref (N+1, 12) reference states, d (6) disturbance held
        over the horizon, u_prev (nu) the command applied now (its tilts are s_0's), guess an
        initial plan (u, x) or a function making one (plan_of), y0 (nu, physical; only with
        actuator lag states, default u_prev) the actuators' outputs when the plan starts.
        Returns the plan (u (N, nu) physical [alpha, zeta] or [zeta]: the commands,
        x (N+1, 12)) and a SolveInfo."""

    def prepare(self, x_ref: np.ndarray, d: np.ndarray, u_prev: np.ndarray, guess: Plan,
                y0: np.ndarray | None = None) -> None:
        """The preparation for the next solve (solvers that `prepares`); here nothing."""

    def prepare_plan(self, plan: Plan, elapsed_s: float, h_s: float, pv: np.ndarray,
                     yaw_ref: np.ndarray, d: np.ndarray, u_prev: np.ndarray,
                     y0: np.ndarray | None = None) -> None:
        """`prepare` at `plan` (u (N, nu), x (N+1, 12), rows h_s apart) shifted by elapsed_s,
        the reference states those of the flight plan's grid from then (pv (N+1, 6), yaw_ref
        (N+1)), the yaw unwrapped next to the shifted plan's first state: the controller's
        preparation in one call (solvers that `prepares_plans`)."""
        raise NotImplementedError(f"{type(self).__name__} does not prepare at plans")

    def discard(self) -> None:
        """Forget a pending preparation (the controller was reset); here nothing."""

    def zero_multipliers(self) -> None:
        """Zero the multipliers kept from the last QP (the exact Hessian's); here none."""

    def describe(self) -> str:
        """What solves the NMPC, for logs and benchmarks."""
        return type(self).__name__

    @staticmethod
    def _failed(guess: Plan, t0: float, iters: int, msg: str
                ) -> tuple[np.ndarray, np.ndarray, SolveInfo]:
        """The (finite) guess as the plan of a failed solve started at perf_counter t0."""
        u, x = (np.nan_to_num(np.asarray(a, float)) for a in guess)
        return u, x, SolveInfo(SolveStatus.FAILED, iters, time.perf_counter() - t0,
                               float("nan"), msg)


def conic_line(kind: str, hessian: str, qp_solver: str) -> str:
    """describe() of a solver whose QP goes through casadi.conic (whose hpipm plugin is always
    the libhpipm CasADi ships)."""
    return f"{kind} {hessian}, {qp_solver} conic" + (
        ", libhpipm CasADi's" if qp_solver == "hpipm" else "")


def conic_qp(name: str, qp_solver: str, h_sp: ca.Sparsity, a_sp: ca.Sparsity,
             qp_max_iterations: int) -> ca.Function:
    """The QP (Hessian sparsity h_sp, constraint Jacobian sparsity a_sp) through
    casadi.conic's `qp_solver` plugin, quiet, not raising on a failure (the caller reads its
    stats): HPIPM (Riccati, the stage structure found from the sparsity) capped at
    qp_max_iterations and started cold, or qrqp, or OSQP to a tight tolerance."""
    qp_opts = {"error_on_fail": False, "print_time": False}
    if qp_solver == "hpipm":
        hpipm.check_conic()
        qp_opts["hpipm"] = {"iter_max": qp_max_iterations, "warm_start": 0}
    elif qp_solver == "qrqp":
        qp_opts.update({"print_iter": False, "print_header": False, "print_info": False})
    elif qp_solver == "osqp":
        qp_opts["osqp"] = {"verbose": False, "eps_abs": 1e-8, "eps_rel": 1e-8, "polish": True}
    return ca.conic(name, qp_solver, {"h": h_sp, "a": a_sp}, qp_opts)
