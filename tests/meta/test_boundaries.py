"""Architecture boundaries, read from the source with `ast` (nothing here imports the packages'
modules except the two argparse builders):

- the wire is the only coupling (which package may import which is tests/meta/test_imports.py's):
  both daemons use trq_wire, the wire's shared arithmetic and file formats, and neither defines
  again a function or class that trq_wire defines (one place for each);
- one clock: the simulator's core never reads the wall clock, sleeps, or uses unseeded randomness
  (only daemon.py and clock.py may touch the wall clock), nor does trq_wire outside
  signing.py and logfile.py;
- every command-line option of both daemons has a help text.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

import pytest

from conftest import source_tree

ROOT = Path(__file__).resolve().parents[2]
WALL_CLOCK_ALLOWED = {"daemon.py", "clock.py"}
BANNED_TIME = {"time", "monotonic", "sleep", "perf_counter", "time_ns", "monotonic_ns"}
# numpy's seeded generator API; anything else under np.random is global, unseeded state
SEEDED_NUMPY = {"default_rng", "SeedSequence", "Generator", "PCG64", "BitGenerator"}


def sources(package: str) -> list[Path]:
    files = sorted((ROOT / package).rglob("*.py"))
    assert len(files) >= 5, f"{package}: found only {files}"
    return files


def parse(path: Path) -> ast.Module:
    return source_tree(path)


def imported_modules(tree: ast.Module) -> list[str]:
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.append(node.module or "")
    return names


def defined_names(tree: ast.Module) -> set[str]:
    """Module-level functions and classes (not imports: a re-export defines nothing)."""
    return {node.name for node in tree.body
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))}


def test_both_daemons_use_trq_wire():
    for package in ("sil_vehicle", "trq_offboard"):
        users = [p for p in sources(package)
                 if any(n.split(".")[0] == "trq_wire" for n in imported_modules(parse(p)))]
        assert len(users) >= 3, f"{package}: only {users} import trq_wire"


def test_what_trq_wire_defines_is_not_defined_again_in_a_daemon():
    shared = set().union(*(defined_names(parse(p)) for p in sources("trq_wire")))
    shared -= {n for n in shared if n.startswith("_")}
    assert {"load_key", "SignatureCheck", "to_pwm", "CsvLog", "cache_dir"} <= shared
    offenders = [f"{p.relative_to(ROOT)}: {name}"
                 for package in ("sil_vehicle", "trq_offboard") for p in sources(package)
                 for name in sorted(defined_names(parse(p)) & shared)]
    assert not offenders, offenders


@pytest.mark.parametrize("package", ["sil_vehicle", "trq_offboard", "trq_lab", "params"])
def test_one_yaml_loader(package):
    """Every YAML file is read (and every overlay written) through trq_params.loader: no other
    module imports yaml."""
    offenders = [f"{path.relative_to(ROOT)}: import {name}"
                 for path in sorted((ROOT / package).rglob("*.py"))
                 if path != ROOT / "params" / "loader.py"
                 for name in imported_modules(parse(path)) if name.split(".")[0] == "yaml"]
    assert not offenders, offenders


def clock_and_random_uses(tree: ast.Module) -> list[str]:
    """Calls of time.time/monotonic/sleep (however imported) and any use of `random`."""
    found = []
    time_aliases, numpy_aliases = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                top, alias = a.name.split(".")[0], a.asname or a.name.split(".")[0]
                if top == "time":
                    time_aliases.add(alias)
                elif top == "random":
                    found.append(f"line {node.lineno}: import {a.name}")
                elif top == "numpy":
                    numpy_aliases.add(alias)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            top = node.module.split(".")[0]
            if top == "random" or node.module == "numpy.random" and any(
                    a.name not in SEEDED_NUMPY for a in node.names):
                found.append(f"line {node.lineno}: from {node.module} import ...")
            elif top == "time" and any(a.name in BANNED_TIME for a in node.names):
                found.append(f"line {node.lineno}: from time import "
                             + ", ".join(a.name for a in node.names))
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        base = node.value
        if isinstance(base, ast.Name) and base.id in time_aliases and node.attr in BANNED_TIME:
            found.append(f"line {node.lineno}: {base.id}.{node.attr}")
        if isinstance(base, ast.Attribute) and base.attr == "random" \
                and isinstance(base.value, ast.Name) and base.value.id in numpy_aliases \
                and node.attr not in SEEDED_NUMPY:
            found.append(f"line {node.lineno}: {base.value.id}.random.{node.attr}")
    return found


def test_checker_sees_what_it_must():
    """The checker itself: it must flag each banned form, and not the seeded ones."""
    bad = ("import time\ntime.time()\n", "import time as t\nt.sleep(1)\n",
           "from time import monotonic\n", "import random\n", "from random import random\n",
           "import numpy as np\nnp.random.rand(3)\n", "from numpy.random import randn\n")
    for text in bad:
        assert clock_and_random_uses(ast.parse(text)), text
    good = ("import numpy as np\nnp.random.default_rng(np.random.SeedSequence(1))\n",
            "from dataclasses import field\nx = 'time.time()'\n")
    for text in good:
        assert not clock_and_random_uses(ast.parse(text)), text


def test_simulator_core_has_no_wall_clock_sleep_or_unseeded_random():
    core = [p for p in sources("sil_vehicle")
            if not (p.parent == ROOT / "sil_vehicle" and p.name in WALL_CLOCK_ALLOWED)]
    assert any(p.name == "vehicle.py" for p in core) and any(p.name == "sitl.py" for p in core)
    offenders = [f"{p.relative_to(ROOT)} {use}" for p in core
                 for use in clock_and_random_uses(parse(p))]
    assert not offenders, offenders


def test_trq_wire_reads_the_wall_clock_only_for_signing_and_the_tlog():
    """The signing clock and the .tlog stamps are wall-clock time by their formats' definition;
    nothing else shared by the daemons may read a clock, sleep or draw random numbers."""
    allowed = {"signing.py", "logfile.py"}
    files = sources("trq_wire")
    assert {p.name for p in files} >= allowed | {"actuators.py", "cache.py"}
    offenders = [f"{p.relative_to(ROOT)} {use}" for p in files if p.name not in allowed
                 for use in clock_and_random_uses(parse(p))]
    assert not offenders, offenders


def build_parsers() -> dict[str, argparse.ArgumentParser]:
    from sil_vehicle.daemon import build_parser as vehicle_parser
    from trq_offboard.daemon import build_parser as offboard_parser
    return {"sil_vehicle": vehicle_parser(), "trq_offboard": offboard_parser()}


@pytest.mark.parametrize("name", ["sil_vehicle", "trq_offboard"])
def test_every_option_has_a_help_text(name):
    parser = build_parsers()[name]
    options = [a for a in parser._actions if a.option_strings]
    assert len(options) >= 5
    missing = [a.option_strings for a in options
               if a.help is None or a.help == argparse.SUPPRESS or len(a.help.strip()) < 5]
    assert not missing, f"{name}: options without help: {missing}"
    text = parser.format_help()
    for a in options:
        long = [s for s in a.option_strings if s.startswith("--")]
        assert all(s in text for s in long), f"{name}: {long} not in --help"


def test_controller_core_uses_no_wall_clock_sleep_or_print():
    """The controller's core (model, observers, NMPC, allocation, reference) never sleeps, never
    reads the calendar (time.time, datetime.now) and never prints: the flight loop and the daemon
    own time and output. (The solvers time themselves with perf_counter and the controller its
    parts with an injected CPU clock: measurements, never inputs of what is computed.)"""
    core = ["config.py", "allocation.py", "eso.py", "reference.py", "controller.py",
            "records.py", "model/dynamics.py", "nmpc/ocp.py", "nmpc/nlp.py", "nmpc/base.py",
            "nmpc/rti.py", "nmpc/feedback.py", "nmpc/factory.py", "predictor.py",
            "effectiveness.py", "diagnosis.py"]
    for name in core:
        text = (ROOT / "trq_offboard" / name).read_text(encoding="utf-8")
        for banned in ("time.time(", "sleep(", "datetime.now", "print("):
            assert banned not in text, f"trq_offboard/{name} uses {banned}"
