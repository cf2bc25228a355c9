"""The RTI's compiled feedback (trq_offboard/nmpc/feedback.py) against its NumPy feedback
(RtiSolver._feedback without the kernel): the same step on the same prepared QP, with the
reference and the disturbance moved after the preparation, in every layout of the stage (tilts
as states or as inputs, actuator lag states, the fixed-rotor quadcopter) and with the exact
Hessian. Solvers run interpreted (codegen off), the kernel attached by hand: only the kernel is
compiled, into a temporary cache."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ocp_problem import TWIN_MARKS, interpreted_rti

from trq_offboard.nmpc import feedback

pytestmark = TWIN_MARKS


def _solver(name, hessian="gauss_newton", actuator_states="off"):
    _, rti, problem = interpreted_rti(name, hessian, actuator_states, feedback)
    assert rti._kernel is None                   # codegen off: the NumPy feedback
    kernel = feedback.FeedbackKernel(rti.ocp, rti._hqp, rti._q2_w, rti._prep_np.results[0:4])
    rti._s0_hess = np.ascontiguousarray(rti._hc[rti._ns:, :rti._ns])
    return rti, kernel, problem


def _both(rti, kernel, prepared, x0, x_ref, d, u_prev, y0):
    """The feedback on a copy of `prepared` by NumPy, then by the kernel: (w, message,
    iterations, multipliers) each."""
    out = []
    for k in (None, kernel):
        rti._kernel = k
        rti._prepared = dataclasses.replace(prepared)
        w, msg = rti._feedback(x0, x_ref, d, u_prev, y0)
        out.append((w, msg, rti.qp_iterations, rti._hqp.pi.copy()))
    return out


@pytest.mark.parametrize("name,hessian,actuator_states", [
    ("trq_nmpc_eso", "gauss_newton", "off"),
    ("trq_nmpc_eso", "gauss_newton", "on"),
    ("quad_nmpc", "gauss_newton", "off"),
    ("trq_nmpc_eso", "exact", "off")])
def test_the_compiled_feedback_takes_numpys_step(name, hessian, actuator_states):
    rti, kernel, (u_trim, x0, x_ref, d, guess) = _solver(name, hessian, actuator_states)
    y0 = u_trim if rti.ocp.n_lag else None
    u, x, _ = rti.solve(x0, x_ref, d, u_trim, guess, y0=y0)          # a plan to prepare at
    rti.prepare(x_ref, d, u_trim, (u, x), y0=y0)
    prepared = rti._prepared
    # the step measured something else than the preparation assumed: state, reference, d,
    # and an applied tilt far from the plan's
    x_ref2 = x_ref.copy()
    x_ref2[:, 0] += 0.05
    x_ref2[3:, 8] += 0.02
    d2 = d + np.array([0.1, -0.05, 0.2, -0.3, 0.1, 0.05])
    x02 = x0 + 0.01
    u_prev = u_trim.copy()
    if rti.ocp.tilting:
        u_prev[0:4] += (0.3, -0.3, 0.2, -0.2)
    (w_np, msg_np, it_np, pi_np), (w_k, msg_k, it_k, pi_k) = _both(
        rti, kernel, prepared, x02, x_ref2, d2, u_prev, y0)
    assert w_np is not None and w_k is not None
    assert msg_k == msg_np and it_k == it_np
    assert np.max(np.abs(w_k - w_np)) < 1e-9
    assert np.max(np.abs(pi_k - pi_np)) < 1e-6 * max(1.0, np.max(np.abs(pi_np)))
    s0 = rti.ocp.initial_stage(x02, u_prev[0:4] if rti.ocp.tilting else None, y0)
    np.testing.assert_array_equal(w_k[rti.ocp.s_index[0]], s0)      # clipped onto s_0
    lbw, ubw = rti.ocp.bounds(x02, u_prev[0:4] if rti.ocp.tilting else None, y0)
    assert np.all(w_k >= lbw) and np.all(w_k <= ubw)


def test_a_non_finite_step_is_refused_as_numpy_refuses_it():
    rti, kernel, (u_trim, x0, x_ref, d, guess) = _solver("trq_nmpc_eso")
    rti.prepare(x_ref, d, u_trim, guess)
    bad = d.copy()
    bad[3] = np.nan
    (w_np, msg_np, _, _), (w_k, msg_k, _, _) = _both(rti, kernel, rti._prepared, x0, x_ref, bad,
                                                     u_trim, None)
    assert w_np is None and w_k is None
    assert msg_k == msg_np == "non-finite QP step"


def test_the_kernel_refuses_an_ocp_it_cannot_read():
    rti, _, _ = _solver("trq_nmpc_eso")
    ocp = dataclasses.replace(rti.ocp, s_index=rti.ocp.s_index[::-1].copy())
    with pytest.raises(ValueError, match="stage-major"):
        feedback.FeedbackKernel(ocp, rti._hqp, rti._q2_w, rti._prep_np.results[0:4])


def test_the_kernel_takes_any_layout_and_refuses_a_wrong_shape():
    """The step's arrays are copied into the kernel's buffers: another memory layout gives the
    same step, a wrong shape is a ValueError that names the array (a copy would broadcast it),
    and so is a preparation buffer of the wrong size."""
    rti, kernel, (u_trim, x0, x_ref, d, guess) = _solver("trq_nmpc_eso")
    rti.prepare(x_ref, d, u_trim, guess)
    P = rti._prepared
    s0 = rti.ocp.initial_stage(x0, u_trim[0:4])
    good = [P.w, P.d, d, P.xr_w, x_ref, s0, rti._s0_hess]
    w, _ = kernel(*good)
    assert w is not None
    strided = list(good)
    strided[4] = np.asfortranarray(x_ref)
    strided[5] = np.repeat(s0, 2)[::2]
    w2, _ = kernel(*strided)
    assert w2.tobytes() == w.tobytes()
    for i, bad in {2: d[:5], 4: x_ref.ravel(), 5: s0[:-1], 6: rti._s0_hess.T}.items():
        args = list(good)
        args[i] = bad
        name = ("w", "d_prep", "d", "xr_prep", "x_ref", "s0", "S0")[i]
        with pytest.raises(ValueError, match=f": {name} must have the shape "):
            kernel(*args)
    buffers = list(rti._prep_np.results[0:4])
    buffers[1] = buffers[1][:-1]
    with pytest.raises(ValueError, match="the preparation's gaps must be"):
        feedback.FeedbackKernel(rti.ocp, rti._hqp, rti._q2_w, buffers)
