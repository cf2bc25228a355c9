"""A direct binding (ctypes) of HPIPM's OCP QP interior-point solver: the libhpipm that ships in the
CasADi wheel, built once and called without CasADi's conic layer.

    qp = OcpQp(ns, nv, N, idxbx, mode="speed")      # workspaces allocated once
    qp.set_hessian(H_stage, H_terminal)             # constant (Gauss-Newton) or per solve
    x, u, pi = qp.solve(At, Bt, b, q, r, lbx, ubx, lbu, ubu)   # At, Bt: A_k', B_k' per stage

The QP (HPIPM's form, Frison & Diehl 2020), with the initial state eliminated (stage 0 has no state
variable: its dynamics carry A_0 ds0 in their constant):

    min  sum_k 1/2 [u_k; x_k]' [R S; S' Q] [u_k; x_k] + r_k' u_k + q_k' x_k  (+ terminal in x_N)
    s.t. x_{k+1} = A_k x_k + B_k u_k + b_k,    lbx_k <= x_k[idxbx] <= ubx_k,  lbu_k <= u_k <= ubu_k

Why not casadi.conic("hpipm"): CasADi's interface spends a large share of the solve before the
first iteration (it allocates and builds HPIPM's workspace on every call and converts the sparse
matrices; measured: docs/solver.md, docs/decisions/2026-12-02-figures-from-comments.md),
and it boxes every state of every stage (unbounded ones with a large number), which
the interior point then carries. Here the workspace is built once, only the finite bounds are
constraints, and the initial state is not a variable.

Only the stable per-field entry points of HPIPM are used (`d_ocp_qp_set_A(stage, mat, qp)` and the
like, column-major), not the `*_set_all` ones whose argument lists changed between versions.
Setting a QP takes one call per field and stage, costly through ctypes (measured:
docs/decisions/2026-12-02-figures-from-comments.md), so with a C compiler a small shim (`_SHIM`,
compiled once and cached by `cache.compiled_c`, linked against the same libhpipm) makes them and
the solve in one call; without one the loop runs in Python. `available()` says whether the
library was found and loaded; the caller falls back to CasADi's conic interface when it was not.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

import numpy as np

__all__ = ["MODES", "OcpQp", "available", "check_conic", "compiled_against", "library_path",
           "other_loaded"]

MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}   # enum hpipm_mode
# further IPM options (d_ocp_qp_ipm_arg_set_<name>, after the mode's defaults): name -> C type
ARG_OPTIONS = {"ric_alg": ctypes.c_int, "pred_corr": ctypes.c_int, "split_step": ctypes.c_int,
               "tol_stat": ctypes.c_double, "tol_eq": ctypes.c_double,
               "tol_ineq": ctypes.c_double, "tol_comp": ctypes.c_double,
               "mu0": ctypes.c_double, "reg_prim": ctypes.c_double}
_LIB: ctypes.CDLL | None = None
_LIB_ERROR: str | None = None
_SHIM: ctypes.CDLL | None | bool = None         # False: tried, not available
_LIB_PATH: Path | None = None                   # the library loaded

_SHIM_SOURCE = r"""
/* trq_hpipm_shim: set one OCP QP's per-solve data, solve it, read the solution (HPIPM). */
extern void d_ocp_qp_set_A(int, double *, void *);
extern void d_ocp_qp_set_B(int, double *, void *);
extern void d_ocp_qp_set_b(int, double *, void *);
extern void d_ocp_qp_set_q(int, double *, void *);
extern void d_ocp_qp_set_r(int, double *, void *);
extern void d_ocp_qp_set_lbx(int, double *, void *);
extern void d_ocp_qp_set_ubx(int, double *, void *);
extern void d_ocp_qp_set_lbu(int, double *, void *);
extern void d_ocp_qp_set_ubu(int, double *, void *);
extern void d_ocp_qp_ipm_solve(void *, void *, void *, void *);
extern void d_ocp_qp_ipm_get_status(void *, int *);
extern void d_ocp_qp_ipm_get_iter(void *, int *);
extern void d_ocp_qp_sol_get_u(int, void *, double *);
extern void d_ocp_qp_sol_get_x(int, void *, double *);
extern void d_ocp_qp_sol_get_pi(int, void *, double *);

/* A and B: stage k's block (column-major) at A + k sa and B + k sb */
int trq_hpipm_solve(int N, int ns, int nv, int nb, void *qp, void *sol, void *arg, void *ws,
                    double *A, int sa, double *B, int sb, double *b, double *q, double *r,
                    double *lbx, double *ubx, double *lbu, double *ubu,
                    double *x, double *u, double *pi, int *iter)
{
    int k, status;
    for (k = 0; k < N; ++k) {
        if (k > 0) {
            d_ocp_qp_set_A(k, A + k * sa, qp);
            d_ocp_qp_set_q(k, q + k * ns, qp);
            d_ocp_qp_set_lbx(k, lbx + k * nb, qp);
            d_ocp_qp_set_ubx(k, ubx + k * nb, qp);
        }
        d_ocp_qp_set_B(k, B + k * sb, qp);
        d_ocp_qp_set_b(k, b + k * ns, qp);
        d_ocp_qp_set_r(k, r + k * nv, qp);
        d_ocp_qp_set_lbu(k, lbu + k * nv, qp);
        d_ocp_qp_set_ubu(k, ubu + k * nv, qp);
    }
    d_ocp_qp_set_q(N, q + N * ns, qp);
    d_ocp_qp_set_lbx(N, lbx + N * nb, qp);
    d_ocp_qp_set_ubx(N, ubx + N * nb, qp);
    d_ocp_qp_ipm_solve(qp, sol, arg, ws);
    d_ocp_qp_ipm_get_status(ws, &status);
    d_ocp_qp_ipm_get_iter(ws, iter);
    for (k = 0; k < N; ++k) {
        d_ocp_qp_sol_get_u(k, sol, u + k * nv);
        d_ocp_qp_sol_get_pi(k, sol, pi + k * ns);
        d_ocp_qp_sol_get_x(k + 1, sol, x + (k + 1) * ns);
    }
    return status;
}
"""


LIBRARY_ENV = "TRQ_HPIPM_LIBRARY"


def library_path() -> Path | None:
    """The libhpipm to load: $TRQ_HPIPM_LIBRARY if set (another build, e.g. one on BLASFEO's
    tuned kernels: `trq-hpipm-fetch` unpacks one; its BLASFEO inside it or beside it), else the
    one of the installed CasADi (next to its own libraries), or None."""
    other = os.environ.get(LIBRARY_ENV)
    if other:
        return Path(other)
    return bundled_path()


def library_label() -> str:
    """Which libhpipm a process started now would solve its QPs with, for a run's record:
    "CasADi's <path>" or "$TRQ_HPIPM_LIBRARY <path>" (or "none found"). Two libraries fly the
    same flight with other last bits (BLASFEO's kernels differ), so a run says which."""
    path = library_path()
    if path is None:
        return "none found"
    return f"${LIBRARY_ENV} {path}" if os.environ.get(LIBRARY_ENV) else f"CasADi's {path}"


def bundled_path() -> Path | None:
    """libhpipm of the installed CasADi (next to its own libraries), or None."""
    try:
        import casadi
    except ImportError:
        return None
    base = Path(casadi.__file__).resolve().parent
    names = {"linux": ["libhpipm.so"], "darwin": ["libhpipm.dylib"],
             "win32": ["libhpipm.dll", "hpipm.dll"]}.get(sys.platform, ["libhpipm.so"])
    for name in names:
        if (base / name).is_file():
            return base / name
    return None


_LOCAL = os.RTLD_LOCAL if hasattr(os, "RTLD_LOCAL") else 0
BLASFEO_NAMES = ("libblasfeo.so", "libblasfeo.so.0", "libblasfeo.dylib", "blasfeo.dll")


def _mapped(path: Path) -> bool:
    """`path` is already mapped into this process (Linux: /proc/self/maps; elsewhere False)."""
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as f:
            target = str(path.resolve())
            return any(line.rstrip("\n").endswith(target) for line in f)
    except OSError:
        return False


def _load_other(path: Path) -> ctypes.CDLL:
    """Another build's libhpipm (OSError, naming the reason, if it cannot serve here). Its
    BLASFEO beside it is loaded first, locally: the library's NEEDED entry resolves to it, and
    its symbols stay out of CasADi's way. A BLASFEO that reports (blasfeo_processor_cpu_features)
    that this processor lacks an instruction set it was built for is refused before any of its
    kernels runs. CasADi's own libhpipm already in the process (casadi.conic's plugin loaded it)
    shares this one's soname, so the compiled shim could bind to either: refused too."""
    bundled = bundled_path()
    if bundled is not None and _mapped(bundled):
        raise OSError("CasADi's own libhpipm is already loaded in this process "
                      "(casadi.conic('hpipm')): the two share a soname")
    for name in BLASFEO_NAMES:
        blas_path = path.parent / name
        if not blas_path.is_file():
            continue
        blas = ctypes.CDLL(str(blas_path), mode=_LOCAL)
        check = getattr(blas, "blasfeo_processor_cpu_features", None)
        if check is not None:
            check.restype, check.argtypes = ctypes.c_int, [ctypes.POINTER(ctypes.c_int)]
            have = ctypes.c_int(0)
            if check(ctypes.byref(have)) == 0:
                need = ctypes.create_string_buffer(256)
                blas.blasfeo_processor_library_string(need)
                raise OSError(f"this processor lacks instructions {blas_path} was built for "
                              f"(it needs {need.value.decode(errors='replace').strip()})")
        break
    return ctypes.CDLL(str(path), mode=_LOCAL)


def loaded_library() -> Path | None:
    """The libhpipm the direct binding loaded in this process (None before its first use or
    when it could not load one)."""
    return _LIB_PATH if _LIB is not None else None


def other_loaded() -> Path | None:
    """The libhpipm of another build ($TRQ_HPIPM_LIBRARY) in use in this process, or None."""
    return _LIB_PATH if _LIB is not None and _LIB_PATH != bundled_path() else None


def check_conic() -> None:
    """Before casadi.conic('hpipm'): RuntimeError if another build's libhpipm is in use here
    (CasADi's plugin would bind to it by their common soname, a different ABI)."""
    other = other_loaded()
    if other is not None:
        raise RuntimeError(f"casadi.conic('hpipm') cannot run in a process that loaded {other} "
                           f"(${LIBRARY_ENV}): CasADi's plugin would bind to it; use the direct "
                           "interface (hpipm_interface: direct) or unset the variable")


def _load() -> ctypes.CDLL | None:
    global _LIB, _LIB_ERROR
    if _LIB is not None or _LIB_ERROR is not None:
        return _LIB
    path = library_path()
    if path is None:
        _LIB_ERROR = "libhpipm not found next to casadi"
        return None
    try:
        try:
            lib = (ctypes.CDLL(str(path), mode=_LOCAL) if path == bundled_path()
                   else _load_other(path))
        except OSError as exc:
            if path == bundled_path():
                raise
            import warnings
            warnings.warn(f"${LIBRARY_ENV}={path} could not be loaded ({exc}): the HPIPM "
                          "bundled with CasADi is used", RuntimeWarning, stacklevel=2)
            path = bundled_path()
            if path is None:
                raise
            lib = ctypes.CDLL(str(path), mode=_LOCAL)
        global _LIB_PATH
        _LIB_PATH = path
        P, I, S = ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t
        sig = {
            "d_ocp_qp_dim_strsize": (S,), "d_ocp_qp_dim_memsize": (S, I),
            "d_ocp_qp_dim_create": (None, I, P, P),
            "d_ocp_qp_strsize": (S,), "d_ocp_qp_memsize": (S, P),
            "d_ocp_qp_create": (None, P, P, P),
            "d_ocp_qp_sol_strsize": (S,), "d_ocp_qp_sol_memsize": (S, P),
            "d_ocp_qp_sol_create": (None, P, P, P),
            "d_ocp_qp_ipm_arg_strsize": (S,), "d_ocp_qp_ipm_arg_memsize": (S, P),
            "d_ocp_qp_ipm_arg_create": (None, P, P, P),
            "d_ocp_qp_ipm_arg_set_default": (None, I, P),
            "d_ocp_qp_ipm_arg_set_iter_max": (None, P, P),
            "d_ocp_qp_ipm_arg_set_warm_start": (None, P, P),
            **{f"d_ocp_qp_ipm_arg_set_{name}": (None, P, P) for name in ARG_OPTIONS},
            "d_ocp_qp_ipm_ws_strsize": (S,), "d_ocp_qp_ipm_ws_memsize": (S, P, P),
            "d_ocp_qp_ipm_ws_create": (None, P, P, P, P),
            "d_ocp_qp_ipm_solve": (None, P, P, P, P),
            "d_ocp_qp_ipm_get_status": (None, P, P),
            "d_ocp_qp_ipm_get_iter": (None, P, P),
        }
        for name in ("nx", "nu", "nbx", "nbu", "ng", "ns"):
            sig[f"d_ocp_qp_dim_set_{name}"] = (None, I, I, P)
        for name in ("A", "B", "b", "Q", "S", "R", "q", "r", "lbx", "ubx", "lbu", "ubu",
                     "idxbx", "idxbu"):
            sig[f"d_ocp_qp_set_{name}"] = (None, I, P, P)
        for name in ("u", "x", "pi"):
            sig[f"d_ocp_qp_sol_get_{name}"] = (None, I, P, P)
        for name, (res, *args) in sig.items():
            f = getattr(lib, name)
            f.restype, f.argtypes = res, args
    except (OSError, AttributeError) as exc:
        _LIB_ERROR = f"{path}: {exc}"
        return None
    _LIB = lib
    return lib


def compiled_against(name: str, source: str) -> Path | None:
    """A shared library built from C `source` and linked against the libhpipm loaded here (by
    its file name: it calls into that one), compiled once and cached (`cache.compiled_c`); None
    without a compiler or when the build fails. Without contraction into fused multiply-adds,
    so that its arithmetic is NumPy's on every platform."""
    from trq_offboard.nmpc.cache import compiled_c
    loaded = _LIB_PATH or library_path()
    lib_dir = str(loaded.parent)
    return compiled_c(name, source, ("-ffp-contract=off", f"-L{lib_dir}",
                                     f"-Wl,-rpath,{lib_dir}", f"-l:{loaded.name}"))


def _load_shim() -> ctypes.CDLL | None:
    """The compiled per-solve shim, or None (no compiler: the loop runs through ctypes)."""
    global _SHIM
    if _SHIM is None:
        _SHIM = False
        path = compiled_against("trq_hpipm_shim", _SHIM_SOURCE)
        if path is not None:
            try:
                shim = ctypes.CDLL(str(path))
                f = shim.trq_hpipm_solve
                f.restype = ctypes.c_int
                f.argtypes = ([ctypes.c_int] * 4 + [ctypes.c_void_p] * 5 + [ctypes.c_int]
                              + [ctypes.c_void_p, ctypes.c_int] + [ctypes.c_void_p] * 11)
                _SHIM = shim
            except OSError:
                pass
    return _SHIM or None


def available() -> tuple[bool, str]:
    """(loaded, why not)."""
    return (_load() is not None, _LIB_ERROR or "")


def _aligned(nbytes: int) -> tuple[np.ndarray, int]:
    """A zeroed buffer and the address of its first 64-byte aligned byte (HPIPM/BLASFEO align)."""
    buf = np.zeros(int(nbytes) + 128, np.uint8)
    addr = buf.ctypes.data
    return buf, addr + (-addr) % 64


class OcpQp:
    """HPIPM OCP QP of horizon N with stage state ns (none at stage 0) and stage input nv (none
    at stage N); state boxes on idxbx (the same at every stage 1..N), every input boxed."""

    def __init__(self, ns: int, nv: int, N: int, idxbx, mode: str = "speed",
                 iter_max: int = 50, shim: bool = True, options: dict | None = None):
        lib = _load()
        if lib is None:
            raise RuntimeError(f"HPIPM is not available: {_LIB_ERROR}")
        if mode not in MODES:
            raise ValueError(f"hpipm mode {mode!r}: expected one of {', '.join(MODES)}")
        self._lib, self.N, self.ns, self.nv = lib, N, ns, nv
        self.idxbx = np.asarray(idxbx, np.int32)
        nb = self.idxbx.size
        keep = []                                         # buffers HPIPM points into

        def struct_and_mem(strsize, memsize_args, memsize_fn):
            s, sa = _aligned(strsize())
            m, ma = _aligned(memsize_fn(*memsize_args))
            keep.extend([s, m])
            return sa, ma

        dim_s, dim_m = struct_and_mem(lib.d_ocp_qp_dim_strsize, (N,), lib.d_ocp_qp_dim_memsize)
        lib.d_ocp_qp_dim_create(N, dim_s, dim_m)
        for k in range(N + 1):
            nxk, nuk = (0 if k == 0 else ns), (0 if k == N else nv)
            lib.d_ocp_qp_dim_set_nx(k, nxk, dim_s)
            lib.d_ocp_qp_dim_set_nu(k, nuk, dim_s)
            lib.d_ocp_qp_dim_set_nbx(k, 0 if k == 0 else nb, dim_s)
            lib.d_ocp_qp_dim_set_nbu(k, nuk, dim_s)
            lib.d_ocp_qp_dim_set_ng(k, 0, dim_s)
            lib.d_ocp_qp_dim_set_ns(k, 0, dim_s)
        qp_s, qp_m = struct_and_mem(lib.d_ocp_qp_strsize, (dim_s,), lib.d_ocp_qp_memsize)
        lib.d_ocp_qp_create(dim_s, qp_s, qp_m)
        sol_s, sol_m = struct_and_mem(lib.d_ocp_qp_sol_strsize, (dim_s,),
                                      lib.d_ocp_qp_sol_memsize)
        lib.d_ocp_qp_sol_create(dim_s, sol_s, sol_m)
        def struct(nbytes):
            buf, addr = _aligned(nbytes)
            keep.append(buf)
            return addr

        arg_s = struct(lib.d_ocp_qp_ipm_arg_strsize())
        def ipm(dim, arg):
            lib.d_ocp_qp_ipm_arg_create(dim, arg, struct_mem_arg(dim))
            lib.d_ocp_qp_ipm_arg_set_default(MODES[mode], arg)
            it = ctypes.c_int(int(iter_max))
            lib.d_ocp_qp_ipm_arg_set_iter_max(ctypes.byref(it), arg)
            for name, value in (options or {}).items():
                if name not in ARG_OPTIONS:
                    raise ValueError(f"hpipm option {name!r}: expected one of "
                                     f"{', '.join(ARG_OPTIONS)}")
                getattr(lib, f"d_ocp_qp_ipm_arg_set_{name}")(
                    ctypes.byref(ARG_OPTIONS[name](value)), arg)
            ws_s = _aligned(lib.d_ocp_qp_ipm_ws_strsize())
            ws_m = _aligned(lib.d_ocp_qp_ipm_ws_memsize(dim, arg))
            keep.extend([ws_s[0], ws_m[0]])
            lib.d_ocp_qp_ipm_ws_create(dim, arg, ws_s[1], ws_m[1])
            return ws_s[1]

        def struct_mem_arg(dim):
            return struct(lib.d_ocp_qp_ipm_arg_memsize(dim))

        ws = ipm(dim_s, arg_s)
        self._qp, self._sol, self._arg, self._ws = qp_s, sol_s, arg_s, ws
        self._keep = keep
        self._idxbx_addr = self.idxbx.ctypes.data
        self._idxbu = np.arange(nv, dtype=np.int32)
        for k in range(N + 1):
            if k > 0:
                lib.d_ocp_qp_set_idxbx(k, self._idxbx_addr, qp_s)
            if k < N:
                lib.d_ocp_qp_set_idxbu(k, self._idxbu.ctypes.data, qp_s)
        # output buffers
        self.x = np.zeros((N + 1, ns))
        self.u = np.zeros((N, nv))
        self.pi = np.zeros((N, ns))
        self._status, self._iter = ctypes.c_int(0), ctypes.c_int(0)
        self.status, self.iterations = 0, 0
        self._shim = _load_shim() if shim else None
        self.uses_shim = self._shim is not None

    @property
    def handles(self) -> tuple:
        """The addresses of HPIPM's QP, solution, argument and workspace structs:
        `trq_hpipm_solve`'s arguments, for compiled callers that solve this QP themselves
        (nmpc/feedback.py)."""
        return (self._qp, self._sol, self._arg, self._ws)

    # --- data ------------------------------------------------------------------------------
    def set_hessian(self, H, HN) -> None:
        """Stage Hessians H (N, ns + nv, ns + nv) of [s; v] (or one for all stages) and the
        terminal HN (ns, ns). Stage 0 uses only its input block (its state is eliminated)."""
        ns, N, lib, qp = self.ns, self.N, self._lib, self._qp
        H = np.asarray(H, float)
        if H.ndim == 2:
            H = np.broadcast_to(H, (N,) + H.shape)
        self._hq = np.asfortranarray(H[:, :ns, :ns].transpose(1, 2, 0))     # (ns, ns, N)
        self._hs = np.asfortranarray(H[:, ns:, :ns].transpose(1, 2, 0))     # (nv, ns, N)
        self._hr = np.asfortranarray(H[:, ns:, ns:].transpose(1, 2, 0))     # (nv, nv, N)
        self._hn = np.asfortranarray(np.asarray(HN, float))
        for k in range(N):
            lib.d_ocp_qp_set_R(k, self._hr[:, :, k].ctypes.data, qp)
            if k > 0:
                lib.d_ocp_qp_set_Q(k, self._hq[:, :, k].ctypes.data, qp)
                lib.d_ocp_qp_set_S(k, self._hs[:, :, k].ctypes.data, qp)
        lib.d_ocp_qp_set_Q(N, self._hn.ctypes.data, qp)

    def solve(self, At, Bt, b, q, r, lbx, ubx, lbu, ubu):
        """At (N, ns, ns) and Bt (N, nv, ns): the transposes of A_k and B_k (so that each stage's
        block is A_k column-major), b (N, ns) (b[0] already holding A_0 ds0), q (N+1, ns)
        (q[0] unused), r (N, nv) (r[0] with S_0 ds0 folded in), lbx/ubx (N+1, nb) (row 0
        unused), lbu/ubu (N, nv). Returns (x (N+1, ns) with x[0] = 0, u (N, nv), pi (N, ns));
        `status` (0 converged, 1 iteration limit, 2 minimum step, 3 NaN) and `iterations`."""
        lib, qp, N = self._lib, self._qp, self.N
        # column-major per stage: (N, rows, cols) -> per stage a Fortran block
        A = np.ascontiguousarray(At, dtype=float)
        B = np.ascontiguousarray(Bt, dtype=float)
        arrays = [np.ascontiguousarray(a, dtype=float) for a in (b, q, r, lbx, ubx, lbu, ubu)]
        b, q, r, lbx, ubx, lbu, ubu = arrays
        if self._shim is not None:
            self.status = self._shim.trq_hpipm_solve(
                N, self.ns, self.nv, self.idxbx.size, qp, self._sol, self._arg, self._ws,
                A.ctypes.data, self.ns * self.ns, B.ctypes.data, self.ns * self.nv,
                b.ctypes.data, q.ctypes.data, r.ctypes.data,
                lbx.ctypes.data, ubx.ctypes.data, lbu.ctypes.data, ubu.ctypes.data,
                self.x.ctypes.data, self.u.ctypes.data, self.pi.ctypes.data,
                ctypes.addressof(self._iter))
            self.iterations = self._iter.value
            return self.x, self.u, self.pi
        # without the shim: the same calls from Python (field, data, stages)
        inner, states, inputs = range(1, N), range(1, N + 1), range(N)
        for name, arr, stages in (("A", A, inner), ("B", B, inputs), ("b", b, inputs),
                                  ("q", q, states), ("r", r, inputs), ("lbx", lbx, states),
                                  ("ubx", ubx, states), ("lbu", lbu, inputs),
                                  ("ubu", ubu, inputs)):
            fn, ptr, stride = getattr(lib, f"d_ocp_qp_set_{name}"), arr.ctypes.data, arr.strides[0]
            for k in stages:
                fn(k, ptr + k * stride, qp)
        lib.d_ocp_qp_ipm_solve(qp, self._sol, self._arg, self._ws)
        lib.d_ocp_qp_ipm_get_status(self._ws, ctypes.byref(self._status))
        lib.d_ocp_qp_ipm_get_iter(self._ws, ctypes.byref(self._iter))
        self.status, self.iterations = self._status.value, self._iter.value
        for name, arr, stages in (("u", self.u, inputs), ("pi", self.pi, inputs),
                                  ("x", self.x, states)):
            fn, ptr, stride = (getattr(lib, f"d_ocp_qp_sol_get_{name}"), arr.ctypes.data,
                               arr.strides[0])
            for k in stages:
                fn(k, self._sol, ptr + k * stride)
        return self.x, self.u, self.pi
