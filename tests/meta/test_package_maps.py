"""Every package's docstring holds its map, and the map is true: read from the source with `ast`.

A map is the block of lines of a package's __init__ docstring of the form

    name        what it is (continued on lines indented further)
    a, b        two modules described together
    sub/        a sub-package
    tick.c      a file that is not Python

The test asks both ways: each name a map gives exists in the package's folder, and each module,
sub-package and non-Python source file of the folder is named by the map (a package of a single
module needs no map). So a moved, renamed or deleted module cannot leave a stale map behind.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TOPS = ("params", "trq_wire", "sil_vehicle", "trq_offboard", "trq_lab")
# a map line: up to 8 spaces of indent, names separated by ", ", then two spaces or more and text
# that does not start an assignment or an argument list (a code example)
MAP_LINE = re.compile(r"^ {0,8}((?:[a-z_][a-z0-9_]*(?:/|\.c)?)(?:, [a-z_][a-z0-9_]*(?:/|\.c)?)*)"
                      r" {2,}(?![=(\-])\S")
SOURCE_SUFFIXES = {".py", ".c"}


def package_dirs() -> list[Path]:
    return sorted(init.parent for top in TOPS for init in (ROOT / top).rglob("__init__.py"))


def map_names(docstring: str) -> set[str]:
    names = set()
    for line in docstring.splitlines():
        m = MAP_LINE.match(line)
        if m:
            names.update(m.group(1).split(", "))
    return names


def entries(folder: Path) -> set[str]:
    """What a map must name: modules (without .py), sub-packages (with /), C sources."""
    found = set()
    for p in folder.iterdir():
        if p.is_dir() and (p / "__init__.py").is_file():
            found.add(p.name + "/")
        elif p.suffix == ".py" and p.name not in ("__init__.py", "__main__.py"):
            found.add(p.stem)
        elif p.suffix == ".c":
            found.add(p.name)
    return found


def test_map_parser():
    doc = ("Intro text, not a map.\n\n    config    frozen records\n    a, b      two\n"
           "    sub/      a package\n    tick.c    C\n    x = f(y)  code\n"
           "    u      = TRQ: [..]\n")
    assert map_names(doc) == {"config", "a", "b", "sub/", "tick.c"}


@pytest.mark.parametrize("folder", package_dirs(), ids=lambda p: str(p.relative_to(ROOT)))
def test_package_map_is_true(folder):
    doc = ast.get_docstring(ast.parse((folder / "__init__.py").read_text(encoding="utf-8")))
    assert doc, f"{folder.relative_to(ROOT)}/__init__.py has no docstring"
    have = entries(folder)
    named = map_names(doc)
    stale = sorted(named - have)
    assert not stale, f"{folder.relative_to(ROOT)}: the map names what does not exist: {stale}"
    if len(have) > 1:
        missing = sorted(have - named)
        assert not missing, f"{folder.relative_to(ROOT)}: the map leaves out {missing}"
