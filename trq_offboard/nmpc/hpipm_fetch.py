"""Fetch an HPIPM built on BLASFEO's tuned kernels for this processor, for the direct binding.

    trq-hpipm-fetch                       # download, unpack into the cache, check, print the path
    trq-hpipm-fetch --wheel FILE.whl      # from a wheel already here (an offline computer)
    export TRQ_HPIPM_LIBRARY=<the printed path>

The HPIPM that ships in CasADi's wheel runs on BLASFEO's generic kernels. comma.ai's
`comma-deps-acados` wheel (PyPI, the acados that openpilot flies; manylinux x86_64 and aarch64)
carries libhpipm with a libblasfeo built for a processor family: X64_INTEL_HASWELL (AVX2, FMA)
on x86_64, ARMV8A_ARM_CORTEX_A57 (NEON) on aarch64. Installing that wheel would also install the
slimmed CasADi it vendors over the project's: it is never installed. This command downloads it
(`pip download --no-deps`, the wheel for this interpreter's platform), takes its two libraries
out into `<cache>/hpipm/<wheel>/` ($TRQ_CACHE_DIR, else ~/.cache/trq-ftc), and checks, in a
child process, that the binding loads them here (trq_offboard/nmpc/hpipm.py: the BLASFEO beside
libhpipm says whether this processor has the instructions it was built for). The controller
uses them only when $TRQ_HPIPM_LIBRARY names that libhpipm; unset, CasADi's is used. What the
tuned kernels gave on the benchmark machine: docs/decisions/2026-12-03-tuned-hpipm-wheel.md.

Exit status: 0 with the path printed, 1 when the download, the unpacking or the check failed
(the reason printed), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from trq_wire.cache import cache_dir

__all__ = ["PACKAGE", "TESTED", "LIBRARIES", "unpack", "check", "main"]

PACKAGE = "comma-deps-acados"
TESTED = "0.2.2.post92"               # the version the direct binding was tested against
LIBRARIES = ("libhpipm.so", "libblasfeo.so")
_LIB_DIR = "acados/install/lib/"      # inside the wheel's purelib data


class FetchError(RuntimeError):
    """Why the libraries could not be fetched, unpacked or loaded."""


def download(version: str, dest: Path) -> Path:
    """The wheel of PACKAGE==version for this interpreter's platform, downloaded into dest."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
           "--dest", str(dest), f"{PACKAGE}=={version}"]
    run = subprocess.run(cmd, capture_output=True, text=True)
    wheels = sorted(dest.glob("*.whl"))
    if run.returncode != 0 or not wheels:
        tail = (run.stderr or run.stdout).strip().splitlines()[-3:]
        raise FetchError(f"pip download {PACKAGE}=={version} failed (exit {run.returncode}): "
                         + " / ".join(tail))
    return wheels[0]


def unpack(wheel: Path, root: Path) -> Path:
    """LIBRARIES out of `wheel` into root/<wheel's name>/; returns the libhpipm path. FetchError
    naming the wheel if it is not a zip or lacks one of them."""
    wheel = Path(wheel)
    try:
        zf = zipfile.ZipFile(wheel)
    except (OSError, zipfile.BadZipFile) as exc:
        raise FetchError(f"{wheel}: not a wheel ({exc})") from None
    with zf:
        found = {}
        for name in zf.namelist():
            base = name.rsplit("/", 1)[-1]
            if base in LIBRARIES and name.endswith(_LIB_DIR + base):
                found[base] = name
        missing = [lib for lib in LIBRARIES if lib not in found]
        if missing:
            raise FetchError(f"{wheel}: no {', '.join(missing)} under .../{_LIB_DIR} (expected "
                             f"a {PACKAGE} wheel)")
        out = Path(root) / wheel.name.removesuffix(".whl")
        out.mkdir(parents=True, exist_ok=True)
        for base, name in found.items():
            tmp = out / (base + ".part")
            tmp.write_bytes(zf.read(name))
            os.replace(tmp, out / base)          # whole files only, even if interrupted
    return out / "libhpipm.so"


def check(path: Path) -> str:
    """Load `path` through the binding in a child process (this one keeps its own HPIPM) and
    solve a small QP; its description, or FetchError with the child's reason."""
    code = ("import numpy as np, warnings\n"
            "warnings.simplefilter('error')\n"
            "from trq_offboard.nmpc import hpipm\n"
            "ok, why = hpipm.available()\n"
            "assert ok and hpipm.other_loaded() is not None, why or 'not loaded'\n"
            "qp = hpipm.OcpQp(2, 1, 3, [0])\n"
            "qp.set_hessian(np.eye(3), np.eye(2))\n"
            "At = np.tile(np.eye(2), (3, 1, 1)); Bt = np.ones((3, 1, 2))\n"
            "x, u, pi = qp.solve(At, Bt, np.zeros((3, 2)), np.ones((4, 2)), np.zeros((3, 1)),\n"
            "                    -np.ones((4, 1)), np.ones((4, 1)), -np.ones((3, 1)),\n"
            "                    np.ones((3, 1)))\n"
            "assert np.all(np.isfinite(x)) and qp.status == 0, qp.status\n"
            "print(hpipm.other_loaded())\n")
    env = dict(os.environ, TRQ_HPIPM_LIBRARY=str(path))
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    if run.returncode != 0:
        lines = (run.stderr or run.stdout).strip().splitlines()
        raise FetchError(f"{path} does not load or solve here: "
                         + (lines[-1] if lines else f"exit {run.returncode}"))
    return run.stdout.strip()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="trq-hpipm-fetch", description=__doc__.splitlines()[0],
                                allow_abbrev=False)
    p.add_argument("--wheel", type=Path, default=None,
                   help=f"a {PACKAGE} wheel already downloaded (no network)")
    p.add_argument("--version", default=TESTED,
                   help=f"the {PACKAGE} version to download (default {TESTED}, the one tested)")
    p.add_argument("--dest", type=Path, default=None,
                   help="where to unpack (default <cache>/hpipm: $TRQ_CACHE_DIR, else "
                        "~/.cache/trq-ftc)")
    p.add_argument("--no-check", action="store_true",
                   help="unpack only (for another computer: check there)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    root = args.dest if args.dest is not None else cache_dir() / "hpipm"
    try:
        if args.wheel is not None:
            path = unpack(args.wheel, root)
        else:
            with tempfile.TemporaryDirectory(prefix="trq-hpipm-") as tmp:
                path = unpack(download(args.version, Path(tmp)), root)
        if not args.no_check:
            check(path)
    except FetchError as exc:
        print(f"trq-hpipm-fetch: {exc}", file=sys.stderr)
        return 1
    print(f"export TRQ_HPIPM_LIBRARY={path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
