"""The real-time iteration's next linearisation point in one compiled call (guess_core.c).

After each step the controller prepares the next one at its plan shifted by the time that will
have elapsed: the plan's states interpolated at elapsed + k h and its inputs taken at the rows
they then fall in (Controller._prepare and _guess), the reference states from the flight
plan's grid with the yaw unwrapped next to the first row's (Controller._reference_states),
all packed into the OCP's decision vector and clipped to its bounds (Ocp.pack, RtiSolver.
prepare). In NumPy that is some forty small array operations a control period, each costing
more in the interpreter than in arithmetic (issue 39, item 5: the whole period's target);
`GuessKernel` does it in one ctypes call, writing the decision vector and the reference
straight into the compiled preparation's input buffers. Its `unpack`, the solve's Ocp.unpack
of its step (the plan's copies and scalings), is a second function of the same library.

The same figures to the bit: guess_core.c repeats the NumPy operations in their order, built
without fused multiply-adds; tests/consistency/test_rti_guess.py holds the preparation it leads
to against the NumPy path's, field by field, in every layout of the stage. The NumPy path stays
the specification, and the path without a C compiler.

Built once a process (trq_wire.cache.built_once), the library cached on disk as the
controller's other compiled parts (nmpc/cache.py's compiled_c).
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np

__all__ = ["GuessKernel", "available"]

SOURCE = Path(__file__).with_name("guess_core.c")
# NumPy's rounding: no fused multiply-adds, no fast-math; libm's fmod for the remainder
FLAGS = ("-ffp-contract=off", "-fno-fast-math", "-lm")


def _functions():
    """(trq_guess, trq_unpack) of the built library, or None without a C compiler (or when
    the build fails)."""
    from trq_offboard.nmpc.cache import loaded_c
    from trq_wire.cache import built_once

    def build():
        p = ctypes.c_void_p
        return loaded_c("trq_guess", SOURCE.read_text(), FLAGS,
                        ("trq_guess_ndims", len(_DIMS), "dimensions"),
                        {"trq_guess": (p, p, p), "trq_unpack": (p, p)})

    return built_once(("guess core",), build)[0]


_DIMS = ("N", "nx", "nu", "ns", "nv", "n_lag", "tilting")     # guess_core.c's enum G_*


def available() -> bool:
    """The kernel could be built and loaded here (a C compiler)."""
    return _functions() is not None


class GuessKernel:
    """The next linearisation point of one OCP (Ocp: its layout, its bounds lbw and ubw, which
    it reads where they are: Ocp.set_throttle_scale changes them in place), written into `w`
    and `x_ref` (the compiled preparation's input buffers: flat, nw and (N+1) nx, C-contiguous
    float64) and into its own `xr_w` (nw). Raises RuntimeError when the kernel is unavailable,
    ValueError when a buffer or the OCP's layout is not what it writes."""

    def __init__(self, ocp, w: np.ndarray, x_ref: np.ndarray) -> None:
        fns = _functions()
        if fns is None:
            raise RuntimeError("the compiled RTI guess is not available (no C compiler)")
        if not ocp.stage_major():
            raise ValueError("the OCP's decision vector is not stage-major [s_0, v_0, ..., s_N]")
        N, nx, nu, ns, nv, n_lag = ocp.n_steps, ocp.nx, ocp.nu, ocp.ns, ocp.nv, ocp.n_lag
        nw = ocp.lbw.size
        if ocp.tilting and nu != 8:
            raise ValueError(f"a tilting OCP's input is 8 wide (got {nu})")
        if n_lag not in (0, nu):
            raise ValueError(f"actuator lag states: none or one per input (got {n_lag} for {nu})")
        for name, buf, size in (("w", w, nw), ("x_ref", x_ref, (N + 1) * nx)):
            if buf.size != size or buf.dtype != np.float64 or not buf.flags.c_contiguous:
                raise ValueError(f"compiled RTI guess: {name} must be {size} float64, "
                                 f"C-contiguous (got {buf.size} {buf.dtype})")
        (self._fn, self._unpack), self.ocp = fns, ocp
        self.w = w
        self.xr_w = np.zeros(nw)
        self._dims = np.array([N, nx, nu, ns, nv, n_lag, int(ocp.tilting)], np.intc)
        self._sc = np.zeros(3)
        self._sc[2] = ocp.step_s
        assert ocp.lbw.flags.c_contiguous and ocp.ubw.flags.c_contiguous
        self._u_scale = np.ascontiguousarray(ocp.u_scale, float).reshape(nu)
        self._lag_gain = (np.ascontiguousarray(ocp.lag_gain, float).reshape(nu) if n_lag
                          else np.zeros(nu))
        # the call's inputs, copied in (any layout and dtype a copy converts)
        self._x_old = np.zeros((N + 1, nx))
        self._u_old = np.zeros((N, nu))
        self._pv = np.zeros((N + 1, 6))
        self._yaw_ref = np.zeros(N + 1)
        self._a_prev = np.zeros(4)
        self._y0 = np.zeros(nu)
        self._xs = np.zeros((N + 1, nx))           # work
        self._ys = np.zeros(nu)
        ptrs = [a.ctypes.data for a in (
            self._x_old, self._u_old, self._pv, self._yaw_ref, self._a_prev, self._y0,
            ocp.lbw, ocp.ubw, self._u_scale, self._lag_gain, w, x_ref, self.xr_w, self._xs,
            self._ys)]
        self._st = (ctypes.c_void_p * len(ptrs))(*ptrs)
        self._dims_ptr, self._sc_ptr = self._dims.ctypes.data, self._sc.ctypes.data
        # unpack's: w in, the plan out
        self._w_in = np.zeros(nw)
        self._u_out = np.zeros((N, nu))
        self._x_out = np.zeros((N + 1, nx))
        ptrs = [a.ctypes.data for a in (self._w_in, self._u_scale, self._u_out, self._x_out)]
        self._st_unpack = (ctypes.c_void_p * len(ptrs))(*ptrs)
        self._keep = (ocp.lbw, ocp.ubw)              # C reads them where they are

    def __call__(self, plan, elapsed_s: float, h_s: float, pv, yaw_ref, u_prev, y0=None
                 ) -> None:
        """The plan (u (N, nu), x (N+1, nx)) made elapsed_s ago, its rows h_s apart, shifted,
        packed and clipped into w; the reference's grid from then (pv (N+1, 6), yaw_ref (N+1))
        into x_ref and xr_w. u_prev: the applied input (its tilts are s_0's); y0: the
        actuators' outputs when the plan starts (lag states; default u_prev)."""
        if self.ocp.lbw is not self._keep[0] or self.ocp.ubw is not self._keep[1]:
            raise RuntimeError("the OCP's bounds were replaced: the kernel holds their address")
        u_old, x_old = plan
        self._u_old[...] = u_old
        self._x_old[...] = x_old
        self._pv[...] = pv
        self._yaw_ref[...] = yaw_ref
        if self.ocp.tilting:
            self._a_prev[...] = np.asarray(u_prev, float)[0:4]
        if self.ocp.n_lag:
            self._y0[...] = u_prev if y0 is None else y0
        self._sc[0] = elapsed_s
        self._sc[1] = h_s
        self._fn(self._dims_ptr, self._sc_ptr, self._st)

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ocp.unpack in one call: (u_plan (N, nu) physical, x_plan (N+1, nx)) of w (nw), new
        arrays."""
        self._w_in[...] = w
        self._unpack(self._dims_ptr, self._st_unpack)
        return self._u_out.copy(), self._x_out.copy()
