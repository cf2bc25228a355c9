"""The controller daemon's control period counted in instructions, by the code that runs them.

    trq-bench-instructions                                  # trq_nmpc_eso, the sim's sensing
    trq-bench-instructions --controller trq_nmpc_eso_fused --sensing mocap
    trq-bench-instructions --floor                          # the replay (the floor) as well
    trq-bench-instructions --anchor acados                  # acados' exact RTI step as well
    trq-bench-instructions --cache                          # and the caches' misses, simulated
    trq-bench-instructions --json out/bench_instructions.json

Why: on a shared VM the same code's period moves by 20 % and more between two flights, and
acados' own step has been seen in two states 1.5x apart (docs/decisions/), so a cut of a few
percent cannot be resolved in time. An instruction count does not move with the machine's
moment: it is what a change to the code changes, to within the few instructions that depend on
timing (resends, timers). It is not time: an AVX2 kernel does more work in an instruction than
the interpreter does, so a share of instructions is not a share of the period, and a ratio of
counts is not the target's ratio of times. Use it to judge a change of our own code (before and
after, on any machine), and time (trq-bench-nmpc --daemons, trq-bench-floor) to judge targets.

How: the two lockstep flights of both daemons of trq_lab/bench/period.py (`fly_daemons`,
`short_s` and `long_s` of vehicle time, the default sim), with the controller daemon run under
valgrind's callgrind (`--tool=callgrind`, its default event: instructions executed, Ir; child
processes not followed; PYTHONHASHSEED=0 so that sets and dicts iterate alike in both flights,
and NumPy's OpenBLAS on one thread, `period_count` says why).
Each flight's count is split by the ELF object whose code ran (callgrind's self cost, `ob=`),
and the period's count of an object is (long - short) / periods, start-up and shut-down
cancelled as period.py cancels them for CPU time. The objects are grouped (`GROUPS`): the
interpreter, its extension modules, NumPy, the QP solver (HPIPM, BLASFEO), the compiled kernels
(the controller's cache: CasADi-generated code and our C cores), CasADi's library, the C
library, the C that ctypes calls (callgrind counts it under libffi's trampoline, not under the
called function), other.

--floor counts the replay of the long flight's controller.csv the same way
(trq_lab/bench/period_floor.py: the daemon's machinery, the math at no cost). --anchor acados
records the bench's rti-exact flight (trq-bench-nmpc's `run_mode`) and replays it once through
acados (trq_lab/bench/acados_anchor.py) under callgrind collecting only inside acados'
`ocp_nlp_solve` (its preparation and feedback calls, everything they call): instructions per
step = that count / the recording's steps. The Python around acados' calls is not counted, as
the time bench does not time it.

--cache adds callgrind's cache simulation (`CACHE_SIM`: first-level instruction and data
caches of 32 KB, a last level of 512 KB standing for one x86 core's L2; a choice, callgrind
simulates two levels) and prints each process's misses per period beside its instructions: how
much code and data a period reads from beyond each level, a figure that, like the count, does
not move with the machine's moment. It simulates one process on caches of its own: what another
process, or the machine, takes from them between two periods is not in it
(docs/decisions/2026-12-07-period-paced.md; `trq-bench-decay` measures that).

A controller under callgrind runs some fifty times slower: the flights take minutes, the
controller's start-up most of it (its listening wait is `LISTEN_TIMEOUT_S`).
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = ["GROUPS", "CACHE_SIM", "callgrind_costs", "callgrind_file", "by_object",
           "by_function", "group_of", "period_count", "acados_count", "main"]

LISTEN_TIMEOUT_S = 900.0       # the controller's start-up under callgrind: imports, cached builds
ACADOS_STEP_FUNCTION = "ocp_nlp_solve"
JSON_FUNCTIONS = 300           # the functions a JSON keeps, those that run most
QUICK_S = 16.0                 # the anchor's recorded flight: trq-bench-nmpc --quick's
# --cache: callgrind's two simulated levels, size,associativity,line (the module's docstring)
CACHE_SIM = ("--cache-sim=yes", "--I1=32768,8,64", "--D1=32768,8,64", "--LL=524288,8,64")
# the simulation's events, as callgrind names them, and how the table names them
CACHE_EVENTS = (("Ir", "instructions"), ("I1mr", "L1 instruction misses"),
                ("ILmr", "L2 instruction misses"), ("DLmr", "L2 data read misses"),
                ("DLmw", "L2 data write misses"))

# (group, a pattern of the object's path); the first that matches names the group
GROUPS = (
    ("interpreter (libpython)", r"libpython"),
    ("QP solver (HPIPM, BLASFEO)", r"lib(hpipm|blasfeo)"),
    ("NumPy", r"/numpy(\.libs)?/"),
    ("CasADi's library", r"libcasadi"),
    ("acados", r"libacados|acados_ocp_solver|acados_solver|_model\.so"),
    # callgrind counts a C function called through ctypes under libffi's call (tested: a loop
    # in a library called by ctypes lands in libffi's trampoline), so that is our C cores' own
    ("C called through ctypes (our C cores; counted under libffi)", r"libffi"),
    ("interpreter's extension modules", r"lib-dynload|site-packages/.*\.cpython-"),
    ("C and C++ runtime", r"/lib(c|m|stdc\+\+|gcc_s|pthread)[.-]|ld-linux"),
    ("compiled kernels (the cache: CasADi-generated, our C cores)", r"\.so$"),
)
OTHER = "other"

_NAMED = re.compile(r"\((\d+)\)(?: (.*))?$")


def group_of(obj: str) -> str:
    for name, pattern in GROUPS:
        if re.search(pattern, obj):
            return name
    return OTHER


def callgrind_file(path: Path) -> tuple[collections.Counter, dict[str, int]]:
    """One pass over a callgrind output file: the self cost of each function (its first event:
    Ir), keyed (its ELF object, the function), and the file's totals per event (its `events:`
    line and its `totals:` line). Each cost line counts for the function it is in, whose object
    is the `ob=` before its `fn=`; the line after `calls=` is the call's inclusive cost, the
    callee's, and is not counted again. Names compressed as `(id) name` are expanded. Raises
    ValueError on a file whose costs do not add up to its own total."""
    names: dict[tuple[str, str], str] = {}

    def expand(kind: str, value: str) -> str:
        m = _NAMED.match(value)
        if m is None:
            return value
        if m.group(2) is not None:
            names[kind, m.group(1)] = m.group(2)
        return names.get((kind, m.group(1)), value)

    cost: collections.Counter = collections.Counter()
    ob = key_now = None
    skip = False
    events, totals = ["Ir"], None
    with open(path, errors="replace") as f:
        for line in f:
            if skip:
                skip = False
                continue
            if not line.strip():
                continue
            head = line[0]
            if head.isdigit() or head in "+-*":
                parts = line.split()
                if len(parts) >= 2:
                    cost[key_now] += int(parts[1])
                continue
            key, _, value = line.rstrip("\n").partition("=")
            if key in ("ob", "cob"):
                name = expand("ob", value)
                if key == "ob":
                    ob = name
            elif key in ("fn", "cfn"):
                name = expand("fn", value)
                if key == "fn":
                    key_now = (ob, name)
            elif key == "calls":
                skip = True
            elif line.startswith("events:"):
                events = line.split()[1:]
            elif line.startswith("totals:"):
                totals = [int(v) for v in line.split()[1:]]
    counted = sum(cost.values())
    if totals is None:
        totals = [counted]
    elif totals[0] != counted:
        raise ValueError(f"{path}: its costs add up to {counted}, its total says {totals[0]}")
    return cost, dict(zip(events, totals))


def callgrind_costs(path: Path) -> tuple[collections.Counter, int]:
    """callgrind_file's costs and the file's total of its first event (Ir)."""
    cost, totals = callgrind_file(path)
    return cost, next(iter(totals.values()))


def by_object(costs: collections.Counter) -> collections.Counter:
    """callgrind_costs' figures summed per ELF object ("?" where callgrind names none)."""
    out: collections.Counter = collections.Counter()
    for (obj, _fn), n in costs.items():
        out[obj or "?"] += n
    return out


def by_function(costs: collections.Counter) -> collections.Counter:
    """callgrind_costs' figures keyed "object's file name: function"."""
    return collections.Counter({f"{(obj or '?').rsplit('/', 1)[-1]}: {fn}": n
                                for (obj, fn), n in costs.items()})


def _only_output(out_dir: Path) -> Path:
    files = sorted(glob.glob(str(out_dir / "callgrind.out.*")))
    if len(files) != 1:
        raise RuntimeError(f"{out_dir}: expected one callgrind output, found {len(files)}")
    return Path(files[0])


def valgrind() -> str:
    path = shutil.which("valgrind")
    if path is None:
        raise RuntimeError("valgrind not found: trq-bench-instructions runs the controller under "
                           "valgrind's callgrind (Debian: apt install valgrind)")
    return path


def callgrind_command(out_dir: Path, command: list[str],
                      extra: tuple[str, ...] = ()) -> list[str]:
    return [valgrind(), "--tool=callgrind", *extra,
            f"--callgrind-out-file={out_dir}/callgrind.out.%p", *command]


def per_period(short: collections.Counter, long_: collections.Counter,
               periods: float) -> dict[str, float]:
    """Each key's instructions per period, (long - short) / periods."""
    return {k: (long_.get(k, 0) - short.get(k, 0)) / periods for k in set(short) | set(long_)}


def grouped(objects: dict[str, float]) -> dict[str, float]:
    out: dict[str, float] = collections.defaultdict(float)
    for obj, n in objects.items():
        out[group_of(obj)] += n
    return dict(out)


def period_count(controller: str, short_s: float, long_s: float, work: Path,
                 sensing: str | None = None, controller_cmd: list[str] | None = None,
                 control_rate_hz: int = 100, cache: bool = False) -> dict:
    """The controller daemon's instructions per period over the two flights (the module's
    docstring); `controller_cmd`: fly_daemons' (default: the real controller); `cache`: with
    the cache simulation, its events per period under "cache"."""
    from trq_lab.bench.period import fly_daemons

    command = list(controller_cmd or [sys.executable, "-m", "trq_offboard"])
    costs = {}
    totals = {}
    flights = {}
    # sets and dicts iterating alike in both flights; NumPy's OpenBLAS on one thread: its idle
    # workers' spinning, serialised by valgrind, otherwise adds a count that varies from flight
    # to flight (the period's BLAS calls are small products, which OpenBLAS runs on the
    # calling thread either way)
    env = {"PYTHONHASHSEED": "0", "OPENBLAS_NUM_THREADS": "1"}
    for name, seconds in (("short", short_s), ("long", long_s)):
        out = work / name / "callgrind"
        out.mkdir(parents=True)
        flights[name] = fly_daemons(seconds, controller, work / name,
                                    controller_cmd=callgrind_command(
                                        out, command, CACHE_SIM if cache else ()),
                                    sensing=sensing, listen_timeout_s=LISTEN_TIMEOUT_S,
                                    controller_env=env)
        costs[name], totals[name] = callgrind_file(_only_output(out))
    periods = (long_s - short_s) * control_rate_hz
    short, long_ = costs["short"], costs["long"]
    short_total, long_total = (next(iter(totals[k].values())) for k in ("short", "long"))
    objects = per_period(by_object(short), by_object(long_), periods)
    return {"periods": periods, "flights": flights,
            "total": (long_total - short_total) / periods,
            "groups": grouped(objects),
            "objects": objects,
            "functions": per_period(by_function(short), by_function(long_), periods),
            **({"cache": per_period(totals["short"], totals["long"], periods)}
               if cache else {})}


def acados_count(recording: Path, hessian: str, controller: str, work: Path,
                 cache: bool = False) -> dict:
    """acados' instructions per RTI step (preparation and feedback) replaying `recording`
    (the module's docstring)."""
    from trq_lab.bench import acados_anchor

    ok, why = acados_anchor.available()
    if not ok:
        raise RuntimeError(why)
    out = work / "acados"
    out.mkdir(parents=True)
    cmd = callgrind_command(out, [sys.executable, "-m", "trq_lab.bench.acados_anchor",
                                  "--replay", str(recording), "--hessian", hessian,
                                  "--controller", controller],
                            extra=(f"--toggle-collect={ACADOS_STEP_FUNCTION}",
                                   *(CACHE_SIM if cache else ())))
    run = subprocess.run(cmd, env=acados_anchor.library_env(), cwd=out, capture_output=True,
                         text=True)
    if run.returncode != 0:
        raise RuntimeError(f"acados' replay under callgrind failed:\n{run.stderr[-2000:]}")
    from trq_lab.bench.nmpc import _last_json_line
    summary = json.loads(_last_json_line(run.stdout))
    costs, totals = callgrind_file(_only_output(out))
    total = next(iter(totals.values()))
    steps = summary["steps"]
    none = collections.Counter()                  # the whole count is the steps'
    objects = per_period(none, by_object(costs), steps)
    return {"steps": steps, "failures": summary.get("failures"), "total": total / steps,
            "groups": grouped(objects), "objects": objects,
            "functions": per_period(none, by_function(costs), steps),
            **({"cache": per_period(none, totals, steps)} if cache else {})}


def table(rows: dict[str, dict]) -> str:
    """Instructions per period (thousands) by group, one column per measured process."""
    names = list(rows)
    groups = sorted({g for r in rows.values() for g in r["groups"]},
                    key=lambda g: -max(r["groups"].get(g, 0.0) for r in rows.values()))
    lines = ["| thousand instructions a period | " + " | ".join(names) + " |",
             "|---|" + "---|" * len(names)]
    for g in groups:
        lines.append(f"| {g} | " + " | ".join(f"{rows[n]['groups'].get(g, 0.0) / 1e3:.0f}"
                                             for n in names) + " |")
    lines.append("| **all** | " + " | ".join(f"**{rows[n]['total'] / 1e3:.0f}**"
                                             for n in names) + " |")
    return "\n".join(lines)


def cache_table(rows: dict[str, dict]) -> str:
    """The simulated caches' events per period (thousands), one row per measured process."""
    lines = ["| thousands a period (a step for acados) | "
             + " | ".join(label for _, label in CACHE_EVENTS) + " |",
             "|---" * (len(CACHE_EVENTS) + 1) + "|"]
    for name, r in rows.items():
        c = r["cache"]
        lines.append(f"| {name} | " + " | ".join(f"{c.get(e, 0.0) / 1e3:.1f}"
                                                 for e, _ in CACHE_EVENTS) + " |")
    return "\n".join(lines)


def top_objects(objects: dict[str, float], n: int = 12) -> str:
    total = sum(objects.values()) or 1.0
    return "\n".join(f"  {v / 1e3:9.0f} k  {v / total:5.3f}  {k}"
                     for k, v in sorted(objects.items(), key=lambda kv: -kv[1])[:n])


def main(argv=None) -> int:
    from trq_lab.bench.period import add_flight_lengths

    ap = argparse.ArgumentParser(prog="trq-bench-instructions",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="trq_nmpc_eso")
    ap.add_argument("--sensing", default=None, help="the vehicle's sensing profile")
    add_flight_lengths(ap, 2.0, 6.0)
    ap.add_argument("--floor", action="store_true",
                    help="also the replay of the long flight (trq-bench-floor's floor)")
    ap.add_argument("--anchor", choices=("acados",), default=None,
                    help="also acados' RTI step on the bench's recorded rti-exact flight")
    ap.add_argument("--cache", action="store_true",
                    help="also simulate the caches (L1 32 KB, L2 512 KB): misses per period")
    ap.add_argument("--functions", type=int, default=0, metavar="N",
                    help="also list the N functions that run most in each process")
    ap.add_argument("--json", type=Path, default=None, help="write the figures to this file")
    args = ap.parse_args(argv)
    if not 0 < args.short_s < args.long_s:
        ap.error(f"--short-s {args.short_s:g} and --long-s {args.long_s:g}: need "
                 f"0 < short < long")
    try:
        valgrind()
    except RuntimeError as exc:
        print(exc, file=sys.stderr)
        return 2
    from trq_lab.bench.nmpc import machine_line
    print(machine_line(), flush=True)
    print(f"controller: {args.controller}; flights {args.short_s:g} s and {args.long_s:g} s of "
          f"vehicle time in lockstep, the controller under callgrind", flush=True)
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="trq-bench-instructions-") as tmp:
        work = Path(tmp)
        rows[args.controller] = period_count(args.controller, args.short_s, args.long_s,
                                             work / "real", args.sensing, cache=args.cache)
        print(f"  {args.controller}: {rows[args.controller]['total'] / 1e3:.0f} k "
              f"instructions a period", flush=True)
        if args.floor:
            from trq_lab.bench.period_floor import replay_command
            csv = work / "real" / "long" / "controller.csv"
            rows["the floor (replay)"] = period_count(
                args.controller, args.short_s, args.long_s, work / "floor", args.sensing,
                controller_cmd=replay_command(csv), cache=args.cache)
            print(f"  the floor: {rows['the floor (replay)']['total'] / 1e3:.0f} k "
                  f"instructions a period", flush=True)
        if args.anchor:
            from trq_lab.bench.nmpc import run_mode
            rec = work / "rec_exact.npz"
            run_mode("rti-exact", QUICK_S, "trq_nmpc_eso", record=rec)
            rows["acados exact RTI step"] = acados_count(rec, "exact", "trq_nmpc_eso", work,
                                                         cache=args.cache)
            print(f"  acados' exact RTI step: "
                  f"{rows['acados exact RTI step']['total'] / 1e3:.0f} k instructions a step "
                  f"({rows['acados exact RTI step']['steps']} steps)", flush=True)
    print()
    print(table(rows))
    if args.cache:
        print(f"\nthe caches, simulated ({' '.join(CACHE_SIM[1:])}):\n{cache_table(rows)}")
    for name, r in rows.items():
        print(f"\n{name}, the objects that run most:\n{top_objects(r['objects'])}")
        if args.functions:
            print(f"{name}, the functions that run most (their own instructions):\n"
                  f"{top_objects(r['functions'], args.functions)}")
    if args.anchor:
        a = rows["acados exact RTI step"]["total"]
        print(f"\n{args.controller}'s period / acados' step, in instructions: "
              f"{rows[args.controller]['total'] / a:.2f} (not the time target's ratio: "
              f"see the module's docstring)")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        def kept(r: dict) -> dict:      # the flights' CPU is not this bench's; the functions
            top = sorted(r["functions"].items(), key=lambda kv: -kv[1])[:JSON_FUNCTIONS]
            return {**{k: v for k, v in r.items() if k not in ("flights", "functions")},
                    "functions": dict(top)}
        args.json.write_text(json.dumps({k: kept(v) for k, v in rows.items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
