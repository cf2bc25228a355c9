"""Report of a scenario: the metrics table (Markdown) and the figures in the manner of the paper.

    trajectories.png   3-D trajectories of every controller against the reference (paper Fig. 4,
                       and Fig. 7 for a time-varying fault)
    observer.png       the observer's disturbance estimate against the true disturbance (Fig. 5)
    errors.png         position and attitude errors over time, fault onset marked (Fig. 6)
    effectiveness.png  each motor's estimated effectiveness against the true one (controllers
                       with motor_effectiveness on), with a zoom on the fault's first 0.2 s
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import trq_params
from sil_vehicle.config import load_vehicle
from sil_vehicle.faultscript import load_script

from trq_lab import metrics as metrics_mod
from trq_lab.reporting.fmt import METRIC_COLUMNS, fmt, table_head, table_row
from trq_lab.reporting.plot import pyplot

def table(results: list[dict]) -> str:
    """The metrics table of a scenario's flights (every column of METRIC_COLUMNS)."""
    return "\n".join(table_head(METRIC_COLUMNS) + [table_row(r, METRIC_COLUMNS) for r in results])


PERIOD_PARTS = (("observer", "observer"), ("effectiveness", "effectiveness"),
                ("predictor", "predictor"), ("feedback", "NMPC feedback"),
                ("prepare", "NMPC preparation"), ("wire", "wire"), ("log", "log"),
                ("period", "whole period"))


def period_rows(runs) -> list[tuple[str, dict[str, float], str]]:
    """(controller, {part: mean CPU ms per control period}, what solved its NMPC) of each run
    whose controller.csv has the controller's CPU columns (trq_offboard/log.py); the solver as
    the log's header says it ("-" in a log older than that line)."""
    rows = []
    for r in runs:
        try:
            meta, steps = metrics_mod.read_csv(Path(r.out) / "controller.csv")
        except (OSError, ValueError):
            continue
        if "cpu_period_ms" not in steps or len(steps["cpu_period_ms"]) == 0:
            continue
        rows.append((r.controller, {k: float(np.nanmean(steps[f"cpu_{k}_ms"]))
                                    if np.isfinite(steps[f"cpu_{k}_ms"]).any() else math.nan
                                    for k, _ in PERIOD_PARTS}, meta.get("solver", "-")))
    return rows


def period_text(rows: list[tuple[str, dict[str, float], str]]) -> list[str]:
    """The controller's CPU per control period by part (mean ms), and what solved each
    controller's NMPC (the library's kernels decide both the time and the last bits): a section
    of the report."""
    if not rows:
        return []
    head = "| controller | " + " | ".join(h for _, h in PERIOD_PARTS) + " |"
    lines = ["## The controller's period", "",
             "CPU time per control period, mean over the flight (ms, measured by the "
             "controller itself: `cpu_*_ms` in controller.csv). The whole period is the CPU "
             "of every thread of the controller process from one step's start to the next: "
             "the parts, the event loop, the transport's frame parse.", "",
             head, "|" + "---|" * (len(PERIOD_PARTS) + 1)]
    for name, parts, _ in rows:
        lines.append(f"| {name} | " + " | ".join(fmt(parts[k], "{:.3f}") for k, _ in
                                                   PERIOD_PARTS) + " |")
    lines += ["", "What solved the NMPC (controller.csv's `solver` line):", ""]
    lines += [f"- `{name}`: {solver}" for name, _, solver in rows]
    return lines + [""]


def envelope_text(envelopes: list[dict]) -> list[str]:
    lines = ["## The physical envelope", "",
             "Hover trim and the wrench margin left at it, under this wind and the worst motor "
             "effectiveness of the fault script (`trq-envelope`): how much more force (N) "
             "or torque (N m) the actuators can add on each body axis while the rest of the "
             "wrench keeps its trim value.", ""]
    for e in envelopes:
        t = e["trim"]
        head = (f"- `{e['vehicle']}`, motor factors {e['motor_factors']}: trim "
                f"{'feasible' if e['feasible'] else '**infeasible**'}, throttle "
                f"{t['throttle_pct']} %, tilt {t['tilt_deg']} deg, roll {t['roll_deg']} deg, "
                f"pitch {t['pitch_deg']} deg")
        if not e["feasible"]:
            head += f"; wrench it cannot produce: {e['residual']}"
        lines.append(head)
        if e["margin"]:
            lines.append("  - margins: " + ", ".join(
                f"{k} {'none' if v is None else f'{v:.2f}'}" for k, v in e["margin"].items()))
    return lines + [""]


def sensing_text(sensing: str | None, results: list[dict]) -> str:
    """What the controllers saw, under the sensing profile flown (its name or path; None: not
    recorded): the estimate (the estimator's own error in the table) or near-truth."""
    if sensing is None:
        return "Sensing profile: not recorded."
    name = f"`{Path(sensing).stem if not trq_params.is_name(sensing) else sensing}`"
    if any(r.get("est_rmse_pos_m") is not None for r in results):
        return (f"Sensing profile {name}: the controllers flew on the vehicle's estimate (its "
                "sensors fused by its estimator). The errors are the truth against the "
                "reference; the estimate columns are the estimator's own error, its estimate "
                "against the truth.")
    return (f"Sensing profile {name}: no estimator; the controllers saw near-truth (the true "
            "state plus the sim file's white noise), so the estimate columns are empty.")


def markdown(scenario, results: list[dict], failures: list[str], figures: list[Path],
             envelopes: list[dict] | None = None,
             periods: list[tuple[str, dict[str, float], str]] | None = None,
             sensing: str | None = None) -> str:
    """The scenario's report.md: its settings, the sensing profile flown (`sensing`) and what
    the controllers saw, the metrics table, the targets, the envelope, the period, figures."""
    lines = [f"# Scenario `{scenario.name}`", "", scenario.description, "",
             f"Seed {scenario.seed}; wind {scenario.wind_speed_m_s:g} m/s from "
             f"{scenario.wind_from_deg:g} deg{' with gusts' if scenario.gusts else ''}; faults: "
             f"`{scenario.faults.name if scenario.faults else 'none'}`; reference: "
             f"{scenario.reference.get('kind', 'from the controller files')}; recovery threshold "
             f"{scenario.recovery_threshold_m:g} m."
             + (f" Offboard link impaired: {scenario.offboard_impair}."
                if scenario.offboard_impair else ""), "", sensing_text(sensing, results), "",
             table(results), ""]
    if scenario.targets or scenario.better:
        lines += ["## Targets", ""]
        for name, targets in scenario.targets.items():
            for key, want in targets.items():
                op = "=" if isinstance(want, bool) else "<="
                lines.append(f"- `{name}`: {key} {op} {want}")
        for better, worse, metric in scenario.better:
            lines.append(f"- `{better}` better than `{worse}` on {metric}")
        lines += ["", "**All met.**" if not failures else "**Missed:**", ""]
        lines += [f"- {f}" for f in failures]
        lines.append("")
    if envelopes:
        lines += envelope_text(envelopes)
    if periods:
        lines += period_text(periods)
    for fig in figures:
        lines += [f"![{fig.stem}]({fig.name})", ""]
    return "\n".join(lines)


def figures(scenario, runs, out: Path) -> list[Path]:
    plt = pyplot()
    data = []
    for r in runs:
        try:
            _, truth = metrics_mod.read_csv(r.out / "flight.csv")
            _, steps = metrics_mod.read_csv(r.out / "controller.csv")
        except (OSError, ValueError):
            continue
        if len(steps.get("stamp_us", [])) == 0:
            continue
        data.append((r.controller, truth, steps))
    if not data:
        return []
    onset_s = None
    if scenario.faults:
        events = load_script(scenario.faults)
        onset_s = events[0].at_us * 1e-6 if events else None
    made = []

    # --- trajectories (Fig. 4 / Fig. 7) ---
    fig = plt.figure(figsize=(8, 6.5))
    ax = fig.add_subplot(projection="3d")
    _, _, steps0 = data[0]
    ax.plot(steps0["ref_pos_e_m"], steps0["ref_pos_n_m"], -steps0["ref_pos_d_m"], "k--",
            lw=1.2, label="reference")
    for name, truth, _ in data:
        ax.plot(truth["pos_e_m"], truth["pos_n_m"], -truth["pos_d_m"], lw=1.0, label=name)
        crash = np.flatnonzero(truth["crashed"] > 0.5)
        if len(crash):
            k = crash[0]
            ax.scatter([truth["pos_e_m"][k]], [truth["pos_n_m"][k]], [-truth["pos_d_m"][k]],
                       marker="x", s=60, color="red")
    ax.set_xlabel("east m")
    ax.set_ylabel("north m")
    ax.set_zlabel("up m")
    ax.set_title(f"{scenario.name}: trajectories")
    ax.legend(loc="upper left", fontsize=8)
    path = out / "trajectories.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    made.append(path)

    # --- errors over time (Fig. 6) ---
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for name, truth, steps in data:
        index = {int(t): i for i, t in enumerate(truth["t_us"].astype(np.int64))}
        stamps = steps["stamp_us"].astype(np.int64)
        keep = np.array([int(s) in index for s in stamps])
        rows = np.array([index[int(s)] for s in stamps[keep]], dtype=np.int64)
        t = stamps[keep] * 1e-6
        pos = np.column_stack([truth[f"pos_{a}_m"][rows] for a in "ned"])
        ref = np.column_stack([steps[f"ref_pos_{a}_m"][keep] for a in "ned"])
        ref[:, 2] = np.minimum(ref[:, 2], metrics_mod.GROUND_DOWN_M)   # as the metrics do
        axes[0].plot(t, np.linalg.norm(pos - ref, axis=1), lw=1, label=name)
        yaw_err = metrics_mod.wrap_deg(
            np.degrees(truth["yaw_rad"][rows] - steps["ref_yaw_rad"][keep]))
        axes[1].plot(t, yaw_err, lw=1, label=name)
        tilt = np.degrees(np.hypot(truth["roll_rad"][rows], truth["pitch_rad"][rows]))
        axes[2].plot(t, tilt, lw=1, label=name)
    axes[0].set_ylabel("position error m")
    axes[0].set_yscale("log")
    axes[1].set_ylabel("yaw error deg")
    axes[2].set_ylabel("roll/pitch tilt deg")
    axes[2].set_xlabel("vehicle time s")
    for a in axes:
        if onset_s is not None:
            a.axvline(onset_s, color="red", ls=":", lw=1)
        a.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"{scenario.name}: errors (fault onset dotted)")
    path = out / "errors.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    made.append(path)

    # --- observer (Fig. 5) ---
    observed = [(n, tr, st) for n, tr, st in data if np.isfinite(st["d_acc_n_m_s2"]).any()
                and np.nanmax(np.abs(st["d_acc_n_m_s2"])) > 0]
    if observed:
        name, truth, steps = observed[0]
        meta, _ = metrics_mod.read_csv(
            next(r.out for r in runs if r.controller == name) / "flight.csv")
        vp = load_vehicle(meta["vehicle_file"])
        index = {int(t): i for i, t in enumerate(truth["t_us"].astype(np.int64))}
        stamps = steps["stamp_us"].astype(np.int64)
        keep = np.array([int(s) in index for s in stamps])
        rows = np.array([index[int(s)] for s in stamps[keep]], dtype=np.int64)
        sub = {k: v[rows] for k, v in truth.items()}
        true_d = metrics_mod.true_disturbance(sub, vp)
        t = stamps[keep] * 1e-6
        est = np.column_stack([steps[c][keep] for c in
                               ("d_acc_n_m_s2", "d_acc_e_m_s2", "d_acc_d_m_s2",
                                "d_ang_p_rad_s2", "d_ang_q_rad_s2", "d_ang_r_rad_s2")])
        labels = ["north m/s²", "east m/s²", "down m/s²", "roll rad/s²", "pitch rad/s²",
                  "yaw rad/s²"]
        fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
        for j in range(6):
            a = axes[j % 3, j // 3]
            a.plot(t, true_d[:, j], "k-", lw=1, label="true (plant - nominal model)")
            a.plot(t, est[:, j], "C1-", lw=1, label="observer estimate")
            a.set_ylabel(labels[j])
            if onset_s is not None:
                a.axvline(onset_s, color="red", ls=":", lw=1)
            a.grid(alpha=0.3)
        axes[0, 0].legend(fontsize=8)
        axes[2, 0].set_xlabel("vehicle time s")
        axes[2, 1].set_xlabel("vehicle time s")
        fig.suptitle(f"{scenario.name}: disturbance seen by the observer of {name}")
        path = out / "observer.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        made.append(path)

    # --- motor effectiveness: the estimate against the truth ---
    estimated = [(n, tr, st) for n, tr, st in data if "eff_motor1" in st
                 and np.nanmin(np.concatenate([st[f"eff_motor{i}"] for i in range(1, 5)])) < 1.0]
    if estimated:
        zoom = onset_s is not None
        fig, axes = plt.subplots(1, 2 if zoom else 1, figsize=(12 if zoom else 7, 4), squeeze=False)
        for k, (name, truth, steps) in enumerate(estimated):
            t = steps["stamp_us"] * 1e-6
            tt = truth["t_us"] * 1e-6
            for i in range(1, 5):
                # the whole flight in s; the zoom in ms from the onset
                for a, (t0, unit) in zip(axes[0], ((0.0, 1.0), (onset_s or 0.0, 1e3))):
                    a.plot((tt - t0) * unit, truth[f"motor{i}_factor"], color=f"C{i - 1}", ls=":",
                           lw=1, label=f"motor {i} true" if k == 0 else None)
                    a.plot((t - t0) * unit, steps[f"eff_motor{i}"], color=f"C{i - 1}", lw=1,
                           label=f"motor {i} {name}")
        axes[0, 0].set_ylabel("effectiveness")
        axes[0, 0].set_xlabel("vehicle time s")
        for a in axes[0]:
            a.grid(alpha=0.3)
        if zoom:
            axes[0, 0].axvline(onset_s, color="red", ls=":", lw=1)
            axes[0, 1].axvline(0.0, color="red", ls=":", lw=1)
            axes[0, 1].set_xlim(-20.0, 200.0)
            axes[0, 1].set_xlabel("ms from the fault's onset")
            axes[0, 1].set_title("the fault's first 0.2 s (estimates every control period)")
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"{scenario.name}: the motors' estimated effectiveness against the truth")
        path = out / "effectiveness.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        made.append(path)
    return made
