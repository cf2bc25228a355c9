"""The flight plan's grid in C: `grid_kernel()`, the function Reference.grid calls where a C
compiler is found (reference_core.c). Why: the controller samples the plan at the horizon's
N + 1 points once a period, each point a dozen Python calls (phases, ramps, trigonometry),
a share of its whole period (issue 39, item 5).

The same figures to the bit: reference_core.c repeats Reference._pv's expressions in Python's
order with libm's pow, sin and cos, built without fused multiply-adds and without the
compiler's builtins; tests/unit/trq_offboard/test_reference.py holds the grid to sample() byte
for byte. Reference._pv stays the specification, and the path without a compiler.

Built once a process (trq_wire.cache.built_once), the library cached on disk as the
controller's other compiled parts (nmpc/cache.py's compiled_c).
"""

from __future__ import annotations

import ctypes
from pathlib import Path

__all__ = ["PARAMS", "KINDS", "grid_kernel"]

SOURCE = Path(__file__).with_name("reference_core.c")
# Python's rounding: no fused multiply-adds, no fast-math, and libm's pow called as CPython's
# float ** calls it (GCC's builtin would make pow(x, 2.0) a product)
FLAGS = ("-ffp-contract=off", "-fno-fast-math", "-fno-builtin", "-lm")
# the plan's figures in the order reference_core.c reads them (its enum P_*)
PARAMS = ("t0", "t1", "t2", "t3", "t4", "t5", "t_takeoff", "t_land",
          "start_n", "start_e", "start_d", "hover_n", "hover_e", "hover_d",
          "end_n", "end_e", "end_d", "ground", "w", "T", "r", "full_ramp", "phi_end",
          "radius", "helix_climb", "step_n", "step_e", "step_d", "duration", "kind", "land",
          "land_below", "crawl", "crawl_ramp")
KINDS = ("hover", "step", "circle", "helix", "figure8")


def grid_kernel():
    """trq_reference_grid(params, t0, step, n, out) of the built library, or None without a C
    compiler (or when the build fails)."""
    from trq_offboard.nmpc.cache import loaded_c
    from trq_wire.cache import built_once

    def build():
        fns = loaded_c("trq_reference", SOURCE.read_text(), FLAGS,
                       ("trq_reference_params", len(PARAMS), "figures"),
                       {"trq_reference_grid": (ctypes.c_void_p, ctypes.c_double,
                                               ctypes.c_double, ctypes.c_int, ctypes.c_void_p)})
        return fns[0] if fns else None

    return built_once(("reference core",), build)[0]
