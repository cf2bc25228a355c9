"""The cache of generated and compiled code, shared by the vehicle's compiled physics tick and
the controller's compiled CasADi functions (generated code is cached on each machine, never committed).

Folder: $TRQ_CACHE_DIR, else ~/.cache/trq-ftc. Compiler: the first of $CC, gcc, cc, clang found
on PATH. A library is built under a temporary name in the cache folder and renamed into place,
so concurrent processes never load a half-written file. What goes into a cache key is each
caller's business; this module only says where files live and how they land there.

`built_once(key, build)` keeps what a build gave in memory for the rest of the process: a
controller, an observer or a filter built again with the same inputs (the next flight of a
campaign worker, the next test) neither rebuilds its symbolic functions nor generates their C
source again to find the library on disk. The key is the build's inputs; the cache folder and the
compiler are added to it, since a compiled build also depends on them.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

__all__ = ["cache_dir", "find_compiler", "build_library", "cached_library", "built_once",
           "forget_built"]

T = TypeVar("T")
# builds kept in memory, the least recently used dropped first (a campaign that perturbs the
# airframe per flight would otherwise keep one per flight)
BUILT_KEPT = 64
_BUILT: OrderedDict[tuple, object] = OrderedDict()


def cache_dir() -> Path:
    env = os.environ.get("TRQ_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "trq-ftc"


def find_compiler() -> str | None:
    """Absolute path of a C compiler on PATH ($CC, gcc, cc, clang), or None."""
    for name in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if name:
            path = shutil.which(name)
            if path:
                return path
    return None


def build_library(cc: str, flags: list[str], source: str, lib: Path,
                  after: list[str]) -> str | None:
    """Compile C `source` into the shared library `lib` (`cc flags file.c -o lib after`, built
    under a temporary name in lib's directory, then renamed into place). None on success, else
    what went wrong: the compiler's error, or an OSError (an unwritable cache directory, a
    vanished compiler)."""
    try:
        lib.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=lib.parent, prefix=".build-") as tmp:
            c_file = Path(tmp) / lib.with_suffix(".c").name
            c_file.write_text(source)
            out = Path(tmp) / lib.name
            res = subprocess.run([cc, *flags, str(c_file), "-o", str(out), *after],
                                 capture_output=True, text=True)
            if res.returncode != 0:
                return res.stderr.strip()[:300]
            os.replace(out, lib)
    except OSError as exc:
        return f"{lib.parent}: {exc}"
    return None


def cached_library(cc: str, flags: list[str], source_file: Path, prefix: str,
                   after: list[str]) -> Path:
    """The shared library of the C file `source_file`, built once per compiler, flags and
    source (its key: a hash of the three, in the name `PREFIX_KEY.so` in the cache folder) and
    reused after. RuntimeError naming the file when the build fails."""
    src = source_file.read_bytes()
    h = hashlib.sha256()
    for part in (os.path.basename(cc).encode(), " ".join(flags).encode(), src):
        h.update(part)
        h.update(b"\0")
    lib = cache_dir() / f"{prefix}_{h.hexdigest()[:20]}.so"
    if lib.exists():
        return lib
    error = build_library(cc, list(flags), src.decode("ascii"), lib, after)
    if error is not None:
        raise RuntimeError(f"{cc} failed on {source_file}: {error}")
    return lib


def built_once(key: tuple, build: Callable[[], T]) -> tuple[T, bool]:
    """(build(), True) the first time for `key` (hashable: everything the build is a function
    of) in this cache folder with this compiler; (the same object, False) after, for as long as
    the process keeps it. The result is shared: keep in it only what is never written to (the
    compiled functions, not the buffers they are evaluated into)."""
    full = (key, str(cache_dir()), find_compiler())
    if full in _BUILT:
        _BUILT.move_to_end(full)
        return _BUILT[full], False
    out = build()
    _BUILT[full] = out
    if len(_BUILT) > BUILT_KEPT:
        _BUILT.popitem(last=False)
    return out, True


def forget_built() -> None:
    """Drop every build kept by `built_once` (a benchmark timing a cold process's build)."""
    _BUILT.clear()
