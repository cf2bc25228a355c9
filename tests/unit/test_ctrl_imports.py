"""The wire is the only coupling: trq_offboard never imports sil_vehicle (read from the source)."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "trq_offboard"


def test_trq_offboard_does_not_import_sil_vehicle():
    offenders = []
    for path in PKG.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            offenders += [f"{path}: {n}" for n in names if n.split(".")[0] == "sil_vehicle"]
    assert not offenders, offenders


def test_core_modules_use_no_wall_clock_or_sleep():
    core = ["config.py", "allocation.py", "eso.py", "reference.py", "controller.py",
            "records.py", "model/dynamics.py", "nmpc/ocp.py", "nmpc/nlp.py", "nmpc/base.py",
            "predictor.py", "effectiveness.py"]
    for name in core:
        text = (PKG / name).read_text(encoding="utf-8")
        for banned in ("time.time(", "sleep(", "datetime.now", "print("):
            assert banned not in text, f"{name} uses {banned}"
