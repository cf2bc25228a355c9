"""The real-time iteration's feedback phase in one compiled call (RtiSolver, direct HPIPM).

Between two preparations the feedback takes the QP prepared at the linearisation point w and
corrects it for what the step measured, then solves it:

    gaps  += dF/dd (d - d_prep)                       (when the disturbance estimate moved)
    grad  -= q2 (x_ref - x_ref_prep)                   (when the reference moved)
    bounds: s_0 fixed to the measured [x0, tilt, lags]
    ds_0 = s_0 - w_0 eliminated: b_0 += A_0 ds_0, r_0 += S_0 ds_0
    HPIPM (nmpc/hpipm.py's shim: the stage fields set, the QP solved, its solution read)
    w+ = clip(w + dw, lbw, ubw), with dw finite

In NumPy that is some forty array operations and a copy of every stage's [A B] a period, each
costing more in the interpreter than in arithmetic; here it is one ctypes call into C compiled
with the shim's source (the same HPIPM entry points), linked against the libhpipm in use. The
arithmetic is NumPy's operation for operation (elementwise; np.clip with its NaN propagation),
except the three small products (dF/dd d, A_0 ds_0, S_0 ds_0),
summed in index order where NumPy's BLAS may order or fuse them differently: the same plan to
rounding. RtiSolver keeps its NumPy feedback as the reference and the path without a C compiler;
tests/consistency/test_rti_feedback.py holds the two to each other.

The decision vector w is stage-major, [s_0, v_0, s_1, v_1, ..., s_N] (Ocp.build's layout, which
`FeedbackKernel` checks); the stage Jacobians come as the preparation's (N, ns + nv, ns) array,
[A_k B_k]' per stage, that is A_k then B_k column-major, handed to HPIPM in place.
"""

from __future__ import annotations

import ctypes

import numpy as np

from trq_offboard.nmpc import hpipm

__all__ = ["FeedbackKernel", "available"]

_SOURCE = hpipm._SHIM_SOURCE + r"""
/* trq_rti_feedback: the RTI's feedback phase (nmpc/feedback.py). */
/* np.clip's steps (a NaN propagates) */
static double clip(double x, double lo, double hi)
{
    x = (x != x || x > lo) ? x : lo;
    return (x != x || x < hi) ? x : hi;
}

/* dims: N, ns, nv, nb, nx, nw.
   st: HPIPM's qp, sol, arg, ws (hpipm.OcpQp.handles), then
   [4] idxbx (int, nb), [5] q2w (nw), [6] lbw0, [7] ubw0 (nw: the OCP's bounds),
   [8] work (3 nw + 2 (N+1) ns + 4 N nv + 2 (N+1) nb + 6 doubles), [9] x ((N+1) ns),
   [10] u (N nv), [11] pi (N ns), [12] iter (int); the preparation's [13] a (N (ns+nv) ns),
   [14] gaps (N ns), [15] grad (nw), [16] jd (N 6 ns); the step's [17] w (nw), [18] d_prep (6),
   [19] d (6), [20] xr_prep (nw), [21] x_ref ((N+1) nx), [22] s0 (ns),
   [23] S0 (nv ns); [24] w_out (nw).
   Returns HPIPM's status (0 converged), or -1 when the step or the multipliers are not finite
   (w_out then untouched). */
int trq_rti_feedback(const int *dims, void *const *st)
{
    const int N = dims[0], ns = dims[1], nv = dims[2], nb = dims[3], nx = dims[4];
    const int nw = dims[5], nz = ns + nv;
    const int *idxbx = (const int *) st[4];
    const double *q2w = st[5], *lbw0 = st[6], *ubw0 = st[7];
    double *work = st[8], *x = st[9], *u = st[10], *pi = st[11];
    int *iter = st[12];
    const double *a = st[13], *gaps = st[14], *grad = st[15], *jd = st[16];
    const double *w = st[17], *d_prep = st[18], *d = st[19], *xr_prep = st[20];
    const double *x_ref = st[21], *s0 = st[22], *S0 = st[23];
    double *w_out = st[24];
    double *lbw = work, *ubw = lbw + nw, *g = ubw + nw, *b = g + nw;
    double *q = b + N * ns, *r = q + (N + 1) * ns, *lbx = r + N * nv, *ubx = lbx + (N + 1) * nb;
    double *lbu = ubx + (N + 1) * nb, *ubu = lbu + N * nv, *ds0 = ubu + N * nv, *dd = ds0 + ns;
    int k, i, j, moved, status;

    /* the dynamics' constants, for the disturbance estimate the step has */
    moved = 0;
    for (j = 0; j < 6; ++j) {
        dd[j] = d[j] - d_prep[j];
        moved |= dd[j] != 0.0;
    }
    for (k = 0; k < N * ns; ++k)
        b[k] = gaps[k];
    if (moved)
        for (k = 0; k < N; ++k)
            for (i = 0; i < ns; ++i) {
                double acc = 0.0;                  /* jd: (N, 6, ns), dF_k/dd column-major */
                for (j = 0; j < 6; ++j)
                    acc += jd[(k * 6 + j) * ns + i] * dd[j];
                b[k * ns + i] += acc;
            }
    /* the cost's gradient, for the reference the step has */
    for (i = 0; i < nw; ++i)
        g[i] = grad[i];
    moved = 0;
    for (k = 0; k <= N && !moved; ++k)
        for (i = 0; i < nx; ++i)
            moved |= x_ref[k * nx + i] != xr_prep[k * nz + i];
    if (moved)
        for (k = 0; k <= N; ++k)
            for (i = 0; i < nx; ++i) {
                const int p = k * nz + i;
                g[p] = grad[p] - q2w[p] * (x_ref[k * nx + i] - xr_prep[p]);
            }
    /* bounds: s_0 fixed */
    for (i = 0; i < nw; ++i) {
        lbw[i] = lbw0[i];
        ubw[i] = ubw0[i];
    }
    for (i = 0; i < ns; ++i) {
        lbw[i] = ubw[i] = s0[i];
        ds0[i] = s0[i] - w[i];
    }
    /* s_0 eliminated: b_0 += A_0 ds_0 (a[0]'s first ns rows are A_0' row-major) */
    for (j = 0; j < ns; ++j) {
        double acc = 0.0;
        for (i = 0; i < ns; ++i)
            acc += ds0[i] * a[i * ns + j];
        b[j] += acc;
    }
    for (k = 0; k <= N; ++k) {
        const double *gs = g + k * nz, *ls = lbw + k * nz, *us = ubw + k * nz, *ws = w + k * nz;
        for (i = 0; i < ns; ++i)
            q[k * ns + i] = gs[i];
        for (i = 0; i < nb; ++i) {
            lbx[k * nb + i] = ls[idxbx[i]] - ws[idxbx[i]];
            ubx[k * nb + i] = us[idxbx[i]] - ws[idxbx[i]];
        }
        if (k == N)
            break;
        for (i = 0; i < nv; ++i) {
            r[k * nv + i] = gs[ns + i];
            lbu[k * nv + i] = ls[ns + i] - ws[ns + i];
            ubu[k * nv + i] = us[ns + i] - ws[ns + i];
        }
    }
    for (i = 0; i < nv; ++i) {       /* r_0 += S_0 ds_0 (S_0: (nv, ns) row-major) */
        double acc = 0.0;
        for (j = 0; j < ns; ++j)
            acc += S0[i * ns + j] * ds0[j];
        r[i] += acc;
    }
    status = trq_hpipm_solve(N, ns, nv, nb, st[0], st[1], st[2], st[3],
                             (double *) a, nz * ns, (double *) a + ns * ns, nz * ns, b, q, r,
                             lbx, ubx, lbu, ubu, x, u, pi, iter);
    for (k = 0; k < N * ns; ++k)
        if (!(pi[k] - pi[k] == 0.0))
            return -1;
    for (i = 0; i < N * nv; ++i)
        if (!(u[i] - u[i] == 0.0))
            return -1;
    for (i = ns; i < (N + 1) * ns; ++i)
        if (!(x[i] - x[i] == 0.0))
            return -1;
    for (i = 0; i < ns; ++i)
        if (!(ds0[i] - ds0[i] == 0.0))
            return -1;
    for (k = 0; k <= N; ++k) {
        const double *ls = lbw + k * nz, *us = ubw + k * nz, *ws = w + k * nz;
        double *wo = w_out + k * nz;
        const double *dx = k == 0 ? ds0 : x + k * ns;
        for (i = 0; i < ns; ++i)
            wo[i] = clip(ws[i] + dx[i], ls[i], us[i]);
        if (k == N)
            break;
        for (i = 0; i < nv; ++i)
            wo[ns + i] = clip(ws[ns + i] + u[k * nv + i], ls[ns + i], us[ns + i]);
    }
    return status;
}
"""

_LIB: ctypes.CDLL | None | bool = None       # False: tried, not available


def _load() -> ctypes.CDLL | None:
    global _LIB
    if _LIB is None:
        _LIB = False
        if hpipm.available()[0]:
            path = hpipm.compiled_against("trq_rti_feedback", _SOURCE)
            if path is not None:
                try:
                    lib = ctypes.CDLL(str(path))
                    f = lib.trq_rti_feedback
                    f.restype = ctypes.c_int
                    f.argtypes = [ctypes.c_void_p] * 2
                    _LIB = lib
                except OSError:
                    pass
    return _LIB or None


def available() -> bool:
    """The compiled feedback could be built and loaded here (a C compiler, HPIPM)."""
    return _load() is not None


class FeedbackKernel:
    """The feedback of one RtiSolver's QP: its OCP's layout and bounds, its HPIPM workspace
    (`qp`: hpipm.OcpQp, whose x, u, pi, status and iterations it fills), the gradient's
    reference weights q2w (nw) and the preparation's output buffers (a (N (ns+nv) ns), gaps
    (N ns), grad (nw), jd (N 6 ns), overwritten in place by each preparation: the kernel reads
    them where they are). Every address is fixed at construction: a call copies the step's
    few small arrays into the kernel's own buffers and hands C one table. Raises RuntimeError
    when the compiled kernel is unavailable."""

    def __init__(self, ocp, qp, q2w: np.ndarray, prepared):
        lib = _load()
        if lib is None:
            raise RuntimeError("the compiled RTI feedback is not available (no C compiler, or "
                               "HPIPM not loaded)")
        N, ns, nv, nx = ocp.n_steps, ocp.ns, ocp.nv, ocp.nx
        nz, nw = ns + nv, ocp.lbw.size
        if not ocp.stage_major():
            raise ValueError("the OCP's decision vector is not stage-major [s_0, v_0, ..., s_N]")
        sizes = {"a": N * nz * ns, "gaps": N * ns, "grad": nw, "jd": N * 6 * ns}
        prepared = dict(zip(sizes, prepared))
        for name, size in sizes.items():
            buf = prepared[name]
            if buf.size != size or buf.dtype != np.float64 or not buf.flags.c_contiguous:
                raise ValueError(f"compiled RTI feedback: the preparation's {name} must be "
                                 f"{size} float64, C-contiguous (got {buf.size} {buf.dtype})")
        self._fn = lib.trq_rti_feedback
        self.ocp, self.qp = ocp, qp
        self._dims = np.array([N, ns, nv, qp.idxbx.size, nx, nw], np.intc)
        self._idxbx = np.ascontiguousarray(qp.idxbx, np.intc)
        self._q2w = np.ascontiguousarray(q2w, float)
        nb = self._idxbx.size
        self._work = np.zeros(3 * nw + 2 * (N + 1) * ns + 4 * N * nv + 2 * (N + 1) * nb + 6)
        self._iter = ctypes.c_int(0)
        # ocp.lbw / ubw are updated in place (Ocp.set_throttle_scale): their addresses hold
        self._lbw0, self._ubw0 = ocp.lbw, ocp.ubw
        assert self._lbw0.flags.c_contiguous and self._ubw0.flags.c_contiguous
        self._prepared = prepared                      # kept alive: C reads them
        # the step's inputs, copied in by each call (any layout and dtype a copy converts)
        self._inputs = tuple((name, np.zeros(shape)) for name, shape in (
            ("w", nw), ("d_prep", 6), ("d", 6), ("xr_prep", nw), ("x_ref", (N + 1, nx)),
            ("s0", ns), ("S0", (nv, ns))))
        self._out = np.zeros(nw)
        handles = [h or 0 for h in qp.handles]
        ptrs = handles + [a.ctypes.data for a in (
            self._idxbx, self._q2w, self._lbw0, self._ubw0, self._work, qp.x, qp.u, qp.pi)]
        ptrs += [ctypes.addressof(self._iter)]
        ptrs += [prepared[name].ctypes.data for name in sizes]
        ptrs += [buf.ctypes.data for _, buf in self._inputs] + [self._out.ctypes.data]
        self._st = (ctypes.c_void_p * len(ptrs))(*ptrs)
        self._dims_ptr = self._dims.ctypes.data

    def __call__(self, w, d_prep, d, xr_prep, x_ref, s0, S0):
        """The feedback on the preparation in the bound buffers, from its w (nw), d_prep (6)
        and xr_prep (nw, the reference at the states' positions) and the step's d (6), x_ref
        (N+1, nx), s0 (ns) and S_0 (nv, ns). Returns (w+ (a new
        array), HPIPM's status), or (None, -1) for a non-finite step. An array of another size
        is a ValueError that names it."""
        if self.ocp.lbw is not self._lbw0 or self.ocp.ubw is not self._ubw0:
            raise RuntimeError("the OCP's bounds were replaced: the kernel holds their address")
        for (name, buf), arr in zip(self._inputs, (w, d_prep, d, xr_prep, x_ref, s0, S0)):
            if arr.shape != buf.shape:                 # (a copy would broadcast)
                raise ValueError(f"compiled RTI feedback: {name} must have the shape "
                                 f"{buf.shape} (got {arr.shape})")
            buf[...] = arr
        status = self._fn(self._dims_ptr, self._st)
        self.qp.iterations = self._iter.value
        if status < 0:
            return None, status
        self.qp.status = status
        return self._out.copy(), status
