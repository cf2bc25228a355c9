"""The test tiers: `pytest -m "not slow"` is the fast tier, so a module under tests/integration/
that starts processes (imports subprocess, or asks for the daemons fixtures) must be marked
slow as a whole (`pytestmark = pytest.mark.slow`). Read from the source with ast."""

from __future__ import annotations

import ast

from conftest import ROOT

INTEGRATION = ROOT / "tests" / "integration"
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
