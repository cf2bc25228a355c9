"""The fused filter's step in C: `FusedCore`, FusedFilter's API (trq_offboard/fused.py) over
fused_core.c, which owns the filter's history and runs its bookkeeping (the samples placed in
the periods they cover, the gates' decisions, the periods run again) around the same compiled
kernel (FusedFilter's two-stretch kernel as two calls of it), in one call a period.

    f = fused_filter(cfg, gravity_m_s2)    # a FusedCore, or FusedFilter where no C compiler is
    f.reset(t_us, pos, vel, euler_rad=e)   # found or codegen is off
    f.add_imu(t_us, f_frd); f.add_pose(t_us, pos)
    health = f.step(t_us, a_known, euler_rad)

Why: the filter's Python around its kernels (a period object, a few dozen NumPy operations on
3-vectors, the arguments copied into the kernels' buffers) cost several times the kernels
themselves, a share of the controller's whole period (issue 39, item 5;
docs/decisions/2026-12-06-period-cuts-tried.md). Compiling that Python as it is did not help;
C that owns its data does.

The same figures to the bit: fused_core.c repeats FusedFilter's methods operation for
operation (FusedFilter writes the accelerometer's rotation out in a fixed order for this), built
without fused multiply-add or fast-math, around the kernels generated from the same CasADi
functions. tests/unit/trq_offboard/test_fused_core.py holds every period's x and P and every
decision equal to FusedFilter's compiled path over sequences with late, lost, rejected and
reset poses. FusedFilter stays the reference, and the path without a compiler.

Built once per configuration and process (trq_wire.cache.built_once), the library cached on
disk as the controller's other compiled parts (nmpc/cache.py's compiled_c). Pure as
FusedFilter: integer microseconds in, no clock, no I/O.
"""

from __future__ import annotations

import ctypes
import math
import weakref
from pathlib import Path
from types import SimpleNamespace

import casadi as ca
import numpy as np

from trq_offboard import fused
from trq_offboard.fused import (CANDIDATES_MAX, HISTORY_MAX, IMU_MAX_SPAN_INTERVALS, N_STATES,
                                FusedConfig, FusedFilter, Health, pose_variances,
                                start_state)

__all__ = ["FusedCore", "fused_filter"]

SOURCE = Path(__file__).with_name("fused_core.c")
# the products and sums as Python rounds them: no contraction into fused multiply-adds (the
# default of GCC on targets that have them, aarch64 companions among them), no fast-math
FLAGS = ("-ffp-contract=off", "-fno-fast-math", "-lm")
_OUT = 22                          # trq_fused_health's figures
_NX, _NP = N_STATES, N_STATES * N_STATES


def _library(cfg: FusedConfig) -> ctypes.CDLL | None:
    """fused_core.c with the configuration's kernels, built once a process (None without a C
    compiler or when the build fails)."""
    from trq_offboard.nmpc.cache import compiled_c, find_compiler
    from trq_wire.cache import built_once

    def build() -> ctypes.CDLL | None:
        if find_compiler() is None:
            return None
        k1 = fused._kernel(cfg)
        cg = ca.CodeGenerator("trq_fused_core.c", {"with_header": False})
        cg.add(k1)
        names = f"#define TRQ_K1 {k1.name()}\n#define TRQ_K1_WORK {k1.name()}_work\n"
        path = compiled_c("trq_fused_core", cg.dump() + names + SOURCE.read_text(), FLAGS)
        if path is None:
            return None
        lib = ctypes.CDLL(str(path))
        p, i64, d = ctypes.c_void_p, ctypes.c_int64, ctypes.c_double
        for name, args, res in (
                ("trq_fused_new", (p,), p), ("trq_fused_free", (p,), None),
                ("trq_fused_reset", (p, i64, p, p, p), None),
                ("trq_fused_add_imu", (p, i64, d, d, d), None),
                ("trq_fused_add_pose", (p, i64, d, d, d, d, d, d), None),
                ("trq_fused_step", (p, i64, p, p, p, p), None),
                ("trq_fused_health", (p, i64, p), None),
                ("trq_fused_periods", (p,), ctypes.c_int),
                ("trq_fused_period", (p, ctypes.c_int, p), None)):
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = args, res
        return lib

    return built_once(("fused core", cfg), build)[0]


def fused_filter(cfg: FusedConfig, gravity_m_s2: float, codegen: bool = True
                 ) -> "FusedCore | FusedFilter":
    """The filter for a configuration: the C core when `codegen` and a C compiler allow,
    else FusedFilter (its NumPy path without codegen)."""
    if codegen:
        lib = _library(cfg)
        if lib is not None:
            return FusedCore(cfg, gravity_m_s2, lib)
    return FusedFilter(cfg, gravity_m_s2, codegen=codegen)


class FusedCore:
    """FusedFilter's public API (reset, add_imu, add_pose, step, health, x, P, t_us, the
    counters) over one fused_core.c filter."""

    compiled = True

    def __init__(self, cfg: FusedConfig, gravity_m_s2: float, lib: ctypes.CDLL) -> None:
        self.cfg = cfg
        self.g = gravity_m_s2
        self._lib = lib
        nominal = round(1e6 / cfg.imu_rate_hz)
        values = np.array([gravity_m_s2, cfg.accel_std_m_s2, float(cfg.imu_rate_hz),
                           cfg.accel_gate, cfg.pose_gate, cfg.autopilot_vel_std_m_s,
                           round(cfg.dropout_s * 1e6), nominal,
                           IMU_MAX_SPAN_INTERVALS * nominal, cfg.accel_reject_max,
                           cfg.regain_poses, cfg.history], float)
        core = lib.trq_fused_new(values.ctypes.data)
        if not core:
            raise ValueError(f"fused filter: history {cfg.history} (at most {HISTORY_MAX}), "
                             f"regain_poses {cfg.regain_poses} (at most {CANDIDATES_MAX}), "
                             "or no memory for the C core")
        self._core = core
        self._finalizer = weakref.finalize(self, lib.trq_fused_free, core)
        self._in = np.zeros(9)               # a_known, euler, vel
        self._a = self._in.ctypes.data
        self._e = self._a + 3 * 8
        self._v = self._a + 6 * 8
        self._out = np.zeros(_OUT)
        self._o = self._out.ctypes.data
        self._stats = np.zeros(_OUT)
        self._period = np.zeros(3 + _NX + _NP)
        self._mocap_r = pose_variances(cfg)      # a pose of the default noise's, formed once
        self._started = False

    def reset(self, t_us: int, pos_ned_m, vel_ned_m_s, pos_std_m: float | None = None,
              euler_rad=(0.0, 0.0, 0.0)) -> None:
        """FusedFilter.reset."""
        x, P = start_state(self.cfg, pos_ned_m, vel_ned_m_s, pos_std_m)
        e = np.array([float(v) for v in euler_rad])
        P = np.asfortranarray(P)          # (held: the call reads its memory)
        self._lib.trq_fused_reset(self._core, int(t_us), x.ctypes.data, P.ctypes.data,
                                  e.ctypes.data)
        self._lib.trq_fused_health(self._core, int(t_us), self._o)
        self._started = True

    def add_imu(self, t_us: int, specific_force_frd_m_s2) -> None:
        """FusedFilter.add_imu."""
        f0, f1, f2 = specific_force_frd_m_s2
        if math.isfinite(f0 + f1 + f2):
            self._lib.trq_fused_add_imu(self._core, int(t_us), f0, f1, f2)

    def add_pose(self, t_us: int, pos_ned_m, std_ned_m=None) -> None:
        """FusedFilter.add_pose."""
        p0, p1, p2 = (float(v) for v in pos_ned_m)
        r = self._mocap_r if std_ned_m is None else pose_variances(self.cfg, std_ned_m)
        if r is not None and math.isfinite(p0 + p1 + p2):
            self._lib.trq_fused_add_pose(self._core, int(t_us), p0, p1, p2, *r)

    def step(self, t_us: int, a_known_ned: np.ndarray, euler_rad=None,
             vel_ned_m_s=None) -> Health:
        """FusedFilter.step."""
        self._check_started("step")
        buf = self._in
        buf[0:3] = a_known_ned
        e = None
        if euler_rad is not None:
            buf[3:6] = euler_rad
            e = self._e
        v = None
        if vel_ned_m_s is not None and self.cfg.autopilot_vel_std_m_s > 0.0:
            buf[6:9] = vel_ned_m_s
            if math.isfinite(buf[6] + buf[7] + buf[8]):
                v = self._v
        self._lib.trq_fused_step(self._core, int(t_us), self._a, e, v, self._o)
        return self._health(self._out.tolist())

    def _check_started(self, what: str) -> None:
        if not self._started:
            raise RuntimeError(f"FusedCore.{what} before reset: the filter has no state yet")

    @staticmethod
    def _health(o: list) -> Health:
        return Health((o[0], o[1], o[2]), (o[3], o[4], o[5]), o[12], o[13], o[14] != 0.0,
                      int(o[15]), int(o[16]), int(o[17]))

    def health(self, t_us: int) -> Health:
        """FusedFilter.health."""
        self._check_started("health")
        self._lib.trq_fused_health(self._core, int(t_us), self._o)
        return self._health(self._out.tolist())

    def _stat(self, i: int) -> float:
        t = int(self._out[21])
        self._lib.trq_fused_health(self._core, t, self._stats.ctypes.data)
        return float(self._stats[i])

    @property
    def x(self) -> np.ndarray:
        return self._out[0:_NX].copy()

    @property
    def P(self) -> np.ndarray:
        return self._periods[-1].P

    @property
    def t_us(self) -> int:
        return int(self._out[21])

    @property
    def test_ratio(self) -> float:
        return self._stat(12)

    # FusedFilter's counters, read from trq_fused_health's figures by index
    rejected = property(lambda self: int(self._stat(15)))
    resets = property(lambda self: int(self._stat(16)))
    accel_rejected = property(lambda self: int(self._stat(17)))
    dropped = property(lambda self: int(self._stat(18)))
    imu_dropped = property(lambda self: int(self._stat(19)))

    @property
    def last_pose_us(self) -> int | None:
        return int(self._stat(20)) if self._started else None

    def dead_reckoning(self, t_us: int) -> bool:
        self._lib.trq_fused_health(self._core, int(t_us), self._stats.ctypes.data)
        return self._stats[14] != 0.0

    @property
    def _periods(self) -> list:
        """The kept periods as FusedFilter's (t_us, x, P, covered_s, acc_taken), copies (for
        tests)."""
        out, buf = [], self._period
        for k in range(self._lib.trq_fused_periods(self._core)):
            self._lib.trq_fused_period(self._core, k, buf.ctypes.data)
            out.append(SimpleNamespace(
                t_us=int(buf[0]), x=buf[1:1 + _NX].copy(),
                P=buf[1 + _NX:1 + _NX + _NP].reshape(_NX, _NX).T.copy(),
                covered_s=float(buf[1 + _NX + _NP]), acc_taken=bool(buf[2 + _NX + _NP])))
        return out
