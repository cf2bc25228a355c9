"""The report of a campaign with a plant axis (identification errors): what the flights of each
controller did on each plant, set against the plant's faulted hover trim.

In: the campaign (`trq_lab.campaign.spec.Campaign`: its controllers, success bar and
targets) and its rows (`campaign.rows_of`: the flight's inputs, with the drawn `plant_*` values,
the metrics and the envelope columns `env_feasible`, `env_min_margin_pct`). Out: Markdown lines for report.md,
the figures beside it, and a JSON-able summary (the campaign's metrics.json). Pure functions of
the rows but for the figures; numpy only (the rank correlation is written here, no scipy).

The words the report uses:

- a flight's *score* is its position RMSE after the fault; a crashed flight, or one without a
  value, scores +inf (it lost the vehicle: worse than any RMSE); a failed flight (an error) has
  no score and is left out of every statistic but the counts;
- a plant's *envelope class*: `no trim` (no hover trim holds with the fault in the mean wind),
  `margin < X %` (a trim, but some motor within X percentage points of full throttle or of
  idle), `margin >= X %`; X is the targets' `min_margin_pct` (5 without targets);
- *paired*: two controllers' flights on the same plant (same `plant_id`: the same draw, fault,
  wind, trajectory and seed); `a` does better than `b` when its score is lower.
"""

from __future__ import annotations

import math
import statistics
from pathlib import Path

import numpy as np

from trq_lab.reporting.fmt import fmt
from trq_lab.reporting.plot import log_norm, pyplot

NO_TRIM = "no trim"


def score(r: dict) -> float | None:
    """Position RMSE after the fault; +inf for a crashed flight; None for a failed one."""
    if r.get("status") == "failed":
        return None
    if r.get("crashed"):
        return math.inf
    v = r.get("rmse_pos_after_fault_m")
    if v is None:
        v = r.get("rmse_pos_m")
    return math.inf if v is None else float(v)


def env_class(r: dict, margin_pct: float) -> str:
    if r.get("env_feasible") is None:
        return "no envelope"
    if not r["env_feasible"] or r.get("env_min_margin_pct") is None:
        return NO_TRIM
    return (f"margin >= {margin_pct:g} %" if r["env_min_margin_pct"] >= margin_pct
            else f"margin < {margin_pct:g} %")


def classes(margin_pct: float) -> tuple[str, str, str]:
    return NO_TRIM, f"margin < {margin_pct:g} %", f"margin >= {margin_pct:g} %"


def rank(a) -> np.ndarray:
    """Ranks 1..n of the values (ties get the mean of their ranks; +-inf are values too)."""
    a = np.asarray(a, dtype=float)
    _, inv, counts = np.unique(a, return_inverse=True, return_counts=True)
    last = np.cumsum(counts)
    return (last - (counts - 1) / 2.0)[inv]


def spearman(x, y) -> float:
    """Spearman's rank correlation of two equally long sequences (NaN pairs dropped): the
    Pearson correlation of their ranks; NaN when either is constant or fewer than 3 pairs."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = ~(np.isnan(x) | np.isnan(y))
    x, y = x[keep], y[keep]
    if len(x) < 3:
        return math.nan
    rx, ry = rank(x), rank(y)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    den = math.sqrt(float(np.dot(rx, rx)) * float(np.dot(ry, ry)))
    return math.nan if den == 0.0 else float(np.dot(rx, ry)) / den


def drawn_keys(rows: list[dict]) -> list[str]:
    """The plant columns that vary over the campaign (the drawn or swept parameters)."""
    keys = [k for k in rows[0] if k.startswith("plant_") and k != "plant_id"] if rows else []
    return [k for k in keys if len({r[k] for r in rows}) > 1]


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q, method="nearest")) if values else None


def _cell(v, spec="{:.4f}") -> str:
    """The shared formatter with this report's defaults: a crashed flight's +inf says so."""
    return fmt(v, spec, inf="crashed")


def _label(key: str) -> str:
    return key.removeprefix("plant_")


def paired(rows: list[dict], a: str, b: str) -> dict:
    """a against b on the same plants: pairs, how often a does better, the median RMSE ratio
    a / b over the pairs where neither crashed, and the pairs where a did not do better."""
    by = {}
    for r in rows:
        if r["controller"] in (a, b) and score(r) is not None:
            by.setdefault(r["plant_id"], {})[r["controller"]] = r
    pairs = [(p[a], p[b]) for p in by.values() if a in p and b in p]
    better = [(ra, rb) for ra, rb in pairs if score(ra) < score(rb)]
    ratios = [score(ra) / score(rb) for ra, rb in pairs
              if math.isfinite(score(ra)) and math.isfinite(score(rb)) and score(rb) > 0]
    return {"pairs": len(pairs), "better": len(better),
            "share": len(better) / len(pairs) if pairs else None,
            "median_ratio": float(statistics.median(ratios)) if ratios else None,
            "a_crashed": sum(math.isinf(score(ra)) for ra, _ in pairs),
            "b_crashed": sum(math.isinf(score(rb)) for _, rb in pairs),
            "not_better": [(ra, rb) for ra, rb in pairs if not score(ra) < score(rb)]}


def _finite(st: dict) -> dict:
    """A controller's summary as strict JSON: an RMSE statistic reached by crashes (+inf) is
    None, and named in `crashed_stats`."""
    out = {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in st.items()}
    out["crashed_stats"] = [k for k, v in st.items() if isinstance(v, float) and math.isinf(v)]
    return out


def _params_text(r: dict, keys: list[str]) -> str:
    return ", ".join(f"{_label(k)} {r[k]:g}" for k in keys)


def _margin_text(r: dict) -> str:
    if r.get("env_feasible") is None:
        return "no envelope"
    if not r["env_feasible"]:
        return NO_TRIM
    return f"{r['env_min_margin_pct']:.1f} %"


def report(campaign, rows: list[dict], out: Path, figures: bool = True
           ) -> tuple[list[str], dict]:
    """The plant sections of report.md and the summary (see the module docstring)."""
    t = campaign.targets
    margin_pct = t.min_margin_pct if t is not None else 5.0
    bar = campaign.success_rmse_m
    ctrls = [c for c in campaign.controllers if any(r["controller"] == c for r in rows)]
    head = t.controller if t is not None and t.controller in ctrls else ctrls[0]
    keys = drawn_keys(rows)
    plants = sorted({r["plant_id"] for r in rows})
    cls = classes(margin_pct)
    lines = ["## Plants: the envelope and the flights", ""]
    ranges = ", ".join(f"`{_label(k)}` {min(r[k] for r in rows):g} to {max(r[k] for r in rows):g}"
                       for k in keys)
    models = sorted({r.get("controller_model", "nominal") for r in rows})
    lines += [f"{len(plants)} plants ({ranges or 'the airframe file as it is'}; the "
              f"controllers' model: {', '.join(models)}). Each plant's faulted hover trim "
              f"(`trq-envelope`'s computation on the perturbed airframe, the flight's fault and "
              f"mean wind) puts it in one class: **{cls[0]}**, **{cls[1]}** (some motor "
              f"within {margin_pct:g} percentage points of full throttle or of idle), "
              f"**{cls[2]}**. The score of a flight is its position RMSE after the fault (a "
              f"crash: worse than any); success: not crashed, landed and below {bar:g} m.", ""]
    summary: dict = {"plants": len(plants), "drawn": [_label(k) for k in keys],
                     "margin_pct": margin_pct, "controllers": {}}
    lines += ["| controller | flights | success | crashed | " + " | ".join(cls)
              + f" | success with {cls[2]} | RMSE p10 m | median | p90 | max |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in ctrls:
        rs = [r for r in rows if r["controller"] == c]
        sc = [v for r in rs if (v := score(r)) is not None]
        n_cls = {k: sum(env_class(r, margin_pct) == k for r in rs) for k in cls}
        ok = [r for r in rs if env_class(r, margin_pct) == cls[2]]
        finite = sorted(v for v in sc if math.isfinite(v))
        st = {"flights": len(rs), "success_rate": sum(r["success"] for r in rs) / len(rs),
              "crashed": sum(bool(r["crashed"]) for r in rs),
              "envelope": n_cls, "success_with_margin":
              (sum(r["success"] for r in ok) / len(ok)) if ok else None,
              "rmse_p10_m": _pct(sc, 10) if sc else None,
              "rmse_median_m": float(statistics.median(sc)) if sc else None,
              "rmse_p90_m": _pct(sc, 90) if sc else None,
              "rmse_max_finite_m": finite[-1] if finite else None}
        summary["controllers"][c] = _finite(st)
        lines.append(f"| {c} | {len(rs)} | {st['success_rate']:.0%} | {st['crashed']} | "
                     + " | ".join(str(n_cls[k]) for k in cls) + " | "
                     + ("-" if not ok else f"{st['success_with_margin']:.0%} ({len(ok)})")
                     + f" | {_cell(st['rmse_p10_m'])} | {_cell(st['rmse_median_m'])} | "
                     f"{_cell(st['rmse_p90_m'])} | {_cell(st['rmse_max_finite_m'])} |")
    lines += ["", "RMSE percentiles count a crash as worse than any RMSE (`crashed` where it "
              "reaches them); `max` is the largest RMSE of a flight that did not crash.", ""]
    # per class: how each controller fares on the plants of each envelope class
    lines += ["Median RMSE after the fault (m) and success per envelope class:", "",
              "| controller | " + " | ".join(cls) + " |", "|---|" + "---|" * len(cls)]
    for c in ctrls:
        cells = []
        for k in cls:
            rs = [r for r in rows if r["controller"] == c and env_class(r, margin_pct) == k
                  and score(r) is not None]
            cells.append("-" if not rs else
                         f"{_cell(statistics.median([score(r) for r in rs]))}, "
                         f"{sum(r['success'] for r in rs)}/{len(rs)}")
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    lines.append("")

    # which parameters explain the misses
    if keys:
        n = len(plants)
        crit = 1.96 / math.sqrt(max(n - 1, 1))
        rho = {c: {} for c in ctrls}
        for c in ctrls:
            rs = [r for r in rows if r["controller"] == c and score(r) is not None]
            y = [score(r) for r in rs]
            for k in keys:
                rho[c][k] = spearman([r[k] for r in rs], y)
            margins = [(-math.inf if r.get("env_feasible") is False else
                        (math.nan if r.get("env_min_margin_pct") is None
                         else r["env_min_margin_pct"])) for r in rs]
            rho[c]["trim margin"] = spearman(margins, y)
        lines += ["## Which parameters explain the misses", "",
                  "Spearman's rank correlation of each drawn parameter with the score (RMSE "
                  "after the fault, a crash the worst), per controller; positive: the larger "
                  "the parameter, the larger the error. The last row is the trim's smallest "
                  f"throttle margin (no trim: the smallest). With {n} plants, |rho| above "
                  f"{crit:.2f} is unlikely by chance (5 %).", "",
                  "| parameter | " + " | ".join(ctrls) + " |", "|---|" + "---|" * len(ctrls)]
        for k in keys + ["trim margin"]:
            lines.append(f"| {_label(k)} | " + " | ".join(
                _cell(rho[c][k], "{:+.2f}") for c in ctrls) + " |")
        ordered = sorted(keys, key=lambda k: -abs(rho[head][k])
                         if not math.isnan(rho[head][k]) else 0.0)
        top = ordered[:2]
        lines += ["", f"The most telling for `{head}`: " + " and ".join(
            f"`{_label(k)}` ({rho[head][k]:+.2f})" for k in top) + ".", ""]
        summary["spearman"] = {c: {_label(k): (None if math.isnan(v) else round(v, 3))
                                   for k, v in d.items()} for c, d in rho.items()}
        summary["most_telling"] = [_label(k) for k in top]
    else:
        top = []

    # paired comparisons
    others = [c for c in ctrls if c != head]
    pair_stats = {}
    if others:
        lines += [f"## `{head}` against the others on the same plants", "",
                  "Each plant flown by both; better: a lower RMSE after the fault (or flying "
                  "where the other crashed). The ratio is the median of "
                  f"RMSE(`{head}`) / RMSE(other) over the pairs where neither crashed.", "",
                  "| against | pairs | better | share | median RMSE ratio | it crashed | "
                  "the other crashed |", "|---|---|---|---|---|---|---|"]
        for o in others:
            p = pair_stats[o] = paired(rows, head, o)
            lines.append(f"| `{o}` | {p['pairs']} | {p['better']} | "
                         f"{_cell(p['share'], '{:.0%}')} | {_cell(p['median_ratio'], '{:.3g}')} | "
                         f"{p['a_crashed']} | {p['b_crashed']} |")
        lines += ["", f"By the envelope class of `{head}`'s plant (its airframe's trim): better "
                  "on (pairs)", "", "| against | " + " | ".join(cls) + " |",
                  "|---|" + "---|" * len(cls)]
        for o in others:
            cells = []
            for k in cls:
                sub = paired([r for r in rows if r["controller"] == o or
                              env_class(r, margin_pct) == k], head, o)
                cells.append("-" if not sub["pairs"] else
                             f"{_cell(sub['share'], '{:.0%}')} ({sub['pairs']})")
            lines.append(f"| `{o}` | " + " | ".join(cells) + " |")
        lines += ["", "The quadcopter flies its own airframe with the same draw of factors (its "
                  "servos are locked, so the servo factors change nothing there).", ""]
        summary["paired"] = {o: {k: v for k, v in p.items() if k != "not_better"}
                             for o, p in pair_stats.items()}

    # targets
    failures: list[str] = []
    if t is not None:
        lines += ["## Targets", ""]
        rs = [r for r in rows if r["controller"] == t.controller and score(r) is not None]
        pop = [r for r in rs if env_class(r, margin_pct) == cls[2]]
        within = [r for r in pop if score(r) < t.rmse_after_fault_m]
        share = len(within) / len(pop) if pop else None
        met = share is not None and share >= t.share
        lines.append(f"- Among the {len(pop)} plants whose trim keeps at least {margin_pct:g} % "
                     f"of throttle margin on every motor, `{t.controller}` stays within "
                     f"{t.rmse_after_fault_m:g} m RMSE after the fault on {len(within)}: "
                     f"**{_cell(share, '{:.1%}')}** (target >= {t.share:.0%}): "
                     + ("met." if met else "missed." if pop else "not judged: no such plant."))
        if not met:
            failures.append(f"{t.controller} within {t.rmse_after_fault_m:g} m on "
                            f"{_cell(share, '{:.0%}')} of the {len(pop)} plants with >= "
                            f"{margin_pct:g} % margin (target >= {t.share:.0%})")
        summary["target_rmse"] = {"plants": len(pop), "within": len(within), "share": share,
                                  "target": t.share, "met": met}
        headline = [f"{t.controller} within {t.rmse_after_fault_m:g} m on "
                    f"{_cell(share, '{:.0%}')} of {len(pop)} plants with >= {margin_pct:g} % "
                    f"margin: {'met' if met else 'missed'}"]
        for b in t.better:
            p = pair_stats.get(b.worse) or paired(rows, t.controller, b.worse)
            ok = p["share"] is not None and p["share"] >= b.share
            trimmed = paired([r for r in rows if r["controller"] == b.worse
                              or r.get("env_feasible")], t.controller, b.worse)
            lines.append(f"- `{t.controller}` does better than `{b.worse}` on {p['better']} of "
                         f"{p['pairs']} paired flights: **{_cell(p['share'], '{:.1%}')}** "
                         f"(target >= {b.share:.0%}): {'met' if ok else 'missed'} (on the "
                         f"{trimmed['pairs']} plants with a trim: "
                         f"{_cell(trimmed['share'], '{:.1%}')}).")
            headline.append(f"better than {b.worse} on {_cell(p['share'], '{:.0%}')} of "
                            f"{p['pairs']} plants ({_cell(trimmed['share'], '{:.0%}')} of the "
                            f"{trimmed['pairs']} with a trim): {'met' if ok else 'missed'}")
            if not ok:
                failures.append(f"{t.controller} better than {b.worse} on "
                                f"{_cell(p['share'], '{:.0%}')} of {p['pairs']} paired flights "
                                f"(target >= {b.share:.0%})")
            summary.setdefault("target_paired", {})[b.worse] = {
                "pairs": p["pairs"], "better": p["better"], "share": p["share"],
                "target": b.share, "met": ok, "pairs_with_trim": trimmed["pairs"],
                "share_with_trim": trimmed["share"]}
        summary["headline"] = "; ".join(headline)
        lines.append("")
        if failures:
            lines += ["**Missed:**", ""] + [f"- {f}" for f in failures] + [""]
        # why: every miss of the headline controller, by envelope class
        misses = [r for r in rs if not score(r) < t.rmse_after_fault_m]
        by_cls = {k: [r for r in misses if env_class(r, margin_pct) == k] for k in cls}
        lines += ["### Where the misses come from", "",
                  f"`{t.controller}` is above {t.rmse_after_fault_m:g} m (or crashed) on "
                  f"{len(misses)} of {len(rs)} plants: "
                  + ", ".join(f"{len(v)} with {k}" for k, v in by_cls.items())
                  + f". Those without trim or with under {margin_pct:g} % of margin are the "
                  "envelope's (the vehicle has little or nothing left to fly the fault with: no "
                  "controller holds them, and the thrust margin, not the observer, sets the "
                  "error); those with the margin are the controller's.", ""]
        ctl_miss = sorted(by_cls[cls[2]], key=lambda r: -score(r))
        if ctl_miss:
            lines += [f"The controller's misses (plants with {cls[2]}):", "",
                      "| plant | trim margin | RMSE after fault m | parameters |",
                      "|---|---|---|---|"]
            for r in ctl_miss[:20]:
                lines.append(f"| `{r['plant_id']}` | {_margin_text(r)} | {_cell(score(r))} | "
                             f"{_params_text(r, keys)} |")
            lines.append("")
        for b in t.better:
            nb = pair_stats.get(b.worse) or paired(rows, t.controller, b.worse)
            nb_cls = {k: sum(env_class(ra, margin_pct) == k for ra, _ in nb["not_better"])
                      for k in cls}
            if nb["not_better"]:
                lines += [f"The {len(nb['not_better'])} pairs where `{t.controller}` is not "
                          f"better than `{b.worse}`: " + ", ".join(
                              f"{v} with {k}" for k, v in nb_cls.items()) + ".", "",
                          f"| plant | trim margin | `{t.controller}` m | `{b.worse}` m | "
                          "parameters |", "|---|---|---|---|---|"]
                for ra, rb in nb["not_better"][:20]:
                    lines.append(f"| `{ra['plant_id']}` | {_margin_text(ra)} | "
                                 f"{_cell(score(ra))} | {_cell(score(rb))} | "
                                 f"{_params_text(ra, keys)} |")
                lines.append("")
        summary["misses"] = {k: len(v) for k, v in by_cls.items()}
    if t is not None:
        summary["failures"] = failures            # the targets missed (trq-results reads it)
    if figures and rows:
        for p in plant_figures(campaign, rows, ctrls, keys, top, margin_pct, out):
            lines += [f"![{p.stem}]({p.name})", ""]
    return lines, summary


def plant_figures(campaign, rows, ctrls, keys, top, margin_pct, out: Path) -> list[Path]:
    """margin.png (RMSE after the fault against the trim's smallest throttle margin, per
    controller), rmse_dist.png (the RMSE distribution per controller), params.png (the median
    RMSE over the two most telling parameters, per controller)."""
    plt = pyplot()
    made = []
    bar = campaign.success_rmse_m
    t = campaign.targets
    target_m = t.rmse_after_fault_m if t is not None else bar
    scored = [r for r in rows if score(r) is not None]
    finite = [score(r) for r in scored if math.isfinite(score(r))]
    lo = max(min(finite) / 1.5, 1e-4) if finite else 1e-3
    hi = max(finite) * 1.5 if finite else 1.0
    crash_y = hi * 1.6
    margins = [r["env_min_margin_pct"] for r in scored if r.get("env_min_margin_pct") is not None]
    no_trim_x = (min(margins) if margins else 0.0) - 1.5
    colours = {NO_TRIM: "tab:red", f"margin < {margin_pct:g} %": "tab:orange",
               f"margin >= {margin_pct:g} %": "tab:green", "no envelope": "tab:gray"}

    # 1) RMSE against the trim's margin
    fig, axes = plt.subplots(1, len(ctrls), figsize=(3.6 * len(ctrls), 3.4), squeeze=False,
                             sharey=True)
    for ax, c in zip(axes[0], ctrls):
        rs = [r for r in scored if r["controller"] == c]
        for r in rs:
            k = env_class(r, margin_pct)
            x = no_trim_x if k in (NO_TRIM, "no envelope") else r["env_min_margin_pct"]
            y = score(r) if math.isfinite(score(r)) else crash_y
            ax.scatter([x], [y], s=14, color=colours[k],
                       marker="^" if not math.isfinite(score(r)) else "o", alpha=0.75)
        ax.set_yscale("log")
        ax.set_ylim(lo, crash_y * 1.5)
        ax.axvline(margin_pct, color="k", lw=0.7, ls="--")
        ax.axhline(target_m, color="k", lw=0.7, ls=":")
        ax.set_title(c, fontsize=9)
        ax.set_xlabel("trim: smallest throttle margin, % (left: no trim)", fontsize=8)
    axes[0][0].set_ylabel("position RMSE after fault, m (triangles: crashed)", fontsize=8)
    fig.suptitle(f"{campaign.name}: error against the faulted trim's throttle margin "
                 f"(dashed: {margin_pct:g} %, dotted: {target_m:g} m)", fontsize=9)
    path = out / "margin.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    made.append(path)

    # 2) the distribution per controller
    fig, ax = plt.subplots(figsize=(6.4, 1.0 + 0.6 * len(ctrls)))
    rng = np.random.default_rng(0)             # vertical jitter of the dots only
    for i, c in enumerate(ctrls):
        rs = [r for r in scored if r["controller"] == c]
        for r in rs:
            k = env_class(r, margin_pct)
            x = score(r) if math.isfinite(score(r)) else crash_y
            ax.scatter([x], [i + rng.uniform(-0.25, 0.25)], s=10, color=colours[k], alpha=0.7,
                       marker="^" if not math.isfinite(score(r)) else "o")
    ax.set_xscale("log")
    ax.set_xlim(lo, crash_y * 1.5)
    ax.axvline(target_m, color="k", lw=0.7, ls=":")
    ax.set_yticks(range(len(ctrls)))
    ax.set_yticklabels(ctrls, fontsize=8)
    ax.set_xlabel("position RMSE after fault, m (right edge: crashed); colour: envelope class "
                  f"(red no trim, orange < {margin_pct:g} %, green >= {margin_pct:g} %)",
                  fontsize=7)
    ax.set_title(f"{campaign.name}: RMSE after the fault per controller", fontsize=9)
    path = out / "rmse_dist.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    made.append(path)

    # 3) the heat map over the two most telling parameters
    if len(top) == 2:
        kx, ky = top
        nb = 5
        ex = np.linspace(min(r[kx] for r in rows), max(r[kx] for r in rows), nb + 1)
        ey = np.linspace(min(r[ky] for r in rows), max(r[ky] for r in rows), nb + 1)
        fig, axes = plt.subplots(1, len(ctrls), figsize=(3.6 * len(ctrls), 3.2), squeeze=False,
                                 sharey=True)
        im = None
        for ax, c in zip(axes[0], ctrls):
            g = np.full((nb, nb), np.nan)
            rs = [r for r in scored if r["controller"] == c]
            for i in range(nb):
                for j in range(nb):
                    cell = [score(r) for r in rs
                            if ey[i] <= r[ky] <= ey[i + 1] and ex[j] <= r[kx] <= ex[j + 1]
                            and (r[ky] < ey[i + 1] or i == nb - 1)
                            and (r[kx] < ex[j + 1] or j == nb - 1)]
                    if cell:
                        g[i, j] = float(np.median(cell))
            shown = np.where(np.isinf(g), crash_y, g)
            im = ax.imshow(shown, origin="lower", aspect="auto", cmap="viridis_r",
                           norm=log_norm(lo, crash_y),
                           extent=(ex[0], ex[-1], ey[0], ey[-1]))
            for i in range(nb):
                for j in range(nb):
                    if not np.isnan(g[i, j]):     # dark text on the light (small) end
                        light = math.log(shown[i, j] / lo) < 0.5 * math.log(crash_y / lo)
                        ax.text((ex[j] + ex[j + 1]) / 2, (ey[i] + ey[i + 1]) / 2,
                                "crash" if np.isinf(g[i, j]) else f"{g[i, j]:.3f}",
                                ha="center", va="center", fontsize=6,
                                color="k" if light else "w")
            ax.set_title(c, fontsize=9)
            ax.set_xlabel(_label(kx), fontsize=8)
        axes[0][0].set_ylabel(_label(ky), fontsize=8)
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
        fig.suptitle(f"{campaign.name}: median RMSE after the fault (m) over the two most "
                     "telling parameters", fontsize=9, y=1.03)
        path = out / "params.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        made.append(path)
    return made
