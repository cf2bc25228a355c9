"""The distribution's shape, read from the source tree and pyproject.toml (nothing is built):

- every package folder of the checkout is listed in [tool.setuptools] packages, so the wheel
  ships all of it (a forgotten sub-package imports in a checkout and fails once installed);
- every console script points at a `main` that exists;
- no module changes sys.path or PYTHONPATH: every import goes through the installed packages.
"""

from __future__ import annotations

import ast
import importlib
import tomllib
from pathlib import Path

import pytest

from conftest import source_tree

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
SOURCE_DIRS = ("sil_vehicle", "trq_offboard", "trq_lab", "params", "tests")


def package_folders() -> set[str]:
    mapping = {v: k for k, v in PYPROJECT["tool"]["setuptools"].get("package-dir", {}).items()}
    found = set()
    for top in ("sil_vehicle", "trq_offboard", "trq_lab", "params", "trq_wire"):
        if not (ROOT / top).is_dir():
            continue
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT).parts
            name = mapping.get(rel[0], rel[0])
            found.add(".".join((name, *rel[1:])))
    return found


def test_every_package_is_listed():
    listed = set(PYPROJECT["tool"]["setuptools"]["packages"])
    missing = package_folders() - listed
    assert not missing, f"pyproject.toml [tool.setuptools] packages lacks {sorted(missing)}"
    stale = listed - package_folders()
    assert not stale, f"pyproject.toml lists packages that do not exist: {sorted(stale)}"


@pytest.mark.parametrize("name, target", sorted(PYPROJECT["project"]["scripts"].items()))
def test_console_scripts_point_at_a_main(name, target):
    module, func = target.split(":")
    assert callable(getattr(importlib.import_module(module), func, None)), f"{name}: {target}"


def test_no_sys_path_manipulation():
    offenders = []
    for top in SOURCE_DIRS:
        for path in (ROOT / top).rglob("*.py"):
            if path.resolve() == Path(__file__).resolve():
                continue        # this file names what it looks for
            tree = source_tree(path)
            for node in ast.walk(tree):
                if isinstance(node, ast.Attribute) and node.attr == "path" and \
                        isinstance(node.value, ast.Name) and node.value.id == "sys":
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: sys.path")
                if isinstance(node, ast.Constant) and node.value == "PYTHON" "PATH":
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}: PYTHONPATH")
    assert not offenders, offenders


def test_the_readme_tables_are_the_result_files():
    """The README's generated blocks match docs/results/ (`trq-results --check`)."""
    from trq_lab.reporting import results

    assert results.main(["--check", "--readme", str(ROOT / "README.md"),
                         "--results", str(ROOT / "docs" / "results")]) == 0
