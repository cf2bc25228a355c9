"""Figures of flights with a motor lost (issue 40): per flight directory (flight.csv and
controller.csv, as trq-scenario and trq-inprocess write them), from the fault's onset on:
height, the thrust axis' tilt from the vertical (trq_lab.metrics.thrust_tilt_deg), the yaw rate
and the horizontal drift from where the motor failed; a dashed line where the controller
declared the motor lost.

    python -m trq_lab.reporting.lost_motor --onset-s 8 --title motor1_lost \
        --out fig.png DIR/trq_nmpc_eso_lost DIR/trq_nmpc_eso DIR/quad_nmpc
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from trq_lab import metrics as metrics_mod
from trq_lab.reporting.plot import pyplot

__all__ = ["figure", "main"]

BEFORE_S = 0.5           # the figure starts this long before the onset


def figure(run_dirs: list[Path], onset_s: float, out: Path, title: str) -> Path:
    plt = pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    onset_us = int(round(onset_s * 1e6))
    for d in run_dirs:
        _, truth = metrics_mod.read_csv(d / "flight.csv")
        _, steps = metrics_mod.read_csv(d / "controller.csv")
        t_us = truth["t_us"].astype(np.int64)
        sel = t_us >= onset_us - int(BEFORE_S * 1e6)
        t = (t_us[sel] - onset_us) * 1e-6
        i0 = int(np.searchsorted(t_us, onset_us))
        drift = np.hypot(truth["pos_n_m"] - truth["pos_n_m"][i0],
                         truth["pos_e_m"] - truth["pos_e_m"][i0])
        (line,) = axes[0].plot(t, -truth["pos_d_m"][sel], lw=1, label=d.name)
        axes[1].plot(t, metrics_mod.thrust_tilt_deg(truth)[sel], lw=1, color=line.get_color())
        axes[2].plot(t, truth["rate_r_rad_s"][sel], lw=1, color=line.get_color())
        axes[3].plot(t, drift[sel], lw=1, color=line.get_color())
        crash = np.flatnonzero(truth["crashed"][sel] > 0.5)
        if len(crash):
            axes[0].plot(t[crash[0]], -truth["pos_d_m"][sel][crash[0]], "x", color="red", ms=9)
        if "lost_motor" in steps:
            lost = np.flatnonzero(steps["lost_motor"] > 0)
            if len(lost):
                for ax in axes:
                    ax.axvline((steps["stamp_us"][lost[0]] - onset_us) * 1e-6, ls="--", lw=0.8,
                               color=line.get_color())
    for ax, label in zip(axes, ("height m", "thrust axis tilt deg", "yaw rate rad/s",
                                "drift from the failure m")):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.axvline(0.0, color="k", lw=0.8)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"{title}: from the motor's loss (x: crash, dashed: declared lost)")
    axes[-1].set_xlabel("s after the onset")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="flight directories")
    ap.add_argument("--onset-s", type=float, required=True, help="the fault's onset (s)")
    ap.add_argument("--out", type=Path, required=True, help="the PNG to write")
    ap.add_argument("--title", default="a motor lost")
    args = ap.parse_args(argv)
    figure(args.runs, args.onset_s, args.out, args.title)
    return 0


if __name__ == "__main__":
    sys.exit(main())
