"""The filter's CasADi functions as one compiled library, cached on disk and never committed
(the vehicle's own small equivalent of trq_offboard.nmpc.cache, which it may not import).

    calls, how = load(functions(g))     # how: "compiled" | "cached" | "interpreted"
    x_next, P_next = calls["predict"](x, P, dA, dV, dt, a, qd)

All functions go into one C file (casadi.CodeGenerator), built once into a shared library with
trq_wire.cache.build_library and called through ctypes with preallocated buffers (an `Evaluator`
per function: the generated C entry point, `name(arg, res, iw, w, mem)`, on NumPy arrays; calling
through casadi.external costs tens of microseconds of conversion per call, more than the
arithmetic). Each call returns dense NumPy arrays (matrices column-major as CasADi's, shaped)
that the next call of the same function overwrites: copy what you keep. The cache key is a
SHA-256 of the generated source, the CasADi version, the compiler and its flags: the source holds
the whole formulation, so a change of equations gives a new library and nothing else does.
Without a C compiler, or when the build fails, the Functions are returned as they are (CasADi's
interpreter, the same arithmetic, slower) with a RuntimeWarning.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import warnings
from pathlib import Path

import casadi as ca
import numpy as np

from trq_wire.cache import build_library, built_once, cache_dir, find_compiler

__all__ = ["CFLAGS", "Evaluator", "load"]

# -O1: builds faster than -O2 for the same speed on generated CasADi code (the controller's
# finding, docs/decisions/2026-12-02-figures-from-comments.md)
CFLAGS = ("-O1", "-fPIC", "-shared")


def _source(fns: dict[str, ca.Function]) -> str:
    cg = ca.CodeGenerator("sil_eskf.c", {"with_header": False})
    for name in sorted(fns):
        cg.add(fns[name])
    return cg.dump()


class Evaluator:
    """One function of the library: inputs copied into its buffers, outputs read from its."""

    def __init__(self, fn: ca.Function, lib: ctypes.CDLL | None) -> None:
        self.name = fn.name()
        self._fn = fn if lib is None else None
        self._in = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        # what an input is written through: a matrix as its column-major view, else flat
        self._in_views = [b.reshape(fn.size_in(i), order="F") if min(fn.size_in(i)) > 1 else b
                          for i, b in enumerate(self._in)]
        self._nz = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._out = [np.zeros(fn.size_out(i), order="F") for i in range(fn.n_out())]
        self._scatter = []
        for i in range(fn.n_out()):
            sp = fn.sparsity_out(i)
            if sp.is_dense():
                self._out[i] = self._nz[i].reshape(fn.size_out(i), order="F")
                self._scatter.append(None)
            else:
                rows, cols = sp.get_triplet()
                self._scatter.append((np.array(rows, int), np.array(cols, int)))
        if lib is None:
            return
        c_ptr = ctypes.c_void_p
        self._arg = (c_ptr * max(fn.sz_arg(), 1))(*[b.ctypes.data for b in self._in])
        self._res = (c_ptr * max(fn.sz_res(), 1))(*[b.ctypes.data for b in self._nz])
        self._iw = (ctypes.c_longlong * max(fn.sz_iw(), 1))()
        self._w = (ctypes.c_double * max(fn.sz_w(), 1))()
        self._c = getattr(lib, self.name)
        self._c.restype = ctypes.c_int

    def __call__(self, *inputs) -> tuple[np.ndarray, ...]:
        for view, v in zip(self._in_views, inputs):
            view[...] = v
        if self._fn is None:
            if self._c(self._arg, self._res, self._iw, self._w, 0):
                raise RuntimeError(f"{self.name} failed")
        else:
            args = [b.reshape(self._fn.size_in(i), order="F") for i, b in enumerate(self._in)]
            for buf, v in zip(self._nz, self._fn.call(args)):
                buf[:] = np.asarray(v.nonzeros())
        for i, s in enumerate(self._scatter):
            if s is not None:
                self._out[i][s] = self._nz[i]
        return tuple(self._out)


def load(fns: dict[str, ca.Function], enabled: bool = True, key: tuple | None = None
         ) -> tuple[dict[str, Evaluator], str]:
    """An Evaluator per function of `fns` (on one compiled, cached library, or on CasADi's
    interpreter when `enabled` is False or no library can be built), and how it was obtained.
    `key`, when given, names what `fns` are a function of: the library is then looked up once
    per process for it (trq_wire.cache.built_once), not by generating its source each time."""
    if not enabled:
        lib_path, how = None, "interpreted"
    elif key is None:
        lib_path, how = _library(fns)
    else:
        (lib_path, how), fresh = built_once(("estimator library", key), lambda: _library(fns))
        how = how if fresh or how == "interpreted" else "cached"
    lib = ctypes.CDLL(str(lib_path)) if lib_path is not None else None
    return {k: Evaluator(f, lib) for k, f in fns.items()}, how


def _library(fns: dict[str, ca.Function]) -> tuple[Path | None, str]:
    cc = find_compiler()
    if cc is None:
        warnings.warn("no C compiler found (tried $CC, gcc, cc, clang): the estimator's "
                      "functions run in CasADi's interpreter (slower)", RuntimeWarning,
                      stacklevel=3)
        return None, "interpreted"
    src = _source(fns)
    h = hashlib.sha256()
    for part in (ca.__version__, os.path.basename(cc), " ".join(CFLAGS), src):
        h.update(part.encode())
        h.update(b"\0")
    lib = cache_dir() / f"sil_eskf_{h.hexdigest()[:20]}.so"
    if lib.exists():
        return lib, "cached"
    error = build_library(cc, list(CFLAGS), src, lib, ["-lm"])
    if error is not None:
        warnings.warn(f"building the estimator's functions failed ({error}): they run in "
                      "CasADi's interpreter", RuntimeWarning, stacklevel=3)
        return None, "interpreted"
    return lib, "compiled"
