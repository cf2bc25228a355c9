"""trq-log-csv: the controller daemon's ULog (controller.ulg, trq_wire.ulog) written as the
CSV log (controller.csv) on the ground, as PX4's logs are converted off the vehicle.

    trq-log-csv logs/offboard-trq_nmpc_eso-20261206-101500      # a log folder: its controller.ulg
    trq-log-csv run/controller.ulg --out run/rows.csv           # one file, named output

The lab's runners (trq-scenario, the benches, trq-stress) convert their flights themselves.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from trq_wire.ulog import to_csv

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="trq-log-csv",
        description="Write the CSV log (controller.csv) of a controller daemon's ULog "
                    "(controller.ulg), beside it unless --out names the file.")
    parser.add_argument("paths", nargs="+", type=Path,
                        help="a .ulg file, or a log folder holding controller.ulg")
    parser.add_argument("--out", type=Path, default=None,
                        help="the CSV file (one path only); default beside the ULog, .csv")
    args = parser.parse_args(argv)
    if args.out is not None and len(args.paths) != 1:
        print("trq-log-csv: --out takes one path", file=sys.stderr)
        return 2
    status = 0
    for path in args.paths:
        ulg = path / "controller.ulg" if path.is_dir() else path
        try:
            if not ulg.is_file():
                raise ValueError(f"{ulg}: no such file")
            out = to_csv(ulg, args.out)
        except (ValueError, OSError) as exc:
            print(f"trq-log-csv: {exc}", file=sys.stderr)
            status = 2
            continue
        print(f"trq-log-csv: {out}")
    return status


if __name__ == "__main__":
    sys.exit(main())
