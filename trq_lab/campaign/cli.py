"""trq-campaign: plan a campaign, fly what is not yet flown on Dask, write flights.csv and the
report (the campaign file and the outputs: `trq_lab.campaign`'s docstring).

    trq-campaign smoke --out out/campaign_smoke --workers 2
    trq-campaign CAMPAIGN.yaml --out DIR [--workers N | --scheduler tcp://HOST:8786]
                             [--max-flights N] [--retry-failed] [--keep-logs] [--report-only]
                             [--rescore] [--dry-run] [--no-figures]

Dask and tqdm (the `campaign` extra) are imported in one place, `_campaign_extra`: planning
(--dry-run), --report-only and --rescore need neither.

Exit status: 0 when every flight of the campaign has flown without an error, 1 otherwise, 2 on a
bad campaign file or command line.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
import traceback
from pathlib import Path

import trq_params
from trq_params import ConfigError

from trq_lab.campaign.flight import rescore, run_flight
from trq_lab.campaign.spec import SENSING_DEFAULT, Campaign, load_campaign
from trq_lab.campaign.store import flight_inputs, load_results, rows_of, write_csv, write_json
from trq_lab.reporting.campaign import wind_label, write_report
from trq_offboard.nmpc import hpipm

PROGRESS_EVERY_S = 2.0       # a terminal's bar is redrawn at most this often
PROGRESS_LOG_EVERY_S = 30.0  # a log's (not a terminal) progress line is written at most this often
PROGRESS_FORMAT = ("  {bar:30} {n_fmt}/{total_fmt} flights{postfix}, {rate_noinv_fmt}, "
                   "elapsed {elapsed}, ETA {remaining}")


def _campaign_extra():
    """(dask.distributed, tqdm): the `campaign` extra, imported here only."""
    try:
        import dask.distributed
        import tqdm
    except ImportError as exc:
        raise SystemExit(f"trq-campaign: {exc.name} is missing: pip install 'trq-ftc[campaign]'")
    return dask.distributed, tqdm


class _Lines:
    """A log's stream for tqdm: each refresh of the bar a line of its own (no carriage return),
    so that a CI log reads as lines."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.replace("\r", "").strip()
        if text:
            self.stream.write(text + "\n")

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(tqdm, total: int, stream):
    """tqdm's bar on a terminal; on a log, one plain line at most every PROGRESS_LOG_EVERY_S and
    one at the end."""
    tty = hasattr(stream, "isatty") and stream.isatty()
    return tqdm.tqdm(total=total, file=stream if tty else _Lines(stream), ascii=" #",
                     bar_format=PROGRESS_FORMAT, unit=" flights", dynamic_ncols=tty,
                     mininterval=PROGRESS_EVERY_S if tty else PROGRESS_LOG_EVERY_S,
                     postfix="0 failed")


def run_campaign(campaign: Campaign, out: Path, *, workers: int | None = None,
                 scheduler: str | None = None, max_flights: int | None = None,
                 retry_failed: bool = False, keep_logs: bool = False,
                 stream=sys.stderr) -> dict:
    """Fly the flights of `campaign` not yet in out/flights; return run info."""
    (out / "flights").mkdir(parents=True, exist_ok=True)
    done = load_results(out)
    todo = [s for s in campaign.flights
            if s["id"] not in done or (retry_failed and done[s["id"]].get("error"))]
    skipped = len(campaign.flights) - len(todo)
    if max_flights is not None:
        todo = todo[:max_flights]
    info = {"planned": len(campaign.flights), "skipped": skipped, "flown": 0, "failed": 0,
            "wall_s": 0.0, "workers": 0, "flights_per_hour": 0.0, "cluster_start_s": 0.0,
            "cpu_s": 0.0, "sim_s": 0.0,
            # the workers inherit this environment: the QP library their NMPCs load
            "qp_library": hpipm.library_label()}
    print(f"campaign: {campaign.name}: {len(campaign.flights)} flights, {skipped} already done, "
          f"{len(todo)} to fly", file=stream, flush=True)
    if not todo:
        return info
    distributed, tqdm = _campaign_extra()
    t_start = time.monotonic()
    cluster = None
    if scheduler:
        client = distributed.Client(scheduler)
    else:
        n = workers or os.cpu_count() or 1
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.ERROR)
        client = distributed.Client(cluster)
    try:
        nworkers = len(client.scheduler_info()["workers"])
        info["workers"] = nworkers
        info["cluster_start_s"] = round(time.monotonic() - t_start, 2)
        print(f"campaign: {nworkers} worker(s) on {client.scheduler.address}", file=stream,
              flush=True)
        log_dir = str(out / "logs") if keep_logs else None
        t0 = time.monotonic()
        futures = [client.submit(run_flight, spec, log_dir, key=f"flight-{spec['id']}",
                                 pure=False) for spec in todo]
        by_key = {f.key: s for f, s in zip(futures, todo)}
        with progress_bar(tqdm, len(todo), stream) as bar:
            for fut in distributed.as_completed(futures):
                spec = by_key[fut.key]
                try:
                    rec = fut.result()
                except Exception:  # the worker died (or the task could not start): keep it
                    rec = {"id": spec["id"], "spec": spec, "status": "failed", "metrics": None,
                           "error": traceback.format_exc(), "wall_s": None, "sim_s": None,
                           "worker": None}
                rec["finished_unix_s"] = round(time.time(), 3)
                write_json(out / "flights" / f"{spec['id']}.json", rec)
                info["flown"] += 1
                info["failed"] += bool(rec.get("error"))
                info["cpu_s"] += rec.get("cpu_s") or 0.0
                info["sim_s"] += rec.get("sim_s") or 0.0
                bar.set_postfix_str(f"{info['failed']} failed", refresh=False)
                bar.update(1)
                fut.release()
        info["wall_s"] = round(time.monotonic() - t0, 2)
        info["flights_per_hour"] = round(3600.0 * info["flown"] / max(info["wall_s"], 1e-9), 1)
        # how much of its cores the cluster got (a shared machine gives less than 100 %)
        info["cpu_share"] = round(info["cpu_s"] / max(info["wall_s"] * nworkers, 1e-9), 3)
        info["cpu_s"] = round(info["cpu_s"], 2)
        info["sim_s"] = round(info["sim_s"], 2)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return info


# the command's on/off options and what each does
SWITCHES = {
    "--retry-failed": "fly again the flights recorded with an error",
    "--keep-logs": "keep each flight's flight.csv and controller.csv in DIR/logs/<id>/ (the "
                   "workers must see DIR)",
    "--report-only": "fly nothing: rewrite flights.csv and report.md from DIR/flights",
    "--rescore": "fly nothing: measure every flight again from its kept logs (DIR/logs/<id>/, "
                 "--keep-logs) with the current metrics, then rewrite flights.csv and report.md",
    "--dry-run": "list the flights and exit",
    "--no-figures": "skip the heat-map PNGs",
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="trq-campaign", description="Fault campaigns at scale: a grid and/or a seeded "
        "random sample of flights over fault, wind, trajectory, link, plant, sensing, sensor "
        "outage and controller, "
        "flown on Dask (resumable).")
    ap.add_argument("campaign", help="a built-in campaign by name (" + ", ".join(
        trq_params.names("campaigns")) + ") or a campaign YAML by path")
    ap.add_argument("--out", type=Path, required=True, help="output directory (resumable)")
    ap.add_argument("--workers", type=int, default=None,
                    help="LocalCluster worker processes, one thread each (default: all cores)")
    ap.add_argument("--scheduler", default=None,
                    help="an existing Dask scheduler, tcp://HOST:8786 (then --workers is ignored)")
    ap.add_argument("--max-flights", type=int, default=None,
                    help="fly at most this many of the flights not yet done, then stop")
    for flag, text in SWITCHES.items():
        ap.add_argument(flag, action="store_true", help=text)
    args = ap.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        ap.error("--workers: expected at least 1")
    if args.max_flights is not None and args.max_flights < 0:
        ap.error("--max-flights: expected 0 or more")
    try:
        campaign = load_campaign(trq_params.resolve("campaigns", args.campaign))
    except ConfigError as exc:
        print(f"campaign: {exc}", file=sys.stderr)
        return 2
    if args.dry_run:
        for s in campaign.flights:
            r = flight_inputs(s)
            plant = "" if "plant" not in s else " plant " + ",".join(
                f"{k}={v:g}" for k, v in sorted(s["plant"].items())) + (
                " (model: the plant)" if s.get("controller_model") == "plant" else "")
            if r["sensing"] != SENSING_DEFAULT:
                plant += f" sensing {r['sensing']}"
            if "outage" in s:
                plant += f" outage {r['outage']}"
            print(f"{s['id']} {s['controller']:14s} fault {r['fault_kind']} {r['severity']:g} "
                  f"wind {wind_label(r)} traj {r['traj_kind']} seed {s['seed']}{plant}")
        print(f"campaign: {campaign.name}: {len(campaign.flights)} flights")
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    info = None
    if args.rescore:
        done = 0
        for fid, rec in load_results(args.out).items():
            new = rescore(rec, args.out / "logs")
            if new is not rec:
                write_json(args.out / "flights" / f"{fid}.json", new)
                done += 1
        print(f"campaign: {done} flights measured again from {args.out / 'logs'}")
    last = args.out / "last_run.json"
    keep_last = args.report_only or args.rescore
    if not keep_last:
        info = run_campaign(campaign, args.out, workers=args.workers, scheduler=args.scheduler,
                            max_flights=args.max_flights, retry_failed=args.retry_failed,
                            keep_logs=args.keep_logs)
        if info["flown"]:
            print(f"campaign: flew {info['flown']} flights ({info['failed']} failed) in "
                  f"{info['wall_s']:.1f} s on {info['workers']} worker(s) (cluster start "
                  f"{info['cluster_start_s']:.1f} s): {info['flights_per_hour']:.0f} flights/hour")
            print(f"campaign: the flights used {info['cpu_s']:.0f} CPU s for {info['sim_s']:.0f} "
                  f"simulated s ({info['cpu_s'] / max(info['flown'], 1):.1f} CPU s a flight); the "
                  f"workers got {info['cpu_share']:.0%} of their cores")
            print(f"campaign: the NMPC's QPs solved by {info['qp_library']}")
        if info["flown"] or not last.is_file():
            write_json(last, info)
        else:                   # nothing flown: the run that flew the flights stays the report's
            keep_last = True
    if keep_last and last.is_file():    # --report-only, --rescore, nothing flown: the last run's
        try:
            info = json.loads(last.read_text())
        except ValueError:
            info = None
    results = load_results(args.out)
    rows = rows_of(campaign, results)
    write_csv(rows, args.out / "flights.csv")
    report = write_report(campaign, rows, args.out, info if info and info.get("flown") else None,
                          figures=not args.no_figures)
    print(f"campaign: {len(rows)} of {len(campaign.flights)} flights in "
          f"{args.out / 'flights.csv'}, "
          f"report {report}")
    complete = len(rows) == len(campaign.flights)
    return 0 if complete and not any(r["status"] == "failed" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
