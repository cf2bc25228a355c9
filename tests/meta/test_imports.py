"""The import graph of the project's modules, read from the source with `ast`:

- no import cycle among the modules (every import counts, inside functions too; only the
  `if TYPE_CHECKING:` blocks, which never run, are left out);
- the packages import each other only downwards, as docs/architecture.md states:

      trq_params, trq_wire   import no other package of the project
      sil_vehicle            trq_params, trq_wire
      trq_offboard           trq_params, trq_wire
      trq_lab                all of them (the experiment layer drives both daemons)

- nothing probes a solver, a controller or a reference with getattr/hasattr: what the flight
  loop and the controller call on them is declared (trq_offboard.nmpc.base.Solver, the loop's
  FlightController, trq_offboard.reference.FlightReference).

An import `from a.b import c` is an edge to the module a.b.c if c is a module, else to a.b;
importing a.b.c runs a/__init__.py too, but a package's __init__ re-exporting its modules is not
counted as a cycle (it is how a package names its public API).
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

from conftest import source_tree

ROOT = Path(__file__).resolve().parents[2]
# folder in the checkout -> import name
PACKAGES = {"params": "trq_params", "trq_wire": "trq_wire", "sil_vehicle": "sil_vehicle",
            "trq_offboard": "trq_offboard", "trq_lab": "trq_lab"}
ALLOWED = {"trq_params": set(), "trq_wire": set(),
           "sil_vehicle": {"trq_params", "trq_wire"},
           "trq_offboard": {"trq_params", "trq_wire"},
           "trq_lab": {"trq_params", "trq_wire", "sil_vehicle", "trq_offboard"}}
PROBES = ("solver", "controller", "ctl", "reference")


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the project by its dotted import name (a package by its own name)."""
    found = {}
    for folder, name in PACKAGES.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = [name, *path.relative_to(root / folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _type_checking_nodes(tree: ast.Module) -> set[int]:
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING",
                                                                   "typing.TYPE_CHECKING"):
            skipped.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return skipped


def imports_of(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The project's modules that module `name` (at `path`) imports."""
    tree = source_tree(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    skipped = _type_checking_nodes(tree)
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in known)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            for a in node.names:
                if f"{base}.{a.name}" in known:
                    found.add(f"{base}.{a.name}")
                elif base in known:
                    found.add(base)
    found.discard(name)
    return found


@functools.lru_cache(maxsize=4)
def graph(root: Path = ROOT) -> dict[str, set[str]]:
    known = modules(root)
    return {name: imports_of(name, path, known) for name, path in known.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm,
    iterative), and the modules that import themselves."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, successors = work[-1]
            advanced = False
            for w in successors:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                    advanced = True
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycle_finder_sees_cycles():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_import_finder_resolves_modules_and_packages(tmp_path):
    (tmp_path / "trq_wire").mkdir()
    (tmp_path / "trq_wire" / "__init__.py").write_text("")
    (tmp_path / "trq_wire" / "a.py").write_text(
        "from trq_wire import b\nfrom . import c\ndef f():\n    import trq_wire.d\n"
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from trq_wire import e\n")
    for other in "bcde":
        (tmp_path / "trq_wire" / f"{other}.py").write_text("")
    for folder in set(PACKAGES) - {"trq_wire"}:
        (tmp_path / folder).mkdir()
    edges = graph(tmp_path)
    assert edges["trq_wire.a"] == {"trq_wire.b", "trq_wire.c", "trq_wire.d"}


def test_no_import_cycle():
    found = cycles(graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_packages_import_only_downwards():
    offenders = [f"{m} imports {t}" for m, targets in graph().items() for t in sorted(targets)
                 if t.split(".")[0] != m.split(".")[0]
                 and t.split(".")[0] not in ALLOWED[m.split(".")[0]]]
    assert not offenders, offenders


def probes(tree: ast.Module) -> list[str]:
    """getattr/hasattr calls whose object is, or is reached through, a solver, a controller or
    a reference (any name along its dotted path: `self.solver.ocp` too)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id in ("getattr", "hasattr") and node.args:
            names = [n.lower() for n in re.findall(r"\w+", ast.unparse(node.args[0]))]
            if any(n.endswith(word) for n in names for word in PROBES):
                found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


def test_probe_finder_sees_probes():
    assert probes(ast.parse("getattr(self.solver, 'prepare', None)"))
    assert probes(ast.parse("getattr(reference, 'grid', None)"))
    assert probes(ast.parse("hasattr(self.solver.ocp, 'set_throttle_scale')"))
    assert probes(ast.parse("hasattr(ctl, 'prepare')"))
    assert probes(ast.parse("getattr(getattr(self.solver, 'ocp'), 'n_lag')"))
    assert not probes(ast.parse("getattr(args, 'seed')"))


def test_nothing_probes_a_solver_a_controller_or_a_reference():
    offenders = [f"{path.relative_to(ROOT)} {use}" for path in modules().values()
                 for use in probes(source_tree(path))]
    assert not offenders, offenders
