"""The test tiers and layout, read from the source with ast:

- `pytest -m "not slow"` is the fast tier, so a module under tests/integration/ that starts
  processes (imports subprocess, or asks for the daemons fixtures) must be marked slow as a
  whole (`pytestmark = pytest.mark.slow`);
- the unit tests mirror the packages they test: tests/unit/PACKAGE/test_MODULE[_what].py, where
  MODULE is a module or sub-package of PACKAGE with its dots written as underscores
  (`test_nmpc_hpipm.py` tests trq_offboard/nmpc/hpipm.py, `test_link_wire.py`
  trq_offboard/link/wire.py), and the file imports that module."""

from __future__ import annotations

import ast
from pathlib import Path

from conftest import ROOT

INTEGRATION = ROOT / "tests" / "integration"
UNIT = ROOT / "tests" / "unit"
# the folder of each package's unit tests -> the package's folder in the checkout
PACKAGES = {"sil_vehicle": "sil_vehicle", "trq_offboard": "trq_offboard",
            "trq_wire": "trq_wire", "trq_lab": "trq_lab", "trq_params": "params"}
PROCESS_FIXTURES = {"daemons", "module_daemons"}


def starts_processes(tree: ast.Module) -> bool:
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(a.name == "subprocess" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.module == "subprocess":
            return True
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if PROCESS_FIXTURES & {a.arg for a in node.args.args}:
                return True
    return False


def marked_slow(tree: ast.Module) -> bool:
    """A module-level `pytestmark` that is, or lists, pytest.mark.slow."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "pytestmark" for t in node.targets):
            marks = node.value.elts if isinstance(node.value, (ast.List, ast.Tuple)) \
                else [node.value]
            return any(ast.unparse(m) == "pytest.mark.slow" for m in marks)
    return False


def test_integration_modules_that_start_processes_are_marked_slow():
    modules = sorted(INTEGRATION.glob("test_*.py"))
    assert len(modules) >= 5, modules
    unmarked = []
    for path in modules:
        tree = ast.parse(path.read_text(), str(path))
        if starts_processes(tree) and not marked_slow(tree):
            unmarked.append(path.name)
    assert not unmarked, f"start processes but are not marked slow as a module: {unmarked}"


def literal_example_counts(tree: ast.Module) -> list[int]:
    """The lines where a property test's max_examples is a number rather than conftest's
    `examples(n)` (which the fast tier scales down)."""
    return [node.lineno for node in ast.walk(tree) if isinstance(node, ast.keyword)
            and node.arg == "max_examples" and isinstance(node.value, ast.Constant)]


def test_property_tests_take_their_example_counts_through_the_tier():
    fixed = {str(path.relative_to(ROOT)): lines for path in sorted((ROOT / "tests").rglob("*.py"))
             if (lines := literal_example_counts(ast.parse(path.read_text(), str(path))))}
    assert not fixed, f"max_examples not through conftest.examples: {fixed}"
    assert literal_example_counts(ast.parse("settings(max_examples=10)")) == [1]
    assert not literal_example_counts(ast.parse("settings(max_examples=examples(10))"))


def test_the_checks_see_what_they_look_for():
    src = "import subprocess\n"
    assert starts_processes(ast.parse(src)) and not marked_slow(ast.parse(src))
    assert starts_processes(ast.parse("def test_a(daemons):\n    pass\n"))
    assert not starts_processes(ast.parse("def test_a(tmp_path):\n    pass\n"))
    assert marked_slow(ast.parse("import pytest\npytestmark = pytest.mark.slow\n"))
    assert marked_slow(ast.parse("pytestmark = [pytest.mark.x, pytest.mark.slow]\n"))


def module_names(folder: Path) -> dict[str, str]:
    """The modules and sub-packages below `folder`: their names with dots as underscores
    (`nmpc_hpipm`) -> their dotted paths (`nmpc.hpipm`)."""
    names = {}
    for path in folder.rglob("*.py"):
        parts = path.relative_to(folder).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts and parts[-1] != "__main__":
            names["_".join(parts)] = ".".join(parts)
    return names


def named_modules(test_name: str, modules: dict[str, str]) -> list[str]:
    """The dotted paths of the modules test_NAME can name: NAME is one, or starts with one and
    '_' (`test_nmpc_hpipm_fetch` can name nmpc.hpipm_fetch or nmpc.hpipm or nmpc)."""
    name = test_name.removeprefix("test_")
    return [dotted for flat, dotted in modules.items()
            if name == flat or name.startswith(flat + "_")]


def imported(tree: ast.Module) -> set[str]:
    """Every dotted name an import reaches: `from a.b import c` gives a.b and a.b.c."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
    return found


def test_the_layout_check_reads_names():
    modules = {"nmpc_hpipm": "nmpc.hpipm", "nmpc": "nmpc", "loop": "loop", "link_wire": "link.wire"}
    assert set(named_modules("test_nmpc_hpipm_fetch", modules)) == {"nmpc.hpipm", "nmpc"}
    assert named_modules("test_loop", modules) == ["loop"]
    assert named_modules("test_link_wire", modules) == ["link.wire"]
    assert not named_modules("test_wire", modules) and not named_modules("test_loops", modules)
    tree = ast.parse("from trq_offboard.nmpc import hpipm\nimport trq_offboard.loop\n")
    assert {"trq_offboard.nmpc.hpipm", "trq_offboard.loop"} <= imported(tree)


def test_unit_tests_mirror_the_packages():
    loose = sorted(p.name for p in UNIT.glob("test_*.py"))
    assert not loose, f"unit tests outside a package's folder: {loose}"
    folders = sorted(p.name for p in UNIT.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert folders == sorted(PACKAGES), folders
    wrong = []
    for folder, source in PACKAGES.items():
        modules = module_names(ROOT / source)
        files = sorted((UNIT / folder).rglob("test_*.py"))
        assert files, folder
        for path in files:
            candidates = named_modules(path.stem, modules)
            if not candidates:
                wrong.append(f"{folder}/{path.name}: names no module of {folder}")
                continue
            reached = imported(ast.parse(path.read_text()))
            if not any(f"{folder}.{m}" in reached for m in candidates):
                wrong.append(f"{folder}/{path.name}: imports none of "
                             + ", ".join(f"{folder}.{m}" for m in candidates))
    assert not wrong, wrong
