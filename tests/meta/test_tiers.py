"""The test tiers and layout, read from the source with ast:

- `pytest -m "not slow"` is the fast tier, so a module under tests/integration/ that starts
  processes (imports subprocess, or asks for the daemons fixtures) must be marked slow as a
  whole (`pytestmark = pytest.mark.slow`);
- the unit tests mirror the packages they test: tests/unit/PACKAGE/test_MODULE[_what].py, where
  MODULE is a module or sub-package of PACKAGE with its dots written as underscores
  (`test_nmpc_hpipm.py` tests trq_offboard/nmpc/hpipm.py, `test_link_wire.py`
  trq_offboard/link/wire.py), and the file imports PACKAGE."""

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


def test_the_checks_see_what_they_look_for():
    src = "import subprocess\n"
    assert starts_processes(ast.parse(src)) and not marked_slow(ast.parse(src))
    assert starts_processes(ast.parse("def test_a(daemons):\n    pass\n"))
    assert not starts_processes(ast.parse("def test_a(tmp_path):\n    pass\n"))
    assert marked_slow(ast.parse("import pytest\npytestmark = pytest.mark.slow\n"))
    assert marked_slow(ast.parse("pytestmark = [pytest.mark.x, pytest.mark.slow]\n"))


def module_names(folder: Path) -> set[str]:
    """The modules and sub-packages below `folder`, dots as underscores (`nmpc_hpipm`)."""
    names = set()
    for path in folder.rglob("*.py"):
        parts = path.relative_to(folder).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if parts and parts[-1] != "__main__":
            names.add("_".join(parts))
    return names


def names_a_module(test_name: str, modules: set[str]) -> bool:
    """Whether test_NAME names a module: NAME is one, or starts with one and '_'."""
    name = test_name.removeprefix("test_")
    return any(name == m or name.startswith(m + "_") for m in modules)


def test_the_layout_check_reads_names():
    modules = {"nmpc_hpipm", "nmpc", "loop", "link_wire"}
    assert names_a_module("test_nmpc_hpipm_fetch", modules)
    assert names_a_module("test_loop", modules) and names_a_module("test_link_wire", modules)
    assert not names_a_module("test_wire", modules) and not names_a_module("test_loops", modules)


def test_unit_tests_mirror_the_packages():
    loose = sorted(p.name for p in UNIT.glob("test_*.py"))
    assert not loose, f"unit tests outside a package's folder: {loose}"
    folders = sorted(p.name for p in UNIT.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert folders == sorted(PACKAGES), folders
    wrong = []
    for folder, source in PACKAGES.items():
        modules = module_names(ROOT / source)
        files = sorted((UNIT / folder).glob("test_*.py"))
        assert files, folder
        for path in files:
            imports = {n.split(".")[0] for node in ast.walk(ast.parse(path.read_text()))
                       for n in ([a.name for a in node.names] if isinstance(node, ast.Import)
                                 else [node.module or ""] if isinstance(node, ast.ImportFrom)
                                 else [])}
            if not names_a_module(path.stem, modules):
                wrong.append(f"{folder}/{path.name}: names no module of {folder}")
            if folder not in imports:
                wrong.append(f"{folder}/{path.name}: does not import {folder}")
    assert not wrong, wrong
