"""trq_lab/reporting/results.py: the README's marked blocks written from metrics.json files."""

from __future__ import annotations

import json
from pathlib import Path

from trq_lab.reporting import results

RUN = {"controller": "trq_nmpc_eso", "vehicle": "trq", "crashed": False, "flight_s": 40.74,
       "rmse_pos_m": 0.00207, "max_pos_err_m": 0.01875, "rmse_pos_after_fault_m": 0.00228,
       "max_yaw_err_deg": 0.2758, "recovery_s": 0.0, "solve_ms_p50": 1.14,
       "solve_ms_p99": 3.77}

README = """# title
intro
<!-- results:demo begin -->
stale
<!-- results:demo end -->
between
<!-- results:scenarios begin -->
<!-- results:scenarios end -->
tail
"""


def _write(tmp_path: Path, readme: str = README) -> tuple[Path, Path]:
    res = tmp_path / "results"
    for name, rmse in (("demo", 0.00228), ("other", 0.0128)):
        (res / name).mkdir(parents=True)
        run = dict(RUN, rmse_pos_after_fault_m=rmse)
        (res / name / "metrics.json").write_text(json.dumps({"scenario": name, "runs": [run]}))
    md = tmp_path / "README.md"
    md.write_text(readme)
    return md, res


def test_blocks_written(tmp_path):
    md, res = _write(tmp_path)
    assert results.main(["--readme", str(md), "--results", str(res)]) == 0
    text = md.read_text()
    assert "stale" not in text
    row = "| trq_nmpc_eso | trq | False | 40.7 | 0.002 | 0.019 | 0.0023 | 0.28 | 0.00 | 1.1 | 3.8 |"
    assert row in text
    assert "| [`other`](results/other/metrics.json) | - | 0.0128 / 0.28 | not recorded |" in text
    assert "`demo`" not in text.split("results:scenarios begin")[1]   # it has its own block
    assert text.startswith("# title\nintro\n<!-- results:demo begin -->\n")
    assert "<!-- results:demo end -->\nbetween\n" in text
    assert text.endswith("<!-- results:scenarios end -->\ntail\n")


def test_check_fails_when_stale_and_passes_after_writing(tmp_path, capsys):
    md, res = _write(tmp_path)
    before = md.read_text()
    assert results.main(["--readme", str(md), "--results", str(res), "--check"]) == 1
    assert md.read_text() == before                       # --check writes nothing
    assert "out of date" in capsys.readouterr().err
    assert results.main(["--readme", str(md), "--results", str(res)]) == 0
    assert results.main(["--readme", str(md), "--results", str(res), "--check"]) == 0


def test_targets_from_failures_and_report(tmp_path):
    md, res = _write(tmp_path)
    doc = json.loads((res / "other" / "metrics.json").read_text())
    doc["failures"] = ["trq_nmpc_eso: rmse_pos_after_fault_m = 0.012849218 (target <= 0.0046)"]
    (res / "other" / "metrics.json").write_text(json.dumps(doc))
    (res / "demo" / "report.md").write_text("# r\n\n## Targets\n\n- `x`: crashed = False\n")
    assert results.main(["--readme", str(md), "--results", str(res)]) == 0
    text = md.read_text()
    assert "Targets of `demo`: met." in text
    assert "missed: trq_nmpc_eso: rmse_pos_after_fault_m = 0.01285 (target <= 0.0046)" in text


def test_missing_result_file_is_named(tmp_path, capsys):
    md, res = _write(tmp_path)
    (res / "demo" / "metrics.json").unlink()
    assert results.main(["--readme", str(md), "--results", str(res)]) == 2
    err = capsys.readouterr().err
    assert str(res / "demo" / "metrics.json") in err and "no such result file" in err
    assert "stale" in md.read_text()                     # nothing written


def test_missing_marker_is_named(tmp_path, capsys):
    md, res = _write(tmp_path, README.replace("<!-- results:demo end -->\n", ""))
    assert results.main(["--readme", str(md), "--results", str(res)]) == 2
    assert "'results:demo end' missing" in capsys.readouterr().err
    md.write_text("no markers here\n")
    assert results.main(["--readme", str(md), "--results", str(res)]) == 2
    assert "no '<!-- results:NAME begin -->' marker" in capsys.readouterr().err
    md.write_text(README)
    assert results.main(["--readme", str(md), "--results", str(res),
                         "--require", "paper_fault50"]) == 2
    assert "'<!-- results:paper_fault50 begin -->' missing" in capsys.readouterr().err


def test_missing_readme_is_named(tmp_path, capsys):
    assert results.main(["--readme", str(tmp_path / "nope.md")]) == 2
    assert "nope.md: no such file" in capsys.readouterr().err


def test_imports_only_the_standard_library():
    """trq-results runs without the simulator or the controller: its module, the formatter and
    the packages above them import the standard library (and the formatter) only."""
    import ast
    lab = Path(results.__file__).resolve().parents[1]
    stdlib = {"__future__", "argparse", "json", "math", "numbers", "os", "re", "sys", "pathlib"}
    for path in (lab / "reporting" / "results.py", lab / "reporting" / "fmt.py",
                 lab / "reporting" / "__init__.py", lab / "__init__.py"):
        tree = ast.parse(path.read_text())
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        assert {n.split(".")[0] for n in names} - {"trq_lab"} <= stdlib, path
        assert names & {"trq_lab", "trq_lab.reporting"} == set(), path
        assert {n for n in names if n.startswith("trq_lab")} <= {"trq_lab.reporting.fmt"}, path
        assert "sys.path" not in path.read_text()
