#!/usr/bin/env python3
"""What a step costs after a wait: the same compiled piece of the control period timed right
after its last call and after a wait of each length, the CPU waiting (a sleep) or kept busy
(a spin that touches nothing).

    trq-bench-decay [--controller trq_nmpc_eso_fused] [--waits-ms 0,0.1,0.3,1,3,10]
                    [--samples 200] [--repeat 3] [--json out/bench_decay.json]

Why: a control loop waits between two steps (for the vehicle in lockstep, for the clock at
100 Hz), a solver's anchor in a tight loop does not. Where a step's cost grows with the wait,
the two are not measured alike, and a ratio of the two says as much about the wait as about
the code (docs/decisions/2026-12-07-period-paced.md; `trq-bench-nmpc --daemons --pacing
realtime` paces both sides alike). A spin that touches nothing evicts nothing of this
process: a cost that grows under it too is taken by the machine (another tenant on the core's
caches, the hypervisor), not by the program's own work.

The pieces, each called as in a period: the fused filter's step (its C core, one IMU sample and
one pose fed before each call) and the RTI's preparation (the compiled linearisation of the
whole horizon, without the Python around it). Per wait and waiting mode, `--samples` calls each
after the wait, then the median of their wall times; the waits in turn, interleaved, `--repeat`
times; printed: the median over the repeats and its ratio to the same piece called at once
(wait 0) in the same repeat.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

import trq_params

__all__ = ["after_wait", "curves", "main", "WAIT_MODES"]

WAIT_MODES = ("sleep", "spin")


def after_wait(step: Callable[[], None], wait_s: float, mode: str, samples: int,
               clock=time.perf_counter, sleep=time.sleep) -> float:
    """The median wall time (s) of `step` called `samples` times, each `wait_s` after the
    previous call ended: the CPU asleep meanwhile (mode sleep) or spinning on `clock` (spin).
    One call first, untimed, so that the first sample also follows a wait."""
    if mode not in WAIT_MODES:
        raise ValueError(f"wait mode {mode!r}: expected one of {', '.join(WAIT_MODES)}")
    if not (wait_s >= 0.0 and samples >= 1):
        raise ValueError(f"wait {wait_s!r} s, {samples!r} samples: expected >= 0 and >= 1")
    step()
    times = []
    for _ in range(samples):
        if wait_s > 0.0:
            if mode == "sleep":
                sleep(wait_s)
            else:
                end = clock() + wait_s
                while clock() < end:
                    pass
        t0 = clock()
        step()
        times.append(clock() - t0)
    return statistics.median(times)


def curves(pieces: dict[str, Callable[[], None]], waits_s: list[float], samples: int,
           repeat: int, measure=after_wait) -> dict:
    """{piece: {mode: {wait_ms: [median s per repeat]}}}: every piece, mode and wait in turn
    within each repeat (a moment of the machine reaches all of them alike)."""
    out = {p: {m: {w * 1e3: [] for w in waits_s} for m in WAIT_MODES} for p in pieces}
    for _ in range(repeat):
        for name, step in pieces.items():
            for mode in WAIT_MODES:
                for w in waits_s:
                    out[name][mode][w * 1e3].append(measure(step, w, mode, samples))
    return out


def table(result: dict) -> str:
    """Markdown: per piece and wait, each mode's median us and its ratio to wait 0."""
    lines = ["| piece | wait ms | asleep us | x at once | spinning us | x at once |",
             "|---|---|---|---|---|---|"]
    for name, modes in result.items():
        for w in modes["sleep"]:
            cells = []
            for mode in WAIT_MODES:
                runs, base = modes[mode][w], modes[mode][min(modes[mode])]
                ratio = statistics.median(r / b for r, b in zip(runs, base))
                cells += [f"{statistics.median(runs) * 1e6:.1f}", f"{ratio:.2f}"]
            lines.append(f"| {name} | {w:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _pieces(controller: str) -> dict[str, Callable[[], None]]:
    """The pieces for a controller file (its fused filter and its RTI)."""
    from trq_offboard.allocation import Allocator
    from trq_offboard.config import load_controller
    from trq_offboard.fused_core import FusedCore, fused_filter
    from trq_offboard.model import PredictionModel
    from trq_offboard.nmpc.rti import RtiSolver

    cfg = load_controller(trq_params.resolve("controller", controller))
    pieces: dict[str, Callable[[], None]] = {}
    if cfg.fused is not None:
        f = fused_filter(cfg.fused, cfg.vehicle.gravity_m_s2)
        if isinstance(f, FusedCore):
            f.reset(0, (0.0, 0.0, -1.0), (0.0, 0.0, 0.0))
            rng = np.random.default_rng(1)
            a_known, euler = np.zeros(3), np.array([0.01, 0.02, 0.3])
            clock = {"t": 0}

            def fused_step() -> None:
                t = clock["t"] = clock["t"] + 10_000
                f.add_imu(t - 2_000, tuple(rng.normal(0.0, 0.1, 3) + (0.0, 0.0, -9.81)))
                f.add_pose(t - 10_000, tuple(rng.normal(0.0, 1e-3, 3) + (0.0, 0.0, -1.0)))
                f.step(t, a_known, euler)
            pieces["fused filter step (C core)"] = fused_step
    model = PredictionModel(cfg.vehicle)
    al = Allocator(cfg.vehicle)
    u_trim = al.command_vector(al.hover())
    rti = RtiSolver(cfg, model, u_trim, cfg.solver.hessian)
    prep = getattr(rti, "_prep_np", None)
    if prep is not None:
        N = cfg.horizon_steps
        x = np.zeros((N + 1, 12))
        x[:, 2] = -1.0
        rti.prepare(x, np.zeros(6), u_trim, (np.tile(u_trim, (N, 1)), x))
        pieces["RTI preparation (compiled)"] = prep.evaluate
    if not pieces:
        raise RuntimeError(f"{controller}: no compiled piece to time (no C compiler, or "
                           "codegen off in the controller file)")
    return pieces


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-decay", description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="trq_nmpc_eso_fused")
    ap.add_argument("--waits-ms", default="0,0.1,0.3,1,3,10",
                    help="the waits, ms, comma-separated (0: called at once)")
    ap.add_argument("--samples", type=int, default=200, help="calls per wait and mode")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    try:
        waits = sorted({float(w) * 1e-3 for w in args.waits_ms.split(",") if w.strip()})
    except ValueError:
        ap.error(f"--waits-ms {args.waits_ms!r}: expected numbers separated by commas")
    if not waits or waits[0] != 0.0:
        ap.error(f"--waits-ms {args.waits_ms!r}: expected times >= 0, 0 among them (the "
                 "figure the others are set against)")
    if args.samples < 1 or args.repeat < 1:
        ap.error("--samples and --repeat: expected at least 1")
    if not trq_params.exists("controller", args.controller):
        ap.error(f"--controller {args.controller}: no params/controller/{args.controller}.yaml")
    from trq_lab.bench.nmpc import machine_line
    print(machine_line(), flush=True)
    try:
        pieces = _pieces(args.controller)
    except RuntimeError as exc:
        print(f"trq-bench-decay: {exc}", file=sys.stderr)
        return 2
    print(f"controller: {args.controller}; {args.samples} calls per wait and mode, "
          f"{args.repeat} repeats, wall time", flush=True)
    result = curves(pieces, waits, args.samples, args.repeat)
    print(table(result))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"controller": args.controller, "curves": result},
                                        indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
