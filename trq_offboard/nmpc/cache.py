"""Compiled CasADi functions, cached on disk and never committed.

    fn, how = compiled(casadi_function)      # how: "compiled" | "cached" | "interpreted"

The function is generated as C (casadi.CodeGenerator), compiled once into a shared library and
loaded with casadi.external. The cache key is a SHA-256 of the generated C source, the CasADi
version, the compiler and its flags: the source already contains the whole formulation with every
parameter baked in as a literal (mass, inertia, rotor geometry, step, weights), so any change of
formulation or parameters gives a new key and a new library, and nothing else does.

Cache directory, compiler and the build of a library: trq_wire.cache ($TRQ_CACHE_DIR, else
~/.cache/trq-ftc; a library is written to a temporary name and renamed into place, so concurrent
processes never load a half-written file).

No C compiler (none of $CC, gcc, cc, clang on PATH), or a failed compilation: the function is
returned as it is (CasADi's interpreter, the pure-Python path) with a RuntimeWarning.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import casadi as ca

from trq_wire.cache import build_library, built_once, cache_dir, find_compiler

__all__ = ["cache_dir", "find_compiler", "compiled", "compiled_many", "compiled_once",
           "compiled_c", "COUNTS", "CFLAGS"]

# -O1 builds faster than -O2 at the same speed (docs/decisions/2026-12-02-figures-from-comments.md)
CFLAGS = ("-O1", "-fPIC", "-shared")
COUNTS = {"compiled": 0, "cached": 0, "interpreted": 0}   # per process, for tests and benches


def _source(fn: ca.Function) -> str:
    cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
    cg.add(fn)
    return cg.dump()


def _key(source: str, cc: str) -> str:
    h = hashlib.sha256()
    for part in (ca.__version__, os.path.basename(cc), " ".join(CFLAGS), source):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def _build(fn: ca.Function, cc: str | None) -> tuple[ca.Function, str]:
    if cc is None:
        warnings.warn(f"no C compiler found (tried $CC, gcc, cc, clang): {fn.name()} runs in "
                      "CasADi's interpreter (slower)", RuntimeWarning, stacklevel=3)
        COUNTS["interpreted"] += 1
        return fn, "interpreted"
    src = _source(fn)
    root = cache_dir()
    lib = root / f"{fn.name()}_{_key(src, cc)}.so"
    if lib.exists():
        COUNTS["cached"] += 1
        return ca.external(fn.name(), str(lib)), "cached"
    error = build_library(cc, list(CFLAGS), src, lib, ["-lm"])
    if error is not None:
        warnings.warn(f"building {fn.name()} failed ({error}): it runs in CasADi's interpreter",
                      RuntimeWarning, stacklevel=3)
        COUNTS["interpreted"] += 1
        return fn, "interpreted"
    COUNTS["compiled"] += 1
    return ca.external(fn.name(), str(lib)), "compiled"


def compiled(fn: ca.Function, enabled: bool = True) -> tuple[ca.Function, str]:
    """fn as a compiled, cached external (or fn itself: interpreted) and how it was obtained."""
    if not enabled:
        COUNTS["interpreted"] += 1
        return fn, "interpreted"
    return _build(fn, find_compiler())


def compiled_many(fns: list[ca.Function], enabled: bool = True) -> list[tuple[ca.Function, str]]:
    """compiled() for several functions, the compilations run in parallel (one per core)."""
    if not enabled:
        return [compiled(f, False) for f in fns]
    cc = find_compiler()
    if cc is None or len(fns) == 1:
        return [_build(f, cc) for f in fns]
    with ThreadPoolExecutor(max_workers=min(len(fns), os.cpu_count() or 1)) as ex:
        return list(ex.map(lambda f: _build(f, cc), fns))


def compiled_once(key: tuple, build: Callable[[], ca.Function], enabled: bool = True
                  ) -> ca.Function:
    """compiled(build(), enabled)'s function, built and compiled once per process for `key`
    (everything `build` is a function of: trq_wire.cache.built_once); the same function after,
    without building it again or generating its source to look it up on disk."""
    (fn, _how), _ = built_once(("compiled", key, enabled), lambda: compiled(build(), enabled))
    return fn


def compiled_c(name: str, source: str, link_args: tuple[str, ...] = ()) -> Path | None:
    """A shared library built from C `source` (plus `link_args`), cached like the functions above
    (the key covers the source, the compiler, the flags and the link arguments); None without a
    compiler or when the compilation fails (with a RuntimeWarning naming the error)."""
    cc = find_compiler()
    if cc is None:
        return None
    root = cache_dir()
    lib = root / f"{name}_{_key(source + chr(0) + ' '.join(link_args), cc)}.so"
    if lib.exists():
        COUNTS["cached"] += 1
        return lib
    error = build_library(cc, ["-O2", "-fPIC", "-shared"], source, lib, list(link_args))
    if error is not None:
        warnings.warn(f"building {name} failed ({error})", RuntimeWarning, stacklevel=2)
        return None
    COUNTS["compiled"] += 1
    return lib


def loaded_c(name: str, source: str, link_args: tuple[str, ...], count: tuple[str, int, str],
             functions: dict[str, tuple]) -> list | None:
    """The functions (their argtypes as given, no result) of the library `compiled_c` builds
    from `source`, in `functions`' order; None without a compiler or when the build fails.
    `count`: (the library's function that returns how many items its source reads, how many
    the Python side names, what they are): a library that reads another number is a
    RuntimeError naming both, before anything calls it."""
    if find_compiler() is None:
        return None
    path = compiled_c(name, source, link_args)
    if path is None:
        return None
    lib = ctypes.CDLL(str(path))
    symbol, expected, what = count
    got = getattr(lib, symbol)()
    if got != expected:
        raise RuntimeError(f"{name}: its C reads {got} {what}, its Python names {expected}")
    out = []
    for fn_name, argtypes in functions.items():
        fn = getattr(lib, fn_name)
        fn.argtypes, fn.restype = argtypes, None
        out.append(fn)
    return out
