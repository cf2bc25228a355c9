"""The RTI's compiled guess (trq_offboard/nmpc/guess_core.py) against the controller's NumPy
preparation (Controller._prepare with compiled_guess off: the plan interpolated and shifted,
the reference states, Ocp.pack, the clip, RtiSolver.prepare): the same preparation to the bit,
every field of it, in every layout of the stage (tilts as states, actuator lag states, the
fixed-rotor quadcopter) and with the exact Hessian; at shifts within a row, across rows, past
the plan's end, with the plan's yaw across +-pi from the reference's and tilts beyond their
bounds. Solvers run interpreted (codegen off), the kernel attached by hand: only the kernel is
compiled, into a temporary cache."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from ocp_problem import TWIN_MARKS, interpreted_rti

from trq_offboard.controller import Controller
from trq_offboard.nmpc import guess_core
from trq_offboard.reference import Reference

pytestmark = TWIN_MARKS


def _controller(name, hessian="gauss_newton", actuator_states="off"):
    cfg, rti, problem = interpreted_rti(name, hessian, actuator_states, guess_core)
    assert rti._guess is None and not rti.prepares_plans   # codegen off: the NumPy path
    args = rti._prep_np.args
    rti._guess = guess_core.GuessKernel(rti.ocp, args[0], args[1])
    rti.prepares_plans = True
    ctl = Controller(cfg, solver=rti)
    return ctl, problem


def _fields(p):
    """The preparation's every array, as bytes (a -0.0 is not a 0.0)."""
    return {f.name: (None if getattr(p, f.name) is None
                     else np.ascontiguousarray(getattr(p, f.name)).tobytes())
            for f in dataclasses.fields(p)}


def _both(ctl, reference):
    """The preparation by the NumPy path, then by the kernel: (fields, x_ref) each, or None
    where the plan was too old to prepare at."""
    out = []
    for compiled in (False, True):
        ctl.compiled_guess = compiled
        ctl.solver._prepared = None
        ctl._grid_key = None
        ctl._prepare(reference)
        p = ctl.solver._prepared
        out.append(None if p is None else (_fields(p), ctl.solver._prep_np.args[1].copy()))
    return out


@pytest.mark.parametrize("name,hessian,actuator_states", [
    ("trq_nmpc_eso", "gauss_newton", "off"),
    ("trq_nmpc_eso", "gauss_newton", "on"),
    ("quad_nmpc", "gauss_newton", "off"),
    ("quad_nmpc", "gauss_newton", "on"),
    ("trq_nmpc_eso", "exact", "off")])
def test_the_compiled_guess_prepares_as_numpy(name, hessian, actuator_states):
    ctl, (u_trim, x0, x_ref, d, guess) = _controller(name, hessian, actuator_states)
    rti = ctl.solver
    y0 = u_trim if rti.ocp.n_lag else None
    u, x, _ = rti.solve(x0, x_ref, d, u_trim, guess, y0=y0)         # a plan to shift
    rng = np.random.default_rng(5)
    u = u + rng.normal(0.0, 0.02, u.shape)
    x = x + rng.normal(0.0, 0.02, x.shape)
    # its yaw across +-pi from the reference's (3.1 rad): unwrapped by 2 pi
    x[:, 8] = -3.1 + 0.01 * np.arange(x.shape[0])
    if rti.ocp.tilting:
        u[3:5, 0] = 2.0                                             # beyond the tilt's bound
    start = np.array([0.3, -0.2, -1.8])
    reference = Reference(ctl.cfg.reference, start, 3.1)
    h, dt = ctl.h, ctl.cfg.control_dt_s
    u_prev = u_trim.copy()
    if rti.ocp.tilting:
        u_prev[0:4] += (0.3, -0.3, 0.2, -0.2)
    ctl._last_d = d.copy()
    ctl._last_u = u_prev
    ctl._scale = np.ones_like(u_prev)
    ctl._y_act = (u_prev + 0.5) if ctl._act_states else None
    prepared = 0
    # shifts: one period, within a row, across rows, on rows (where t / h falls a rounding
    # below a whole row), near and past the plan's end
    for elapsed in (dt, 0.3 * h, 1.7 * h + 0.001, h, 2 * h, 3 * h, 7 * h, 0.15, 0.35,
                    (ctl.N - 1.2) * h, (ctl.N - 0.01) * h, ctl.N * h + 0.01):
        ctl._plan, ctl._plan_t = (u.copy(), x.copy()), 4.0
        ctl._last_t = 4.0 + elapsed - dt
        numpy_path, kernel = _both(ctl, reference)
        if numpy_path is None:
            assert kernel is None
            continue
        assert kernel is not None
        fields_np, xr_np = numpy_path
        fields_k, xr_k = kernel
        for field, value in fields_np.items():
            assert fields_k[field] == value, f"{field} differs at elapsed {elapsed:g} s"
        assert xr_k.tobytes() == xr_np.tobytes()
        prepared += 1
    assert prepared >= 10
    # the lag states' outputs default to the applied input, as RtiSolver.prepare's
    if ctl._act_states:
        ctl._y_act = None
        ctl._plan, ctl._plan_t, ctl._last_t = (u.copy(), x.copy()), 4.0, 4.0
        numpy_path, kernel = _both(ctl, reference)
        assert kernel[0] == numpy_path[0]


@pytest.mark.parametrize("name,actuator_states", [
    ("trq_nmpc_eso", "off"), ("trq_nmpc_eso", "on"), ("quad_nmpc", "off"), ("quad_nmpc", "on")])
def test_the_compiled_unpack_is_the_ocps(name, actuator_states):
    ctl, _ = _controller(name, actuator_states=actuator_states)
    ocp, kernel = ctl.solver.ocp, ctl.solver._guess
    rng = np.random.default_rng(11)
    for _ in range(5):
        w = rng.normal(0.0, 3.0, ocp.lbw.size)
        w[rng.integers(0, w.size, 3)] = (np.nan, np.inf, -0.0)
        u_np, x_np = ocp.unpack(w)
        u_k, x_k = kernel.unpack(w)
        assert u_k.shape == u_np.shape and x_k.shape == x_np.shape
        assert u_k.tobytes() == u_np.tobytes() and x_k.tobytes() == x_np.tobytes()
        u_k[0, 0] = 123.0                           # new arrays: the next unpack's are its own
        assert kernel.unpack(w)[0][0, 0] == u_np[0, 0]


def test_the_unwrapped_yaw_is_pythons_remainder():
    """The reference's yaw next to the plan's across the seam, as Python's float remainder
    puts it (the sign of the divisor), including at exact multiples of pi; a plan's yaw of
    -0.0 kept as the NumPy path keeps it."""
    ctl, (u_trim, x0, x_ref, d, guess) = _controller("trq_nmpc_eso")
    rti = ctl.solver
    u, x, _ = rti.solve(x0, x_ref, d, u_trim, guess)
    seams = [(3.0, -3.0), (-math.pi, math.pi), (math.pi, -math.pi), (0.0, 2 * math.pi),
             (-7.0, 7.0), (1e-300, -1e-300), (0.0, -math.pi - 0.5), (0.0, math.pi + 0.5),
             (0.0, -math.pi), (0.0, math.pi), (-0.0, 0.0), (-0.0, -0.0)]
    seams += [(0.3, 0.3 + a) for a in np.linspace(-3 * math.pi, 3 * math.pi, 37)]
    for yaw_plan, yaw_ref in seams:
        x[:, 8] = yaw_plan
        ctl._plan, ctl._plan_t, ctl._last_t = (u.copy(), x.copy()), 1.0, 1.0
        ctl._last_d, ctl._last_u = d.copy(), u_trim.copy()
        reference = Reference(ctl.cfg.reference, np.zeros(3), yaw_ref)
        numpy_path, kernel = _both(ctl, reference)
        assert kernel[1].tobytes() == numpy_path[1].tobytes(), (yaw_plan, yaw_ref)
        assert kernel[0] == numpy_path[0], (yaw_plan, yaw_ref)


def test_a_non_finite_plan_propagates_as_numpys():
    """A NaN or an infinity in the plan reaches the decision vector where NumPy's path puts
    it (np.clip lets a NaN through), not clipped into the bounds."""
    ctl, (u_trim, x0, x_ref, d, guess) = _controller("trq_nmpc_eso")
    rti = ctl.solver
    u, x, _ = rti.solve(x0, x_ref, d, u_trim, guess)
    x[5, 3], x[9, 0], u[2, 5] = np.nan, np.inf, np.nan
    ctl._plan, ctl._plan_t, ctl._last_t = (u, x), 1.0, 1.0
    ctl._last_d, ctl._last_u = d.copy(), u_trim.copy()
    reference = Reference(ctl.cfg.reference, np.zeros(3), 0.0)
    w = []
    for compiled in (False, True):
        ctl.compiled_guess = compiled
        ctl._prepare(reference)
        w.append(ctl.solver._prepared.w.copy())
    assert np.isnan(w[0]).any()
    np.testing.assert_array_equal(w[1], w[0])      # NaNs in the same places


def test_the_kernel_refuses_what_it_cannot_write():
    ctl, _ = _controller("trq_nmpc_eso")
    rti = ctl.solver
    args = rti._prep_np.args
    with pytest.raises(ValueError, match="x_ref must be"):
        guess_core.GuessKernel(rti.ocp, args[0], np.zeros(3))
    with pytest.raises(ValueError, match="w must be"):
        guess_core.GuessKernel(rti.ocp, args[0].astype(np.float32), args[1])
    # bounds replaced rather than changed in place: the kernel would read the old ones
    kernel = rti._guess
    rti.ocp.lbw = rti.ocp.lbw.copy()
    u = np.zeros((ctl.N, rti.ocp.nu))
    x = np.zeros((ctl.N + 1, 12))
    with pytest.raises(RuntimeError, match="bounds were replaced"):
        kernel((u, x), 0.01, ctl.h, np.zeros((ctl.N + 1, 6)), np.zeros(ctl.N + 1),
               np.zeros(rti.ocp.nu))
