"""A campaign's report: success rate, position RMSE and diagnosis time per controller against
fault severity and wind (tables and heat maps), where each controller stops coping, the flight
targets (`flight_targets`: a bar on one metric of one controller's flights, under one sensing
profile or all, with one outage or all), with a sensor outage axis the largest position error
in each outage's window (trq_lab.metrics.max_pos_err_outage_m) beside them and the tables per
outage when it varies, and the summary that trq-results reads (metrics.json).

In: a campaign (`trq_lab.campaign.spec.Campaign`) and the rows of its flights
(`trq_lab.campaign.store.rows_of`). Out: report.md, success.png, rmse.png and metrics.json in the
output directory; with a plant axis, the plant-campaign report's sections and figures too.
"""

from __future__ import annotations

import re
import statistics
from pathlib import Path

import numpy as np

from trq_lab.campaign.spec import LINK_KEYS, Campaign
from trq_lab.campaign.store import has_outage, write_json
from trq_lab.reporting import plant_campaign
from trq_lab.reporting.fmt import fmt
from trq_lab.reporting.plot import log_norm, pyplot

def _bins(values: list[float], max_distinct: int = 12, n_bins: int = 8):
    """A function value -> (sort key, label): distinct values if few, equal-width bins if many."""
    distinct = sorted(set(values))
    if len(distinct) <= max_distinct:
        return lambda v: (v, f"{v:g}")
    lo, hi = distinct[0], distinct[-1]
    width = (hi - lo) / n_bins or 1.0

    def f(v):
        k = min(int((v - lo) / width), n_bins - 1)
        a, b = lo + k * width, lo + (k + 1) * width
        return (a, f"{a:.3g}-{b:.3g}")
    return f


def _link_label(r: dict) -> str:
    """'' for a clean link, else what is impaired (loss %, delay and jitter ms, ...)."""
    parts = []
    if r.get("link_loss"):
        parts.append(f"{100 * r['link_loss']:g} % lost")
    if r.get("link_delay_ms"):
        parts.append(f"{r['link_delay_ms']:g} ms")
    if r.get("link_jitter_ms"):
        parts.append(f"+-{r['link_jitter_ms']:g} ms jitter")
    if r.get("link_duplicate"):
        parts.append(f"{100 * r['link_duplicate']:g} % dup")
    if r.get("link_reorder"):
        parts.append(f"{100 * r['link_reorder']:g} % reordered")
    return ", link " + " ".join(parts) if parts else ""


def wind_label(r: dict) -> str:
    s = f"{r['wind_speed_m_s']:g} m/s"
    if r["wind_speed_m_s"]:
        s += f" from {r['wind_direction_deg']:g}"
    if r["wind_gusts"]:
        s += " gusts"
    return s + _link_label(r)


def cells(rows: list[dict]):
    """Group the rows by (controller, wind key, severity key): the heat-map cells."""
    sev_of = {kind: _bins([r["severity"] for r in rows if r["fault_kind"] == kind])
              for kind in {r["fault_kind"] for r in rows}}
    def conditions(r):                 # the wind and the link a flight met
        return (r["wind_speed_m_s"], r["wind_direction_deg"], r["wind_gusts"],
                *(r.get(f"link_{k}", 0.0) for k in LINK_KEYS))
    wind_distinct = {conditions(r) for r in rows}
    speed_bin = _bins([r["wind_speed_m_s"] for r in rows])
    out: dict[tuple, list[dict]] = {}
    for r in rows:
        if len(wind_distinct) <= 12:
            wkey = (conditions(r), wind_label(r))
        else:
            k, label = speed_bin(r["wind_speed_m_s"])
            wkey = ((k, *conditions(r)[3:]), f"{label} m/s{_link_label(r)}")
        skey, slabel = sev_of[r["fault_kind"]](r["severity"])
        kind_label = {"motor": "motor loss", "servo": "servo stuck deg", "none": "no fault"}
        sev = ((r["fault_kind"], skey), f"{kind_label[r['fault_kind']]} {slabel}"
               if r["fault_kind"] != "none" else "no fault")
        out.setdefault((r["controller"], wkey, sev), []).append(r)
    return out


def _rmse_of(r: dict) -> float | None:
    v = r.get("rmse_pos_after_fault_m")
    return v if v is not None else r.get("rmse_pos_m")


def summarise(campaign: Campaign, rows: list[dict]):
    groups = cells(rows)
    winds = sorted({k[1] for k in groups}, key=lambda w: w[0])
    sevs = sorted({k[2] for k in groups}, key=lambda s: s[0])
    stats = {}
    for key, rs in groups.items():
        ok = sum(r["success"] for r in rs)
        rm = [v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None]
        stats[key] = {"n": len(rs), "ok": ok, "rate": ok / len(rs),
                      "crashed": sum(bool(r["crashed"]) for r in rs),
                      "failed": sum(r["status"] == "failed" for r in rs),
                      "rmse_median": float(statistics.median(rm)) if rm else None,
                      "rmse_max": max(rm) if rm else None}
    return winds, sevs, stats


def coping_limit(campaign, winds, sevs, stats, controller, wind) -> str:
    """The largest motor-loss severity up to which every flight of this controller and wind
    succeeded (every smaller severity as well)."""
    last = None
    for sev in sevs:
        if sev[0][0] != "motor":
            continue
        s = stats.get((controller, wind, sev))
        if s is None:
            continue
        if s["ok"] < s["n"]:
            break
        last = sev
    return "none" if last is None else last[1].replace("motor loss ", "")


def heatmaps(campaign: Campaign, winds, sevs, stats, out: Path, sensing: str = ""
             ) -> list[Path]:
    """success.png and rmse.png; of one sensing profile's flights (`sensing`, its label):
    success_<label>.png and rmse_<label>.png."""
    plt = pyplot()
    under = f" under {sensing}" if sensing else ""
    made = []
    ctrls = list(campaign.controllers)
    for what, fname, title in (("rate", "success.png", "success rate"),
                               ("rmse_median", "rmse.png", "median position RMSE after fault, m")):
        fig, axes = plt.subplots(1, len(ctrls), figsize=(2.2 + 0.7 * len(sevs) * len(ctrls),
                                                         1.6 + 0.45 * len(winds)),
                                 squeeze=False, sharey=True)
        grid_all = []
        for c in ctrls:
            g = np.full((len(winds), len(sevs)), np.nan)
            for i, w in enumerate(winds):
                for j, s in enumerate(sevs):
                    st = stats.get((c, w, s))
                    if st is not None and st[what] is not None:
                        g[i, j] = st[what]
            grid_all.append(g)
        finite = np.concatenate([g[np.isfinite(g)] for g in grid_all]) if grid_all else []
        for ax, c, g in zip(axes[0], ctrls, grid_all):
            if what == "rate":
                im = ax.imshow(g, vmin=0.0, vmax=1.0, cmap="RdYlGn", aspect="auto")
            else:
                lo = max(float(np.min(finite)), 1e-4) if len(finite) else 1e-3
                hi = max(float(np.max(finite)), lo * 10) if len(finite) else 1.0
                im = ax.imshow(g, norm=log_norm(lo, hi), cmap="viridis_r", aspect="auto")
            for i in range(g.shape[0]):
                for j in range(g.shape[1]):
                    if np.isfinite(g[i, j]):
                        txt = f"{g[i, j]:.0%}" if what == "rate" else f"{g[i, j]:.3f}"
                        ax.text(j, i, txt, ha="center", va="center", fontsize=7)
            ax.set_title(c, fontsize=9)
            ax.set_xticks(range(len(sevs)))
            ax.set_xticklabels([s[1].replace("motor loss ", "") for s in sevs], rotation=60,
                               fontsize=7)
            ax.set_xlabel("motor effectiveness lost" if all(s[0][0] in ("motor", "none")
                                                            for s in sevs) else "fault", fontsize=8)
            ax.set_yticks(range(len(winds)))
            ax.set_yticklabels([w[1] for w in winds], fontsize=7)
        axes[0][0].set_ylabel("wind", fontsize=8)
        fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
        fig.suptitle(f"{campaign.name}{under}: {title} (success: not crashed, RMSE after fault < "
                     f"{campaign.success_rmse_m:g} m)" if what == "rate" else
                     f"{campaign.name}{under}: {title}", fontsize=9, y=1.04)
        tag = re.sub(r"[^A-Za-z0-9.-]+", "_", sensing)       # a label as a file name's part
        path = out / (fname.replace(".png", f"_{tag}.png") if sensing else fname)
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        made.append(path)
    return made


def sensing_label(profile: str) -> str:
    """A sensing profile as the report names it: a built-in name, or a file's stem."""
    return Path(profile).stem if profile else ""


def _median(rows: list[dict], key: str) -> float | None:
    """The median of `key` over the rows that have it (None if none has)."""
    values = [r[key] for r in rows if r.get(key) is not None]
    return float(statistics.median(values)) if values else None


def _controller_summary(campaign: Campaign, rows: list[dict]) -> dict:
    out = {}
    for c in campaign.controllers:
        rs = [r for r in rows if r["controller"] == c]
        rm = [v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None]
        if rs:
            out[c] = {"flights": len(rs), "success_rate": sum(r["success"] for r in rs) / len(rs),
                      "crashed": sum(bool(r["crashed"]) for r in rs),
                      "rmse_median_m": float(statistics.median(rm)) if rm else None,
                      "diagnosis_median_s": _median(rs, "diagnosis_s")}
            if has_outage(campaign):
                errs = [r["max_pos_err_outage_m"] for r in rs
                        if r.get("max_pos_err_outage_m") is not None]
                out[c].update(outage_err_median_m=_median(rs, "max_pos_err_outage_m"),
                              outage_err_max_m=max(errs) if errs else None)
    return out


# the columns of a flight's conditions: two controllers' flights with the same are a pair
_CONDITION_PREFIXES = ("sensing", "seed", "repeat", "fault_", "wind_", "link_", "traj_",
                       "plant_", "outage")


def _conditions(r: dict) -> tuple:
    return tuple(sorted((k, str(v)) for k, v in r.items() if k.startswith(_CONDITION_PREFIXES)))


def _paired_flights(rows: list[dict]) -> dict:
    """The flights that did not fail, by (sensing, outage, conditions) and then controller."""
    by: dict = {}
    for r in rows:
        if r.get("status") != "failed":
            by.setdefault((r["sensing"], r.get("outage", "none"), _conditions(r)),
                          {})[r["controller"]] = r
    return by


def _paired_stats(by: dict, c: str, head: str, where) -> dict | None:
    """`c` against `head` over the pairs of `by` whose (sensing, outage) `where` accepts: pairs,
    better, the median, smallest and largest ratio of RMSE after the fault (where neither
    crashed), later diagnoses and crashes; None without a pair."""
    pairs = [(g[c], g[head]) for (s, o, _), g in by.items() if where(s, o) and c in g
             and head in g]
    if not pairs:
        return None
    ratios = [_rmse_of(a) / _rmse_of(b) for a, b in pairs
              if not a["crashed"] and not b["crashed"] and _rmse_of(a) is not None
              and _rmse_of(b)]
    better = sum((not a["crashed"] and b["crashed"]) or (
        not a["crashed"] and _rmse_of(a) is not None and _rmse_of(b) is not None
        and _rmse_of(a) < _rmse_of(b)) for a, b in pairs)
    later = sum(b.get("diagnosis_s") is not None and (
        a.get("diagnosis_s") is None or a["diagnosis_s"] > b["diagnosis_s"]) for a, b in pairs)
    return {"pairs": len(pairs), "better": better,
            "median_ratio": float(statistics.median(ratios)) if ratios else None,
            "min_ratio": min(ratios) if ratios else None,
            "max_ratio": max(ratios) if ratios else None, "later_diagnosis": later,
            "crashed": sum(bool(a["crashed"]) for a, _ in pairs),
            "other_crashed": sum(bool(b["crashed"]) for _, b in pairs)}


def _ratio_text(st: dict) -> str:
    if st["median_ratio"] is None:
        return "-"
    return f"{st['median_ratio']:.3f} ({st['min_ratio']:.3f}-{st['max_ratio']:.3f})"


def paired_by_seed(campaign: Campaign, rows: list[dict]) -> tuple[list[str], dict]:
    """Each controller against the campaign's first on the same conditions and seed (flight by
    flight, per sensing profile and outage): (report lines, summary). A pair counts where both
    flew (not failed); the ratio is RMSE after the fault, the other's over the first's, over the
    pairs where neither crashed; a later diagnosis is the other's diagnosis_s above the first's
    (or missing where the first's is known)."""
    head = campaign.controllers[0]
    s_col, o_col = len(campaign.sensings) > 1, len(campaign.outages) > 1   # their columns
    by = _paired_flights(rows)
    lines = [f"## Paired, flight by flight, against `{head}`", "",
             f"Each flight of a controller against `{head}`'s under the same conditions and "
             "seed. Ratio: RMSE after the fault, the controller's over "
             f"`{head}`'s (median and range over the pairs where neither crashed); better: "
             "a lower RMSE or flying where the other crashed; a later diagnosis: its "
             "diagnosis_s above the other's.", "",
             "| sensing " * s_col + "| outage " * o_col + "| controller | pairs | better | "
             "median ratio (range) | later diagnosis | it crashed | the other crashed |",
             "|---" * (s_col + o_col) + "|---|---|---|---|---|---|---|"]
    summary: dict = {}
    for p, o, c in ((p, o, c) for p in campaign.sensings for o in campaign.outages
                    for c in campaign.controllers[1:]):
        st = _paired_stats(by, c, head, lambda s, so: (s, so) == (p, o))
        if st is None:
            continue
        lines.append(f"| {sensing_label(p)} " * s_col + f"| {o} " * o_col
                     + f"| {c} | {st['pairs']} | {st['better']} | {_ratio_text(st)} | "
                     f"{st['later_diagnosis']} | {st['crashed']} | {st['other_crashed']} |")
        name = sensing_label(p) or "-"
        summary.setdefault(name if o == "none" else f"{name} {o}", {})[c] = st
    return (lines + [""] if summary else []), summary


def judge_paired_targets(campaign: Campaign, rows: list[dict]
                         ) -> tuple[list[str], list[str], list[str], list[dict]]:
    """The campaign's paired targets judged on its rows: (report lines, failures, headline
    parts, one summary per target). Met: at least one pair, the median ratio at most the bar,
    no more crashes than the other, and (no_later_diagnosis) no later diagnosis."""
    if not campaign.paired_targets:
        return [], [], [], []
    by = _paired_flights(rows)
    lines = ["## Paired targets", "",
             "Each target on a controller's flights paired with another's on the same "
             "conditions and seed (the table above): the median ratio of RMSE after the fault "
             "at most the bar, no more crashes, and no later diagnosis when it asks.", ""]
    failures, headline, summary = [], [], []
    for t in campaign.paired_targets:
        def where(s, o, t=t):
            return ((t.sensing is None or s == t.sensing)
                    and (t.outage is None or o.split()[0] == t.outage))
        st = _paired_stats(by, t.controller, t.against, where)
        under = (f" under `{sensing_label(t.sensing)}`" if t.sensing else "") + (
            f" with outage `{t.outage}`" if t.outage else "")
        met = (st is not None and st["median_ratio"] is not None
               and st["median_ratio"] <= t.max_median_ratio
               and st["crashed"] <= st["other_crashed"]
               and not (t.no_later_diagnosis and st["later_diagnosis"]))
        text = (f"`{t.controller}` against `{t.against}`{under}: median ratio <= "
                f"{t.max_median_ratio:g}, no more crashes"
                + (", no later diagnosis" if t.no_later_diagnosis else ""))
        got = ("no pair" if st is None else
               f"{_ratio_text(st)} over {st['pairs']} pairs, better on {st['better']}, "
               f"crashed {st['crashed']} against {st['other_crashed']}, later diagnosis "
               f"{st['later_diagnosis']}")
        lines.append(f"- {text}: {got}: **{'met' if met else 'missed'}**.")
        short = (f"{t.controller} / {t.against}"
                 f"{' ' + sensing_label(t.sensing) if t.sensing else ''}"
                 f"{' outage ' + t.outage if t.outage else ''} paired ratio "
                 f"{fmt(st and st['median_ratio'], '{:.3f}')} <= {t.max_median_ratio:g}")
        # a miss the ratio does not explain: say which clause
        why = [] if st is None else (
            ([f"crashed {st['crashed']} against {st['other_crashed']}"]
             if st["crashed"] > st["other_crashed"] else [])
            + ([f"later diagnosis on {st['later_diagnosis']} of {st['pairs']} pairs"]
               if t.no_later_diagnosis and st["later_diagnosis"] else []))
        if not met and why:
            short += " (" + ", ".join(why) + ")"
        headline.append(f"{short} {'met' if met else 'missed'}")
        if not met:
            failures.append(short)
        summary.append({"controller": t.controller, "against": t.against,
                        "sensing": t.sensing and sensing_label(t.sensing), "outage": t.outage,
                        "max_median_ratio": t.max_median_ratio, **(st or {"pairs": 0}),
                        "met": met})
    lines.append("")
    if failures:
        lines += ["**Missed:**", ""] + [f"- {f}" for f in failures] + [""]
    return lines, failures, headline, summary


def meets(r: dict, target) -> bool:
    """Whether one flight's row meets a flight target (trq_params.schema.FlightTarget): not
    failed, not crashed (unless the target is on `crashed` itself), its metric (and `per`)
    known, metric <= max (times `per`)."""
    if r.get("status") == "failed":
        return False
    value = r.get(target.metric)
    if value is None or (target.metric != "crashed" and r.get("crashed")):
        return False
    bar = target.max
    if target.per is not None:
        per = r.get(target.per)
        if per is None:
            return False
        bar *= float(per)
    return float(value) <= bar


def target_text(t) -> str:
    """A flight target as the report writes it: who, under which profile, what bar."""
    under = f" under `{sensing_label(t.sensing)}`" if t.sensing is not None else ""
    if t.outage is not None:
        under += " without an outage" if t.outage == "none" else f" with a {t.outage} outage"
    bar = f"{t.max:g} x {t.per}" if t.per is not None else f"{t.max:g}"
    return f"`{t.controller}`{under}: {t.metric} <= {bar} on >= {t.share:.0%} of its flights"


def judge_flight_targets(campaign: Campaign, rows: list[dict]
                         ) -> tuple[list[str], list[str], list[str], list[dict]]:
    """The campaign's flight targets judged on its rows: (report lines, failures, headline
    parts, one summary per target)."""
    if not campaign.flight_targets:
        return [], [], [], []
    lines = ["## Flight targets", "",
             "Each target over the flights of one controller (under one sensing profile, with "
             "one outage, when it names them): the share of them that meet the bar (a failed "
             "flight, or a crashed one unless the target is on `crashed`, does not), and the "
             "median of the metric.", ""]
    failures, headline, summary = [], [], []
    for t in campaign.flight_targets:
        rs = [r for r in rows if r["controller"] == t.controller
              and (t.sensing is None or r["sensing"] == t.sensing)
              and (t.outage is None or r.get("outage", "none").split()[0] == t.outage)]
        ok = sum(meets(r, t) for r in rs)
        share = ok / len(rs) if rs else None
        met = share is not None and share >= t.share
        values = [float(r[t.metric]) for r in rs if r.get(t.metric) is not None]
        median = float(statistics.median(values)) if values else None
        ratios = [float(r[t.metric]) / r[t.per] for r in rs if t.per is not None
                  and r.get(t.metric) is not None and r.get(t.per)]
        extra = (f", median ratio {statistics.median(ratios):.3g}" if ratios else "")
        verdict = "met" if met else "missed" if rs else "not judged: no such flight"
        lines.append(f"- {target_text(t)}: {ok} of {len(rs)} "
                     f"({fmt(share, '{:.0%}')}; median {fmt(median, '{:.4g}')}{extra}): "
                     f"**{verdict}**.")
        short = (f"{t.controller}{' ' + sensing_label(t.sensing) if t.sensing else ''}"
                 f"{' outage ' + t.outage if t.outage else ''} "
                 f"{t.metric} <= {t.max:g}{' x ' + t.per if t.per else ''}: {ok}/{len(rs)}")
        headline.append(f"{short} {'met' if met else 'missed'}")
        if not met:
            failures.append(f"{short} (target >= {t.share:.0%})")
        summary.append({"controller": t.controller, "sensing": t.sensing and
                        sensing_label(t.sensing), **({"outage": t.outage} if t.outage else {}),
                        "metric": t.metric, "max": t.max,
                        "per": t.per, "share_target": t.share, "flights": len(rs), "met_by": ok,
                        "share": share, "median": median, "met": met})
    lines.append("")
    if failures:
        lines += ["**Missed:**", ""] + [f"- {f}" for f in failures] + [""]
    return lines, failures, headline, summary


def _cell_sections(campaign: Campaign, rows: list[dict], out: Path, figures: bool,
                   sensing: str = "") -> list[str]:
    """Per controller, the success rate and the median RMSE per wind and fault severity, where
    each controller stops coping, and the heat maps: of the flights under one sensing profile
    (`sensing`, its label) when the campaign varies it."""
    lines: list[str] = []
    under = f" under `{sensing}`" if sensing else ""
    winds, sevs, stats = summarise(campaign, rows)
    if campaign.has_plant and len(winds) * len(sevs) == 1:
        figures = False                  # one cell: the cell tables and heat maps say nothing
        stats = {}
    head = "| wind | " + " | ".join(s[1] for s in sevs) + " |"
    rule = "|---|" + "---|" * len(sevs)
    for c in campaign.controllers:
        if not any(k[0] == c for k in stats):
            continue
        lines += [f"## `{c}`" + under, "", "Success rate (successful / flown) and, below, "
                  "the median position RMSE after the fault (m) of the flights that did not "
                  "crash, per wind (rows) and fault severity (columns).", "", head, rule]
        for w in winds:
            cellv = []
            for s in sevs:
                st = stats.get((c, w, s))
                cellv.append("" if st is None else f"{st['rate']:.0%} ({st['ok']}/{st['n']})")
            lines.append(f"| {w[1]} | " + " | ".join(cellv) + " |")
        lines += ["", head, rule]
        for w in winds:
            cellv = []
            for s in sevs:
                st = stats.get((c, w, s))
                cellv.append("" if st is None else fmt(st["rmse_median"]))
            lines.append(f"| {w[1]} | " + " | ".join(cellv) + " |")
        lines.append("")
    if stats and any(s[0][0] == "motor" for s in sevs):
        lines += ["## Where each controller stops coping" + under, "",
                  "The largest loss of motor effectiveness up to which every flight (every motor, "
                  "every smaller loss) succeeded.", "",
                  "| wind | " + " | ".join(campaign.controllers) + " |",
                  "|---|" + "---|" * len(campaign.controllers)]
        for w in winds:
            lines.append(f"| {w[1]} | " + " | ".join(
                coping_limit(campaign, winds, sevs, stats, c, w) for c in campaign.controllers)
                + " |")
        lines.append("")
        first = campaign.controllers[0]
        worse = []
        for (c, w, s), st in stats.items():
            if c == first:
                continue
            mine = stats.get((first, w, s))
            if mine is not None and mine["rate"] < st["rate"]:
                worse.append(f"{w[1]}, {s[1]}: `{first}` {mine['rate']:.0%} < `{c}` "
                             f"{st['rate']:.0%}")
        lines += [f"`{first}` copes at least as often as every other controller in every cell."
                  if not worse else f"Cells where `{first}` succeeds less often than another "
                  "controller:", ""] + [f"- {x}" for x in sorted(worse)] + [""]
    if figures:
        for p in heatmaps(campaign, winds, sevs, stats, out, sensing):
            lines += [f"![{p.stem}]({p.name})", ""]
    return lines


def write_report(campaign: Campaign, rows: list[dict], out: Path, run_info: dict | None = None,
                 figures: bool = True) -> Path:
    lines = [f"# Campaign `{campaign.name}`", "", campaign.description.strip(), ""]
    n_plan = len(campaign.flights)
    failed = [r for r in rows if r["status"] == "failed"]
    lines += [f"{len(rows)} of {n_plan} flights flown; {sum(r['success'] for r in rows)} "
              f"successful, {sum(bool(r['crashed']) for r in rows)} crashed, {len(failed)} "
              f"failed (errors in `flights/<id>.json`). Success: not crashed, landed and "
              f"position RMSE after the fault below {campaign.success_rmse_m:g} m. Controllers: "
              + ", ".join(f"`{c}`" for c in campaign.controllers) + ".", ""]
    if run_info:
        lines += [f"Last run: {run_info['flown']} flights in {run_info['wall_s']:.0f} s on "
                  f"{run_info['workers']} worker(s): **{run_info['flights_per_hour']:.0f} "
                  f"flights/hour**"
                  + (f"; the NMPC's QPs solved by {run_info['qp_library']} (another library "
                     "flies the same flights with other last bits)" if "qp_library" in run_info
                     else "") + ".", ""]
    summary: dict = {"campaign": campaign.name, "description": campaign.description.strip(),
                     "planned": n_plan, "flights": len(rows),
                     "failed": len(failed), "success_rmse_m": campaign.success_rmse_m}
    if not rows:
        (out / "report.md").write_text("\n".join(lines) + "\n")
        write_json(out / "metrics.json", summary)
        return out / "report.md"
    varied = len(campaign.sensings) > 1
    groups = [(p, [r for r in rows if r["sensing"] == p]) for p in campaign.sensings]
    outage = has_outage(campaign)                # the outage's columns
    o_varied = len(campaign.outages) > 1         # and its own column, rows and sections
    o_groups = [(o, [r for r in rows if r.get("outage", "none") == o])
                for o in campaign.outages]
    # the table's row groups: each (profile, outage) flown, in the campaign's order
    table = [(p, o, [r for r in prs if not o or r.get("outage", "none") == o])
             for p, prs in (groups if varied else [("", rows)])
             for o in (campaign.outages if o_varied else [""])]
    by = " and ".join(["sensing profile"] * varied + ["outage"] * o_varied)
    lines += ["## Success rate per controller" + (f" and {by}" if by else ""), "",
              ("| sensing " if varied else "") + ("| outage " if o_varied else "")
              + "| controller | flights | success | crashed | "
              "failed | median RMSE after fault m |" + (" median estimate error m |" if varied
                                                       else "") + " median diagnosis s |"
              + (" median max error in outage m | max error in outage m |" if outage else ""),
              ("|---" if varied else "") + ("|---" if o_varied else "")
              + "|---|---|---|---|---|---|" + ("---|" if varied else "") + "---|"
              + ("---|---|" if outage else "")]
    for p, o, prs in table:
        for c in campaign.controllers:
            rs = [r for r in prs if r["controller"] == c]
            if not rs:
                continue
            rm = sorted(v for r in rs if not r["crashed"] and (v := _rmse_of(r)) is not None)
            est = [r["est_rmse_pos_m"] for r in rs if r.get("est_rmse_pos_m") is not None]
            in_outage = [r["max_pos_err_outage_m"] for r in rs
                         if r.get("max_pos_err_outage_m") is not None]
            lines.append((f"| {sensing_label(p)} " if varied else "")
                         + (f"| {o} " if o_varied else "")
                         + f"| {c} | {len(rs)} | {sum(r['success'] for r in rs) / len(rs):.0%} | "
                         f"{sum(bool(r['crashed']) for r in rs)} | "
                         f"{sum(r['status'] == 'failed' for r in rs)} | "
                         f"{fmt(statistics.median(rm) if rm else None)} |"
                         + (f" {fmt(statistics.median(est) if est else None)} |" if varied
                            else "") + f" {fmt(_median(rs, 'diagnosis_s'), '{:.2f}')} |"
                         + (f" {fmt(_median(rs, 'max_pos_err_outage_m'))} | "
                            f"{fmt(max(in_outage) if in_outage else None)} |" if outage else ""))
    lines.append("")
    if campaign.has_plant:
        plant_lines, plant_summary = plant_campaign.report(campaign, rows, out, figures)
        lines += plant_lines
        summary.update(plant_summary)
    else:
        summary["controllers"] = _controller_summary(campaign, rows)
    if varied:
        summary["sensing"] = {sensing_label(p): _controller_summary(campaign, prs)
                              for p, prs in groups}
    if o_varied:
        summary["outage"] = {o: _controller_summary(campaign, ors) for o, ors in o_groups}
        if varied:
            summary["sensing_outage"] = {
                f"{sensing_label(p)} {o}": _controller_summary(campaign, prs)
                for p, o, prs in table}
    if not campaign.has_plant and len(campaign.controllers) > 1:
        pair_lines, summary["paired_by_seed"] = paired_by_seed(campaign, rows)
        lines += pair_lines
    for key, judge in (("paired_targets", judge_paired_targets),
                       ("flight_targets", judge_flight_targets)):
        target_lines, failures, headline, judged = judge(campaign, rows)
        if judged:
            lines += target_lines
            summary[key] = judged
            # beside the plant targets' (trq-results reads both keys)
            summary["failures"] = summary.get("failures", []) + failures
            summary["headline"] = "; ".join(([summary["headline"]] if summary.get("headline")
                                             else []) + headline)
    write_json(out / "metrics.json", summary)
    for p, o, prs in table:
        if prs:
            label = ", ".join(x for x in (sensing_label(p), o and f"outage {o}") if x)
            lines += _cell_sections(campaign, prs, out, figures, label)
    if failed:
        lines += ["## Failed flights", ""]
        for r in failed[:20]:
            lines.append(f"- `{r['id']}` ({r['controller']}): {r['error']}")
        if len(failed) > 20:
            lines.append(f"- ... and {len(failed) - 20} more")
        lines.append("")
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return out / "report.md"
