"""trq_lab/reporting/results.py's block 'profiles SCENARIO': one scenario flown under each
sensing profile (RESULTS/sensing/SCENARIO-PROFILE/metrics.json), a row per profile in the
profiles' order, per controller the RMSE after the fault, the max yaw error, the estimator's
own position RMSE and the diagnosis time, a crash said so; a result without its profile, or no
result at all, is an error naming the file or folder; the block sits beside the others."""

from __future__ import annotations

import json
from pathlib import Path

from trq_lab.reporting import results

RUN = {"controller": "trq_nmpc_eso", "vehicle": "trq", "crashed": False, "flight_s": 40.74,
       "rmse_pos_m": 0.00207, "max_pos_err_m": 0.01875, "rmse_pos_after_fault_m": 0.00228,
       "max_yaw_err_deg": 0.2758, "recovery_s": 0.0, "solve_ms_p50": 1.14,
       "solve_ms_p99": 3.77, "est_rmse_pos_m": None, "diagnosis_s": 0.02}

README = """# title
<!-- results:demo begin -->
<!-- results:demo end -->

The same per profile:

<!-- results:profiles demo begin -->
stale
<!-- results:profiles demo end -->
<!-- results:scenarios begin -->
<!-- results:scenarios end -->
tail
"""


def _write(tmp_path: Path, profiles=("gnss", "truth", "mocap")) -> tuple[Path, Path]:
    """(README, results folder): the demo scenario, another one, and demo per profile."""
    md = tmp_path / "README.md"
    md.write_text(README)
    res = tmp_path / "results"
    (res / "demo").mkdir(parents=True)
    (res / "demo" / "metrics.json").write_text(json.dumps({"scenario": "demo", "runs": [RUN]}))
    (res / "other").mkdir()
    (res / "other" / "metrics.json").write_text(json.dumps({"scenario": "other",
                                                            "runs": [RUN]}))
    for p in profiles:
        d = res / "sensing" / f"demo-{p}"
        d.mkdir(parents=True)
        est = None if p == "truth" else {"mocap": 0.0016, "gnss": 1.7123}[p]
        runs = [dict(RUN, est_rmse_pos_m=est),
                dict(RUN, controller="quad_nmpc", crashed=True, rmse_pos_after_fault_m=1.2787,
                     max_yaw_err_deg=178.81, diagnosis_s=None, est_rmse_pos_m=est)]
        (d / "metrics.json").write_text(json.dumps({"scenario": "demo", "sensing": p,
                                                    "runs": runs}))
    return md, res


def _main(md: Path, res: Path, *more: str) -> int:
    return results.main(["--readme", str(md), "--results", str(res), *more])


def test_the_block_a_row_per_profile(tmp_path):
    md, res = _write(tmp_path)
    assert _main(md, res) == 0
    text = md.read_text()
    block = text.split("<!-- results:profiles demo begin -->\n")[1].split(
        "<!-- results:profiles demo end -->")[0]
    assert "stale" not in block
    lines = block.splitlines()
    assert lines[0].startswith("| sensing; each cell: pos RMSE after fault m / max yaw err deg "
                               "/ estimate pos RMSE m")
    assert lines[0].endswith(" | `trq_nmpc_eso` | `quad_nmpc` |")
    assert lines[2] == ("| `truth` | 0.0023 / 0.28 / - / 0.02 | "
                        "1.2787 / 178.81 / - / - (crashed) |")
    assert lines[3].startswith("| `mocap` | 0.0023 / 0.28 / 0.0016 / 0.02 |")
    assert lines[4].startswith("| `gnss` | 0.0023 / 0.28 / 1.712 / 0.02 |")   # 4 digits
    assert len(lines) == 5                                   # the header, the rule, 3 rows
    # the other blocks as before: the sensing folder is not a scenario of the scenarios block
    scen = text.split("results:scenarios begin")[1]
    assert "`other`" in scen and "sensing" not in scen
    assert "The same per profile:\n\n<!-- results:profiles demo begin -->" in text
    assert _main(md, res, "--check") == 0


def test_a_result_without_its_profile_is_named(tmp_path, capsys):
    md, res = _write(tmp_path)
    path = res / "sensing" / "demo-mocap" / "metrics.json"
    doc = json.loads(path.read_text())
    del doc["sensing"]
    path.write_text(json.dumps(doc))
    assert _main(md, res) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "no 'sensing'" in err
    assert "stale" in md.read_text()                          # nothing written


def test_no_result_for_the_block_is_named(tmp_path, capsys):
    md, res = _write(tmp_path, profiles=())
    assert _main(md, res) == 2
    err = capsys.readouterr().err
    assert str(res / "sensing") in err and "results:profiles demo" in err


def test_the_marker_takes_a_kind_and_its_argument():
    text = ("<!-- results:profiles paper_fault50 begin -->\n"
            "<!-- results:profiles paper_fault50 end -->\n")
    assert results.blocks_in(text, "README") == ["profiles paper_fault50"]
