#!/usr/bin/env python3
"""Benchmark of the fused filter's step: its C core (trq_offboard/fused_core.c) against
FusedFilter's compiled path (trq_offboard/fused.py), in one run.

    trq-bench-fused [--controller trq_nmpc_eso_fused] [--repeat 7] [--steps 2000]
                    [--numpy] [--json out/bench_fused.json]

Each filter is fed what the controller gives it a control period in a mocap flight (the
controller file's FusedConfig: its HIGHRES_IMU rate, one pose a period one period late, the
attitude and the known input), `--steps` periods, then `step`; the pairs run alternately
`--repeat` times. Printed: the thread CPU microseconds a period (add_imu, add_pose and step
together), minimum and median over the repeats for each, and the ratio core / reference paired
repeat by repeat (median). `--numpy` adds FusedFilter's NumPy path (no compiler). A warm
in-process figure: in the daemon the same code also pays its cold caches
(`trq-bench-nmpc --daemons`, the controller's `cpu_observer_ms`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

import trq_params
from trq_lab.bench.nmpc import machine_line
from trq_offboard.config import load_controller
from trq_offboard.fused import FusedConfig, FusedFilter
from trq_offboard.fused_core import FusedCore, fused_filter

__all__ = ["feed", "measure", "main"]

G = 9.81


def feed(f, steps: int, cfg: FusedConfig, seed: int = 1) -> float:
    """`steps` control periods (10 ms) of a hover's samples into filter `f`: thread CPU s a
    period. The samples are drawn before the clock starts."""
    rng = np.random.default_rng(seed)
    imu_us = round(1e6 / cfg.imu_rate_hz)
    n_imu = (steps * 10_000) // imu_us + 1
    forces = [tuple(v) for v in rng.normal(0.0, cfg.accel_std_m_s2, (n_imu, 3))
              + (0.01, -0.02, -G)]
    poses = [tuple(v) for v in rng.normal(0.0, cfg.mocap_std_m, (steps, 3)) + (0.0, 0.0, -1.0)]
    a_known, euler = np.array([0.0, 0.0, 0.0]), np.array([0.01, 0.02, 0.3])
    f.reset(0, (0.0, 0.0, -1.0), (0.0, 0.0, 0.0))
    t_imu, j = 0, 0
    c0 = time.thread_time()
    for k in range(1, steps + 1):
        t = k * 10_000
        while t_imu + imu_us <= t:
            t_imu += imu_us
            f.add_imu(t_imu, forces[j])
            j += 1
        f.add_pose(t - 10_000, poses[k - 1])
        f.step(t, a_known, euler)
    return (time.thread_time() - c0) / steps


def measure(cfg: FusedConfig, repeat: int, steps: int, numpy_path: bool = False) -> dict:
    """{name: [us a period per repeat]} for the core, the reference (and the NumPy path)."""
    makers = {"core": lambda: fused_filter(cfg, G),
              "reference": lambda: FusedFilter(cfg, G, codegen=True)}
    if numpy_path:
        makers["numpy"] = lambda: FusedFilter(cfg, G, codegen=False)
    core = makers["core"]()
    if not isinstance(core, FusedCore):
        raise SystemExit("trq-bench-fused: no C compiler found, the core cannot be built")
    for make in makers.values():          # built and warm before the clock
        feed(make(), 50, cfg)
    out: dict[str, list[float]] = {name: [] for name in makers}
    for _ in range(repeat):
        for name, make in makers.items():
            out[name].append(feed(make(), steps, cfg) * 1e6)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="trq-bench-fused", description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="trq_nmpc_eso_fused",
                    help="a controller file with estimator kind fused (name or path)")
    ap.add_argument("--repeat", type=int, default=7, help="alternate repeats")
    ap.add_argument("--steps", type=int, default=2000, help="control periods per repeat")
    ap.add_argument("--numpy", action="store_true", help="also FusedFilter's NumPy path")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.steps < 1:
        ap.error("--repeat and --steps must be at least 1")
    cfg = load_controller(trq_params.resolve("controller", args.controller)).fused
    if cfg is None:
        ap.error(f"--controller {args.controller}: its estimator is not the fused filter")
    print(machine_line(), flush=True)
    figures = measure(cfg, args.repeat, args.steps, args.numpy)
    print(f"the fused filter, thread CPU us a control period (add_imu, add_pose, step), "
          f"{args.repeat} alternate repeats of {args.steps} periods:")
    for name, values in figures.items():
        print(f"  {name:9s} min {min(values):7.1f}  median {statistics.median(values):7.1f}  "
              f"({' '.join(f'{v:.1f}' for v in values)})")
    ratios = [c / r for c, r in zip(figures["core"], figures["reference"])]
    print(f"core / reference, paired repeat by repeat: {statistics.median(ratios):.2f} "
          f"(median; {min(ratios):.2f} to {max(ratios):.2f})")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine_line(), "us_per_period": figures,
                                         "core_over_reference": ratios}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
