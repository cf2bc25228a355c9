"""trq-results: the README's results tables, generated from result files.

Contract. In: result directories, one per scenario, each holding the ``metrics.json`` that
``trq-scenario NAME --out DIR`` writes (``{"scenario": ..., "runs": [{"controller": ...,
"crashed": ..., "rmse_pos_after_fault_m": ..., ...}], "envelope": [...]}``) and, optionally, the
``report.md`` written beside it. Out: the blocks of a Markdown file between markers

    <!-- results:paper_fault50 begin -->  ...  <!-- results:paper_fault50 end -->
    <!-- results:profiles paper_fault50 begin -->  ...  <!-- results:profiles paper_fault50 end -->
    <!-- results:scenarios begin -->      ...  <!-- results:scenarios end -->
    <!-- results:campaigns begin -->      ...  <!-- results:campaigns end -->

rewritten in place: the first is the full table of one scenario (any scenario name works), the
second one scenario flown under each sensing profile, a row per profile (the result directories
``sensing/<scenario>-<profile>/`` of ``trq-scenario <scenario> --sensing <profile>``, the profile
as their ``metrics.json`` records it), the third
one row per scenario found under the results directory (other than those with a block of
their own), the fourth one row per campaign found there: the ``metrics.json`` that ``trq-campaign``
writes (``{"campaign": ..., "flights": ..., "controllers": {NAME: {"success_rate": ...,
"rmse_median_m": ...}}, "plants": ..., "failures": [...]}``; a campaign's is told from a
scenario's by its "campaign" key). Whether a scenario's targets were met is taken from
``metrics.json``'s
``"failures"`` list when it has one, else from the "Missed" section of the ``report.md`` beside
it ("none set" when that report has no Targets section); without either, "not recorded". Text
outside the markers is never touched.
``--check`` writes nothing and exits 1 when a block is out of date.

It imports only the standard library: it runs without the simulator or the controller installed.
Exit status: 0 done (or up to date), 1 out of date (``--check``), 2 a missing file or marker, or a
result file that cannot be read (the message names it).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from pathlib import Path

from trq_lab.reporting.fmt import columns, fmt, table_head, table_row

__all__ = ["ResultsError", "campaigns_table", "main", "profiles_table", "render_block",
           "scenario_table", "scenarios_table", "update_text"]

# The faults of the shipped scenarios, as the scenarios table names them (metrics.json does not
# name its fault; a "fault" key in it, when present, wins).
FAULTS = {
    "paper_fault50": "50 % from t = 12 s",
    "paper_timevarying": "`0.8 - 0.2 sin(0.01 t)` (the paper's Fig. 7)",
    "fast_timevarying": "`0.8 - 0.2 sin(t)` (period 6 s)",
    "paper_fault50_lossy": "50 %, offboard link 10 % loss, 20 ms each way",
    "nominal": "none",
    "motor1_lost": "0 % (off) from t = 8 s, hovering at 5 m",
    "mocap_dropout": "50 %; the motion capture off from 14 s to 15 s",
    "gnss_outage": "50 %, under rtk; the GNSS receiver off from 14 s to 18.5 s",
    "mocap_lost": "none; the motion capture lost for good at 15 s",
}

# The controllers' column order (others follow in the order metrics.json lists them).
CONTROLLERS = ("trq_nmpc_eso", "trq_nmpc_eso_paper", "trq_nmpc", "quad_nmpc")

# the full table's columns: the reports' metric columns, the RMSE after the fault to 0.1 mm
COLUMNS = columns(("controller", "vehicle", "crashed", "flight_s", "rmse_pos_m", "max_pos_err_m",
                   "rmse_pos_after_fault_m", "max_yaw_err_deg", "recovery_s", "solve_ms_p50",
                   "solve_ms_p99"), {"rmse_pos_after_fault_m": "{:.4f}"})

SCENARIOS_BLOCK = "scenarios"
CAMPAIGNS_BLOCK = "campaigns"
PROFILES_BLOCK = "profiles"          # "profiles SCENARIO": one scenario per sensing profile
SENSING_DIR = "sensing"              # where its result directories live, SCENARIO-PROFILE each
# the profiles' row order (others follow by name)
PROFILES = ("truth", "mocap", "rtk", "gnss")
# a block's name: one word, or a kind and its argument ("profiles paper_fault50")
_NAME = r"[A-Za-z0-9_.-]+(?: [A-Za-z0-9_.-]+)?"
_MARK = re.compile(r"<!-- results:(" + _NAME + r") (begin|end) -->")


class ResultsError(Exception):
    """A missing or unreadable result file, or a missing or unbalanced marker."""


def load_metrics(path: Path) -> dict:
    """One metrics.json, checked for the keys the tables read."""
    doc = _read_json(path)
    if not isinstance(doc.get("runs"), list):
        raise ResultsError(f"{path}: no 'runs' list (not a metrics.json of trq-scenario)")
    for i, run in enumerate(doc["runs"]):
        if not isinstance(run, dict) or "controller" not in run:
            raise ResultsError(f"{path}: runs[{i}] has no 'controller'")
    return doc


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise ResultsError(f"{path}: no such result file")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ResultsError(f"{path}: not a readable metrics.json ({exc})") from exc
    if not isinstance(doc, dict):
        raise ResultsError(f"{path}: not a mapping")
    return doc


def is_campaign(path: Path) -> bool:
    """Whether a metrics.json is a campaign's (trq-campaign) rather than a scenario's."""
    return "campaign" in _read_json(path)


def load_campaign_metrics(path: Path) -> dict:
    """One campaign's metrics.json, checked for the keys the campaigns table reads."""
    doc = _read_json(path)
    if not isinstance(doc.get("controllers"), dict) or "flights" not in doc:
        raise ResultsError(f"{path}: no 'controllers' mapping or no 'flights' (not a "
                           "metrics.json of trq-campaign)")
    return doc


def campaigns_table(paths: list[Path], base: Path | None = None) -> str:
    """One row per campaign: its name (a link to the report.md beside its metrics.json, when
    there is one), flights (plants), per controller success rate / median position RMSE after
    the fault, and its targets (the campaign's own "headline" of them when it writes one)."""
    docs = [(p, load_campaign_metrics(p)) for p in paths]
    controllers: list[str] = []
    for _, doc in docs:
        for c in doc["controllers"]:
            if c not in controllers:
                controllers.append(c)
    controllers = [c for c in CONTROLLERS if c in controllers] + \
        [c for c in controllers if c not in CONTROLLERS]
    # a controller given by its file's path: named by the file (no machine's folders)
    head = ["campaign", "flights"] + [f"{Path(c).stem} success / median RMSE after fault m"
                                      for c in controllers] + ["targets"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for path, doc in docs:
        flights = str(doc["flights"]) + (f" ({doc['plants']} plants)" if doc.get("plants")
                                         else "")
        report = path.with_name("report.md")
        name = f"`{doc['campaign']}`"
        cells = [f"[{name}]({_shown(report, base)})" if report.is_file() else name, flights]
        for c in controllers:
            st = doc["controllers"].get(c)
            if st is None:
                cells.append("not flown")
                continue
            rate = st.get("success_rate")
            median = ("crashed" if "rmse_median_m" in st.get("crashed_stats", ())
                      else fmt(st.get("rmse_median_m"), "{:.4f}"))
            cells.append(("-" if rate is None else f"{rate:.0%}") + " / " + median)
        cells.append(doc.get("headline") or targets_met(path, doc))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _ordered(runs: list[dict]) -> list[dict]:
    rank = {c: i for i, c in enumerate(CONTROLLERS)}
    return sorted(runs, key=lambda r: rank.get(r["controller"], len(rank)))


def targets_met(metrics_path: Path, doc: dict) -> str:
    """'met', 'missed: ...' or 'not recorded', from metrics.json or the report beside it."""
    failures = doc.get("failures")
    if failures is None:
        report = metrics_path.with_name("report.md")
        if not report.is_file():
            return "not recorded"
        text = report.read_text()
        if "## Targets" not in text:
            return "none set"
        section = text.split("## Targets", 1)[1].split("\n## ", 1)[0]
        failures = []
        if "**Missed:**" in section:
            missed = section.split("**Missed:**", 1)[1]
            failures = [ln[2:].strip() for ln in missed.splitlines() if ln.startswith("- ")]
    if not failures:
        return "met"
    return "missed: " + "; ".join(_short_failure(f) for f in failures)


def _short_failure(text: str) -> str:
    """'c: key = 0.0128492 (target <= 0.0046)' with the value rounded to 4 significant digits."""
    def rounded(m: re.Match) -> str:
        return f"{float(m.group(0)):.4g}"
    return re.sub(r"(?<![\w.])\d+\.\d{5,}", rounded, text)


def _shown(path: Path, base: Path | None) -> str:
    """``path`` as the README names it: relative to ``base`` (the README's folder) if given."""
    return Path(os.path.relpath(path, base)).as_posix() if base is not None else path.as_posix()


def scenario_table(metrics_path: Path, base: Path | None = None) -> str:
    """The full table of one scenario, with its source and whether its targets were met."""
    doc = load_metrics(metrics_path)
    lines = table_head(COLUMNS)
    for run in _ordered(doc["runs"]):
        if "error" in run:
            lines.append(f"| {run['controller']} | " + f"{run['error']} |")
            continue
        lines.append(table_row(run, COLUMNS))
    lines.append("")
    lines.append(f"Targets of `{doc.get('scenario', metrics_path.parent.name)}`: "
                 f"{targets_met(metrics_path, doc)}. Source: `{_shown(metrics_path, base)}`.")
    return "\n".join(lines)


def scenarios_table(paths: list[Path], base: Path | None = None) -> str:
    """One row per scenario: its name (a link to its report.md, else to its metrics.json), its
    fault, per controller pos RMSE after fault / max yaw error."""
    docs = [(p, load_metrics(p)) for p in paths]
    controllers: list[str] = []
    for _, doc in docs:
        for run in _ordered(doc["runs"]):
            if run["controller"] not in controllers:
                controllers.append(run["controller"])
    controllers = [c for c in CONTROLLERS if c in controllers] + \
        [c for c in controllers if c not in CONTROLLERS]
    head = ["scenario", "fault on motor 1"] + [
        f"{c} pos RMSE after fault m / max yaw err deg" for c in controllers] + ["targets"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for path, doc in docs:
        name = doc.get("scenario", path.parent.name)
        by = {r["controller"]: r for r in doc["runs"]}
        report = path.with_name("report.md")
        source = report if report.is_file() else path
        cells = [f"[`{name}`]({_shown(source, base)})",
                 str(doc.get("fault", FAULTS.get(name, "-")))]
        cells += [_run_cell(by.get(c), (("rmse_pos_after_fault_m", "{:.4f}"),
                                         ("max_yaw_err_deg", "{:.2f}"))) for c in controllers]
        cells.append(targets_met(path, doc))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _run_cell(run: dict | None, figures: tuple[tuple[str, str], ...]) -> str:
    """A run's figures joined by ' / ' (a crash said so), or why there are none."""
    if run is None:
        return "not flown"
    if "error" in run:
        return "no usable logs"
    cell = " / ".join(fmt(run.get(key), spec) for key, spec in figures)
    return cell + (" (crashed)" if run.get("crashed") else "")


def profiles_table(paths: list[Path], base: Path | None = None) -> str:
    """One scenario flown under each sensing profile (its metrics.json's "sensing"), a row per
    profile: per controller the position RMSE after the fault, the maximum yaw error, the
    estimator's own position RMSE (its estimate against the truth; none under `truth`) and the
    fault's diagnosis time, a crash said so; the first header cell says what a cell holds."""
    docs = [(p, load_metrics(p)) for p in paths]
    for path, doc in docs:
        if not isinstance(doc.get("sensing"), str):
            raise ResultsError(f"{path}: no 'sensing' (the profile flown, which trq-scenario "
                               "records in metrics.json)")
    rank = {p: i for i, p in enumerate(PROFILES)}
    docs.sort(key=lambda d: (rank.get(_profile(d[1]), len(rank)), _profile(d[1])))
    controllers: list[str] = []
    for _, doc in docs:
        for run in _ordered(doc["runs"]):
            if run["controller"] not in controllers:
                controllers.append(run["controller"])
    head = [("sensing; each cell: pos RMSE after fault m / max yaw err deg / estimate pos RMSE m "
             "(the estimator's own error; none under `truth`: no estimator) / diagnosis s (none "
             "without an effectiveness observer, or crashed)")] + [f"`{c}`" for c in controllers]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for path, doc in docs:
        by = {r["controller"]: r for r in doc["runs"]}
        cells = [f"`{_profile(doc)}`"]
        cells += [_run_cell(by.get(c), (("rmse_pos_after_fault_m", "{:.4f}"),
                                         ("max_yaw_err_deg", "{:.2f}"),
                                         ("est_rmse_pos_m", "{:.4g}"),
                                         ("diagnosis_s", "{:.2f}"))) for c in controllers]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _profile(doc: dict) -> str:
    """The profile a scenario's metrics.json records: a built-in name, or a file's stem."""
    value = doc["sensing"]
    return Path(value).stem if "/" in value or value.endswith((".yaml", ".yml")) else value


def blocks_in(text: str, source: str) -> list[str]:
    """The names of the marked blocks, in order; unbalanced markers are an error."""
    names: list[str] = []
    open_name: str | None = None
    for m in _MARK.finditer(text):
        name, kind = m.group(1), m.group(2)
        if kind == "begin":
            if open_name is not None:
                raise ResultsError(f"{source}: marker 'results:{open_name} end' missing "
                                   f"(before 'results:{name} begin')")
            open_name = name
        else:
            if open_name != name:
                raise ResultsError(f"{source}: marker 'results:{name} end' without its begin")
            names.append(name)
            open_name = None
    if open_name is not None:
        raise ResultsError(f"{source}: marker 'results:{open_name} end' missing")
    return names


def render_block(name: str, results_dir: Path, own_blocks: list[str],
                 base: Path | None = None) -> str:
    """The generated text of block ``name`` (without its markers)."""
    if name.startswith(PROFILES_BLOCK + " "):
        scenario = name.split(" ", 1)[1]
        where = results_dir / SENSING_DIR
        paths = sorted(where.glob(f"{scenario}-*/metrics.json"))
        if not paths:
            raise ResultsError(f"{where}: no {scenario}-<profile>/metrics.json for the block "
                               f"'results:{name}'")
        return profiles_table(paths, base)
    if name == CAMPAIGNS_BLOCK:
        paths = sorted(p for p in results_dir.glob("*/metrics.json") if is_campaign(p))
        if not paths:
            raise ResultsError(f"{results_dir}: no campaign's */metrics.json for the block "
                               f"'results:{CAMPAIGNS_BLOCK}'")
        return campaigns_table(paths, base)
    if name == SCENARIOS_BLOCK:
        paths = sorted(p for p in results_dir.glob("*/metrics.json")
                       if p.parent.name not in own_blocks and not is_campaign(p))
        if not paths:
            raise ResultsError(f"{results_dir}: no */metrics.json for the block "
                               f"'results:{SCENARIOS_BLOCK}'")
        return scenarios_table(paths, base)
    return scenario_table(results_dir / name / "metrics.json", base)


def update_text(text: str, results_dir: Path, source: str = "README",
                required: tuple[str, ...] = (), base: Path | None = None) -> str:
    """``text`` with every marked block regenerated from ``results_dir``."""
    names = blocks_in(text, source)
    for name in required:
        if name not in names:
            raise ResultsError(f"{source}: marker '<!-- results:{name} begin -->' missing")
    own = [n for n in names if n not in (SCENARIOS_BLOCK, CAMPAIGNS_BLOCK)]
    for name in names:
        body = render_block(name, results_dir, own, base)
        pattern = re.compile(r"(<!-- results:" + re.escape(name) + r" begin -->\n)"
                             r".*?(<!-- results:" + re.escape(name) + r" end -->)", re.S)
        text = pattern.sub(lambda m: m.group(1) + body + "\n" + m.group(2), text, count=1)
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="trq-results",
        description="Regenerate the README's results tables (the blocks between "
                    "'<!-- results:NAME begin -->' and '<!-- results:NAME end -->') from "
                    "result files: RESULTS/<scenario>/metrics.json as trq-scenario writes it. "
                    "Block NAME is that scenario's full table; block 'profiles NAME' that "
                    "scenario per sensing profile (RESULTS/sensing/NAME-<profile>/"
                    "metrics.json); block 'scenarios' has one row "
                    "per other scenario found; block 'campaigns' one row per campaign "
                    "(RESULTS/<campaign>/metrics.json as trq-campaign writes it).")
    parser.add_argument("--readme", type=Path, default=Path("README.md"),
                        help="the Markdown file to update in place (default: README.md)")
    parser.add_argument("--results", type=Path, default=Path("docs/results"),
                        help="the directory of result directories (default: docs/results); "
                             "the tables name their sources relative to the README's folder")
    parser.add_argument("--require", action="append", default=[], metavar="NAME",
                        help="a block that must be present (repeatable); a missing marker "
                             "is an error")
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1 if the file is out of date")
    args = parser.parse_args(argv)
    if not args.readme.is_file():
        print(f"trq-results: {args.readme}: no such file", file=sys.stderr)
        return 2
    old = args.readme.read_text()
    try:
        if not blocks_in(old, str(args.readme)) and not args.require:
            raise ResultsError(f"{args.readme}: no '<!-- results:NAME begin -->' marker")
        new = update_text(old, args.results, str(args.readme), tuple(args.require),
                          base=args.readme.resolve().parent)
    except ResultsError as exc:
        print(f"trq-results: {exc}", file=sys.stderr)
        return 2
    if args.check:
        if new != old:
            print(f"trq-results: {args.readme} is out of date (run trq-results)",
                  file=sys.stderr)
            return 1
        print(f"trq-results: {args.readme} is up to date")
        return 0
    if new != old:
        args.readme.write_text(new)
        print(f"trq-results: {args.readme} updated")
    else:
        print(f"trq-results: {args.readme} already up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
