"""The physics tick compiled: `tick.c` built once with the system's C compiler, loaded by ctypes.

    core = load_core()          # a CompiledCore, or None (no compiler, or the build failed)
    p = core.params(vp, sim)    # the parameter array, once
    s = core.new_state()        # the state/input array, read and written by every tick
    event = core.tick(p, s)     # 0 or ATTITUDE (IMPACT: no longer returned; the ground's events
                                # are judged in Vehicle._ground_events for both cores)

`tick.c` repeats the arithmetic of the Python reference (`Vehicle._step_python` and the pure
functions of this package) operation for operation, built without fused multiply-add and without
fast-math, so that both give bit-identical flights; tests/consistency/test_compiled_core.py holds
them to equality. The Python code stays the reference and the readable statement of the model;
the compiled tick is a faster way of running the same arithmetic (`trq-bench-sim` measures both
side by side; a record of its figures: docs/simulator.md).

Cache: trq_wire.cache (the folder the controller's compiled functions use too), one library per
hash of the source, compiler and flags, written to a temporary name and renamed into place
(concurrent processes never load a half-written file). Never committed.
"""

from __future__ import annotations

import ctypes
import warnings
from functools import lru_cache
from pathlib import Path

from trq_wire.cache import cached_library, find_compiler

__all__ = ["CompiledCore", "load_core", "find_compiler", "CFLAGS", "IMPACT", "ATTITUDE"]

SOURCE = Path(__file__).parent / "dynamics" / "tick.c"
# -ffp-contract=off: no fused multiply-add (it would round differently from Python's a * b + c);
# never -ffast-math (it reorders sums)
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
IMPACT, ATTITUDE = 1, 2

# indices of the arrays (tick.c, enums P_* and S_*)
GEAR_MAX = 8                      # contact points the array holds (params/schema.py's limit)
P_SIZE = 17 + 3 + 3 + 28 + 8 + 3 * GEAR_MAX
S_X, S_MOTOR, S_TILT, S_LANDED, S_CRASHED, S_RUNNING, S_T = 0, 13, 17, 21, 22, 23, 24
S_CMD_THROTTLE, S_CMD_TILT, S_WIND, S_MOTOR_FAULT, S_SERVO_FAULT = 25, 29, 33, 36, 56
S_IMPACT_SPEED, S_ANCHORS, S_SIZE = 64, 65, 65 + 2 * GEAR_MAX


class CompiledCore:
    """The loaded library and the array types it takes."""

    def __init__(self, lib_path: Path) -> None:
        self.path = lib_path
        lib = ctypes.CDLL(str(lib_path))
        p_size, s_size = ctypes.c_int(), ctypes.c_int()
        lib.trq_tick_sizes(ctypes.byref(p_size), ctypes.byref(s_size))
        if (p_size.value, s_size.value) != (P_SIZE, S_SIZE):
            raise RuntimeError(f"{lib_path}: array sizes ({p_size.value}, {s_size.value}) differ "
                               f"from compiled.py's ({P_SIZE}, {S_SIZE})")
        self.P = ctypes.c_double * P_SIZE
        self.S = ctypes.c_double * S_SIZE
        self.tick = lib.trq_tick
        self.tick.argtypes = (self.P, self.S)
        self.tick.restype = ctypes.c_int

    def params(self, vp, crash_speed_m_s: float, crash_tilt_rad: float, dt_s: float,
               motor_factor: float, motor_max: float, servo_factor: float,
               servo_max: float) -> ctypes.Array:
        """The parameter array of tick.c (enum P_*) from the vehicle's parameters."""
        values = [dt_s, vp.mass_kg, *vp.inertia_kg_m2, vp.gravity_m_s2, vp.drag_N_s2_m2,
                  vp.idle_pct, motor_factor, motor_max, servo_factor, servo_max, vp.tilt_min_rad,
                  vp.tilt_max_rad, float(vp.tilt_locked), crash_speed_m_s, crash_tilt_rad,
                  vp.thrust_N.c2, vp.thrust_N.c1, vp.thrust_N.c0,
                  vp.torque_Nm.c2, vp.torque_Nm.c1, vp.torque_Nm.c0]
        for rotor in vp.rotors:
            values += [float(rotor.spin), *rotor.position_frd_m, *rotor.tilt_axis_frd]
        gear = vp.gear
        if len(gear.points_frd_m) > GEAR_MAX:
            raise ValueError(f"{len(gear.points_frd_m)} contact points, tick.c holds {GEAR_MAX}")
        values += [gear.ground_down_m, gear.reach_down_m, gear.stiffness_N_m, gear.damping_N_s_m,
                   gear.friction, gear.stick_stiffness_N_m, gear.stick_damping_N_s_m,
                   float(len(gear.points_frd_m))]
        values += [c for point in gear.points_frd_m for c in point]
        values += [0.0] * (3 * (GEAR_MAX - len(gear.points_frd_m)))
        if len(values) != P_SIZE:
            raise ValueError(f"{len(values)} parameters for tick.c, expected {P_SIZE}")
        return self.P(*values)

    def new_state(self) -> ctypes.Array:
        return self.S()


def _build(cc: str) -> Path:
    return cached_library(cc, list(CFLAGS), SOURCE, "sil_tick", ["-lm"])


@lru_cache(maxsize=1)
def load_core() -> CompiledCore | None:
    """The compiled tick (built and cached on first use), or None with a RuntimeWarning when
    no C compiler is found or the build fails: the vehicle then runs the Python reference."""
    cc = find_compiler()
    if cc is None:
        warnings.warn("no C compiler found (tried $CC, gcc, cc, clang): the vehicle's physics "
                      "runs in Python (the same results, slower: docs/simulator.md)",
                      RuntimeWarning,
                      stacklevel=2)
        return None
    try:
        return CompiledCore(_build(cc))
    except (OSError, RuntimeError) as exc:
        warnings.warn(f"the compiled physics tick is unavailable ({exc}): the vehicle's physics "
                      "runs in Python", RuntimeWarning, stacklevel=2)
        return None
